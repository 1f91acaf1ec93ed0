"""Figures of the pixel Kalman tuning: the cost heat map over (q, r) and the error/effort
trade-off (``experiments.tuning``). They return ``Figure`` objects and need no pyplot."""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure
from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter
from numpy.typing import NDArray

from experiments.tuning.objective import SEED_Q_SCALE, SEED_R_SCALE


def plot_heatmap(grid: pd.DataFrame, trials: pd.DataFrame | None = None) -> Figure:
    """Heat map of the mean cost over log10 q × log10 r, one panel per delay.

    The seed's (0.01, 0.1) is a white star, the grid's best point a white circle, optuna's
    trials (if given, columns ``delay_s, q, r``) small black dots. With the margin columns of
    ``grid_search``: cells whose linearised loop (with the steady-state filter) is unstable are
    hatched, and lines of equal phase margin are drawn. The phase margin depends on ``q/r``
    only, so the lines are diagonals, interpolated in ``log(q/r)`` between the grid's ratios.
    """
    delays = sorted(grid.delay_s.unique())
    fig = Figure(figsize=(5.2 * len(delays) + 0.8, 4.6), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(delays), squeeze=False)[0])
    finite = grid.cost[np.isfinite(grid.cost) & (grid.cost > 0)]
    norm = LogNorm(finite.min(), finite.max()) if len(finite) else None
    mesh = None
    for ax, d in zip(axes, delays, strict=True):
        g = grid[grid.delay_s == d]
        qs, rs = np.sort(g.q.unique()), np.sort(g.r.unique())
        Z = g.pivot_table(index="r", columns="q", values="cost").reindex(index=rs, columns=qs)
        lq, lr = np.log10(qs), np.log10(rs)
        eq, er = _edges(lq), _edges(lr)
        mesh = ax.pcolormesh(eq, er, Z.to_numpy(), norm=norm, cmap="viridis")
        _unstable_and_margins(ax, g, qs, rs, eq, er)
        _points(ax, g, trials, d)
        ax.set_xlim(eq[0], eq[-1])
        ax.set_ylim(er[0], er[-1])
        ax.set_xlabel("log10 q  (Q = q·I4)")
        ax.set_ylabel("log10 r  (R = r·I2)")
        ax.set_title(
            f"closed-loop cost, vision delay {d * 1e3:.2f} ms\n(hatched: linearised loop unstable)",
            fontsize=9,
        )
        ax.legend(fontsize=7, loc="lower right")
    if mesh is not None:
        cb = fig.colorbar(mesh, ax=list(axes), label="mean cost J (deg)")
        _log_labels(cb.ax.yaxis, norm.vmin, norm.vmax)
    return fig


def _unstable_and_margins(ax, g: pd.DataFrame, qs: NDArray, rs: NDArray, eq: NDArray,
                          er: NDArray) -> None:
    """On one panel (grid rows ``g`` at one delay, cell edges ``eq``, ``er`` in log10 q and
    log10 r): hatch the cells whose linearised loop is unstable and draw the lines of equal
    phase margin (every 10°, interpolated in log(q/r)), when ``g`` has those columns."""
    if "stable" in g:
        for row in g[~g.stable.astype(bool)].itertuples():
            iq, ir = int(np.searchsorted(qs, row.q)), int(np.searchsorted(rs, row.r))
            ax.fill_between(
                [eq[iq], eq[iq + 1]],
                er[ir],
                er[ir + 1],
                facecolor="none",
                edgecolor="w",
                hatch="//",
                linewidth=0.0,
            )
    if "phase_margin_deg" in g:
        pm = g.groupby("q_over_r").phase_margin_deg.first().dropna()
        if len(pm) >= 2 and pm.max() > pm.min():
            fq, fr = np.meshgrid(
                np.linspace(eq[0], eq[-1], 200), np.linspace(er[0], er[-1], 200)
            )
            lx = np.log10(pm.index.to_numpy())
            field_ = np.interp(fq - fr, lx, pm.to_numpy(), left=np.nan, right=np.nan)
            levels = np.arange(0.0, 90.0, 10.0)
            levels = levels[(levels > pm.min()) & (levels < pm.max())]
            if len(levels):
                cs = ax.contour(fq, fr, field_, levels=levels, colors="w", linewidths=0.7)
                ax.clabel(cs, fmt="PM %.0f°", fontsize=7)


def _points(ax, g: pd.DataFrame, trials: pd.DataFrame | None, d: float) -> None:
    """On one panel (grid rows ``g`` at delay ``d``, s): optuna's trials as dots, the grid's
    best point as a circle and the seed's (0.01, 0.1) as a star."""
    if trials is not None and len(trials):
        t = trials[np.isclose(trials.delay_s, d)]
        ax.plot(np.log10(t.q), np.log10(t.r), "k.", ms=3, label="optuna trials")
    if g.cost.notna().any():
        best = g.loc[g.cost.idxmin()]
        ax.plot(
            np.log10(best.q),
            np.log10(best.r),
            "o",
            mfc="none",
            mec="w",
            ms=12,
            mew=2,
            label=f"grid best ({best.q:.3g}, {best.r:.3g})",
        )
    ax.plot(
        np.log10(SEED_Q_SCALE),
        np.log10(SEED_R_SCALE),
        "*",
        color="w",
        mec="k",
        ms=14,
        label="seed (0.01, 0.1)",
    )


def plot_tradeoff(grid: pd.DataFrame, trials: pd.DataFrame | None = None) -> Figure:
    """Cost and phase margin against ``q/r``: the trade-off between filtering and lag.

    Top: the grid's mean cost (deg) per ``q/r`` (averaged over the grid points that share the
    ratio) for each delay, optuna's trials as dots. Bottom: the phase margin (deg) of the loop
    with the steady-state filter (missing where the linearised loop is unstable) and the
    filter's noise gain. The seed's ``q/r = 0.1`` is the dotted line."""
    fig = Figure(figsize=(7.0, 6.0), layout="constrained")
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    for i, d in enumerate(sorted(grid.delay_s.unique())):
        g = grid[grid.delay_s == d].groupby("q_over_r")
        cost = g.cost.mean()
        label = f"{d * 1e3:.2f} ms"
        ax1.loglog(cost.index, cost.to_numpy(), "o-", color=f"C{i}", label=f"grid, {label}")
        if trials is not None and len(trials):
            t = trials[np.isclose(trials.delay_s, d)]
            ax1.loglog(t.q / t.r, t.cost, ".", color=f"C{i}", alpha=0.6, label=f"optuna, {label}")
        if "phase_margin_deg" in grid:
            pm = g.phase_margin_deg.first()
            ax2.semilogx(pm.index, pm.to_numpy(), "o-", color=f"C{i}", label=f"PM, {label}")
    if "noise_gain" in grid:
        ng = grid.groupby("q_over_r").noise_gain.first()
        ax2b = ax2.twinx()
        ax2b.semilogx(ng.index, ng.to_numpy(), "k--", lw=0.8)
        ax2b.set_ylabel("filter noise gain (--)")
    for ax in (ax1, ax2):
        ax.axvline(SEED_Q_SCALE / SEED_R_SCALE, color="0.4", ls=":", lw=1)
        ax.grid(alpha=0.3, which="both")
    ax1.set_ylabel("mean cost J (deg)")
    _log_labels(ax1.yaxis, *ax1.get_ylim())
    ax1.legend(fontsize=7)
    ax2.set_ylabel("phase margin (deg)")
    ax2.set_xlabel("q / r  (seed: 0.1, dotted)")
    ax2.legend(fontsize=7, loc="lower right")
    ax1.set_title("more filtering (small q/r) lowers the noise but adds lag", fontsize=9)
    return fig


def _log_labels(axis, lo: float, hi: float) -> None:
    """Plain numbers on a log axis: ticks at 1, 2, 5 × 10^k (every integer multiple when the
    axis spans less than a decade), no labels on the minor ticks."""
    subs = (1.0, 2.0, 5.0) if hi >= 10.0 * lo else tuple(float(k) for k in range(1, 10))
    axis.set_major_locator(LogLocator(subs=subs))
    axis.set_major_formatter(FormatStrFormatter("%.3g"))
    axis.set_minor_formatter(NullFormatter())


def _edges(c: NDArray[np.float64]) -> NDArray[np.float64]:
    """Cell edges around sorted centres (half a step beyond the ends)."""
    if len(c) == 1:
        return np.array([c[0] - 0.5, c[0] + 0.5])
    mid = 0.5 * (c[1:] + c[:-1])
    return np.concatenate([[2 * c[0] - mid[0]], mid, [2 * c[-1] - mid[-1]]])
