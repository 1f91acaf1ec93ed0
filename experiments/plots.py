"""Figures shared by the notebooks and reports: closed-loop runs side by side and a strip of
what the camera saw."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from latency.loop import LoopResult
from plant.camera import sensor_to_image


def plot_runs_side_by_side(results: dict[str, LoopResult]) -> Figure:
    """Tilt against its reference, geodesic error (deg) and delivered torque (N·m) over time,
    one column per run."""
    fig, axes = plt.subplots(3, len(results), figsize=(5.5 * len(results), 7), sharex=True,
                             sharey="row", squeeze=False)
    for j, (name, r) in enumerate(results.items()):
        s = r.steps
        axes[0, j].plot(s.t_s, s.tilt_deg, label="tilt")
        axes[0, j].plot(s.t_s, s.ref_tilt_deg, "k--", lw=0.8, label="reference")
        axes[1, j].plot(s.t_s, s.error_deg)
        for c in "xyz":
            axes[2, j].plot(s.t_s, s[f"torque_delivered_{c}_Nm"], label=c)
        axes[0, j].set_title(name)
        axes[2, j].set_xlabel("time (s)")
    axes[0, 0].set_ylabel("tilt (deg)")
    axes[1, 0].set_ylabel("geodesic error (deg)")
    axes[2, 0].set_ylabel("torque (N·m)")
    axes[0, 0].legend()
    axes[2, 0].legend()
    for ax in axes.flat:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def frame_strip(results: dict[str, LoopResult], renderer, n_frames: int = 6) -> Figure:
    """Frames re-rendered at ``n_frames`` times of each run (rows), with the true marker
    centres marked; ``renderer`` is an ``AnalyticRenderer`` or ``MujocoRenderer``."""
    duration = max(float(r.steps.t_s.iloc[-1]) for r in results.values())
    times = np.linspace(0.0, duration, n_frames + 2)[1:-1]
    fig, axes = plt.subplots(len(results), len(times), squeeze=False,
                             figsize=(2.6 * len(times), 2.4 * len(results)))
    for i, (name, r) in enumerate(results.items()):
        s = r.steps
        for j, t in enumerate(times):
            row = s.iloc[int(np.argmin(np.abs(s.t_s.to_numpy() - t)))]
            q = row[["qw", "qx", "qy", "qz"]].to_numpy(float)
            omega = row[["omega_x_rad_s", "omega_y_rad_s", "omega_z_rad_s"]].to_numpy(float)
            frame = renderer.render(q, t_exposure=float(row.t_s), omega=omega)
            uv = sensor_to_image(frame.marker_px, frame.binning)
            ax = axes[i, j]
            ax.imshow(frame.image)
            ax.plot(uv[:, 0], uv[:, 1], "c+", ms=8)
            ax.set_title(f"{row.t_s:.2f} s, tilt {row.tilt_deg:.2f}°", fontsize=8)
            ax.set_xticks([])
            ax.set_yticks([])
        axes[i, 0].set_ylabel(name, fontsize=8)
    fig.tight_layout()
    return fig
