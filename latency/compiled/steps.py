"""The rotor between events in the compiled run loop: the compiled physics step
(``plant.rigid_body._step_row``, the one code of the physics) with the coils' lag, the steps
table's rows at the grid points, the tilt-stop events, and the event record."""

from __future__ import annotations

import numpy as np
from numba import njit

from latency.compiled import layout
from latency.compiled.cache import compiled_in
from latency.compiled.layout import (
    _CMD,
    _CUR,
    _EST,
    _EV_CONTACT,
    _EV_RELEASE,
    _K,
    _N_EV,
    _P_COS_STOP,
    _P_H,
    _P_N_STEPS,
    _P_TAU_L,
    _Q,
    _SAT,
    _STOP,
    _T,
    _TCMD,
    _TDEL,
    _W,
)
from latency.numba_cache import drop_stale_cache
from plant import rigid_body, torque
from plant.rigid_body import (
    FASTMATH,
    PHYSICS_SUBSTEPS,
    SUBSTEP_ANGLE_RAD,
    _rotor_tuples,
    _step_row,
)
from plant.torque import N_COILS

#: The modules whose code these kernels compile in (``cache``).
COMPILED_IN = compiled_in((rigid_body, torque), (layout,))
drop_stale_cache(__file__, COMPILED_IN)


@njit(cache=True)
def _event(st, evs, t, code, a, b, c, d):
    """Append an event (time s, code of ``EVENT_KINDS``, up to four numbers) to the record."""
    n = int(st[_N_EV])
    evs[n, 0], evs[n, 1], evs[n, 2], evs[n, 3], evs[n, 4], evs[n, 5] = t, code, a, b, c, d
    st[_N_EV] = n + 1


@njit(cache=True)
def _record(st, k, ref_grid, log, evs, par):
    """Row k of the steps table (``latency.loop._StepLog``) from the state at grid point k;
    a tilt-stop contact or release event where the flag changes (each row shows the flag of
    the row before).

    Compiled mirror of ``latency.loop._StepLog.write_rows``."""
    row = log[k]
    row[0] = k * par[_P_H]
    # element by element: a slice per field costs more than the copy itself
    for i in range(4):
        row[1 + i] = st[_Q + i]
        row[8 + i] = ref_grid[k, i]
        row[34 + i] = st[_EST + i]
    for i in range(3):
        row[5 + i] = st[_W + i]
        row[12 + i] = st[_TCMD + i]
        row[15 + i] = st[_TDEL + i]
    for i in range(N_COILS):
        row[18 + i] = st[_CUR + i]
    row[38] = st[_SAT]
    row[39] = st[_STOP]
    stop = 1.0 if 1.0 - 2.0 * (st[_Q + 1] ** 2 + st[_Q + 2] ** 2) < par[_P_COS_STOP] else 0.0
    if stop != st[_STOP]:
        _event(st, evs, row[0], _EV_CONTACT if stop > 0 else _EV_RELEASE, 0.0, 0.0, 0.0, 0.0)
    st[_STOP] = stop


@njit(cache=True, fastmath=FASTMATH)
def _advance(st, target, ref_grid, log, evs, par, J, J_inv, com, m_g, coils, magnets, gain,
             scal, pairs):
    """``latency.segments._advance_segment`` on the run's state: to the next grid point or the
    target, whichever is first (whole steps, a shortened last one, the coils' first-order
    lag exact at each step's start), recording each grid point, until within 1e-12 s of the
    target.

    Compiled mirror of ``latency.segments._advance_segment``."""
    h, tau_l, n_steps = par[_P_H], par[_P_TAU_L], int(par[_P_N_STEPS])
    # one rotor's state as tuples, stepped by the physics kernel's per-row function with the
    # run's pair lists ``pairs`` (no array per step)
    q = (st[_Q], st[_Q + 1], st[_Q + 2], st[_Q + 3])
    w = (st[_W], st[_W + 1], st[_W + 2])
    cur = st[_CUR : _CUR + N_COILS].copy()
    cmd = st[_CMD : _CMD + N_COILS]
    rotor = _rotor_tuples(J, J_inv, com, m_g, scal)
    cutoff = np.arccos(scal[3])
    decay_h = np.exp(-h / tau_l) if tau_l > 0 else 0.0  # the coils' lag over a whole step
    t, k = st[_T], int(st[_K])
    while True:
        t_grid = (k + 1) * h
        t_to = min(target, t_grid)
        if t_to > t:
            dt = t_to - t
            n = int(np.floor(dt / h + 1e-9))
            rest = dt - n * h
            for s in range(n + 1):
                hk = h if s < n else rest
                if s == n and not rest > 1e-12:
                    break
                decay = (decay_h if hk == h else np.exp(-hk / tau_l)) if tau_l > 0 else 0.0
                for i in range(N_COILS):
                    cur[i] = cmd[i] + (cur[i] - cmd[i]) * decay
                q, w, _ = _step_row(q, w, cur, hk, (0.0, 0.0, 0.0), PHYSICS_SUBSTEPS, rotor,
                                    coils, magnets, gain, cutoff, pairs, SUBSTEP_ANGLE_RAD)
            t = t_to
            st[_Q], st[_Q + 1], st[_Q + 2], st[_Q + 3] = q
            st[_W], st[_W + 1], st[_W + 2] = w
            for i in range(N_COILS):
                st[_CUR + i] = cur[i]
        if abs(t - t_grid) < 1e-12 and k + 1 <= n_steps:
            k += 1
            _record(st, k, ref_grid, log, evs, par)
        if t >= target - 1e-12:
            break
    st[_T], st[_K] = t, k
