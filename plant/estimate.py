"""What an observer releases for one frame: the seam between observers and controllers.

It lives in ``plant`` (the lowest package) because both ``observer`` and ``controller`` use it
(docs/architecture.md: imports flow experiments -> latency -> controller, observer -> plant).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray


def _nan(*shape: int) -> NDArray[np.float64]:
    return np.full(shape, np.nan)


@dataclass(frozen=True)
class Estimate:
    """What an observer releases for one frame.

    Attributes
    ----------
    t_exposure : mid-exposure time of the frame, s.
    t_available : when the observer released the estimate, s (latency = the difference).
    q : (4,) attitude estimate (at ``t_exposure`` unless the observer predicts forward; then at
        ``t_available``), NaN when invalid.
    euler_zyz : (3,) the seed's (spin, tilt, yaw), rad, for reports.
    marker_px : (N, 2) marker pixels used, sensor px.
    covariance : (3, 3) attitude covariance (rotation vector, body frame), rad^2.
    valid : the attitude can be used.
    lost : the tracker has lost the markers (the estimate may be a prediction).
    reason : why the estimate is invalid or lost.
    compute_time_s : measured wall-clock compute time of the observer for this frame, s.
    omega : (3,) body rate estimate, rad/s, NaN when the observer has none.
    t_state : the time (s) that ``q`` and ``omega`` describe: ``t_exposure`` for a plain
        measurement, ``t_available`` for an observer that predicts across its own latency.
        None means ``t_exposure``.
    """

    t_exposure: float
    t_available: float
    q: NDArray[np.float64]
    euler_zyz: NDArray[np.float64]
    marker_px: NDArray[np.float64]
    covariance: NDArray[np.float64]
    valid: bool
    lost: bool = False
    reason: str = ""
    compute_time_s: float = 0.0
    omega: NDArray[np.float64] = field(default_factory=lambda: _nan(3))
    t_state: float | None = None

    @property
    def state_time(self) -> float:
        """The time (s) that ``q`` describes."""
        return self.t_exposure if self.t_state is None else self.t_state

    @property
    def latency_s(self) -> float:
        """t_available - t_exposure, s."""
        return self.t_available - self.t_exposure
