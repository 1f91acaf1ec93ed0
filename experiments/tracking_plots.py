"""Figures of the tracking benchmark (``experiments.tracking_bench``): precision curves like
seed 000 Figures 11, 12a/c and 14a/c, and the centre error over the frames like 12b/d and 14b/d.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

from experiments.sequences import TrackingSequence
from experiments.tracking_metrics import PRECISION_PX, THRESHOLDS_PX
from experiments.tracking_runs import MARKER_NAMES, TrackRun, pooled_precision


def plot_precision_curves(
    runs: Sequence[TrackRun], seqs: Sequence[TrackingSequence], case: str
) -> Figure:
    """Precision curves of every tracker in one case, main and auxiliary marker side by side
    (seed Figure 11; 12a/c and 14a/c for the occlusion and blur cases)."""
    fig = Figure(figsize=(10, 4))
    axes = fig.subplots(1, 2, sharey=True)
    for name in dict.fromkeys(r.tracker for r in runs if r.case == case):
        curves = pooled_precision(runs, seqs, name, case)
        for m, ax in enumerate(axes):
            p20 = curves[m][int(PRECISION_PX)]
            ax.plot(THRESHOLDS_PX, curves[m], label=f"{name} [{p20:.3f}]")
    for m, ax in enumerate(axes):
        ax.axvline(PRECISION_PX, color="0.6", lw=0.8, ls="--")
        ax.set_title(f"{('main (red)', 'auxiliary (yellow)')[m]} marker, {case}")
        ax.set_xlabel("centre location error threshold (sensor px)")
        ax.set_xlim(0, THRESHOLDS_PX[-1])
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right", fontsize=8)
    axes[0].set_ylabel("precision")
    fig.tight_layout()
    return fig


def plot_error_curves(
    runs: Sequence[TrackRun], seq: TrackingSequence, ymax_px: float = 100.0
) -> Figure:
    """Centre error over frames of every tracker on one sequence, main and auxiliary marker
    (seed Figures 12b/d, 14b/d); disturbed frames shaded; errors beyond ``ymax_px`` leave the
    chart as in the seed's figures."""
    fig = Figure(figsize=(10, 6))
    axes = fig.subplots(2, 1, sharex=True)
    frames = np.arange(seq.n_frames)
    for r in runs:
        if r.sequence != seq.name:
            continue
        e = r.errors(seq)
        for m, ax in enumerate(axes):
            # a frame without an estimate (inf) is drawn off the chart; frame 0 (NaN) is not
            ax.plot(frames, np.where(np.isinf(e[:, m]), 10 * ymax_px, e[:, m]), lw=1,
                    label=r.tracker)
    for m, ax in enumerate(axes):
        for flags, colour, label in ((seq.occluded, "0.3", "occluded"),
                                     (seq.blurred, "tab:orange", "blurred")):
            idx = np.flatnonzero(flags)
            if idx.size:
                ax.axvspan(idx.min() - 0.5, idx.max() + 0.5, color=colour, alpha=0.15,
                           label=label)
        ax.axhline(PRECISION_PX, color="0.6", lw=0.8, ls="--")
        ax.set_ylim(0, ymax_px)
        ax.set_ylabel(f"{MARKER_NAMES[m]} error (sensor px)")
        ax.grid(alpha=0.3)
    axes[0].set_title(f"centre location error, {seq.name}")
    axes[0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[1].set_xlabel("frame")
    fig.tight_layout()
    return fig
