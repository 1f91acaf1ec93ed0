"""Bode and Nyquist data and plots of a loop. Plots return new ``matplotlib.figure.Figure``
objects; no backend is selected here."""

from __future__ import annotations

import math

import numpy as np
from matplotlib.figure import Figure
from numpy.typing import ArrayLike, NDArray

from latency.margins.grid import _grid
from latency.margins.model import LoopModel
from latency.margins.nyquist import nyquist_count
from latency.margins.result import Margins


def bode_data(
    model: LoopModel, omega: ArrayLike | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """``(omega_rad_s, magnitude, phase_deg)`` of ``L(jw)``.

    The phase is continuous along the grid and starts in (-360°, 0°] at the lowest frequency.
    The linear phase ``-w (tau + T/2)`` of the delay and the hold is added analytically, so it
    stays right where the grid is too coarse to unwrap it; the remainder is unwrapped (it jumps
    by ±180° where the hold's ``sin(wT/2)`` changes sign, at multiples of the sampling rate)."""
    w = (_grid(model.response, model.features_rad_s) if omega is None
         else np.asarray(omega, dtype=float))
    Lw = model.response(w)
    lin = model.delay_s + (0.0 if model.sample_period_s is None else 0.5 * model.sample_period_s)
    ph = np.unwrap(np.angle(Lw * np.exp(1j * w * lin)))
    ph -= 2 * np.pi * np.ceil(ph[0] / (2 * np.pi))  # first value in (-2 pi, 0]
    ph = ph - w * lin
    return w, np.abs(Lw), np.degrees(ph)


def nyquist_data(
    model: LoopModel, omega: ArrayLike | None = None
) -> tuple[NDArray[np.float64], NDArray[np.complex128]]:
    """``(omega_rad_s, L(j omega))`` on the refined grid, positive frequencies only."""
    if omega is None:
        _, _, w, Lw = nyquist_count(model)
        return w, Lw
    w = np.asarray(omega, dtype=float)
    return w, model.response(w)


def bode_band(model: LoopModel, margins: Margins | None = None, decades: float = 1.5) -> NDArray:
    """A frequency grid (rad/s) around the crossovers: ``decades`` below the lowest gain
    crossover to ``decades`` above the highest (or the phase crossovers when there is no gain
    crossover), capped at 1.5 times the Nyquist frequency of a sampled loop. Without crossovers
    (or ``margins``), one decade either side of the loop's characteristic frequencies."""
    marks = [] if margins is None else [
        x for x in (*margins.crossovers_rad_s, *margins.phase_crossovers_rad_s) if x > 0
    ]
    feats = model.features_rad_s
    lo, hi = (min(marks), max(marks)) if marks else (feats[0], feats[-1])
    w_lo, w_hi = lo / 10**decades, hi * 10**decades
    if model.sample_period_s is not None:
        w_hi = min(w_hi, 1.5 * model.nyquist_rad_s)
    return np.logspace(np.log10(w_lo), np.log10(max(w_hi, 10 * w_lo)), 600)


def plot_bode(
    model: LoopModel, margins: Margins | None = None, omega: ArrayLike | None = None
) -> Figure:
    """Bode plot of ``L(jw)`` around its crossovers (frequency in Hz); a new Figure.

    The band defaults to :func:`bode_band`. The phase is shifted by a whole number of turns so
    that it reads in (-360°, 0°] at the critical gain crossover (or at the band's centre), where
    the -180° line that sets the phase margin is drawn; gain crossovers (the critical one
    solid), phase crossovers and the Nyquist frequency are vertical lines named in the legend.
    """
    w = bode_band(model, margins) if omega is None else np.asarray(omega, dtype=float)
    w, mag, ph = bode_data(model, w)
    ref_w = math.sqrt(w[0] * w[-1])
    k = None if margins is None else margins.critical_crossover
    if k is not None:
        ref_w = margins.crossovers_rad_s[k]
    ph_ref = float(np.interp(math.log(ref_w), np.log(w), ph))
    ph = ph - 360.0 * math.ceil(ph_ref / 360.0)  # (-360°, 0°] at the reference frequency
    fig = Figure(figsize=(7.5, 6), layout="constrained")
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    f = w / (2 * np.pi)
    ax1.loglog(f, mag, color="C0", label="|L|")
    ax1.axhline(1.0, color="0.5", lw=0.8)
    ax1.set_ylabel("|L|")
    ax1.set_ylim(bottom=max(float(mag.min()), 1e-3))  # |L| < 1e-3 cannot reach -1
    ax2.semilogx(f, ph, color="C0", label="arg L")
    for turn in range(-6, 3):
        level = -180.0 + 360.0 * turn
        if ph.min() - 30 < level < ph.max() + 30:
            ax2.axhline(level, color="0.5", lw=0.8)
    ax2.set_ylabel("arg L (deg)")
    ax2.set_xlabel("frequency (Hz)")
    lines = []
    if model.sample_period_s is not None and 0.5 / model.sample_period_s <= f[-1]:
        lines.append((0.5 / model.sample_period_s, "C3", ":", "Nyquist frequency 1/(2T)"))
    if margins is not None:
        for i, x in enumerate(margins.crossovers_rad_s):
            crit = i == k
            name = (
                f"{'critical ' if crit else ''}gain crossover {x / (2 * np.pi):.3g} Hz, "
                f"PM {margins.phase_margins_deg[i]:+.1f}°"
            )
            lines.append((x / (2 * np.pi), "C1", "-" if crit else "--", name))
        for x, g in zip(margins.phase_crossovers_rad_s, margins.phase_crossover_gains,
                        strict=True):
            if x > 0:
                lines.append((x / (2 * np.pi), "C2", "-.",
                              f"phase crossover {x / (2 * np.pi):.3g} Hz, |L| = {g:.3g}"))
        fig.suptitle(margins.summary().split(" (delay")[0].rstrip(", "), fontsize=8)
    for x, colour, style, name in lines:
        ax1.axvline(x, color=colour, ls=style, lw=0.9, label=name)
        ax2.axvline(x, color=colour, ls=style, lw=0.9)
    ax1.legend(fontsize=7, loc="lower left")
    return fig


def plot_nyquist(
    model: LoopModel,
    margins: Margins | None = None,
    omega: ArrayLike | None = None,
    radius: float = 3.0,
) -> Figure:
    """Nyquist plot of ``L(jw)`` for ``w > 0`` (solid) and its mirror (dashed), the point -1 and
    the unit circle, zoomed to ``|L| <= radius``; a new Figure."""
    _, Lw = nyquist_data(model, omega)
    fig = Figure(figsize=(6, 6), layout="constrained")
    ax = fig.subplots()
    Lc = np.where(np.abs(Lw) <= radius * 1.5, Lw, np.nan)
    ax.plot(Lc.real, Lc.imag, "C0")
    ax.plot(Lc.real, -Lc.imag, "C0--", lw=0.8)
    th = np.linspace(0, 2 * np.pi, 200)
    ax.plot(np.cos(th), np.sin(th), color="0.6", lw=0.8)
    ax.plot([-1], [0], "r+", ms=12)
    ax.set_xlim(-radius, radius)
    ax.set_ylim(-radius, radius)
    ax.set_aspect("equal")
    ax.set_xlabel("Re L")
    ax.set_ylabel("Im L")
    if margins is not None:
        ax.set_title(margins.summary(), fontsize=7, wrap=True)
    return fig
