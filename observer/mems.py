"""The MEMS baseline's attitude estimator (seed 000 §5): gyro integration with an accelerometer
tilt correction, initial bias zeroing and the seed's decoupled, unwrapped yaw.

The seed compares its camera against an ICM42605 IMU sampled at 200 Hz with ranges ±2000 °/s and
±16 g (seed 000 Table 2), mounted on a fixture that stands in for the rotor's bottom (§5). Its yaw
is compared after an SO(3) decoupling, Ψ = atan2(R21, R11), temporal phase unwrapping and initial
bias zeroing (§5.3). The IMU model is
``observer.imu``; this module is the estimator.

**The estimator** (``MemsEstimatorConfig``, ``MemsAttitudeEstimator``): an explicit complementary
filter. Per sample, body rate ω̂ = gyro - b̂_g. The gyro step propagates the attitude with the exact
quaternion exponential of the trapezoidal mean rate, and the accelerometer step then turns it
toward the measured vertical:

    q⁻_k = q_{k-1} ⊗ exp( ½ Δt (ω̂_{k-1} + ω̂_k)/2 ),   q_k = q⁻_k ⊗ exp( ½ Δt k_P (v_m × v̂) ),

where v̂ = R(q⁻_k)ᵀ e_Z is the predicted direction of the reaction to gravity in the body frame and
v_m the direction of the measured specific force after removing the estimated accelerometer bias
and the sensor's lever-arm terms ω̂ × (ω̂ × r) and ω̂̇ × r (ω̂̇ by backward difference). The
correction is perpendicular to v̂, so the rotation about the vertical (yaw) is pure gyro
integration, as in the seed's MEMS. Samples whose |f| differs from g by more than a gate are not
used for the correction. The correction is proportional only (no integral term), so a residual
gyro bias b leaves a steady misalignment of the vertical of (u × b)(1 - k_P Δt)/k_P (u = true "up"
in the body frame; the factor is that of the correction applied after each gyro step), and an
accelerometer bias b_a leaves b_a,⊥/g.

Initial bias zeroing (seed 000 §5.3): the first ``zero_window_s`` seconds are taken as stationary.
The gyro bias estimate is the mean gyro reading over the window. If the initial attitude is
known (``q_init``, as on the seed's bench where the fixture holds a known pose), the
accelerometer bias is also zeroed, as the mean reading minus R(q_init)ᵀ (0, 0, g); otherwise the
initial tilt comes from the mean accelerometer reading and the heading is ``initial_yaw_rad``.
The seed applies "initial bias zeroing" to the yaw traces of both schemes after unwrapping; we
read it as both operations: the gyro bias from the stationary window (an IMU cannot otherwise be
used), and the subtraction of the first valid unwrapped yaw (``psi_zeroed``).

The seed's decoupled yaw (§5.3): the MEMS's coupled Z-Y-X Euler angles (ψ_m, θ_m, φ_m) give
R = Rz(ψ_m) Ry(θ_m) Rx(φ_m), the sensor's x axis in the global frame is R's first column, and
Ψ = atan2(R21, R11) is its azimuth. Since R is the rotor-to-stator rotation here, Ψ is computed
from the quaternion directly. Note that for |θ_m| < 90° this equals ψ_m itself (R11 = cos ψ cos θ,
R21 = sin ψ cos θ). In the seed's Z-Y-Z angles, Ψ = γ + atan2(sin α, cos β cos α): Ψ = γ on the
§5.3 bench (tilt about Y, then yaw of the table about Z, α = 0) and Ψ = α + γ at β = 0.
Unwrapping adds the multiple of 2π that keeps successive samples within π of each other, valid
while |rate| < π f_s (18,000 °/s at 200 Hz, far beyond the gyro's range).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import Field

from observer.imu import G0, ImuConfig, ImuSamples, StrictSettings
from observer.types import Estimate
from plant import attitude


class MemsEstimatorConfig(StrictSettings):
    """Settings of the complementary filter and of the initial bias zeroing."""

    k_p_rad_s: float = Field(
        1.0,
        ge=0.0,
        description="Our choice: accelerometer correction gain (rad/s per unit "
        "misalignment), i.e. a 1 s tilt time constant; 0 = gyro integration only.",
    )
    accel_gate_g: float = Field(
        0.1,
        gt=0.0,
        description="Our choice: skip the correction when | |f| - g | exceeds this (g).",
    )
    zero_window_s: float = Field(
        2.0,
        ge=0.0,
        description="Seed 000 §5.3 initial bias zeroing; the 2 s stationary window is our "
        "choice (shorter than the seed's 5 s dwell). 0 = no zeroing.",
    )
    zero_accel_bias: bool = Field(
        True, description="Also zero the accelerometer bias when q_init is known."
    )
    compensate_lever_arm: bool = Field(
        True,
        description="Our choice: remove ω̂×(ω̂×r) and ω̂̇×r from the specific force before the "
        "tilt correction (r = the IMU's position).",
    )


# --------------------------------------------------------------------------------------------
# Quaternion helpers (vectorised where the simulator needs them)
# --------------------------------------------------------------------------------------------
def decoupled_yaw(q: ArrayLike) -> NDArray[np.float64] | float:
    """The seed's decoupled global yaw Ψ = atan2(R21, R11) (seed 000 §5.3), rad in (-π, π].

    ``q`` is one quaternion (4,) or an array (..., 4), rotor (sensor) to stator. Ψ is the azimuth
    of the sensor's x axis projected onto the horizontal plane.
    """
    qn = attitude.normalize(q)
    w, x, y, z = np.moveaxis(qn, -1, 0)
    r21 = 2.0 * (x * y + w * z)
    r11 = 1.0 - 2.0 * (y * y + z * z)
    psi = np.arctan2(r21, r11)
    return float(psi) if np.ndim(psi) == 0 else psi


def unwrap_phase(psi: ArrayLike) -> NDArray[np.float64]:
    """Temporal phase unwrapping (seed 000 §5.3): add to each angle (rad) the multiple of 2π that
    keeps it within π of its unwrapped predecessor. NaN entries stay NaN and are skipped."""
    psi = np.asarray(psi, dtype=float)
    out = np.full_like(psi, np.nan)
    prev_raw = prev_unw = math.nan
    for i, a in enumerate(psi):
        if not math.isfinite(a):
            continue
        if math.isnan(prev_unw):
            prev_unw = float(a)
        else:
            prev_unw += _wrap(a - prev_raw)
        prev_raw = float(a)
        out[i] = prev_unw
    return out


def _wrap(a: float) -> float:
    """Wrap one angle (rad) into (-π, π]."""
    return math.pi - math.fmod(math.fmod(math.pi - a, 2 * math.pi) + 2 * math.pi, 2 * math.pi)


# --------------------------------------------------------------------------------------------
# Truth trajectories
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MemsEstimate:
    """The estimator's output for one IMU sample.

    Attributes
    ----------
    t : sample time, s.
    q : (4,) attitude, rotor to stator; NaN while zeroing or when invalid.
    euler_zyz : (3,) the seed's (spin α, tilt β, yaw γ), rad, via ``plant.attitude.to_zyz``
        (at β ≈ 0 only α + γ is meaningful).
    psi : the seed's decoupled yaw Ψ = atan2(R21, R11), rad in (-π, π].
    psi_unwrapped : Ψ after temporal phase unwrapping, rad.
    psi_zeroed : unwrapped Ψ minus its first valid value (the seed's initial zeroing), rad.
    omega : (3,) bias-corrected body rate, rad/s.
    gyro_bias : (3,) the gyro bias estimate in use, rad/s.
    valid : the attitude can be used.
    reason : why not (e.g. "zeroing", "non-finite sample"), "" when valid.
    compute_time_s : wall-clock time of the update, s.
    """

    t: float
    q: NDArray[np.float64]
    euler_zyz: NDArray[np.float64]
    psi: float
    psi_unwrapped: float
    psi_zeroed: float
    omega: NDArray[np.float64]
    gyro_bias: NDArray[np.float64]
    valid: bool
    reason: str = ""
    compute_time_s: float = 0.0

    def to_estimate(self) -> Estimate:
        """As the observer seam's ``Estimate`` (no markers, no covariance; released at the
        sample time)."""
        return Estimate(
            t_exposure=self.t,
            t_available=self.t,
            q=self.q.copy(),
            euler_zyz=self.euler_zyz.copy(),
            marker_px=np.empty((0, 2)),
            covariance=np.full((3, 3), np.nan),
            valid=self.valid,
            lost=False,
            reason=self.reason,
            compute_time_s=self.compute_time_s,
            omega=self.omega.copy(),
        )


@dataclass(frozen=True)
class MemsTrack:
    """The estimator's outputs over a sample sequence, one row per sample (fields as in
    ``MemsEstimate``; invalid rows are NaN)."""

    t: NDArray[np.float64]
    q: NDArray[np.float64]
    euler_zyz: NDArray[np.float64]
    psi: NDArray[np.float64]
    psi_unwrapped: NDArray[np.float64]
    psi_zeroed: NDArray[np.float64]
    omega: NDArray[np.float64]
    gyro_bias: NDArray[np.float64]
    valid: NDArray[np.bool_]


def _qmul(a: tuple, b: tuple) -> tuple[float, float, float, float]:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def _qexp(rv: list[float]) -> tuple[float, float, float, float]:
    """Unit quaternion of one rotation vector (rad): exp of (0, rv/2)."""
    theta = math.sqrt(rv[0] * rv[0] + rv[1] * rv[1] + rv[2] * rv[2])
    half = 0.5 * theta
    ks = math.sin(half) / theta if theta > 1e-8 else 0.5 - theta * theta / 48.0
    return (math.cos(half), ks * rv[0], ks * rv[1], ks * rv[2])


def _cross(a: tuple, b: tuple) -> tuple[float, float, float]:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _level_quaternion(f_body: NDArray[np.float64], yaw_rad: float) -> NDArray[np.float64]:
    """The attitude whose body-frame "up" is the direction of ``f_body`` and whose decoupled yaw
    Ψ is ``yaw_rad``: the shortest rotation taking that direction to e_Z, then a turn about Z."""
    n = float(np.linalg.norm(f_body))
    if n < 1e-9:  # no specific force to level on (free fall): start upright
        return attitude.axis_angle([0, 0, 1], yaw_rad)
    u = f_body / n
    axis = np.cross(u, [0.0, 0.0, 1.0])
    s, c = np.linalg.norm(axis), float(u[2])
    q_tilt = attitude.axis_angle(axis, math.atan2(s, c)) if s > 1e-12 else np.array([1.0, 0, 0, 0])
    if c < 0 and s <= 1e-12:
        q_tilt = np.array([0.0, 1.0, 0.0, 0.0])
    psi0 = decoupled_yaw(q_tilt)
    return attitude.multiply(attitude.axis_angle([0, 0, 1], yaw_rad - psi0), q_tilt)


class MemsAttitudeEstimator:
    """Gyro integration with an accelerometer tilt correction, initial bias zeroing and the
    seed's decoupled, unwrapped yaw (seed 000 §5.3). Model in the module docstring.

    Parameters
    ----------
    config : filter and zeroing settings; default ``MemsEstimatorConfig()``.
    imu : the IMU description (sensor position for the lever-arm terms, gravity); default
        ``ImuConfig()``.
    q_init : the known attitude during the stationary window (rotor to stator), or None to
        level from the accelerometer.
    initial_yaw_rad : decoupled yaw Ψ given to the levelled initial attitude when ``q_init`` is
        None, rad.
    """

    def __init__(
        self,
        config: MemsEstimatorConfig | None = None,
        imu: ImuConfig | None = None,
        q_init: ArrayLike | None = None,
        initial_yaw_rad: float = 0.0,
    ) -> None:
        self.config = config or MemsEstimatorConfig()
        self.imu = imu or ImuConfig()
        self.q_init = None if q_init is None else attitude.normalize(q_init, "q_init")
        self.initial_yaw_rad = float(attitude.check_finite("initial_yaw_rad", initial_yaw_rad))
        self.reset()

    def reset(self) -> None:
        """Forget all samples: the next sample starts the zeroing window."""
        self._t0: float | None = None
        self._t_prev: float | None = None
        self._window_g: list[NDArray[np.float64]] = []
        self._window_a: list[NDArray[np.float64]] = []
        self._window_t: list[float] = []
        self._q: tuple[float, float, float, float] | None = None
        self._w_prev = (0.0, 0.0, 0.0)
        self.gyro_bias = np.zeros(3)
        self.accel_bias = np.zeros(3)
        self._psi_prev = math.nan
        self._psi_unw = math.nan
        self._psi_ref = math.nan

    @property
    def initialised(self) -> bool:
        """True once the zeroing window is over and an attitude is being propagated."""
        return self._q is not None

    # --- one sample -------------------------------------------------------------------------
    def update(self, t: float, gyro: ArrayLike, accel: ArrayLike) -> MemsEstimate:
        """Process one IMU sample: time ``t`` (s), gyro (3,) rad/s, accel (3,) m/s², body frame.

        Never raises on bad data: a non-finite sample or a time that does not increase gives an
        invalid estimate and leaves the state untouched.
        """
        tic = time.perf_counter()
        g = np.asarray(gyro, dtype=float).reshape(-1)
        a = np.asarray(accel, dtype=float).reshape(-1)
        t = float(t)
        if g.shape != (3,) or a.shape != (3,):
            return self._invalid(t, f"gyro and accel need 3 entries, got {g.shape}, {a.shape}")
        if not (math.isfinite(t) and np.all(np.isfinite(g)) and np.all(np.isfinite(a))):
            return self._invalid(t, "non-finite IMU sample")
        if self._t_prev is not None and t <= self._t_prev:
            return self._invalid(t, f"time {t} s does not increase (previous {self._t_prev} s)")

        if self._q is None:
            if self._t0 is None:
                self._t0 = t
            if t - self._t0 < self.config.zero_window_s - 1e-12:
                self._window_g.append(g)
                self._window_a.append(a)
                self._window_t.append(t)
                self._t_prev = t
                return self._invalid(t, "zeroing (stationary window)")
            had_window = bool(self._window_g)
            self._finish_zeroing(a)
            if not had_window:  # no stationary window: the attitude starts at this sample
                self._t_prev = t
                self._w_prev = tuple(g - self.gyro_bias)
                return self._output(t, np.asarray(self._w_prev), tic)

        dt = t - self._t_prev
        w = g - self.gyro_bias
        wt = (float(w[0]), float(w[1]), float(w[2]))
        # 1) gyro: exact exponential of the trapezoidal mean rate over the interval
        q = _qmul(self._q, _qexp([0.5 * (self._w_prev[i] + wt[i]) * dt for i in range(3)]))
        # 2) accelerometer: rotate toward the measured "up" at this sample's time
        k = self.config.k_p_rad_s
        if k > 0.0:
            f = a - self.accel_bias
            if self.config.compensate_lever_arm:
                r = self.imu.position_m
                wdot = tuple((wt[i] - self._w_prev[i]) / dt for i in range(3))
                f = f - np.asarray(_cross(wdot, r)) - np.asarray(_cross(wt, _cross(wt, r)))
            fn = math.sqrt(float(f @ f))
            if fn > 0.0 and abs(fn - self.imu.gravity_m_s2) <= self.config.accel_gate_g * G0:
                qw, qx, qy, qz = q
                v_hat = (
                    2.0 * (qx * qz - qw * qy),
                    2.0 * (qy * qz + qw * qx),
                    1.0 - 2.0 * (qx * qx + qy * qy),
                )
                e = _cross((f[0] / fn, f[1] / fn, f[2] / fn), v_hat)
                q = _qmul(q, _qexp([k * e[i] * dt for i in range(3)]))
        nq = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
        self._q = (q[0] / nq, q[1] / nq, q[2] / nq, q[3] / nq)
        self._w_prev = wt
        self._t_prev = t
        return self._output(t, w, tic)

    def _finish_zeroing(self, a_now: NDArray[np.float64]) -> None:
        """End of the stationary window: bias estimates and the initial attitude (``a_now``, the
        current accelerometer sample, levels the start when there was no window)."""
        g_ref = np.array([0.0, 0.0, self.imu.gravity_m_s2])
        if self._window_g:
            self.gyro_bias = np.mean(self._window_g, axis=0)
            a_mean = np.mean(self._window_a, axis=0)
        else:
            a_mean = a_now
        if self.q_init is not None:
            q0 = self.q_init
            if self._window_a and self.config.zero_accel_bias:
                self.accel_bias = a_mean - attitude.to_matrix(q0).T @ g_ref
        else:
            q0 = _level_quaternion(a_mean, self.initial_yaw_rad)
        self._q = tuple(float(c) for c in q0)
        if self._window_g:
            # the rotor was at rest over the window: start the propagation at its last sample
            self._t_prev = self._window_t[-1]
            self._w_prev = tuple(float(c) for c in self._window_g[-1] - self.gyro_bias)
        self._window_g, self._window_a, self._window_t = [], [], []

    def _output(self, t: float, w: NDArray[np.float64], tic: float) -> MemsEstimate:
        q = np.array(self._q)
        psi = decoupled_yaw(q)
        if math.isnan(self._psi_unw):
            self._psi_unw = psi
            self._psi_ref = psi
        else:
            self._psi_unw += _wrap(psi - self._psi_prev)
        self._psi_prev = psi
        return MemsEstimate(
            t=t,
            q=q,
            euler_zyz=np.array(attitude.to_zyz(q)),
            psi=psi,
            psi_unwrapped=self._psi_unw,
            psi_zeroed=self._psi_unw - self._psi_ref,
            omega=np.array(w, dtype=float),
            gyro_bias=self.gyro_bias.copy(),
            valid=True,
            compute_time_s=time.perf_counter() - tic,
        )

    def _invalid(self, t: float, reason: str) -> MemsEstimate:
        nan3 = np.full(3, np.nan)
        return MemsEstimate(
            t=t,
            q=np.full(4, np.nan),
            euler_zyz=nan3,
            psi=math.nan,
            psi_unwrapped=math.nan,
            psi_zeroed=math.nan,
            omega=nan3.copy(),
            gyro_bias=self.gyro_bias.copy(),
            valid=False,
            reason=reason,
        )

    # --- a whole sequence -------------------------------------------------------------------
    def run(self, samples: ImuSamples) -> MemsTrack:
        """Reset, then process every sample of ``samples`` in order; one output row each."""
        self.reset()
        out = [
            self.update(t, g, a)
            for t, g, a in zip(samples.t, samples.gyro, samples.accel, strict=True)
        ]
        return MemsTrack(
            t=np.array([e.t for e in out]),
            q=np.array([e.q for e in out]),
            euler_zyz=np.array([e.euler_zyz for e in out]),
            psi=np.array([e.psi for e in out]),
            psi_unwrapped=np.array([e.psi_unwrapped for e in out]),
            psi_zeroed=np.array([e.psi_zeroed for e in out]),
            omega=np.array([e.omega for e in out]),
            gyro_bias=np.array([e.gyro_bias for e in out]),
            valid=np.array([e.valid for e in out]),
        )
