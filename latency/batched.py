"""The batched engine: many measurement-model runs of the timed loop advanced together.

Each run is a ``latency.loop.ClosedLoop`` (its own seed, delays, observer settings, gains and
reference). Its events (frames, releases, commands) run through the loop's own timeline
(``ClosedLoop.timeline``), which yields each time the physics must advance by some dt with held
currents. The engine collects one such request from every unfinished run and serves all of
them with one call of the vectorised rigid-body step (``plant.rigid_body.RigidBody``) over the
batch: whole physics steps and the shortened steps that put events on their exact times, each
run with its own length. The physics is therefore the same code as the event loop's
(``plant.dynamics.MujocoPlant`` advances one rotor with the same step), and so are the event
handlers and the random streams: run by run, the two engines compute the same trajectory to
rounding (tests/test_batched.py).

Where the time goes (docs/closed_loop.md): the batched physics costs about as much per rotor as
CasADi-generated C called per rotor, and a run's events and per-step bookkeeping stay Python per
run. Not covered: MuJoCo's natively delayed sensor (``mujoco_sensor_delay_s``), which needs the
MuJoCo data of each run; those runs raise ``ValueError``. The engine is agnostic of the front
end, but image-in-the-loop runs gain nothing from batching the physics (the renderer and tracker
dominate), so callers send them to the event loop.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from tqdm import tqdm

from latency.loop import ClosedLoop, LoopResult
from plant import attitude
from plant.params import PlantParams
from plant.rigid_body import RigidBody
from plant.torque import N_COILS, Allocation, TorqueMap, allocate


class _Batch:
    """The physical state of B rotors with the same ``PlantParams``: attitudes (B, 4), body rates
    (B, 3), rad/s, and actual coil currents (B, 16), A."""

    def __init__(self, params: PlantParams, loops: Sequence[ClosedLoop]) -> None:
        self.params = params
        self.body = RigidBody(params)
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
        h = self.params.physics_dt_s
        tau_L = self.params.motor.coil_time_constant_s
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
        return allocate(torque, K, float(self.batch.params.motor.i_max_A))

    def tilt_stop_active(self) -> bool:
        return bool(self.batch.body.tilt_stop_active(self.batch.q[self.row][None])[0])

    def delayed_q(self) -> NDArray[np.float64]:
        raise ValueError("the batched engine has no MuJoCo sensors; use the event loop")


def run_batched(loops: Sequence[ClosedLoop], progress: bool = False) -> list[LoopResult]:
    """Run the closed loops together and return their results, in order.

    Runs with different ``PlantParams`` are batched separately. Each result is what
    ``loop.run()`` returns (the same tables and ``summarize`` metrics).
    """
    for lp in loops:
        if lp.config.mujoco_sensor_delay_s is not None:
            raise ValueError("mujoco_sensor_delay_s needs MuJoCo's sensors: use the event loop")
    results: list[LoopResult | None] = [None] * len(loops)
    groups: dict[str, list[int]] = {}
    for i, lp in enumerate(loops):
        groups.setdefault(lp.params.model_dump_json(), []).append(i)
    bar = tqdm(total=len(loops), disable=not progress, desc="batched runs", unit="run")
    for members in groups.values():
        group = [loops[i] for i in members]
        for i, res in zip(members, _run_group(group), strict=True):
            results[i] = res
            bar.update(1)
    bar.close()
    return [r for r in results if r is not None]


def _run_group(loops: Sequence[ClosedLoop]) -> list[LoopResult]:
    """Loops that share their ``PlantParams``: lockstep over the physics requests."""
    batch = _Batch(loops[0].params, loops)
    plants = [_RunPlant(batch, i) for i in range(len(loops))]
    timelines = [lp.timeline(pl) for lp, pl in zip(loops, plants, strict=True)]
    results: list[LoopResult | None] = [None] * len(loops)
    cmd = np.zeros((len(loops), N_COILS))
    dt = np.zeros(len(loops))
    live = np.ones(len(loops), dtype=bool)

    def resume(i: int, first: bool) -> None:
        try:
            c, step = next(timelines[i]) if first else timelines[i].send(None)
            cmd[i], dt[i] = c, step
        except StopIteration as done:
            results[i] = done.value
            live[i] = False

    for i in range(len(loops)):
        resume(i, True)
    disturbances = [pl.disturbance for pl in plants]  # set by each timeline at its start
    while live.any():
        rows = np.flatnonzero(live)
        batch.advance(rows, cmd[rows], dt[rows], disturbances)
        for i in rows:
            resume(int(i), False)
    return [r for r in results if r is not None]
