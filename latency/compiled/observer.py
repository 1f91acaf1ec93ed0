"""The observer in the compiled run loop: the pixel Kalman filters of the two markers and the
per-frame least-squares solve (the warm-started Levenberg-Marquardt iteration of
``observer.cor_solver``, the one code of the iteration)."""

from __future__ import annotations

import numpy as np
from numba import njit

from latency.compiled import layout
from latency.compiled.cache import compiled_in
from latency.compiled.layout import (
    _KF,
    _KF_SIZE,
    _P_KF_Q,
    _P_KF_R,
    _P_KF_V0,
    _P_MAX_COND,
    _P_MAX_IT,
    _P_MAX_RMS,
    _P_MAX_TILT,
    _P_STEP_TOL,
    _R_OK,
)
from latency.numba_cache import drop_stale_cache
from observer import cor_solver
from observer.cor_solver import (
    _CONVERGED,
    _SINGULAR,
    BEHIND_CAMERA,
    DEGENERATE,
    FAR_SIDE,
    ILL_CONDITIONED,
    NOT_CONVERGED,
    RESIDUAL_TOO_LARGE,
    _lm,
    _residual_jac,
    condition_number,
    normal_equations,
)
from observer.gk import pixel_kalman
from observer.gk.pixel_kalman import F_CV, H_CV

#: The modules whose code these kernels compile in (``cache``).
COMPILED_IN = compiled_in((cor_solver, pixel_kalman), (layout,))
drop_stale_cache(__file__, COMPILED_IN)


@njit(cache=True)
def _solve(q_prev, uv, P, t_cor, intr, par):
    """``CorSolver.solve`` warm-started at q_prev on both markers' pixels uv (2, 2) (the front
    end measures both or none): (q, valid, reason code, its number).

    Compiled mirror of ``observer.cor_solver.CorSolver.solve``."""
    nan4 = np.full(4, np.nan)
    q = q_prev / np.sqrt(q_prev @ q_prev)
    r, _ = _residual_jac(q, P, uv, t_cor, intr)
    if not np.all(np.isfinite(r)):
        return nan4, False, BEHIND_CAMERA, 0.0
    q, status, it, cost, J = _lm(q, P, uv, t_cor, intr, int(par[_P_MAX_IT]), par[_P_STEP_TOL])
    if status == _SINGULAR:
        return nan4, False, DEGENERATE, 0.0
    if status != _CONVERGED:
        return nan4, False, NOT_CONVERGED, 0.0
    q = q / np.sqrt(q @ q)
    if q[0] < 0:
        q = -q
    rms = np.sqrt(cost / r.shape[0])
    cond = condition_number(normal_equations(J, r)[0])
    if not np.isfinite(cond) or cond > par[_P_MAX_COND]:
        return nan4, False, ILL_CONDITIONED, cond
    if rms > par[_P_MAX_RMS]:
        return nan4, False, RESIDUAL_TOO_LARGE, rms
    tilt = np.arccos(min(max(1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2]), -1.0), 1.0))
    if tilt > par[_P_MAX_TILT]:
        return nan4, False, FAR_SIDE, tilt
    return q, True, _R_OK, 0.0


@njit(cache=True)
def _pixel_kalman(st, par, z, lost):
    """The filters of ``PixelKalmanObserver.process`` (``observer.gk.pixel_kalman.PixelKalman``,
    filterpy's equations: the prior, then the update in Joseph form, or coasting on the prior
    when the frame is lost) on the measured centres z (2, 2), sensor px: the filtered centres
    (NaN for a filter not yet initialised).

    Compiled mirror of ``observer.pixel_observer.PixelKalmanObserver.process`` and
    ``observer.gk.pixel_kalman.PixelKalman``."""
    Q = par[_P_KF_Q : _P_KF_Q + 16].copy().reshape(4, 4)
    R = par[_P_KF_R : _P_KF_R + 4].copy().reshape(2, 2)
    out = np.full((2, 2), np.nan)
    for i in range(2):
        b = _KF + i * _KF_SIZE
        x = st[b + 1 : b + 5].copy()
        P = st[b + 5 : b + 21].copy().reshape(4, 4)
        initialised = st[b] > 0
        if initialised:
            x = F_CV @ x
            P = 1.0 * ((F_CV @ P) @ F_CV.T) + Q
        if not lost and np.isfinite(z[i, 0]) and np.isfinite(z[i, 1]):
            if not initialised:
                x = np.array([z[i, 0], z[i, 1], 0.0, 0.0])
                P = np.zeros((4, 4))
                P[:2, :2] = R
                P[2, 2] = P[3, 3] = par[_P_KF_V0]
                initialised = True
            else:
                PHT = P @ H_CV.T
                K = PHT @ np.linalg.inv(H_CV @ PHT + R)
                x = x + K @ (z[i] - H_CV @ x)
                I_KH = np.eye(4) - K @ H_CV
                P = (I_KH @ P) @ I_KH.T + (K @ R) @ K.T
        st[b] = 1.0 if initialised else 0.0
        st[b + 1 : b + 5] = x
        st[b + 5 : b + 21] = P.ravel()
        if initialised:
            out[i] = x[:2]
    return out
