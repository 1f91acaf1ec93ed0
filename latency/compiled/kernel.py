"""The compiled run loop's kernel: a run's events, walked in order, with the rotor advanced
between them (``steps``), one handler per kind of event as the event loop has them."""

from __future__ import annotations

import numpy as np
from numba import njit

from latency.compiled import allocation, frontend, layout, mpc, observer, pid, rotations, steps
from latency.compiled.allocation import _least_norm, _torque_map
from latency.compiled.cache import compiled_in
from latency.compiled.frontend import _capture
from latency.compiled.layout import (
    _ALLOC_Q,
    _ALLOC_SAT,
    _ALLOC_T,
    _CMD,
    _DIV,
    _DIV_DEG,
    _EST,
    _EV_DIVERGENCE,
    _EV_DROPPED,
    _EV_INVALID_CMD,
    _EV_INVALID_EST,
    _EV_LOSS,
    _EV_REACQ,
    _EV_SATURATION,
    _F_CAP_LOST,
    _F_CAP_REASON,
    _F_CENTRE,
    _F_DROPPED,
    _F_EST,
    _F_HELD_FROM,
    _F_INDEX,
    _F_LATENCY,
    _F_LOST,
    _F_MEAS,
    _F_REASON,
    _F_REASON_VALUE,
    _F_RELEASED,
    _F_T_EXP,
    _F_T_REL,
    _F_TORQUE,
    _F_TRUE,
    _F_VALID,
    _FRAME,
    _K,
    _LOST,
    _OBS_Q,
    _OBS_T,
    _P_DIV_DEG,
    _P_DURATION,
    _P_I_MAX,
    _P_KF_ON,
    _P_KT_COS,
    _P_LOSS_PX,
    _P_MAX_INVALID,
    _P_MPC,
    _P_TRUTH,
    _Q,
    _R_LOST,
    _RELEASE,
    _SAT,
    _T,
    _TCMD,
    _TDEL,
    _W,
)
from latency.compiled.mpc import _mpc
from latency.compiled.observer import _pixel_kalman, _solve
from latency.compiled.pid import _pid
from latency.compiled.rotations import _geodesic
from latency.compiled.steps import _advance, _event, _record
from latency.numba_cache import drop_stale_cache
from plant import rigid_body
from plant.rigid_body import PAIR_REUSE_RAD, _pair_lists
from plant.torque import N_COILS

#: The modules whose code these kernels compile in (``cache``).
COMPILED_IN = compiled_in((rigid_body,), (layout, rotations, frontend, observer, pid, mpc,
                                          allocation, steps))
drop_stale_cache(__file__, COMPILED_IN)


@njit(cache=True)
def _on_frame(st, t, i, f, timing, ref_q, par, true_model, rng, meas, evs):
    """Frame ``i``'s mid-exposure at ``t`` (s), its timing (t_exposure, t_release, dropped)
    and the reference attitude ``ref_q`` at ``t``: the divergence check, and unless the frame
    is dropped, the front end's capture, the loss check against the seed's threshold and the
    frame's record ``f``.

    Compiled mirror of ``latency.loop.ClosedLoop._on_frame``."""
    q = st[_Q : _Q + 4]
    err = np.degrees(_geodesic(q, ref_q))
    newly = (not np.isfinite(err) or err > par[_P_DIV_DEG]) and st[_DIV] == 0
    if newly:
        st[_DIV], st[_DIV_DEG] = 1.0, err
    f[_F_INDEX], f[_F_T_EXP], f[_F_T_REL] = i, timing[0], timing[1]
    f[_F_DROPPED] = timing[2]
    if timing[2] > 0:
        _event(st, evs, t, _EV_DROPPED, i, 0.0, 0.0, 0.0)
    else:
        truth, cap_lost, reason = _capture(st, q, st[_W : _W + 3], par, *true_model, rng, meas)
        worst, any_finite, lost = -np.inf, False, cap_lost
        for j in range(2):
            du, dv = meas[j, 0] - truth[j, 0], meas[j, 1] - truth[j, 1]
            d = np.sqrt(du * du + dv * dv)
            if np.isfinite(d):
                any_finite = True
                worst = max(worst, d)
            if not d <= par[_P_LOSS_PX]:
                lost = True
        if lost != (st[_LOST] > 0):
            _event(st, evs, t, _EV_LOSS if lost else _EV_REACQ, reason,
                   worst if any_finite else np.nan, 0.0, 0.0)
            st[_LOST] = 1.0 if lost else 0.0
        f[_F_TRUE : _F_TRUE + 4] = truth.ravel()
        f[_F_MEAS : _F_MEAS + 4] = meas.ravel()
        f[_F_CENTRE] = worst if any_finite else np.nan
        f[_F_LOST] = 1.0 if lost else 0.0
        f[_F_CAP_LOST] = 1.0 if cap_lost else 0.0
        f[_F_CAP_REASON] = reason
    if newly:
        _event(st, evs, t, _EV_DIVERGENCE, st[_DIV_DEG], 0.0, 0.0, 0.0)


@njit(cache=True)
def _on_release(st, t, i, f, ref_q, ref_w, ref_a, par, obs_model, evs, mpc_args):
    """Frame ``i``'s release at ``t`` (s), the reference (attitude, rate, acceleration)
    sampled at ``t``: the observer (the pixel Kalman filters when the run has them, the
    solve), its estimate in the frame's record ``f``, and the controller's command on it
    (kept in ``f`` for the command event). ``mpc_args``: as ``_run_events``'s.

    Compiled mirror of ``latency.loop.ClosedLoop._on_release``."""
    t_exp = f[_F_T_EXP]
    uv = f[_F_MEAS : _F_MEAS + 4].copy().reshape(2, 2)
    lost = f[_F_CAP_LOST] > 0
    if par[_P_KF_ON] > 0:  # the filters' prior stands in for a lost frame
        uv = _pixel_kalman(st, par, uv, lost)
        lost = lost and not np.all(np.isfinite(uv))
    if lost:
        code, value = _R_LOST, f[_F_CAP_REASON]
    else:
        q_sol, ok, code, value = _solve(st[_OBS_Q : _OBS_Q + 4], uv, *obs_model, par)
        if ok:
            st[_OBS_Q : _OBS_Q + 4], st[_OBS_T] = q_sol, t_exp
    valid = t_exp - st[_OBS_T] <= par[_P_MAX_INVALID]
    st[_EST : _EST + 4] = st[_OBS_Q : _OBS_Q + 4]
    f[_F_RELEASED] = 1.0
    f[_F_EST : _F_EST + 4] = st[_OBS_Q : _OBS_Q + 4]
    f[_F_VALID], f[_F_REASON], f[_F_REASON_VALUE] = 1.0 if valid else 0.0, code, value
    f[_F_HELD_FROM] = st[_OBS_T] if st[_OBS_T] < t_exp else np.nan
    f[_F_LATENCY] = t - t_exp
    if not valid:
        _event(st, evs, t, _EV_INVALID_EST, i, 0.0, 0.0, 0.0)
    if par[_P_MPC] > 0:
        torque = _mpc(st, valid, st[_EST : _EST + 4], st[_OBS_T], t, i, mpc_args)
    else:
        torque = _pid(st, par, valid, st[_EST : _EST + 4], st[_OBS_T], ref_q, ref_w, ref_a)
    if not np.all(np.isfinite(torque)):
        _event(st, evs, t, _EV_INVALID_CMD, torque[0], torque[1], torque[2], 0.0)
        torque[:] = 0.0
    f[_F_TORQUE : _F_TORQUE + 3] = torque


@njit(cache=True)
def _on_command(st, t, f, par, coils, magnets, tm_gain, alloc_ready, evs):
    """The command of the frame whose record is ``f`` at ``t`` (s): its currents, the least-norm
    ones within the limits, or with ``alloc_ready`` those of ``plant.torque.allocate`` that
    the caller put in ``st``; the saturation event where the flag changes. Returns True,
    with the torque and the attitude to allocate at in ``st``, when the least-norm currents
    break the limits (nothing applied).

    Compiled mirror of ``latency.loop.ClosedLoop._on_command``."""
    torque = f[_F_TORQUE : _F_TORQUE + 3]
    if alloc_ready:  # the allocation of ``plant.torque.allocate``, set by the caller
        saturated = st[_ALLOC_SAT]
    else:  # the least-norm currents, when they are within the limits
        truth_q = par[_P_TRUTH] > 0 or f[_F_VALID] == 0
        q_alloc = st[_Q : _Q + 4].copy() if truth_q else f[_F_EST : _F_EST + 4].copy()
        K = _torque_map(q_alloc, coils, magnets, tm_gain, par[_P_KT_COS])
        currents, delivered, solved = _least_norm(K, torque)
        if not solved or np.max(np.abs(currents)) > par[_P_I_MAX]:
            st[_ALLOC_T : _ALLOC_T + 3] = torque
            st[_ALLOC_Q : _ALLOC_Q + 4] = q_alloc
            return True
        st[_CMD : _CMD + N_COILS] = currents
        st[_TDEL : _TDEL + 3] = delivered
        saturated = 0.0
    if saturated != st[_SAT]:
        if saturated > 0:
            delivered = st[_TDEL : _TDEL + 3]
            _event(st, evs, t, _EV_SATURATION, np.sqrt(delivered @ delivered),
                   np.sqrt(torque @ torque), 0.0, 0.0)
        st[_SAT] = saturated
    st[_TCMD : _TCMD + 3] = torque
    return False


@njit(cache=True)
def _run_events(e, alloc_ready, ev_t, ev_kind, ev_idx, frames, ref_grid, ref_q, ref_w, ref_a,
                par, J, J_inv, com, m_g, coils, magnets, gain, scal, true_model, obs_model,
                tm_gain, rng, st, log, fr, evs, mpc_args):
    """Run the events from index e on (``latency.compiled``'s docstring). Returns the index of
    a command whose currents need ``plant.torque.allocate`` (its torque and attitude in
    ``st``; call again with ``alloc_ready`` and the allocation in ``st``), or the number of
    events when the run is complete. ``true_model`` and ``obs_model`` are (markers (2, 3), m;
    CoR in the camera frame (3,), m; intrinsics (7,)) of the camera's truth and of the
    observer's model. ``mpc_args``: the MPC's arrays (``mpc._mpc_arrays``; placeholders for a PID
    run).

    Compiled mirror of ``latency.loop.ClosedLoop.timeline``."""
    duration = par[_P_DURATION]
    if st[_K] < 0:
        st[_K] = 0.0
        _record(st, 0, ref_grid, log, evs, par)
    meas = np.empty((2, 2))
    # the rotor's pair lists, kept from step to step while they cover its turn
    pairs = _pair_lists(magnets.shape[0], coils.shape[0], PAIR_REUSE_RAD)
    while e < ev_t.shape[0]:
        target = min(ev_t[e], duration)
        if target > st[_T]:
            _advance(st, target, ref_grid, log, evs, par, J, J_inv, com, m_g, coils, magnets,
                     gain, scal, pairs)
        t = st[_T]
        i = ev_idx[e]
        if ev_kind[e] == _FRAME:
            _on_frame(st, t, i, fr[i], frames[i], ref_q[e], par, true_model, rng, meas, evs)
        elif ev_kind[e] == _RELEASE:
            _on_release(st, t, i, fr[i], ref_q[e], ref_w[e], ref_a[e], par, obs_model, evs,
                        mpc_args)
        else:
            if _on_command(st, t, fr[i], par, coils, magnets, tm_gain, alloc_ready, evs):
                return e
            alloc_ready = False
        e += 1
    if duration > st[_T]:
        _advance(st, duration, ref_grid, log, evs, par, J, J_inv, com, m_g, coils, magnets,
                 gain, scal, pairs)
    return e
