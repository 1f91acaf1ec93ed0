"""The observer's interfaces (docs/architecture.md): what an attitude solver returns;
``Estimate`` (what an observer releases) lives in ``plant.estimate`` because the controllers need
it too.

Pixels are full-sensor pixels (the seed's unit) unless a name says otherwise. A quaternion is
(w, x, y, z), rotor to stator. A result that cannot be trusted is returned with ``valid=False``
and a ``reason``; it is never an exception in the middle of a loop and never a silent number.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from plant.estimate import Estimate

__all__ = ["AttitudeSolver", "Estimate", "SolverResult"]


def _nan(*shape: int) -> NDArray[np.float64]:
    return np.full(shape, np.nan)


@dataclass(frozen=True)
class SolverResult:
    """Attitude from one set of marker pixels.

    Attributes
    ----------
    q : (4,) quaternion, NaN when invalid.
    covariance : (3, 3) covariance of the attitude error as a rotation vector in the rotor (body)
        frame, rad^2 (``q_true = q ⊗ exp(delta)``), NaN when the solver gives none.
    valid : whether ``q`` can be used.
    reason : why not, when ``valid`` is False ("" otherwise).
    residual_rms_px : RMS reprojection residual, sensor px (NaN if not applicable).
    iterations : solver iterations (0 for closed forms).
    """

    q: NDArray[np.float64]
    covariance: NDArray[np.float64] = field(default_factory=lambda: _nan(3, 3))
    valid: bool = True
    reason: str = ""
    residual_rms_px: float = float("nan")
    iterations: int = 0

    @classmethod
    def invalid(cls, reason: str) -> SolverResult:
        """A failed solve: NaN attitude, ``valid`` False and ``reason`` saying why."""
        return cls(q=_nan(4), valid=False, reason=reason)


class AttitudeSolver(Protocol):
    """Marker pixels -> attitude. ``marker_px`` is (N, 2), sensor px, rows in the target's
    marker order (red, yellow, ...); NaN rows are missing markers."""

    def solve(
        self, marker_px: NDArray[np.float64], q_prev: NDArray[np.float64] | None = None
    ) -> SolverResult:
        """The attitude from marker pixels ``marker_px`` (N, 2), sensor px, starting from
        ``q_prev`` (4,) when given; a ``SolverResult`` that is invalid, with a reason, when the
        pixels do not determine it."""
