"""Padé approximation of the loop, for comparison with the exact delay only."""

from __future__ import annotations

import control as ct
import numpy as np
from numpy.typing import NDArray

from latency.margins.grid import _base_grid, _refine
from latency.margins.model import LoopModel
from latency.margins.result import Margins, _crossings, margins_from_crossings


def _pade_poly(T: float, order: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    num, den = ct.pade(T, order)
    return np.asarray(num, dtype=float), np.asarray(den, dtype=float)


def _padd(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.polyadd(a, b)


def loop_pade(model: LoopModel, order: int = 6) -> ct.TransferFunction:
    """A rational approximation of ``L``, for comparison only.

    Every exponential is replaced by its ``(order, order)`` Padé approximant
    ``e^{-s h} ~ n_h(s)/d_h(s)``: the delay (``h = tau``), the hold
    ``(1 - e^{-sT})/(sT) ~ (d_T - n_T) / (s T d_T)`` (``d_T - n_T`` has an exact root at 0, which
    cancels the ``s``) and, in a discrete factor ``G(z)``, ``z^{-1} = e^{-sT} ~ n_T/d_T``.

    Returns
    -------
    TransferFunction
        Continuous-time SISO.
    """
    num = np.array([1.0])
    den = np.array([1.0])
    T = model.sample_period_s
    nT = dT = None
    if T is not None:
        nT, dT = _pade_poly(T, order)
    for f in model.factors:
        if f.dt is None:
            num, den = np.polymul(num, f.num), np.polymul(den, f.den)
            continue
        assert nT is not None and dT is not None
        n = max(f.num.size, f.den.size) - 1
        b = np.concatenate([np.zeros(n + 1 - f.num.size), f.num])  # coefficients of z^n..z^0
        a = np.concatenate([np.zeros(n + 1 - f.den.size), f.den])
        # G = sum_k b[k] z^{n-k} / sum_k a[k] z^{n-k} = sum_k b[k] q^k / sum_k a[k] q^k, q = z^-1
        gn = np.array([0.0])
        gd = np.array([0.0])
        for k in range(n + 1):
            term = np.array([1.0])
            for _ in range(k):
                term = np.polymul(term, nT)
            for _ in range(n - k):
                term = np.polymul(term, dT)
            gn = _padd(gn, b[k] * term)
            gd = _padd(gd, a[k] * term)
        num, den = np.polymul(num, gn), np.polymul(den, gd)
    if T is not None:
        assert nT is not None and dT is not None
        diff = np.polysub(dT, nT)
        zoh_num = diff[:-1]  # divide by s: the constant term is zero
        num, den = np.polymul(num, zoh_num), np.polymul(den, T * dT)
    if model.delay_s > 0.0:
        nd, dd = _pade_poly(model.delay_s, order)
        num, den = np.polymul(num, nd), np.polymul(den, dd)
    return ct.tf(np.trim_zeros(num, "f"), np.trim_zeros(den, "f"))


def pade_margins(model: LoopModel, order: int = 6) -> Margins:
    """Margins of the Padé approximation :func:`loop_pade`, stability from its closed-loop poles.

    For comparison with :func:`loop_margins`: the margins come from the same crossing search on
    the rational response, the verdict from the roots of ``den + num`` of ``L``.
    """
    Lr = loop_pade(model, order)
    num = np.asarray(Lr.num[0][0], dtype=float)
    den = np.asarray(Lr.den[0][0], dtype=float)
    poles = np.roots(np.polyadd(den, num))
    Z = int(np.sum(poles.real > 0.0))

    def fun(w: NDArray[np.float64]) -> NDArray[np.complex128]:
        s = 1j * np.asarray(w, dtype=float)
        return np.polyval(num, s) / np.polyval(den, s)

    w, Lw = _refine(fun, _base_grid(model.response, model.features_rad_s))
    cr = _crossings(fun, w, Lw)
    return margins_from_crossings(
        cr, stable=Z == 0, unstable_poles=Z, delay_s=model.delay_s, formulation=f"pade-{order}",
        confirmation=f"closed-loop poles of the Padé-{order} loop: {Z} in the RHP",
    )
