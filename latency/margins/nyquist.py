"""The Nyquist encirclement count on the exact-delay response (see :mod:`latency.margins`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from latency.margins.grid import _base_grid, _refine
from latency.margins.model import LoopModel


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
    if omega is None:
        w0 = _base_grid(model.response, model.features_rad_s)
    else:
        w0 = np.sort(np.asarray(omega, dtype=float))
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
