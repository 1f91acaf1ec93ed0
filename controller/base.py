"""The controller seam (DESIGN.md): ``command(estimate, reference, t) -> torque``.

A controller receives the observer's latest ``Estimate`` (which carries its own ``t_exposure``
and ``t_available``), the reference trajectory and the current time, and returns the torque on
the rotor in the stator frame (N·m). The closed loop measures the wall-clock time of every call
and adds it to the latency; controllers may also report their own solve time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from plant.estimate import Estimate


@dataclass(frozen=True)
class RefSample:
    """The reference at one time: attitude (w, x, y, z), body rate (rad/s) and body angular
    acceleration (rad/s²) of the desired motion."""

    q: NDArray[np.float64]
    omega: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    alpha: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))


class Reference(Protocol):
    """A reference trajectory: ``sample(t)`` for any time t (s)."""

    def sample(self, t: float) -> RefSample: ...


class Controller(Protocol):
    """Attitude controller. ``reset()`` clears its internal state (integrators, warm starts)."""

    def command(self, estimate: Estimate, reference: Reference, t: float) -> NDArray[np.float64]:
        """Torque (3,), N·m, stator frame, to apply from time ``t`` (s)."""
        ...

    def reset(self) -> None: ...
