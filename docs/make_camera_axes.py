"""Draw ``docs/camera_axes.png``: the default camera's frame at rest with the image axes, the stator
axes and the directions in which spin and tilt move the markers (docs/real_data.md).

Run from the repository root: ``python docs/make_camera_axes.py``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from plant import attitude
from plant.camera import sensor_to_image
from plant.params import PlantParams
from plant.render_analytic import AnalyticRenderer

OUT = Path(__file__).resolve().parent / "camera_axes.png"


def main() -> None:
    p = PlantParams()
    renderer = AnalyticRenderer(p, seed=0)
    rest = renderer.render(attitude.from_zyz(0.0, 0.0, 0.0))
    b = rest.binning
    centres = sensor_to_image(rest.marker_px, b)
    tilted = sensor_to_image(renderer.render(attitude.from_zyz(0.0, np.deg2rad(10.0),
                                                               0.0)).marker_px, b)
    spun = sensor_to_image(renderer.render(attitude.from_zyz(np.deg2rad(30.0), 0.0,
                                                             0.0)).marker_px, b)
    fig = Figure(figsize=(7.5, 6.4))
    ax = fig.subplots()
    ax.imshow(rest.image)
    h, w = rest.image.shape[:2]
    arrow = {"color": "white", "width": 2.5, "head_width": 10, "length_includes_head": True}
    ax.arrow(8, 8, 90, 0, **arrow)
    ax.arrow(8, 8, 0, 90, **arrow)
    ax.text(104, 12, "u (image px) = stator X", color="white", va="center")
    ax.text(12, 112, "v = stator Y", color="white", va="top")
    ax.text(12, 140, "stator Z points into the picture\n(the camera looks up, +Z)",
            color="white", va="top", fontsize=8)
    for (u, v), name in zip(centres, ("red (main)", "yellow (aux)"), strict=True):
        ax.annotate(f"{name}\n({u:.0f}, {v:.0f})", (u, v), (u - 30, v + 95), color="white",
                    fontsize=8, arrowprops={"color": "white", "arrowstyle": "-"})
    mid, mid_t = centres.mean(axis=0), tilted.mean(axis=0)
    ax.annotate("", mid_t, mid, arrowprops={"color": "cyan", "arrowstyle": "->", "lw": 2})
    ax.text(mid[0], mid[1] - 60, "tilt β = 10° at yaw γ = 0:\nthe markers move to -u",
            color="cyan", fontsize=8, ha="center")
    for k in range(2):
        ax.annotate("", spun[k], centres[k],
                    arrowprops={"color": "orange", "arrowstyle": "->", "lw": 2,
                                "connectionstyle": "arc3,rad=0.2"})
    ax.text(spun[1][0] + 30, spun[1][1] - 10, "spin α = +30°:\nu turns toward v\n(clockwise "
            "on screen)", color="orange", fontsize=8, va="center")
    dist = float(np.hypot(*(centres[1] - centres[0])))
    ax.set_title(f"default camera at rest ({w} x {h} px, binning {b}): markers "
                 f"{dist:.0f} px apart", fontsize=10)
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    fig.tight_layout()
    fig.savefig(OUT, dpi=90)
    print(OUT)


if __name__ == "__main__":
    main()
