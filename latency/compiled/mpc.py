"""The MPC in the compiled run loop: ``controller.mpc.MPCController`` with its default SQP +
HPIPM solver and a fixed compute latency, its whole solver as machine code
(``controller.mpc_machine``, called through its address): the delay compensation over the
command history, the warm start and the solve. Its solver statistics
(``MPCController.unconverged`` and the like) are not kept."""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from controller import mpc_machine
from controller.mpc import MPCController
from controller.mpc_machine import MachineMPC, call_casadi, machine_mpc, weight_values
from latency.compiled import layout, pid, rotations
from latency.compiled.cache import compiled_in
from latency.compiled.layout import _RATE_W, _RELEASE
from latency.compiled.pid import _attitude_rate
from latency.compiled.rotations import _unit
from latency.loop import ClosedLoop
from latency.numba_cache import drop_stale_cache
from plant import attitude

#: The modules whose code these kernels compile in (``cache``).
COMPILED_IN = compiled_in((mpc_machine,), (layout, rotations, pid))
drop_stale_cache(__file__, COMPILED_IN)

#: The MPC's settings (``mpar``), by index: horizon N, step h (s), decision variables, constraints,
#: parameters, torque limit (N·m), the lead of each command (compute latency plus actuation
#: delay, s), delay-aware, hold on invalid estimates, the history's span (s), the prediction's
#: step (s), the RK4 chunk's length.
(_MP_N, _MP_H, _MP_NW, _MP_NG, _MP_NP, _MP_LIMIT, _MP_LEAD, _MP_AWARE, _MP_HOLD, _MP_KEEP,
 _MP_DSTEP, _MP_CHUNK) = range(12)
#: The MPC's state (``mst``): the last torque (3), a warm start (0/1), its t0 (s), the history's
#: first and end rows; then the warm start's w (nw), lam_x (nw) and lam_g (ng).
_M_TORQUE, _M_WARM, _M_WARM_T0, _M_HIST_FIRST, _M_HIST_END, _M_W = 0, 3, 4, 5, 6, 7


def _mpc_arrays(loop: ClosedLoop, ev_t: NDArray, ev_kind: NDArray, ev_idx: NDArray,
                n_frames: int) -> tuple:
    """The ``mpc`` argument of ``_run_events``: the MPC's settings (``_MP_*``), the NLP's
    parameters of each frame's release (as ``MPCController._parameters`` makes them before
    it aligns the signs, then the cost's weights, ``weight_values``; row = frame), the bounds
    (lbx, ubx, lbg, ubg), the decision vector's layout (X, U, S positions), the MPC's state
    and command history, the generated functions' call arguments (solver, RK4 chunk) and
    their input and output arrays. A PID run gets placeholders of the same types.

    Compiled mirror of ``controller.mpc.MPCController._parameters``."""
    ctrl = loop.controller
    if not isinstance(ctrl, MPCController):
        f1, f2 = np.zeros(1), np.zeros((1, 1))
        i1, i2 = np.zeros(1, np.int64), np.zeros((1, 1), np.int64)
        return (f1, f2, f1, i2, i2, i1, f1, np.zeros((1, 4)), np.zeros((2, 5), np.int64), f1,
                f1, f1, f1)
    cfg, pr = ctrl.config, ctrl.problem
    machine: MachineMPC | None = machine_mpc(pr)
    assert machine is not None and cfg.compute_latency_s is not None  # ``coverage``
    N, h, nw, ng = pr.N, pr.h, pr.nw, pr.ng
    lead = cfg.compute_latency_s + cfg.actuation_delay_s
    released = ev_kind == _RELEASE
    t_rel, rows = ev_t[released], ev_idx[released]
    n_rel = len(t_rel)
    if cfg.reference_preview:
        t0 = t_rel + lead if cfg.delay_aware else t_rel
        ref = loop.reference.sample_many((t0[:, None] + h * np.arange(N + 1)).ravel())
        qr = attitude.normalize(np.asarray(ref.q, float).reshape(n_rel, N + 1, 4), "reference.q")
        wr = np.asarray(ref.omega, float).reshape(n_rel, N + 1, 3)
        ar = np.asarray(ref.alpha, float).reshape(n_rel, N + 1, 3)[:, :N]
    else:  # the reference at the call, held, without rate
        held = attitude.normalize(np.asarray(loop.reference.sample_many(t_rel).q, float),
                                  "reference.q")
        qr = np.repeat(held[:, None], N + 1, axis=1)
        wr, ar = np.zeros((n_rel, N + 1, 3)), np.zeros((n_rel, N, 3))
    J = pr.J
    tau = J * ar + np.cross(wr[:, :N], J * wr[:, :N])  # body frame of the reference
    tff = np.einsum("rkij,rkj->rki", attitude.to_matrix(qr[:, :N]), tau)  # R(q) = R(-q)
    weights = weight_values(pr)  # the machine code's extra parameters, the same at each release
    n_p = 7 * (N + 1) + 3 * N + len(weights)
    mref = np.zeros((n_frames, n_p))
    mref[rows] = np.concatenate([qr.reshape(n_rel, -1), wr.reshape(n_rel, -1),
                                 tff.reshape(n_rel, -1), np.tile(weights, (n_rel, 1))], axis=1)
    mpar = np.zeros(12)
    mpar[_MP_N], mpar[_MP_H], mpar[_MP_NW], mpar[_MP_NG], mpar[_MP_NP] = N, h, nw, ng, n_p
    mpar[_MP_LIMIT], mpar[_MP_LEAD] = ctrl.torque_limit, lead
    mpar[_MP_AWARE], mpar[_MP_HOLD] = cfg.delay_aware, cfg.invalid_command == "hold"
    mpar[_MP_KEEP], mpar[_MP_DSTEP] = N * h + 1.0, cfg.prediction_step_s
    mpar[_MP_CHUNK] = pr.chunk
    solve, rk4 = machine.solver, machine.rk4_chunk
    # the inputs' and outputs' layout that ``_mpc`` and ``_mpc_predict`` assume
    assert list(np.diff(solve.offsets_in)) == [nw, n_p, nw, nw, ng, ng, nw, ng]
    assert list(np.diff(solve.offsets_out)[:5]) == [nw, 1, ng, nw, ng]
    assert list(np.diff(rk4.offsets_in)) == [7, 3 * pr.chunk, pr.chunk]
    bounds = np.concatenate([pr.lbw, pr.ubw, pr.lbg, pr.ubg])
    calls = np.array([solve.call_args(), rk4.call_args()], dtype=np.int64)
    return (mpar, mref, bounds, np.ascontiguousarray(pr.ix), np.ascontiguousarray(pr.iu),
            np.ascontiguousarray(pr.i_s), np.zeros(_M_W + 2 * nw + ng),
            np.zeros((n_frames + 1, 4)), calls, solve.inputs, solve.outputs, rk4.inputs,
            rk4.outputs)


@njit(cache=True)
def _mpc_record(mst, mhist, t_apply, torque, keep):
    """``MPCController.record_command``: the stator torque (N·m) acts from ``t_apply`` (s);
    the rows (time, torque) older than ``keep`` s before it are forgotten (all but one).

    Compiled mirror of ``controller.mpc.MPCController.record_command``."""
    n = int(mst[_M_HIST_END])
    mhist[n, 0] = t_apply
    mhist[n, 1:4] = torque
    mst[_M_HIST_END] = n + 1
    while (mst[_M_HIST_END] - mst[_M_HIST_FIRST] > 1
           and mhist[int(mst[_M_HIST_FIRST]) + 1, 0] < t_apply - keep):
        mst[_M_HIST_FIRST] += 1


@njit(cache=True)
def _mpc_predict(x, t_from, t_to, mpar, mst, mhist, rk4, r_in, r_out):
    """``MPCController.predict``: the twin's state x (7,) carried from ``t_from`` to ``t_to``
    (s) under the history's torques (zero before the first), in steps of at most the
    prediction step, a chunk of RK4 steps per call of the generated ``rk4_chunk`` (padded with
    zero steps, as ``predict`` pads).

    Compiled mirror of ``controller.mpc.MPCController.predict``."""
    if t_to <= t_from:
        return x
    first, end = int(mst[_M_HIST_FIRST]), int(mst[_M_HIST_END])
    chunk, dmax = int(mpar[_MP_CHUNK]), mpar[_MP_DSTEP]
    # the segments' ends: t_from, the commands' start times inside (t_from, t_to), t_to
    edges = [t_from]
    for r in range(first, end):
        if t_from < mhist[r, 0] < t_to:
            edges.append(mhist[r, 0])
    edges.append(t_to)
    filled = 0
    x_at, T_at, h_at = 0, 7, 7 + 3 * chunk  # the chunk's inputs x (7), T (3 x chunk), h (chunk)
    r_in[x_at : x_at + 7] = x
    for s in range(len(edges) - 1):
        a, b = edges[s], edges[s + 1]
        k = first - 1  # the last command started at or before a (searchsorted, side right)
        for r in range(first, end):
            if mhist[r, 0] <= a:
                k = r
        n = max(int(np.ceil((b - a) / dmax - 1e-9)), 1)
        for _ in range(n):
            for c in range(3):
                r_in[T_at + 3 * filled + c] = mhist[k, 1 + c] if k >= first else 0.0
            r_in[h_at + filled] = (b - a) / n
            filled += 1
            if filled == chunk:
                call_casadi(rk4[0], rk4[1], rk4[2], rk4[3], rk4[4])
                r_in[x_at : x_at + 7] = r_out[7 * (chunk - 1) : 7 * chunk]
                filled = 0
    if filled > 0:
        r_in[T_at + 3 * filled : h_at] = 0.0
        r_in[h_at + filled : h_at + chunk] = 0.0
        call_casadi(rk4[0], rk4[1], rk4[2], rk4[3], rk4[4])
        r_in[x_at : x_at + 7] = r_out[7 * (chunk - 1) : 7 * chunk]
    return r_in[x_at : x_at + 7].copy()


@njit(cache=True)
def _mpc_initial_state(st, q_est, t_state, t, mpar, mst, mhist, rk4, r_in, r_out):
    """The NLP's initial state x (7,) and its time t0 (s) for an estimate's attitude
    ``q_est`` describing ``t_state`` at the call time ``t``: the attitude, the rate from
    successive attitudes (0 until known), carried to the command's start when delay-aware.

    Compiled mirror of ``controller.mpc.MPCController._initial_state``."""
    q = _unit(q_est)
    _attitude_rate(st, q, t_state)
    x = np.empty(7)
    for i in range(4):
        x[i] = q[i]
    for i in range(3):
        w = st[_RATE_W + i]
        x[4 + i] = w if np.isfinite(w) else 0.0
    t0 = t
    if mpar[_MP_AWARE] > 0:
        t0 = t + mpar[_MP_LEAD]
        x = _mpc_predict(x, t_state, t0, mpar, mst, mhist, rk4, r_in, r_out)
    return x, t0


@njit(cache=True)
def _mpc_parameters(p, row, x, N):
    """The NLP's parameters ``p`` of a release from its row of ``_mpc_arrays``: each
    reference attitude on the side of the one before (the first on x's).

    Compiled mirror of ``controller.mpc.MPCController._parameters``."""
    p[:] = row
    prev = x[:4].copy()
    for k in range(N + 1):
        qk = p[4 * k : 4 * k + 4]
        if qk[0] * prev[0] + qk[1] * prev[1] + qk[2] * prev[2] + qk[3] * prev[3] < 0:
            qk *= -1.0
        prev = qk.copy()


@njit(cache=True)
def _mpc_guess(guess, lam, x, t0, mpar, mst, mix, miu, mis):
    """The solver's initial guess ``guess`` (nw,) and multipliers ``lam`` (nw + ng,): the
    previous solution shifted by the steps elapsed since its t0 (its multipliers when none
    has), or x held over the horizon without a previous solution.

    Compiled mirror of ``controller.mpc.MPCController._initial_guess``."""
    N, h = int(mpar[_MP_N]), mpar[_MP_H]
    nw, ng = int(mpar[_MP_NW]), int(mpar[_MP_NG])
    lam[:] = 0.0
    if mst[_M_WARM] == 0:
        for k in range(N + 1):
            guess[mix[k]] = x
        for k in range(N):
            guess[miu[k]] = 0.0
        guess[mis] = 0.0
        return
    w_prev = mst[_M_W : _M_W + nw]
    m = int(np.rint((t0 - mst[_M_WARM_T0]) / h))
    m = min(max(m, 0), N)
    for k in range(N + 1):
        guess[mix[k]] = w_prev[mix[min(k + m, N)]]
    for k in range(N):
        guess[miu[k]] = w_prev[miu[min(k + m, N - 1)]]
        guess[mis[k]] = w_prev[mis[min(k + m, N - 1)]]
    guess[mix[0]] = x
    guess[mis[0]] = 0.0
    for k in range(N + 1):
        qk = guess[mix[k][:4]]
        if qk[0] * x[0] + qk[1] * x[1] + qk[2] * x[2] + qk[3] * x[3] < 0:
            guess[mix[k][:4]] = -qk
    if m == 0:
        lam[:] = mst[_M_W + nw : _M_W + 2 * nw + ng]


@njit(cache=True)
def _mpc_keep(status, s_out, t0, mpar, mst, miu, torque):
    """After a solve of return code ``status`` with the outputs ``s_out``: a solution kept
    as the next warm start and its first torque (N·m, limited) in ``torque``; after a failed
    solve no warm start, the torque held.

    Compiled mirror of ``controller.mpc.MPCController.command``."""
    nw, ng = int(mpar[_MP_NW]), int(mpar[_MP_NG])
    w = s_out[:nw]
    if status != 0 or not np.all(np.isfinite(w)):  # a failed solve: hold the torque
        mst[_M_WARM] = 0.0
        return
    at_lx = nw + 1 + ng  # the outputs x, f, g, lam_x, lam_g, lam_p
    mst[_M_W : _M_W + nw] = w
    mst[_M_W + nw : _M_W + 2 * nw + ng] = s_out[at_lx : at_lx + nw + ng]
    mst[_M_WARM], mst[_M_WARM_T0] = 1.0, t0
    T = w[miu[0]]
    n = np.sqrt(T[0] * T[0] + T[1] * T[1] + T[2] * T[2])
    if n > mpar[_MP_LIMIT]:  # solver tolerance: never ask beyond the limit
        T *= mpar[_MP_LIMIT] / n
    torque[:] = T


@njit(cache=True)
def _mpc(st, valid, q_est, t_state, t, frame, mpc):
    """The MPC's command on an estimate (valid, attitude, the time it describes) at the
    release time ``t`` (s) of frame ``frame``: the stator-frame torque (3,), N·m. The NLP's
    parameters of each release are sampled beforehand (``_mpc_arrays``; the reference's signs
    are aligned here, ``_mpc_parameters``); the solve is the generated SQP solver
    (``controller.mpc_machine``).

    Compiled mirror of ``controller.mpc.MPCController.command``."""
    (mpar, mref, mbounds, mix, miu, mis, mst, mhist, calls, s_in, s_out, r_in, r_out) = mpc
    N = int(mpar[_MP_N])
    nw, ng, n_p = int(mpar[_MP_NW]), int(mpar[_MP_NG]), int(mpar[_MP_NP])
    torque = mst[_M_TORQUE : _M_TORQUE + 3]
    if not valid:  # ``_safe``: the invalid-estimate policy
        if mpar[_MP_HOLD] == 0:
            torque[:] = 0.0
        _mpc_record(mst, mhist, t + mpar[_MP_LEAD], torque, mpar[_MP_KEEP])
        return torque.copy()
    x, t0 = _mpc_initial_state(st, q_est, t_state, t, mpar, mst, mhist, calls[1], r_in, r_out)
    # the solver's inputs: x0 (nw), p (n_p), lbx, ubx (nw), lbg, ubg (ng), lam_x0 (nw), lam_g0
    at_p, at_lbx, at_ubx, at_lbg = nw, nw + n_p, 2 * nw + n_p, 3 * nw + n_p
    at_lam_x, at_lam_g = 3 * nw + n_p + 2 * ng, 4 * nw + n_p + 2 * ng
    _mpc_parameters(s_in[at_p : at_p + n_p], mref[frame], x, N)
    _mpc_guess(s_in[:nw], s_in[at_lam_x : at_lam_g + ng], x, t0, mpar, mst, mix, miu, mis)
    # ``controller.mpc_problem.MPCProblem.bounds``: the first state fixed to x0
    s_in[at_lbx : at_lbg + 2 * ng] = mbounds
    s_in[at_lbx : at_lbx + 7] = x
    s_in[at_ubx : at_ubx + 7] = x
    solve = calls[0]
    status = call_casadi(solve[0], solve[1], solve[2], solve[3], solve[4])
    _mpc_keep(status, s_out, t0, mpar, mst, miu, torque)
    _mpc_record(mst, mhist, t0, torque, mpar[_MP_KEEP])
    return torque.copy()
