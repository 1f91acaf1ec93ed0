"""Bode and Nyquist data and plots of a loop. Plots return new ``matplotlib.figure.Figure``
objects; no backend is selected here."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from numpy.typing import ArrayLike, NDArray

from latency.margins.model import LoopModel
from latency.margins.nyquist import _grid, nyquist_count
from latency.margins.result import Margins


def bode_data(
    model: LoopModel, omega: ArrayLike | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """``(omega_rad_s, magnitude, phase_deg)`` of ``L(jw)``.

    The phase is continuous along the grid and starts in (-360°, 0°] at the lowest frequency.
    The linear phase ``-w (tau + T/2)`` of the delay and the hold is added analytically, so it
    stays right where the grid is too coarse to unwrap it; the remainder is unwrapped (it jumps
    by ±180° where the hold's ``sin(wT/2)`` changes sign, at multiples of the sampling rate)."""
    w = _grid(model) if omega is None else np.asarray(omega, dtype=float)
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


def plot_bode(
    model: LoopModel, margins: Margins | None = None, omega: ArrayLike | None = None
) -> Figure:
    """Bode plot of ``L(jw)`` (frequency in Hz on the axis), crossovers marked; a new Figure."""
    w, mag, ph = bode_data(model, omega)
    fig = Figure(figsize=(7, 6), layout="constrained")
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    f = w / (2 * np.pi)
    ax1.loglog(f, mag)
    ax1.axhline(1.0, color="0.5", lw=0.8)
    ax1.set_ylabel("|L|")
    ax2.semilogx(f, ph)
    for k in range(-20, 1):
        if ph.min() - 360 < -180 + 360 * k < ph.max() + 360:
            ax2.axhline(-180 + 360 * k, color="0.5", lw=0.8)
    ax2.set_ylabel("arg L (deg)")
    ax2.set_xlabel("frequency (Hz)")
    if model.sample_period_s is not None:
        for ax in (ax1, ax2):
            ax.axvline(0.5 / model.sample_period_s, color="C3", ls=":", lw=0.8)
    if margins is not None:
        for x in margins.crossovers_rad_s:
            ax1.axvline(x / (2 * np.pi), color="C1", ls="--", lw=0.8)
        ax1.set_title(margins.summary(), fontsize=7, wrap=True)
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
