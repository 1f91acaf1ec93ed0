"""Frequency grid refined where the loop moves fast, and the Nyquist encirclement count on the
exact-delay response (see :mod:`latency.margins`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    from latency.margins.model import LoopModel


_SMALL_GAIN = 1e-3  # |L| below this cannot wind around -1 and sets gain margins > 60 dB
_PHASE_STEP = np.pi / 8  # largest phase step between grid points where |L| >= _SMALL_GAIN
_CLOSE_STEP = 0.25  # largest |dL| relative to the distance to -1

def _base_grid(model: LoopModel, per_decade: int = 60) -> NDArray[np.float64]:
    feats = model.features_rad_s
    w_lo = 1e-3 * feats[0]
    w_hi = 1e3 * feats[-1]
    for _ in range(12):
        tail = np.logspace(np.log10(w_hi / 10.0), np.log10(w_hi), 40)
        if np.max(np.abs(model.response(tail))) < _SMALL_GAIN:
            break
        w_hi *= 10.0
    else:
        raise ValueError("|L(jw)| does not fall below 1e-3 at high frequency")
    n = int(np.ceil(per_decade * np.log10(w_hi / w_lo))) + 1
    return np.logspace(np.log10(w_lo), np.log10(w_hi), n)


def _refine(
    fun: Callable[[NDArray[np.float64]], NDArray[np.complex128]],
    w: NDArray[np.float64],
    max_rounds: int = 40,
    geometric: bool = True,
) -> tuple[NDArray[np.float64], NDArray[np.complex128]]:
    """Insert midpoints (geometric for frequencies, arithmetic for angles) until the phase of
    ``L`` moves less than pi/8 between points (where ``|L| >= 1e-3``) and ``L`` moves less than a
    quarter of its distance to -1."""
    Lw = fun(w)
    for _ in range(max_rounds):
        a, b = Lw[:-1], Lw[1:]
        with np.errstate(divide="ignore", invalid="ignore"):
            dphi = np.abs(np.angle(b / a))
        dphi = np.where(np.isfinite(dphi), dphi, np.pi)
        big = np.maximum(np.abs(a), np.abs(b)) >= _SMALL_GAIN
        dist = np.minimum(np.abs(1.0 + a), np.abs(1.0 + b))
        bad = (big & (dphi > _PHASE_STEP)) | (np.abs(b - a) > _CLOSE_STEP * dist)
        bad &= (w[1:] - w[:-1]) > 1e-12 * np.maximum(np.abs(w[1:]), 1e-300)
        if not np.any(bad):
            break
        idx = np.nonzero(bad)[0]
        mid = np.sqrt(w[idx] * w[idx + 1]) if geometric else 0.5 * (w[idx] + w[idx + 1])
        w = np.insert(w, idx + 1, mid)
        Lw = np.insert(Lw, idx + 1, fun(mid))
    return w, Lw


def _grid(model: LoopModel) -> NDArray[np.float64]:
    w, _ = _refine(model.response, _base_grid(model))
    return w


def nyquist_count(
    model: LoopModel, omega: ArrayLike | None = None
) -> tuple[int, int, NDArray[np.float64], NDArray[np.complex128]]:
    """Nyquist criterion on the exact-delay loop: closed-loop poles in the open right half-plane.

    The D-contour runs up the imaginary axis from ``j eps`` to ``j w_max``, closes through the
    right half-plane (where ``|L| < 1e-3``), returns along ``-j w`` and is indented to the right of
    the origin by the half circle ``s = eps e^{j theta}``, ``theta`` from -pi/2 to pi/2 (so poles
    at the origin count as stable open-loop poles). ``eps`` is 1e-3 times the smallest
    characteristic frequency of the loop. The winding number of ``1 + L`` is accumulated from the
    phase of ``(1 + L_{i+1}) / (1 + L_i)`` on a grid refined until each step is small; by
    conjugate symmetry the lower half contributes as much as the upper half. For the delayed loop
    (retarded, strictly proper) this is the Nyquist criterion for ``1 + L(s) = 0``.

    Parameters
    ----------
    model : LoopModel
    omega : array_like, optional
        Starting grid (rad/s); it is refined. Default: 1e-3 x the smallest to 1e3 x the largest
        characteristic frequency, 60 points per decade, extended until ``|L| < 1e-3``. A grid
        given here must start below every pole/zero magnitude (its first point is the
        indentation radius) and end where ``|L| < 1e-3``.

    Returns
    -------
    Z : int
        Closed-loop poles in the open right half-plane, ``Z = P + N``; stable iff ``Z == 0``.
    N : int
        Clockwise encirclements of -1 by ``L`` along the contour.
    omega : ndarray
        The refined grid (rad/s).
    L : ndarray
        ``L(j omega)`` on it.
    """
    w0 = _base_grid(model) if omega is None else np.sort(np.asarray(omega, dtype=float))
    eps = float(w0[0])
    w, Lw = _refine(model.response, w0)
    g = 1.0 + Lw
    upper = float(np.sum(np.angle(g[1:] / g[:-1])))
    # closing arc at |s| = w_max (|L| < 1e-3 there): from 1 + L(jw_max) to its conjugate
    close = float(np.angle(np.conj(g[-1]) / g[-1]))
    # indentation: theta from -pi/2 to pi/2, from s = -j eps to s = +j eps
    _, L_arc = _refine(
        lambda th: model(eps * np.exp(1j * th)),
        np.linspace(-np.pi / 2, np.pi / 2, 401),
        geometric=False,
    )
    arc = 1.0 + L_arc
    arc_phase = float(np.sum(np.angle(arc[1:] / arc[:-1])))
    total = 2.0 * upper + close + arc_phase
    winding = total / (2.0 * np.pi)  # counter-clockwise turns of 1 + L along a clockwise contour
    W = int(round(winding))
    if abs(winding - W) > 1e-3:
        raise RuntimeError(f"Nyquist winding number {winding:.4f} is not an integer")
    Z = model.open_loop_rhp_poles - W
    N = -W
    return Z, N, w, Lw
