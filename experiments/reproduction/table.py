"""The seed's protocols and figures, and the kinematic rotary table that runs them
(``experiments.reproduction``)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from controller.base import RefSample
from controller.reference import SeedSteps, zyz_sample

Axis = Literal["spin", "tilt", "yaw"]
AXES: tuple[Axis, ...] = ("spin", "tilt", "yaw")

#: Seed 000 §5: a steady-state window is 90 frames (2.5 s) ...
STEADY_WINDOW_FRAMES = 90
#: ... whose angular standard deviation is below 0.3°.
STEADY_STD_MAX_RAD = math.radians(0.3)

#: The seed's RMSEs (seed 000 §5.1–5.3), degrees: its numbers, not ours.
SEED_RMSE_DEG: dict[str, dict[Axis, float]] = {
    "camera": {"spin": 0.2979, "tilt": 0.1496, "yaw": 0.8847},
    "mems": {"spin": 1.3120, "tilt": 0.2640, "yaw": 15.0819},
}

#: The camera back ends run on the same tracked pixels: key -> (label, seed row it compares with).
CAMERA_BACKENDS: dict[str, tuple[str, str]] = {
    "camera_closed_form": ("Camera, seed's closed form (§2.3–2.5)", "camera"),
    "camera_least_squares": ("Camera, CoR least squares", "camera"),
    "camera_least_squares_kalman": (
        "Camera, least squares on the seed's pixel Kalman (§3.2.1)",
        "camera",
    ),
    "camera_aekf": (
        "Camera, quaternion AEKF on the marker pixels (seed 001 App. C; no torque input)",
        "camera",
    ),
}

#: The MEMS variants: key -> (label, known start attitude during the zeroing window).
MEMS_VARIANTS: dict[str, tuple[str, bool]] = {
    "mems_known_start": ("MEMS, known start (gyro and accelerometer zeroed)", True),
    "mems_levelled_start": ("MEMS, levelled start (gyro zeroed only)", False),
}


# ------------------------------------------------------------------------------------------------
# The rotary table
# ------------------------------------------------------------------------------------------------
def _min_jerk(tau: float) -> tuple[float, float, float]:
    """Minimum-jerk profile s(τ) = 10τ³ − 15τ⁴ + 6τ⁵ on τ ∈ [0, 1] with ds/dτ and d²s/dτ²
    (zero rate and acceleration at both ends)."""
    t = min(max(tau, 0.0), 1.0)
    s = t * t * t * (10.0 - 15.0 * t + 6.0 * t * t)
    ds = 30.0 * t * t * (1.0 - t) ** 2
    dds = 60.0 * t * (1.0 - t) * (1.0 - 2.0 * t)
    return s, ds, dds


def zyz_line(steps: SeedSteps) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The protocol as a line in the Z-Y-Z angles: ``(α, β, γ) = base + direction · v`` (rad) for
    the table angle v (rad), matching ``SeedSteps.attitude_of`` (tested).

    spin: (v, 0, 0); tilt toward azimuth a: (−a, v, a); yaw at tilt β: (0, β, v) for the rotary
    table (``turn_shaft``), (−v, β, v) for a shaft sweeping the cone without turning.
    """
    if steps.axis == "spin":
        return np.zeros(3), np.array([1.0, 0.0, 0.0])
    if steps.axis == "tilt":
        a = math.radians(steps.azimuth_deg)
        return np.array([-a, 0.0, a]), np.array([0.0, 1.0, 0.0])
    beta = math.radians(steps.tilt_deg)
    return np.array([0.0, beta, 0.0]), np.array([0.0 if steps.turn_shaft else -1.0, 0.0, 1.0])


class RotaryTable:
    """A perfect kinematic rotary table running a ``SeedSteps`` protocol with smooth moves.

    Parameters
    ----------
    steps : SeedSteps
        Axis, step values (deg) and dwell (s) (seed 000 §5); its ``t_start_s`` is not used.
    move_s : float
        Duration of the minimum-jerk move between two steps, s (our choice: 1 s; 0 = jumps).
    rest_s : float
        Rest at the first value before step 0, s (our choice: 2 s, the MEMS zeroing window).

    The timeline is in the module docstring. ``sample(t)`` is a ``controller.base.RefSample``
    (attitude, body rate rad/s, body acceleration rad/s²), exact.
    """

    def __init__(self, steps: SeedSteps, move_s: float = 1.0, rest_s: float = 2.0) -> None:
        if not (math.isfinite(move_s) and move_s >= 0.0):
            raise ValueError(f"move_s must be a finite number >= 0 s, got {move_s!r}")
        if not (math.isfinite(rest_s) and rest_s >= 0.0):
            raise ValueError(f"rest_s must be a finite number >= 0 s, got {rest_s!r}")
        self.steps = steps
        self.axis: Axis = steps.axis
        self.move_s = float(move_s)
        self.rest_s = float(rest_s)
        self.dwell_s = float(steps.dwell_s)
        self.values_rad = np.deg2rad(steps.values())
        self.base, self.direction = zyz_line(steps)

    @property
    def n_steps(self) -> int:
        """Number of steps (dwells)."""
        return len(self.values_rad)

    @property
    def period_s(self) -> float:
        """Move + dwell, s."""
        return self.move_s + self.dwell_s

    @property
    def duration_s(self) -> float:
        """End of the last dwell, s."""
        return self.rest_s + self.n_steps * self.period_s

    def dwell_start_s(self, k: int) -> float:
        """Start of dwell k, s."""
        return self.rest_s + k * self.period_s + self.move_s

    def _where(self, t: float) -> tuple[int, float]:
        """(step k, time since T_k) for t ≥ rest_s; (−1, t − rest_s) before."""
        if t < self.rest_s:
            return -1, t - self.rest_s
        k = min(int((t - self.rest_s) // self.period_s), self.n_steps - 1)
        return k, t - self.rest_s - k * self.period_s

    def value(self, t: float) -> tuple[float, float, float]:
        """Table angle v (rad) with its first (rad/s) and second (rad/s²) derivative at t (s)."""
        k, dt = self._where(float(t))
        if k < 0:
            return float(self.values_rad[0]), 0.0, 0.0
        v1 = float(self.values_rad[k])
        v0 = float(self.values_rad[max(k - 1, 0)])
        if self.move_s == 0.0 or dt >= self.move_s:
            return v1, 0.0, 0.0
        s, ds, dds = _min_jerk(dt / self.move_s)
        d = v1 - v0
        return v0 + d * s, d * ds / self.move_s, d * dds / self.move_s**2

    def values_at(self, t: ArrayLike) -> NDArray[np.float64]:
        """Table angle (rad) at each time of ``t`` (s)."""
        return np.array([self.value(x)[0] for x in np.asarray(t, dtype=float).reshape(-1)])

    def sample(self, t: float) -> RefSample:
        """Attitude (w, x, y, z), body rate (rad/s) and body acceleration (rad/s²) at t (s)."""
        v, dv, ddv = self.value(t)
        return zyz_sample(self.base + self.direction * v, self.direction * dv,
                          self.direction * ddv)

    def dwell_id(self, t: ArrayLike) -> NDArray[np.int64]:
        """Index of the dwell that contains each time of ``t`` (s), −1 outside the dwells
        (rest, moves, after the end). Dwell k is [T_k + move_s, T_k + move_s + dwell_s)."""
        t = np.asarray(t, dtype=float).reshape(-1)
        out = np.full(t.shape, -1, dtype=np.int64)
        rel = t - self.rest_s
        k = np.floor(rel / self.period_s).astype(np.int64)
        phase = rel - k * self.period_s
        inside = (rel >= 0) & (k < self.n_steps) & (phase >= self.move_s - 1e-12)
        out[inside] = k[inside]
        return out

    def frame_times(self, frame_rate_hz: float) -> NDArray[np.float64]:
        """Mid-exposure times k/f (s) of the frames in [0, duration)."""
        n = int(math.floor(self.duration_s * frame_rate_hz + 1e-9))
        return np.arange(n) / float(frame_rate_hz)


def make_table(axis: Axis, values_deg: Sequence[float] | None = None, dwell_s: float = 5.0,
               move_s: float = 1.0, rest_s: float = 2.0, yaw_tilt_deg: float = 15.0
               ) -> RotaryTable:
    """The seed's protocol for ``axis`` (seed 000 §5; ``values_deg`` None = ``SeedSteps``'
    defaults: spin 0–70° by 10°, tilt 0–15° by 5°, yaw 0–90° by 10° at 15° tilt)."""
    steps = SeedSteps(axis=axis, values_deg=None if values_deg is None else tuple(values_deg),
                      dwell_s=dwell_s, tilt_deg=yaw_tilt_deg)
    return RotaryTable(steps, move_s=move_s, rest_s=rest_s)
