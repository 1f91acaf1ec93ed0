"""Frequency grids refined where a loop's response moves fast (see :mod:`latency.margins`).

The grid functions take the response and the characteristic frequencies rather than a loop
object, so the loop model and the Nyquist count both use them without importing each other.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

_SMALL_GAIN = 1e-3  # |L| below this cannot wind around -1 and sets gain margins > 60 dB
_PHASE_STEP = np.pi / 8  # largest phase step between grid points where |L| >= _SMALL_GAIN
_CLOSE_STEP = 0.25  # largest |dL| relative to the distance to -1


def _base_grid(
    response: Callable[[NDArray[np.float64]], NDArray[np.complex128]],
    features_rad_s: Sequence[float],
    per_decade: int = 60,
) -> NDArray[np.float64]:
    """Log-spaced grid (rad/s) from 1e-3 x the smallest to 1e3 x the largest characteristic
    frequency, ``per_decade`` points per decade, its top extended by decades until ``|L|`` of
    ``response`` falls below ``_SMALL_GAIN``; ``ValueError`` if it never does."""
    feats = features_rad_s
    w_lo = 1e-3 * feats[0]
    w_hi = 1e3 * feats[-1]
    for _ in range(12):
        tail = np.logspace(np.log10(w_hi / 10.0), np.log10(w_hi), 40)
        if np.max(np.abs(response(tail))) < _SMALL_GAIN:
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


def _grid(
    response: Callable[[NDArray[np.float64]], NDArray[np.complex128]],
    features_rad_s: Sequence[float],
) -> NDArray[np.float64]:
    """The analysis grid (rad/s) of a loop: ``_base_grid`` refined by ``_refine``."""
    w, _ = _refine(response, _base_grid(response, features_rad_s))
    return w
