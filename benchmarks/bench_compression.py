"""What a lossy video costs the attitude: the same rendered frames tracked from PNG files and from
an mp4 (OpenCV's ``mp4v`` codec, the one ``pmspm track`` writes its annotated video with).

Renders ``--frames`` frames (analytic renderer, sensor noise on) of an 8° cone whose azimuth turns
at 1.5 rad/s while the rotor spins at 0.6 rad/s about its shaft, at the camera's 36 frames/s;
writes them as a PNG folder and an mp4; runs ``pmspm track`` (``experiments.track.run_track``,
``kcf_gk``, the least-squares back end) on both; and records the geodesic attitude error against
the rendered attitudes (frames with both markers measured; frame k against truth k) and the
RMS error of each Z-Y-Z angle, in deg, with the files' sizes.

Run: python benchmarks/bench_compression.py [--frames 200] [--quick]
(``--quick``: 20 frames, to check that it runs.)
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np
from _report import record

from experiments.sources import open_source
from experiments.track import run_track
from experiments.track_accuracy import attitude_accuracy
from observer.trackers import make_pair_tracker
from plant import attitude
from plant.params import PlantParams
from plant.render_analytic import AnalyticRenderer


def motion(t: float):
    """The rendered attitude at time t (s): an 8° cone at 1.5 rad/s with a 0.6 rad/s spin."""
    g = 1.5 * t
    return attitude.from_zyz(0.6 * t - g, np.deg2rad(8.0), g)


def angle_rms_deg(table, q_true) -> dict[str, float]:
    """RMS error (deg) of spin, tilt and yaw over the frames with both markers measured."""
    rows = table[table["attitude_source"] == "both measured"]
    truth = np.rad2deg(attitude.to_zyz_array(np.asarray(q_true)[rows["frame_index"]]))
    est = rows[["spin_deg", "tilt_deg", "yaw_deg"]].to_numpy()
    d = (est - truth + 180.0) % 360.0 - 180.0
    return {f"{name}_rms_deg": float(np.sqrt(np.nanmean(d[:, i] ** 2)))
            for i, name in enumerate(("spin", "tilt", "yaw"))}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    n = 20 if args.quick else args.frames
    p = PlantParams()
    renderer = AnalyticRenderer(p, seed=0)
    fps = p.camera.frame_rate_hz
    q_true, figures = [], {"frames": float(n)}
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        (d / "png").mkdir()
        w, h = renderer.width, renderer.height
        writer = cv2.VideoWriter(str(d / "rec.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
        for k in range(n):
            q = motion(k / fps)
            q_true.append(q)
            bgr = cv2.cvtColor(renderer.render(q, t_exposure=k / fps).image, cv2.COLOR_RGB2BGR)
            writer.write(bgr)
            cv2.imwrite(str(d / "png" / f"{k:04d}.png"), bgr)
        writer.release()
        figures["mp4_size_MB"] = (d / "rec.mp4").stat().st_size / 1e6
        figures["png_size_MB"] = sum(f.stat().st_size for f in (d / "png").iterdir()) / 1e6
        for kind, src in (("png", d / "png"), ("mp4", d / "rec.mp4")):
            out = run_track(open_source(str(src)), make_pair_tracker("kcf_gk", p),
                            d / f"run_{kind}", "auto", write_video=False)
            acc = attitude_accuracy(out.table, q_true)
            figures |= {f"{kind}_{k}": v for k, v in acc.items()}
            figures |= {f"{kind}_{k}": v for k, v in angle_rms_deg(out.table, q_true).items()}
    record("bench_compression", "Compression cost: attitude from mp4 vs PNG frames", figures,
           notes="Geodesic attitude error (deg) of `pmspm track` (kcf_gk, least squares) "
           "against the rendered attitudes, frames with both markers measured; the RMS of each "
           "Z-Y-Z angle wraps differences to ±180°.")


if __name__ == "__main__":
    main()
