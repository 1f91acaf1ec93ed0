"""A whole run in the compiled run loop: its inputs, the kernel's calls (with the LP of
``plant.torque.allocate`` in between when the least-norm currents break the limits), and its
result as the event loop's."""

from __future__ import annotations

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from latency.compiled.coverage import _solver_observer, coverage
from latency.compiled.events import _schedule
from latency.compiled.kernel import _run_events
from latency.compiled.layout import (
    _ALLOC_Q,
    _ALLOC_SAT,
    _ALLOC_T,
    _CMD,
    _DIV,
    _DIV_DEG,
    _EST,
    _F_DROPPED,
    _F_LATENCY,
    _F_LOST,
    _F_T_EXP,
    _K,
    _KF,
    _KF_SIZE,
    _N_EV,
    _N_FR,
    _N_STATE,
    _OBS_Q,
    _Q,
    _RATE_Q,
    _RATE_T,
    _RATE_W,
    _T_PREV,
    _TDEL,
    _W,
)
from latency.compiled.mpc import _mpc_arrays
from latency.compiled.settings import _model_arrays, _plant_parts, _settings
from latency.compiled.tables import (
    _NO_EVENTS,
    _NO_ROWS,
    _events_table,
    _frames_columns,
    _summary_rows,
)
from latency.loop import ClosedLoop, _StepLog
from latency.loop_config import LoopResult
from latency.metrics import frame_values, step_values, summarize, summarize_values
from plant.torque import N_COILS, allocate


def run(loop: ClosedLoop, tables: bool = True) -> LoopResult:
    """Run ``loop`` (``coverage(loop).path`` must be ``"compiled"``) and return what
    ``loop.run()`` returns: the same tables and ``summarize`` metrics (``latency.compiled``'s
    docstring: where they differ).

    ``tables=False`` leaves the steps, frames and events tables of the result empty (tables
    without rows that all such results share; do not modify them): the summary is computed
    from the kernel's arrays, without building the tables or the events' texts (for sweeps
    that keep the summaries only)."""
    if (cov := coverage(loop)).path != "compiled":
        raise ValueError(f"the compiled run loop does not cover this run ({cov.reason}); use "
                         "the event loop")
    c, p = loop.config, loop.params
    ev_t, ev_kind, ev_idx, frames = _schedule(loop)
    n_steps = loop.n_steps
    ref_grid = np.ascontiguousarray(
        loop.reference.sample_many(np.arange(n_steps + 1) * p.physics_dt_s).q)
    ref = loop.reference.sample_many(ev_t)
    body_consts, tm, camera_truth, tm_gain = _plant_parts(p)
    solver = _solver_observer(loop).solver  # type: ignore[union-attr]
    par = _settings(loop)
    st = _initial_state(c.q0, c.omega0_rad_s)
    # A summary-only run's step rows are read before the next run writes them: one buffer
    # serves them all (each row is written whole before it is read).
    log = _StepLog(n_steps + 1) if tables else None
    rows = log.a if log is not None else _summary_rows(n_steps + 1)
    fr = np.full((len(frames), _N_FR), np.nan)
    evs = np.zeros((4 * len(frames) + n_steps + 8, 6))
    mpc = _mpc_arrays(loop, ev_t, ev_kind, ev_idx, len(frames))
    args = (ev_t, ev_kind, ev_idx, frames, ref_grid, np.ascontiguousarray(ref.q),
            np.ascontiguousarray(ref.omega), np.ascontiguousarray(ref.alpha), par, *body_consts,
            camera_truth, _model_arrays(solver.model), tm_gain, loop.front_end.rng, st, rows,
            fr, evs, mpc)
    e, ready = 0, False
    while (e := _run_events(e, ready, *args)) < len(ev_t):
        # least-norm currents beyond the limits: the LP and bounded solve of ``allocate``
        alloc = allocate(st[_ALLOC_T : _ALLOC_T + 3], tm(st[_ALLOC_Q : _ALLOC_Q + 4]),
                         p.motor.i_max_A)
        st[_CMD : _CMD + N_COILS], st[_TDEL : _TDEL + 3] = alloc.currents, alloc.delivered
        st[_ALLOC_SAT], ready = float(alloc.saturated), True
    n_rows = int(st[_K]) + 1
    evs = evs[: int(st[_N_EV])]
    stopped = f"divergence: geodesic error {st[_DIV_DEG]:.1f} deg" if st[_DIV] > 0 else ""
    if not tables:
        # The summary straight from the kernel's arrays: no tables, no events' texts.
        a = rows[:n_rows]
        values = step_values(a[:, 0], a[:, 1:5], a[:, 8:12], a[:, 15:18], a[:, 39] > 0,
                             c.step_metrics)
        frame_metrics = frame_values(fr[:, _F_T_EXP], fr[:, _F_DROPPED] > 0,
                                     fr[:, _F_LOST] == 1.0, fr[:, _F_LATENCY], a[-1, 0])
        summary = summarize_values(values, a[-1, 0], frame_metrics, len(evs), c.duration_s,
                                   stopped)
        return LoopResult(_NO_ROWS, _NO_ROWS, _NO_EVENTS, summary, c.model_dump(mode="json"))
    assert log is not None
    steps = log.columns(n_rows)
    frames_cols = _frames_columns(fr, solver)
    events = _events_table(evs, frames_cols)
    summary = summarize(steps, frames_cols, events, c.duration_s, stopped, c.step_metrics)
    return LoopResult(pd.DataFrame(steps), pd.DataFrame(frames_cols), events, summary,
                      c.model_dump(mode="json"))


def _initial_state(q0: ArrayLike, omega0: ArrayLike) -> NDArray[np.float64]:
    """A run's scalar state (``st``) at its start: the rotor at the attitude ``q0`` with the
    body rate ``omega0`` (rad/s), the observer's solution ``q0``, the controllers, the front
    end and the filters reset, the steps table not started."""
    st = np.zeros(_N_STATE)
    q0 = np.asarray(q0, dtype=float) / np.linalg.norm(q0)
    st[_Q : _Q + 4], st[_W : _W + 3], st[_OBS_Q : _OBS_Q + 4] = q0, omega0, q0
    st[_K], st[_T_PREV], st[_RATE_T] = -1.0, np.nan, -np.inf
    for b in (_KF, _KF + _KF_SIZE):  # PixelKalman.reset: X = 0, P = I, not initialised
        st[b + 5 : b + 21] = np.eye(4).ravel()
    for at, n in ((_EST, 4), (_RATE_Q, 4), (_RATE_W, 3)):
        st[at : at + n] = np.nan
    return st
