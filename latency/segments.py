"""The physics between a run's events: a timeline's request (``Advance``: move to the next
event with the currents held), its answer (``Segment``: the state at every physics grid point
passed) and the two ways one run's requests are served:

* ``_advance_segment``, step by step through ``MujocoPlant.advance`` (MuJoCo's delayed sensor
  and a disturbance hook need it);
* ``KernelAdvance``, through the compiled run loop's kernel (``latency.compiled.steps._advance``),
  which ``latency.loop.ClosedLoop.run`` uses for every other run.

``latency.batched`` serves many runs' requests together.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from plant.dynamics import MujocoPlant
from plant.torque import N_COILS

#: Columns of the kernel's rows read here: the first 40 of the steps table
#: (``latency.compiled.steps._record``: time, state, reference, torques, currents, flags).
KERNEL_ROW_WIDTH = 40


@dataclass(frozen=True)
class Advance:
    """A timeline's request: move the physics from ``t_s`` to ``t_target_s`` (s) with the coil
    currents ``currents`` (16,), A, held, stopping at each physics grid point; ``k_log`` is the
    index of the last grid point recorded."""

    currents: NDArray[np.float64]
    t_s: float
    t_target_s: float
    k_log: int


@dataclass(frozen=True)
class Segment:
    """The answer to an ``Advance``: the time reached ``t_s`` and, at each grid point passed
    (``k_log + 1``, ``k_log + 2``, ...), the attitude (n, 4), body rate (n, 3), rad/s, actual
    currents (n, 16), A, and MuJoCo's delayed-sensor reading (n, 4) or None."""

    t_s: float
    q: NDArray[np.float64]
    omega: NDArray[np.float64]
    currents: NDArray[np.float64]
    q_native: NDArray[np.float64] | None = None


def _advance_segment(
    plant: MujocoPlant, req: Advance, h: float, n_steps: int, native: bool
) -> Segment:
    """Serve an ``Advance`` on one plant: step to the next grid point or the target, whichever
    is first (``MujocoPlant.advance`` puts the target on its exact time), record the state at
    each grid point up to ``n_steps``, until within 1e-12 s of the target.

    Mirrored in ``latency.compiled.steps._advance``; keep both in step
    (tests/test_compiled_mirror.py checks them equal)."""
    t, k = req.t_s, req.k_log
    rows: list[tuple] = []
    while True:
        t_grid = (k + 1) * h
        t_to = min(req.t_target_s, t_grid)
        if t_to > t:
            plant.advance(req.currents, t_to - t)
            t = t_to
        if abs(t - t_grid) < 1e-12 and k + 1 <= n_steps:
            k += 1
            rows.append((plant.q, plant.omega, plant.currents,
                         plant.delayed_q() if native else None))
        if t >= req.t_target_s - 1e-12:
            break
    if not rows:
        empty = np.zeros((0, 4))
        return Segment(t, empty, np.zeros((0, 3)), np.zeros((0, N_COILS)))
    q, w, cur, nat = zip(*rows, strict=True)
    return Segment(t, np.array(q), np.array(w), np.array(cur), np.array(nat) if native else None)


class KernelAdvance:
    """Serves one run's ``Advance`` requests with the compiled run loop's physics
    (``latency.compiled.steps._advance``: the compiled physics step, the coils' lag and the
    grid points, with the run's pair lists kept across steps) and writes the state reached back
    into the plant. ``_advance_segment`` does the same step by step from Python (about 0.1 ms
    a physics step, the largest cost of a measurement-model run); the two agree to 1e-12
    (tests/test_compiled_mirror.py). For plants without MuJoCo's delayed sensor and without a
    disturbance: ``_advance_segment`` serves those."""

    def __init__(self, plant: MujocoPlant, n_steps: int) -> None:
        # imported here: latency.compiled imports latency.loop, which imports this module
        from latency.compiled import layout as lay
        from latency.compiled.settings import physics_settings
        from latency.compiled.steps import _advance
        from plant.rigid_body import PAIR_REUSE_RAD, _pair_lists

        self._lay, self._kernel, self.plant = lay, _advance, plant
        self.consts = plant.body.consts
        self.pairs = _pair_lists(self.consts[5].shape[0], self.consts[4].shape[0],
                                 PAIR_REUSE_RAD)
        self.par = physics_settings(plant.params, n_steps)
        self.state = np.zeros(lay._N_STATE)
        # the kernel's steps table and event record (their rows are read here; the reference
        # and the tilt-stop events are the timeline's)
        self.rows = np.zeros((n_steps + 1, KERNEL_ROW_WIDTH))
        self.events = np.zeros((n_steps + 1, 6))
        self.ref = np.zeros((n_steps + 1, 4))

    def __call__(self, req: Advance) -> Segment:
        """The ``Segment`` of ``req`` (as ``_advance_segment``), the plant moved to its end."""
        lay, st, plant = self._lay, self.state, self.plant
        st[lay._T], st[lay._K], st[lay._N_EV] = req.t_s, req.k_log, 0
        st[lay._Q : lay._Q + 4] = plant.q
        st[lay._W : lay._W + 3] = plant.omega
        st[lay._CUR : lay._CUR + N_COILS] = plant.currents
        st[lay._CMD : lay._CMD + N_COILS] = req.currents
        self._kernel(st, req.t_target_s, self.ref, self.rows, self.events, self.par,
                     *self.consts, self.pairs)
        k = int(st[lay._K])
        plant.set_state(st[lay._Q : lay._Q + 4], st[lay._W : lay._W + 3],
                        st[lay._CUR : lay._CUR + N_COILS], st[lay._T])
        rows = self.rows[req.k_log + 1 : k + 1]
        return Segment(float(st[lay._T]), rows[:, 1:5].copy(), rows[:, 5:8].copy(),
                       rows[:, 18:34].copy())
