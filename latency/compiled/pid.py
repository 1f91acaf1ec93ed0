"""The PID in the compiled run loop (``controller.pid.PIDController`` on the estimates the
observer releases), and the rate from successive attitudes that the PID and the MPC use."""

from __future__ import annotations

import numpy as np
from numba import njit

from latency.compiled import layout, rotations
from latency.compiled.cache import compiled_in
from latency.compiled.layout import (
    _D,
    _D_INIT,
    _INT,
    _LAST_TAU,
    _P_AW,
    _P_FF,
    _P_FRIC,
    _P_FRIC_W,
    _P_HOLD,
    _P_J,
    _P_KD,
    _P_KI,
    _P_KP,
    _P_LIMIT,
    _P_TAU_F,
    _P_TT,
    _PEND,
    _RATE_Q,
    _RATE_T,
    _RATE_W,
    _T_PREV,
)
from latency.compiled.rotations import _conj_mul, _matrix, _mtv, _mv, _rotvec, _unit
from latency.numba_cache import drop_stale_cache

#: The modules whose code these kernels compile in (``cache``).
COMPILED_IN = compiled_in((), (layout, rotations))
drop_stale_cache(__file__, COMPILED_IN)


@njit(cache=True)
def _attitude_rate(st, q, t_state):
    """``controller.pid.RateFromAttitude.update`` with the unit attitude q (4-tuple) described
    at ``t_state`` (s): the rate estimate (rad/s) in ``st[_RATE_W : _RATE_W + 3]``.

    Compiled mirror of ``controller.pid.RateFromAttitude.update``."""
    has_prev = not np.isnan(st[_RATE_Q])
    if has_prev and t_state > st[_RATE_T]:
        rv = _rotvec(_conj_mul(st[_RATE_Q : _RATE_Q + 4], q))
        for i in range(3):
            st[_RATE_W + i] = rv[i] / (t_state - st[_RATE_T])
    if not has_prev or t_state > st[_RATE_T]:
        for i in range(4):
            st[_RATE_Q + i] = q[i]
        st[_RATE_T] = t_state


@njit(cache=True)
def _pid(st, par, valid, q_est, t_state, ref_q, ref_w, ref_a):
    """``PIDController.command`` on an estimate (valid, attitude, the time it describes) with
    the reference sampled at the call: the stator-frame torque (3,), N·m.

    Compiled mirror of ``controller.pid.PIDController.command``."""
    if not valid:
        st[_PEND : _PEND + 3] = 0.0
        st[_T_PREV] = t_state
        if par[_P_HOLD] == 0:
            st[_LAST_TAU : _LAST_TAU + 3] = 0.0
        return st[_LAST_TAU : _LAST_TAU + 3].copy()
    dt = 0.0 if np.isnan(st[_T_PREV]) else max(t_state - st[_T_PREV], 0.0)
    st[_T_PREV] = t_state
    q = _unit(q_est)
    q_e = _conj_mul(q, ref_q)
    e = _rotvec(q_e)
    R_e = _matrix(q_e)
    w_r = _mv(R_e, ref_w)
    a_r = _mv(R_e, ref_a)
    _attitude_rate(st, q, t_state)
    if np.isfinite(st[_RATE_W]) and np.isfinite(st[_RATE_W + 1]) and np.isfinite(st[_RATE_W + 2]):
        blend = 1.0 - np.exp(-dt / par[_P_TAU_F])
        for i in range(3):
            x = w_r[i] - st[_RATE_W + i]
            st[_D + i] = x if st[_D_INIT] == 0 else st[_D + i] + blend * (x - st[_D + i])
        st[_D_INIT] = 1.0
    tau = np.empty(3)
    for i in range(3):
        st[_INT + i] = st[_INT + i] + st[_PEND + i] * dt
        tau[i] = par[_P_KP + i] * e[i] + st[_INT + i] + par[_P_KD + i] * st[_D + i]
        if par[_P_FRIC] > 0.0:
            tau[i] = tau[i] + par[_P_FRIC] * np.tanh(e[i] / par[_P_FRIC_W])
    if par[_P_FF] > 0:
        J = (par[_P_J], par[_P_J + 1], par[_P_J + 2])
        Jw = (J[0] * w_r[0], J[1] * w_r[1], J[2] * w_r[2])
        gyro = (w_r[1] * Jw[2] - w_r[2] * Jw[1], w_r[2] * Jw[0] - w_r[0] * Jw[2],
                w_r[0] * Jw[1] - w_r[1] * Jw[0])
        for i in range(3):
            tau[i] = tau[i] + J[i] * a_r[i] + gyro[i]
    R = _matrix(q)
    T = _mv(R, tau)
    n = np.sqrt(T[0] * T[0] + T[1] * T[1] + T[2] * T[2])
    saturated = n > par[_P_LIMIT]
    if saturated:
        f = par[_P_LIMIT] / n
        T = (T[0] * f, T[1] * f, T[2] * f)
    tau_sat = _mtv(R, T)
    for i in range(3):
        rate = par[_P_KI + i] * e[i]
        excess = tau[i] - tau_sat[i]
        if par[_P_AW] == 0:
            rate = rate + (tau_sat[i] - tau[i]) / par[_P_TT + i]
        elif par[_P_AW] == 1 and saturated and np.sign(e[i]) == np.sign(excess) and abs(excess) > 0:
            rate = 0.0
        st[_PEND + i] = rate
        st[_LAST_TAU + i] = T[i]
    return np.array(T)
