"""The controller interface: ``command(estimate, reference, t) -> torque``.

A controller receives the observer's latest ``Estimate`` (which carries its own ``t_exposure``
and ``t_available``), the reference trajectory and the current time, and returns the torque on
the rotor in the stator frame (N·m). The closed loop measures the wall-clock time of every call
and adds it to the latency; controllers keep their own per-call times in ``compute_times_s``.

**Invalid estimates** have one policy, the controller's ``invalid_command`` (``InvalidCommand``):
the loop hands every estimate to the controller, valid or not, and the controller answers an
invalid one with zero torque or by holding its last command. The loop overrides only a command
that is not a finite (3,) torque (with zero torque, reported back by ``record_command``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from plant.estimate import Estimate


@dataclass(frozen=True)
class RefSample:
    """The reference at one time: attitude (w, x, y, z), body rate (rad/s) and body angular
    acceleration (rad/s²) of the desired motion; from ``Reference.sample_many``, the same at
    n times, with a leading axis of n."""

    q: NDArray[np.float64]
    omega: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    alpha: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))


class Reference(Protocol):
    """A reference trajectory: ``sample(t)`` for any time t (s), ``sample_many(t)`` for an
    array of times at once (the loop samples the whole physics grid of a run in one call).

    Subclass it to inherit a ``sample_many`` that calls ``sample`` once per time; the
    generators of ``controller.reference`` compute it as arrays."""

    def sample(self, t: float) -> RefSample:
        """The reference at time ``t`` (s): attitude ``q`` (4,), rate ``omega`` (3,), rad/s, and
        acceleration ``alpha`` (3,), rad/s²."""

    def sample_many(self, t: NDArray[np.float64]) -> RefSample:
        """The reference at each time of ``t`` (n,), s: a ``RefSample`` whose ``q`` is (n, 4),
        ``omega`` (n, 3), rad/s, and ``alpha`` (n, 3), rad/s²."""
        samples = [self.sample(float(x)) for x in np.asarray(t, dtype=float).reshape(-1)]
        return RefSample(
            q=np.array([s.q for s in samples], dtype=float).reshape(-1, 4),
            omega=np.array([s.omega for s in samples], dtype=float).reshape(-1, 3),
            alpha=np.array([s.alpha for s in samples], dtype=float).reshape(-1, 3),
        )


#: What a controller commands while its estimate is invalid: zero torque, or its last command.
InvalidCommand = Literal["zero", "hold"]


class Controller(Protocol):
    """Attitude controller. ``reset()`` clears its internal state (integrators, warm starts).

    Subclass it to inherit the no-op ``record_command`` (controllers without a command
    history)."""

    def command(self, estimate: Estimate, reference: Reference, t: float) -> NDArray[np.float64]:
        """Torque (3,), N·m, stator frame, to apply from time ``t`` (s); an invalid estimate
        gets the controller's ``invalid_command``."""
        ...

    def reset(self) -> None:
        """Clear the internal state (integrators, warm starts, command history) before a run."""

    def record_command(self, t_apply: float, torque: NDArray[np.float64]) -> None:
        """The loop replaced this controller's command by ``torque`` (N·m, stator frame) from
        ``t_apply`` (s). Controllers that predict with their own command history (the MPC's
        delay compensation) record it; the others ignore it."""
        return None
