"""The study's figures (``experiments.study``): each function builds a new
``matplotlib.figure.Figure`` (no pyplot state, no backend chosen), saves it to ``path`` and
returns it. Delay marks carry their values; legends sit outside the axes; 95 % intervals are
drawn as bands; points that are not drawn (failed runs, runs that never settle) are marked."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.figure import Figure

#: Line colour and label of each controller variant of the sweep.
CONTROLLER_STYLE: dict[str, tuple[str, str]] = {
    "pid": ("C0", "PID"),
    "pid_noff": ("C9", "PID, no reference feedforward"),
    "pid_friction": ("C2", "PID + friction compensation"),
    "mpc": ("C1", "MPC"),
    "mpc_nopreview": ("C3", "MPC, no reference preview"),
}
_GRID_MS = np.linspace(0, 60, 61).round(6)


def mark_delays(ax: Axes, marks: dict[str, float], zero_line: bool = True) -> None:
    """Dotted vertical lines at the named delays (ms), each labelled with its name and value.

    Labels of marks closer than 6 % of the axis width are staggered in height so they do not
    overlap; a mark beyond the axis is named at the edge with an arrow instead of a line."""
    lo, hi = ax.get_xlim()
    span = max(hi - lo, 1e-9)
    inside = {k: v for k, v in marks.items() if lo <= v <= hi}
    for edge, arrow, beyond in ((lo, "←", lambda v: v < lo), (hi, "→", lambda v: v > hi)):
        names = [f"{k} {v:.2f} ms" for k, v in sorted(marks.items(), key=lambda kv: kv[1])
                 if beyond(v)]
        if names:  # one label at the edge for the marks off the axis
            ax.text(edge, 0.02, f" {', '.join(names)} {arrow}", rotation=90, fontsize=7,
                    va="bottom", ha="right" if edge == hi else "left",
                    transform=ax.get_xaxis_transform(), color="0.25")
    level, last = 0, -np.inf
    for name, ms in sorted(inside.items(), key=lambda kv: kv[1]):
        level = level + 1 if (ms - last) / span < 0.06 else 0
        last = ms
        ax.axvline(ms, color="k", lw=0.8, ls=":")
        ax.text(ms, 0.02 + 0.34 * (level % 3), f" {name} {ms:.2f} ms", rotation=90, fontsize=7,
                va="bottom", ha="right", transform=ax.get_xaxis_transform(), color="0.25")
    ax.set_xlim(lo, hi)
    ax.grid(alpha=0.3)
    if zero_line:
        ax.axhline(0, color="grey", lw=0.5)


def _save(fig: Figure, path: Path) -> Figure:
    fig.savefig(path, dpi=110)
    return fig


def _outside_legend(ax: Axes) -> None:
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, borderaxespad=0.0)


def plot_margins(df: pd.DataFrame, marks: dict[str, float], path: Path) -> Figure:
    """PID phase margin, delay margin and headroom, jitter margin against vision delay."""
    fig = Figure(figsize=(10, 9), layout="constrained")
    ax = fig.subplots(3, 1, sharex=True)
    grid = df[df.vision_delay_ms.round(6).isin(_GRID_MS)]
    for mode, style in (("sequential", "-"), ("pipelined", "--")):
        g = grid[grid.observer == mode]
        ax[0].plot(g.vision_delay_ms, g.phase_margin_deg, style, color="C0",
                   label=f"{mode} observer")
        ax[1].plot(g.vision_delay_ms, 1e3 * g.delay_margin_s, style, color="C0",
                   label=f"delay margin, {mode} (update period fixed)")
        ax[1].plot(g.vision_delay_ms, 1e3 * g.headroom_s, style, color="C3",
                   label=f"headroom, {mode} (delay scanned through the pipeline)")
        ax[2].plot(g.vision_delay_ms, 1e3 * g.jitter_margin_s, style, color="C0",
                   label=f"{mode} observer")
    for a in ax:
        a.set_xlim(0, 60)
        mark_delays(a, marks)
        _outside_legend(a)
    ax[0].set_ylabel("phase margin (deg)")
    ax[1].set_ylabel("extra delay (ms)")
    ax[2].set_ylabel("jitter margin (ms)")
    ax[2].set_xlabel("vision delay = observer latency (ms); curves stop where the loop is unstable")
    fig.suptitle("Per-axis PID attitude loop as it runs: margins against vision delay")
    return _save(fig, path)


def plot_pm_pid_vs_mpc(
    pid: pd.DataFrame, mpc: pd.DataFrame, marks: dict[str, float], path: Path
) -> Figure:
    """Phase and delay margin against vision delay for the PID and the MPC's linearised law."""
    fig = Figure(figsize=(10, 7), layout="constrained")
    ax = fig.subplots(2, 1, sharex=True)
    for mode, style in (("sequential", "-"), ("pipelined", "--")):
        g = pid[(pid.observer == mode) & pid.vision_delay_ms.round(6).isin(_GRID_MS)]
        ax[0].plot(g.vision_delay_ms, g.phase_margin_deg, style, color="C0", label=f"PID, {mode}")
        ax[1].plot(g.vision_delay_ms, 1e3 * g.delay_margin_s, style, color="C0",
                   label=f"PID, {mode}")
        for aware, colour in ((True, "C1"), (False, "C2")):
            h = mpc[(mpc.observer == mode) & (mpc.delay_aware == aware)
                    & mpc.vision_delay_ms.round(6).isin(_GRID_MS)]
            tag = "MPC" if aware else "MPC without delay compensation"
            ax[0].plot(h.vision_delay_ms, h.phase_margin_deg, style, color=colour,
                       label=f"{tag}, {mode}")
            ax[1].plot(h.vision_delay_ms, 1e3 * h.delay_margin_s, style, color=colour,
                       label=f"{tag}, {mode}")
    for a in ax:
        a.set_xlim(0, 60)
        mark_delays(a, marks)
    _outside_legend(ax[0])
    ax[0].set_ylabel("critical phase margin (deg)")
    ax[1].set_ylabel("delay margin (ms)")
    ax[1].set_xlabel("vision delay (ms); curves stop where the loop is unstable")
    fig.suptitle("PID and MPC (linearised law): margins against vision delay")
    return _save(fig, path)


#: Line style and label of each tracker's curves in the sweep's plots.
TRACKER_STYLE = {"gk_transt": ("o-", "GK-TransT"), "dual_transt": ("s--", "dual TransT"),
                 "kcf_gk": ("^:", "KCF+GK"), "k2cf": ("v-.", "K²CF")}


def _band(ax: Axes, g: pd.DataFrame, col: str, colour: str, label: str, scale: float = 1.0,
          marker: str = "o-") -> None:
    """Mean line with its 95 % band (columns ``col``, ``col_lo``, ``col_hi``)."""
    x = g.vision_delay_ms.to_numpy()
    ax.plot(x, scale * g[col], marker, color=colour, ms=3, label=label)
    if f"{col}_lo" in g:
        ax.fill_between(x, scale * g[f"{col}_lo"], scale * g[f"{col}_hi"], color=colour,
                        alpha=0.2, lw=0)


def _mark_excluded(ax: Axes, x: np.ndarray, colour: str, label: str) -> None:
    """Crosses at the bottom of the axes where points are missing (not drawn as zero)."""
    if len(x):
        ax.plot(x, np.full(len(x), 0.03), "x", color=colour, ms=7, mew=1.5,
                transform=ax.get_xaxis_transform(), label=label)


def _mark_onset(ax: Axes, onset_ms: float, colour: str, label: str) -> None:
    """The delay (ms) from which the analysis says the loop is unstable: a solid line and a
    shade beyond it (nothing if the analysis found no onset)."""
    if np.isfinite(onset_ms):
        lo, hi = ax.get_xlim()
        if onset_ms >= hi:  # beyond the sweep's delays: widen the axis to show it
            hi = onset_ms + 0.05 * (hi - lo)
            ax.set_xlim(lo, hi)
        ax.axvspan(onset_ms, hi, color=colour, alpha=0.08, lw=0)
        ax.axvline(onset_ms, color=colour, lw=2,
                   label=f"{label}: analysis unstable from {onset_ms:.1f} ms")


def plot_sweep(
    intervals: pd.DataFrame, failed: pd.DataFrame, marks: dict[str, float], path: Path,
    onsets_ms: dict[str, float] | None = None,
) -> Figure:
    """RMS error, lost frames and probability of loss of control against vision delay on the
    random references, with 95 % intervals over seeds, one colour per peak rate and one line
    style per tracker (its own loss model); runs that failed (``failed``: rows of the sweep)
    marked by crosses; beside each controller's loss-of-control curves the delay from which the
    analysis says its loop is unstable (``onsets_ms``, per controller)."""
    rnd = intervals[intervals.reference.str.startswith("random")]
    if "tracker" not in rnd:  # one loss model for every run
        rnd = rnd.assign(tracker="")
    fig = Figure(figsize=(12, 10), layout="constrained")
    ax = fig.subplots(3, 2, sharex=True)
    refs = sorted(rnd.reference.unique())
    for j, ctrl in enumerate(("pid", "mpc")):
        for (tracker, ref), g in rnd[rnd.controller == ctrl].groupby(["tracker", "reference"]):
            colour = f"C{refs.index(ref)}"
            style, tname = TRACKER_STYLE.get(tracker, ("o-", tracker))
            name = (f"{tname}, " if tname else "") + "peak rate " + \
                ref.removeprefix("random_").replace("rad_s", " rad/s")
            _band(ax[0, j], g, "rms_error_deg", colour, name, marker=style)
            _band(ax[1, j], g, "lost_frame_fraction", colour, name, 100.0, marker=style)
            _band(ax[2, j], g, "p_loss_of_control", colour, name, marker=style)
            bad = failed[(failed.controller == ctrl) & (failed.reference == ref)]
            _mark_excluded(ax[0, j], bad.vision_delay_ms.to_numpy(), colour, "failed run")
        ax[0, j].set_title(CONTROLLER_STYLE[ctrl][1])
        ax[0, j].set_yscale("log")
        ax[0, j].set_ylabel("RMS attitude error (deg)")
        ax[1, j].set_ylabel("lost frames (%)")
        ax[2, j].set_ylabel("P(loss of control)")
        ax[2, j].set_ylim(-0.03, 1.03)
        ax[2, j].set_xlabel("vision delay (ms)")
        for a in ax[:, j]:
            mark_delays(a, marks, zero_line=False)
        _mark_onset(ax[2, j], (onsets_ms or {}).get(ctrl, np.nan), "k",
                    CONTROLLER_STYLE[ctrl][1])
        _outside_legend(ax[2, j])
    _outside_legend(ax[0, 1])
    fig.suptitle("Closed loop (measurement model, each tracker's loss model, sequential "
                 "observer): error, tracking loss and loss of control, mean over seeds with "
                 "95 % intervals")
    return _save(fig, path)


def plot_steps(intervals: pd.DataFrame, marks: dict[str, float], path: Path) -> Figure:
    """5° tilt step against vision delay for every controller variant: overshoot (of the
    commanded step), settling time (absolute band) and steady-state error, 95 % intervals;
    delays where a controller did not settle in any run are marked by crosses."""
    st = intervals[intervals.reference == "tilt_step_5deg"]
    fig = Figure(figsize=(12, 8), layout="constrained")
    ax = fig.subplots(3, 1, sharex=True)
    for ctrl, g in st.groupby("controller"):
        colour, label = CONTROLLER_STYLE[ctrl]
        _band(ax[0], g, "overshoot_pct", colour, label)
        _band(ax[1], g, "settling_time_s", colour, label)
        _band(ax[2], g, "steady_state_error_deg", colour, label)
        never = g[~np.isfinite(g.settling_time_s)]
        _mark_excluded(ax[1], never.vision_delay_ms.to_numpy(), colour,
                       f"{label}: does not settle")
    ax[0].set_ylabel("overshoot (% of 5°)")
    ax[1].set_ylabel("settling time (s)")
    ax[2].set_ylabel("steady-state error (deg)")
    ax[2].set_yscale("log")
    ax[2].set_xlabel("vision delay (ms)")
    for a in ax:
        mark_delays(a, marks, zero_line=False)
    _outside_legend(ax[0])
    _outside_legend(ax[1])
    fig.suptitle("5° tilt step against vision delay (commanded step, absolute settling band)")
    return _save(fig, path)


def plot_boundary_overlay(
    intervals: pd.DataFrame, boundaries_ms: dict[str, float], marks: dict[str, float],
    path: Path,
) -> Figure:
    """The predicted stability boundary (analysis) over the simulated probability of loss of
    control (sweep, every random reference pooled, 95 % Wilson intervals), PID and MPC, one
    marker per tracker."""
    fig = Figure(figsize=(11, 5), layout="constrained")
    ax = fig.subplots()
    finite = [b for b in boundaries_ms.values() if np.isfinite(b)]
    right = max([*intervals.vision_delay_ms, *finite, 0.0]) + 5.0
    trackers = list(dict.fromkeys(intervals.get("tracker", pd.Series(["all"]))))
    for c, ctrl in enumerate(("pid", "mpc")):
        colour, label = CONTROLLER_STYLE[ctrl]
        for k, tracker in enumerate(trackers):
            g = intervals[intervals.controller == ctrl]
            if "tracker" in g:
                g = g[g.tracker == tracker]
            if not len(g):
                continue
            fmt, tname = TRACKER_STYLE.get(tracker, ("o-", tracker))
            # side by side where the points coincide
            x = g.vision_delay_ms.to_numpy() + 0.3 * (2 * c + k - 1.5)
            p = g.p_loss_of_control.to_numpy()
            err = np.vstack([p - g.p_loss_of_control_lo, g.p_loss_of_control_hi - p])
            ax.errorbar(x, p, yerr=err, fmt=fmt, color=colour, ms=5, capsize=3, mfc="none",
                        label=f"{label}, {tname}: P(loss of control), simulated")
    ax.set_xlim(min(0.0, float(intervals.vision_delay_ms.min())) - 2.0, right)
    for ctrl in ("pid", "mpc"):
        colour, label = CONTROLLER_STYLE[ctrl]
        _mark_onset(ax, boundaries_ms.get(ctrl, np.nan), colour, label)
    ax.set_ylim(-0.03, 1.03)
    ax.set_xlabel("vision delay (ms), sequential observer")
    ax.set_ylabel("probability of loss of control")
    mark_delays(ax, marks, zero_line=False)
    _outside_legend(ax)
    fig.suptitle("Predicted stability boundary (linearised analysis) against simulated loss "
                 "of control")
    return _save(fig, path)


def plot_time_series(series: dict[str, pd.DataFrame], delays_ms: tuple[float, float],
                     path: Path) -> Figure:
    """Tilt and geodesic error of the 5° step, PID and MPC, at two vision delays."""
    fig = Figure(figsize=(12, 6), layout="constrained")
    ax = fig.subplots(2, 2, sharex=True, sharey="row")
    for j, d in enumerate(delays_ms):
        for ctrl in ("pid", "mpc"):
            s = series[f"{ctrl}_{d:.2f}ms"]
            colour, label = CONTROLLER_STYLE[ctrl]
            ax[0, j].plot(s.t_s, s.tilt_deg, color=colour, label=label)
            ax[1, j].plot(s.t_s, s.error_deg, color=colour, label=label)
        ax[0, j].plot(s.t_s, s.ref_tilt_deg, "k--", lw=0.8, label="reference")
        ax[0, j].set_title(f"vision delay {d:.2f} ms")
        ax[1, j].set_yscale("log")
        ax[1, j].set_xlabel("time (s)")
        for a in ax[:, j]:
            a.grid(alpha=0.3)
    ax[0, 0].set_ylabel("tilt (deg)")
    ax[1, 0].set_ylabel("geodesic error (deg)")
    _outside_legend(ax[0, 1])
    fig.suptitle("5° tilt step at GK-TransT's and the dual TransT's latency")
    return _save(fig, path)
