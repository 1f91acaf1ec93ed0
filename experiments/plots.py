"""Figures shared by the notebooks and reports: closed-loop runs side by side and a strip of
what the camera saw. Each function builds a new ``matplotlib.figure.Figure`` (no pyplot state,
no backend chosen), saves it to ``path`` if given and returns it."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from latency.loop_config import LoopResult
from plant.camera import sensor_to_image

if TYPE_CHECKING:
    from plant.render_analytic import AnalyticRenderer
    from plant.render_mujoco import MujocoRenderer


def _finish(fig: Figure, path: Path | str | None) -> Figure:
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


def plot_runs_side_by_side(results: dict[str, LoopResult],
                           path: Path | str | None = None) -> Figure:
    """Tilt against its reference, geodesic error (deg) and delivered torque (N·m) over time,
    one column per run."""
    fig = Figure(figsize=(5.5 * len(results), 7), layout="tight")
    axes = fig.subplots(3, len(results), sharex=True, sharey="row", squeeze=False)
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
    return _finish(fig, path)


def strip_rows(results: dict[str, LoopResult], n_frames: int) -> dict[str, pd.DataFrame]:
    """Per run, the logged rows nearest to ``n_frames`` times spread evenly inside the longest
    run (its ends excluded)."""
    duration = max(float(r.steps.t_s.iloc[-1]) for r in results.values())
    times = np.linspace(0.0, duration, n_frames + 2)[1:-1]
    out = {}
    for name, r in results.items():
        t = r.steps.t_s.to_numpy()
        out[name] = r.steps.iloc[[int(np.argmin(np.abs(t - ti))) for ti in times]]
    return out


def frame_strip(results: dict[str, LoopResult], renderer: AnalyticRenderer | MujocoRenderer,
                n_frames: int = 6, path: Path | str | None = None) -> Figure:
    """Frames re-rendered at ``n_frames`` times of each run (rows, ``strip_rows``), with the
    true marker centres marked; ``renderer`` is an ``AnalyticRenderer`` or ``MujocoRenderer``."""
    rows = strip_rows(results, n_frames)
    fig = Figure(figsize=(2.6 * n_frames, 2.4 * len(rows)), layout="tight")
    axes = fig.subplots(len(rows), n_frames, squeeze=False)
    for i, (name, picked) in enumerate(rows.items()):
        for j, (_, row) in enumerate(picked.iterrows()):
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
    return _finish(fig, path)
