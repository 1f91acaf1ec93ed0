"""The batched engine: many measurement-model runs of the timed loop.

Each run is a ``latency.loop.ClosedLoop`` (its own seed, delays, observer settings, gains and
reference). The engine decides per run (``latency.compiled.coverage``, from the types of its
parts and its settings, with the reason for a run it leaves to the rounds) which path computes
it:

* the compiled run loop (``latency.compiled``): the default case (measurement front end,
  per-frame least squares with or without the pixel Kalman filter, the PID or the MPC with its
  solver as machine code, model latencies), a whole run, events and physics, in one numba call;
* the lockstep rounds (``_run_group``) for the others: each run's events go through the loop's
  own timeline (``ClosedLoop.timeline``), which, between two events, asks for the physics to
  move to the next event with its currents held (an ``Advance``). The engine serves the open
  requests of all runs together: each round moves every such run to its next physics grid
  point or its event, with one call of the compiled rigid-body step
  (``plant.rigid_body.RigidBody``) over the batch, each run with its own step length (whole
  physics steps, and the shortened steps that put events on their exact times); it stores the
  states at the grid points and hands them back (a ``Segment``) when a run reaches its event.

Both paths use the physics of the event loop (``plant.dynamics.MujocoPlant`` advances one rotor
with the same compiled step) and its random streams: run by run, the engines compute the same
trajectory to rounding (tests/test_batched.py). Where the time goes: docs/closed_loop.md. Not
covered: MuJoCo's natively delayed sensor (``mujoco_sensor_delay_s``), which needs the MuJoCo
data of each run; those runs raise ``ValueError``. The engine is agnostic of the front end, but
image-in-the-loop runs gain nothing from batching the physics (the renderer and tracker
dominate), so callers send them to the event loop.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from tqdm import tqdm

from latency import compiled
from latency.loop import ClosedLoop
from latency.loop_config import LoopResult
from latency.segments import Advance, Segment
from plant import attitude
from plant.params import PlantParams
from plant.rigid_body import RigidBody
from plant.torque import N_COILS, Allocation, TorqueMap, allocate

_log = logging.getLogger(__name__)


class _Batch:
    """The physical state of B rotors with the same ``PlantParams``: attitudes (B, 4), body rates
    (B, 3), rad/s, and actual coil currents (B, 16), A."""

    def __init__(self, params: PlantParams, loops: Sequence[ClosedLoop]) -> None:
        self.params = params
        self.body = RigidBody(params)
        self.h = float(params.physics_dt_s)  # s, cached out of the model for the rounds
        self.tau_L = float(params.motor.coil_time_constant_s)  # s
        self.i_max = float(params.motor.i_max_A)  # A
        self.torque_map = TorqueMap(params.motor)
        self.q = np.array([attitude.normalize(lp.config.q0, "q0") for lp in loops])
        self.omega = np.array([np.asarray(lp.config.omega0_rad_s, float) for lp in loops])
        self.currents = np.zeros((len(loops), N_COILS))

    def advance(
        self,
        rows: NDArray[np.intp],
        cmd: NDArray[np.float64],
        dt: NDArray[np.float64],
        disturbances: Sequence[Callable[[float], NDArray[np.float64]] | None],
    ) -> None:
        """Advance ``rows`` by ``dt`` (s, one per row) with the commanded currents ``cmd``
        (rows, 16) held: as ``MujocoPlant.advance``, whole physics steps, then one shorter step
        for the remainder, and the coils' first-order lag, exact at each step's start.
        ``disturbances[i]`` (None: none) gives run i's body torque (N·m) for a step of h s."""
        h, tau_L = self.h, self.tau_L
        n = np.floor(dt / h + 1e-9).astype(int)
        rest = dt - n * h
        for k in range(int(n.max(initial=0)) + 1):
            whole = n > k
            last = (n == k) & (rest > 1e-12)
            sel = whole | last
            if not sel.any():
                continue
            idx = rows[sel]
            hk = np.where(whole[sel], h, rest[sel])
            decay = np.exp(-hk / tau_L)[:, None] if tau_L > 0 else 0.0
            c = cmd[sel]
            self.currents[idx] = c + (self.currents[idx] - c) * decay
            d = None
            if any(disturbances[i] is not None for i in idx):
                d = np.zeros((len(idx), 3))
                for j, (i, hi) in enumerate(zip(idx, hk, strict=True)):
                    fn = disturbances[i]
                    if fn is not None:
                        d[j] = fn(float(hi))
            self.q[idx], self.omega[idx] = self.body.step(
                self.q[idx], self.omega[idx], self.currents[idx], hk, d
            )


class _RunPlant:
    """One run's view of the batch, what its timeline reads (``latency.loop.PlantState``)."""

    def __init__(self, batch: _Batch, row: int) -> None:
        self.batch, self.row = batch, row
        self.disturbance: Callable[[float], NDArray[np.float64]] | None = None

    @property
    def q(self) -> NDArray[np.float64]:
        return self.batch.q[self.row].copy()

    @property
    def omega(self) -> NDArray[np.float64]:
        return self.batch.omega[self.row].copy()

    @property
    def currents(self) -> NDArray[np.float64]:
        return self.batch.currents[self.row].copy()

    def allocate(self, torque: ArrayLike, q: ArrayLike | None = None) -> Allocation:
        """Currents for a stator-frame torque (N·m) with the motor's limit, K at ``q`` (default
        the run's attitude), as ``MujocoPlant.allocate``."""
        K = self.batch.torque_map(self.q if q is None else q)
        return allocate(torque, K, self.batch.i_max)

    def delayed_q(self) -> NDArray[np.float64]:
        raise ValueError("the batched engine has no MuJoCo sensors; use the event loop")


def run_batched(
    loops: Sequence[ClosedLoop], progress: bool = False, tables: bool = True
) -> list[LoopResult]:
    """Run the closed loops together and return their results, in order.

    Runs of the default case (``latency.compiled.coverage``) run whole in the compiled run
    loop, one after the other; the others advance together in lockstep, those with different
    ``PlantParams`` in separate batches, and a run alone in its batch runs on the event loop.
    Why runs leave the compiled run loop is logged (``logging``, INFO, logger
    ``latency.batched``): one line per distinct reason, with the number of runs.
    Each result is what ``loop.run()`` returns (the same tables and ``summarize`` metrics).
    ``tables=False`` lets the compiled run loop leave its results' steps, frames and events
    tables empty (``latency.compiled.run``), for sweeps that keep the summaries only.
    """
    for lp in loops:
        if lp.config.mujoco_sensor_delay_s is not None:
            raise ValueError("mujoco_sensor_delay_s needs MuJoCo's sensors: use the event loop")
    results: list[LoopResult | None] = [None] * len(loops)
    groups: dict[str, list[int]] = {}
    fallbacks: Counter[str] = Counter()
    bar = tqdm(total=len(loops), disable=not progress, desc="batched runs", unit="run")
    for i, lp in enumerate(loops):
        cov = compiled.coverage(lp)
        if cov.path == "compiled":  # the default case: the whole run in the compiled loop
            results[i] = compiled.run(lp, tables)
            bar.update(1)
        else:
            fallbacks[cov.reason] += 1
            groups.setdefault(lp.params.model_dump_json(), []).append(i)
    for reason, n in fallbacks.items():
        _log.info("%d of %d runs not in the compiled run loop: %s", n, len(loops), reason)
    for members in groups.values():
        group = [loops[i] for i in members]
        # A batch of one gains nothing from the lockstep rounds: the event loop calls the same
        # compiled step for its rotor without the rounds' bookkeeping, with the same results.
        done = [group[0].run()] if len(group) == 1 else _run_group(group)
        for i, res in zip(members, done, strict=True):
            results[i] = res
            bar.update(1)
    bar.close()
    return [r for r in results if r is not None]


def _run_group(loops: Sequence[ClosedLoop]) -> list[LoopResult]:
    """Loops that share their ``PlantParams``, in lockstep: each round moves every run with an
    open ``Advance`` to its next grid point or its target (``latency.segments._advance_segment``
    for many runs), stores the state at the grid points, and resumes the runs whose target is
    reached with their ``Segment``."""
    B = len(loops)
    batch = _Batch(loops[0].params, loops)
    h = batch.h
    plants = [_RunPlant(batch, i) for i in range(B)]
    timelines = [lp.timeline(pl) for lp, pl in zip(loops, plants, strict=True)]
    results: list[LoopResult | None] = [None] * B
    n_steps = np.array([lp.n_steps for lp in loops])
    cmd = np.zeros((B, N_COILS))
    t, t_target = np.zeros(B), np.zeros(B)
    k = np.zeros(B, dtype=int)
    open_ = np.zeros(B, dtype=bool)  # an Advance is being served
    # The state at the grid points of each open Advance (grown when a segment is longer).
    cap = 64
    buf = np.zeros((B, cap, 4 + 3 + N_COILS))
    filled = np.zeros(B, dtype=int)

    def take(i: int, req: Advance) -> None:
        cmd[i], t[i], t_target[i], k[i] = req.currents, req.t_s, req.t_target_s, req.k_log
        filled[i] = 0
        open_[i] = True

    def resume(i: int, seg: Segment | None) -> None:
        try:
            take(i, next(timelines[i]) if seg is None else timelines[i].send(seg))
        except StopIteration as done:
            results[i] = done.value
            open_[i] = False

    for i in range(B):
        resume(i, None)
    disturbances = [pl.disturbance for pl in plants]  # set by each timeline at its start
    while open_.any():
        rows = np.flatnonzero(open_)
        t_grid = (k[rows] + 1) * h
        t_to = np.minimum(t_target[rows], t_grid)
        move = t_to > t[rows]
        if move.any():
            mv = rows[move]
            batch.advance(mv, cmd[mv], t_to[move] - t[mv], disturbances)
            t[mv] = t_to[move]
        on_grid = (np.abs(t[rows] - t_grid) < 1e-12) & (k[rows] + 1 <= n_steps[rows])
        if on_grid.any():
            g = rows[on_grid]
            k[g] += 1
            if filled[g].max() >= cap:
                buf = np.concatenate([buf, np.zeros_like(buf)], axis=1)
                cap = buf.shape[1]
            buf[g, filled[g]] = np.concatenate(
                [batch.q[g], batch.omega[g], batch.currents[g]], axis=1
            )
            filled[g] += 1
        for i in rows[t[rows] >= t_target[rows] - 1e-12]:
            seg = buf[i, : filled[i]]
            resume(int(i), Segment(float(t[i]), seg[:, :4].copy(), seg[:, 4:7].copy(),
                                   seg[:, 7:].copy()))
    return [r for r in results if r is not None]
