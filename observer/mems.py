"""The MEMS baseline (seed 000 §5): an IMU on the rotor and its attitude estimator.

One module of about 900 lines: the IMU model and its estimator are one baseline, described
together by seed 000 §5.3 (noise terms, zeroing, yaw decoupling, unwrapping), and tested as one.

The seed compares its camera against an ICM42605 IMU sampled at 200 Hz with ranges ±2000 °/s and
±16 g (seed 000 Table 2), mounted on a fixture that stands in for the rotor's bottom (§5). Its yaw
is compared after an SO(3) decoupling, Ψ = atan2(R21, R11), temporal phase unwrapping and initial
bias zeroing (§5.3). This module has two parts.

**The IMU model** (``ImuConfig``, ``simulate_imu``). The sensor frame coincides with the rotor
(body) frame; the sensor sits at ``position_m`` in the rotor frame, by default at the bottom pole
(0, 0, -R), where the seed's fixture carries it. Per sample k at the output rate f_s = 1/Δt:

    gyro_k  = Q_g( sat_g( (I + S_g) ω_k + b_g,k + n_g,k ) )
    accel_k = Q_a( sat_a( f_k + b_a,k + n_a,k ) )
    f_k     = ω̇_k × r + ω_k × (ω_k × r) + R(q_k)ᵀ (0, 0, g)     (specific force, body frame)

with ω the body rate and r the sensor position (the centre of the rotor is fixed, so the sensor's
acceleration is only the tangential and centripetal terms; gravity is along -Z).
The white parts n are discrete Gaussian with standard deviation σ = N·sqrt(f_s), the usual
discretisation of a noise density N given per √Hz (Allan deviation N/sqrt(τ), so the angle random
walk over a time T has standard deviation N·sqrt(T)). The gyro bias is
b_g = b_turn-on + b_GM + b_RW: a constant drawn once, a first-order Gauss–Markov process standing
in for bias instability, and a rate random walk. The accelerometer bias is a turn-on constant plus
a random walk. sat clips to the full-scale range; Q rounds to the 16-bit code
(LSB = 2·range/2^16, codes -2^15 … 2^15-1), as the chip's 16-bit output registers do.
The sensor's on-chip anti-alias and user filters are not modelled (point sampling of the truth),
nor is the Earth's rate (15 °/h, absorbed by the stationary bias zeroing on a real bench).

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
from typing import Annotated

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field
from scipy.signal import lfilter

from observer.types import Estimate
from plant import attitude

Vec3 = Annotated[tuple[float, float, float], Field(description="3-vector")]

#: One degree in rad.
DEG = math.pi / 180.0
#: Standard gravity (m/s²), the unit "g" of datasheet accelerometer figures.
G0 = 9.80665


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


# --------------------------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------------------------
class ImuConfig(_Strict):
    """An ICM42605-class IMU on the rotor. Fields in datasheet units, with names saying so; the
    properties give SI values (rad/s, m/s², s).

    Sources: rate and ranges from seed 000 Table 2; noise densities from the TDK InvenSense
    ICM-42605 datasheet (DS-000292, "Gyroscope Noise 3.8 mdps/√Hz, Accelerometer Noise
    70 µg/√Hz"); the 16-bit output from the same datasheet. Bias terms and the mounting position
    are our choices (the seed gives none), each explained on its field.
    """

    rate_hz: float = Field(200.0, gt=0.0, description="Seed 000 Table 2: 200 Hz sampling.")
    gyro_range_dps: float = Field(2000.0, gt=0.0, description="Seed 000 Table 2: ±2000 °/s.")
    accel_range_g: float = Field(16.0, gt=0.0, description="Seed 000 Table 2: ±16 g.")
    adc_bits: int = Field(16, ge=2, le=32, description="ICM-42605 datasheet: 16-bit outputs.")
    quantize: bool = Field(True, description="Round to the output code (False: ideal ADC).")
    gyro_noise_density_dps_rthz: float = Field(
        0.0038, ge=0.0, description="ICM-42605 datasheet: rate noise 3.8 mdps/√Hz."
    )
    gyro_bias_instability_dph: float = Field(
        5.0,
        ge=0.0,
        description="Our choice: 5 °/h, typical of consumer MEMS gyros (the ICM-42605 "
        "datasheet gives no figure). Modelled as a Gauss–Markov process whose Allan-deviation "
        "peak equals the flicker floor 0.664·B of a bias instability B.",
    )
    gyro_bias_correlation_time_s: float = Field(
        100.0, gt=0.0, description="Our choice: Gauss–Markov correlation time of the instability."
    )
    gyro_rate_random_walk_dph_rth: float = Field(
        20.0, ge=0.0, description="Our choice: rate random walk 20 °/h/√h (consumer MEMS class)."
    )
    gyro_turn_on_bias_dps: float = Field(
        0.5,
        ge=0.0,
        description="Our choice: 1σ per axis of the constant turn-on bias; consumer 6-axis "
        "parts of this class quote zero-rate offsets of about ±0.5–1 °/s.",
    )
    gyro_scale_error_pct: float = Field(
        0.0,
        ge=0.0,
        description="Our choice: 1σ per-axis scale-factor error, drawn at turn-on; 0 by "
        "default (not among the terms modelled).",
    )
    accel_noise_density_ug_rthz: float = Field(
        70.0, ge=0.0, description="ICM-42605 datasheet: accelerometer noise 70 µg/√Hz."
    )
    accel_turn_on_bias_mg: float = Field(
        5.0,
        ge=0.0,
        description="Our choice: 1σ per axis after a basic calibration; uncalibrated "
        "consumer zero-g offsets are tens of mg.",
    )
    accel_bias_random_walk_ug_rts: float = Field(
        10.0, ge=0.0, description="Our choice: accelerometer bias random walk, µg/√s."
    )
    position_m: Vec3 = Field(
        (0.0, 0.0, -0.065),
        description="Sensor position in the rotor frame: the bottom pole (0, 0, -R), where "
        "seed 000 §5's fixture carries the IMU; R = 65 mm from seed 000 Table 2.",
    )
    gravity_m_s2: float = Field(
        9.81, ge=0.0, description="Gravity along -Z, as in plant.params.RotorParams."
    )

    # --- SI views ---------------------------------------------------------------------------
    @property
    def dt_s(self) -> float:
        """Sample period, s."""
        return 1.0 / self.rate_hz

    @property
    def gyro_range_rad_s(self) -> float:
        """Gyro full scale, rad/s."""
        return self.gyro_range_dps * DEG

    @property
    def accel_range_m_s2(self) -> float:
        """Accelerometer full scale, m/s²."""
        return self.accel_range_g * G0

    @property
    def gyro_lsb_rad_s(self) -> float:
        """Gyro output resolution, rad/s: 2·range / 2^bits."""
        return 2.0 * self.gyro_range_rad_s / 2.0**self.adc_bits

    @property
    def accel_lsb_m_s2(self) -> float:
        """Accelerometer output resolution, m/s²: 2·range / 2^bits."""
        return 2.0 * self.accel_range_m_s2 / 2.0**self.adc_bits

    @property
    def gyro_noise_density(self) -> float:
        """Gyro white-noise density N_g, rad/s/√Hz (angle random walk, rad/√s)."""
        return self.gyro_noise_density_dps_rthz * DEG

    @property
    def gyro_bias_instability(self) -> float:
        """Bias instability B, rad/s."""
        return self.gyro_bias_instability_dph * DEG / 3600.0

    @property
    def gyro_gauss_markov_sigma(self) -> float:
        """Stationary standard deviation of the Gauss–Markov bias, rad/s.

        A first-order Gauss–Markov process of standard deviation σ has its Allan-deviation peak
        0.6174·σ at τ ≈ 1.89 T; flicker noise of bias instability B has the floor 0.664·B. We set
        0.6174·σ = 0.664·B.
        """
        return self.gyro_bias_instability * 0.664 / 0.6174

    @property
    def gyro_rate_random_walk(self) -> float:
        """Rate random walk K, rad/s/√s."""
        return self.gyro_rate_random_walk_dph_rth * DEG / 3600.0 / 60.0

    @property
    def gyro_turn_on_bias(self) -> float:
        """1σ turn-on gyro bias per axis, rad/s."""
        return self.gyro_turn_on_bias_dps * DEG

    @property
    def accel_noise_density(self) -> float:
        """Accelerometer white-noise density, m/s²/√Hz."""
        return self.accel_noise_density_ug_rthz * 1e-6 * G0

    @property
    def accel_turn_on_bias(self) -> float:
        """1σ turn-on accelerometer bias per axis, m/s²."""
        return self.accel_turn_on_bias_mg * 1e-3 * G0

    @property
    def accel_bias_random_walk(self) -> float:
        """Accelerometer bias random walk, m/s²/√s."""
        return self.accel_bias_random_walk_ug_rts * 1e-6 * G0

    @classmethod
    def ideal(cls, **overrides: object) -> ImuConfig:
        """A noise-free, bias-free, unquantised IMU (ranges and rate kept), for checks of the
        kinematics; keyword arguments override fields."""
        fields: dict[str, object] = dict(
            quantize=False,
            gyro_noise_density_dps_rthz=0.0,
            gyro_bias_instability_dph=0.0,
            gyro_rate_random_walk_dph_rth=0.0,
            gyro_turn_on_bias_dps=0.0,
            accel_noise_density_ug_rthz=0.0,
            accel_turn_on_bias_mg=0.0,
            accel_bias_random_walk_ug_rts=0.0,
        )
        fields.update(overrides)
        return cls(**fields)


class MemsEstimatorConfig(_Strict):
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
def _quat_exp(rv: NDArray[np.float64]) -> NDArray[np.float64]:
    """Unit quaternion(s) of rotation vector(s) ``rv`` (..., 3), rad: exp of (0, rv/2)."""
    theta = np.linalg.norm(rv, axis=-1, keepdims=True)
    half = 0.5 * theta
    # sin(θ/2)/θ, with its series near 0
    k = np.where(theta > 1e-8, np.sin(half) / np.where(theta > 0, theta, 1.0), 0.5 - theta**2 / 48)
    return np.concatenate([np.cos(half), k * rv], axis=-1)


def _quat_log(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation vector(s) (..., 3), rad, of unit quaternion(s), taking the shorter way."""
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    k = np.where(s > 1e-12, angle / np.where(s > 0, s, 1.0), 2.0)
    return k * q[..., 1:]


def _rotate_to_body(q: NDArray[np.float64], v_stator: ArrayLike) -> NDArray[np.float64]:
    """R(q)ᵀ v for each quaternion in ``q`` (N, 4): a stator vector in body components."""
    R = attitude.to_matrix(q)
    return np.einsum("nji,j->ni", R, np.asarray(v_stator, dtype=float))


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
class Trajectory:
    """A truth trajectory of the rotor.

    Attributes
    ----------
    t : (N,) strictly increasing times, s.
    q : (N, 4) attitude quaternions (w, x, y, z), rotor to stator.
    omega : (N, 3) body-frame angular velocity, rad/s.
    omega_dot : (N, 3) body-frame angular acceleration, rad/s², or None to differentiate
        ``omega`` numerically.
    """

    t: NDArray[np.float64]
    q: NDArray[np.float64]
    omega: NDArray[np.float64]
    omega_dot: NDArray[np.float64] | None = None


def constant_rate_trajectory(
    duration_s: float,
    omega_body: ArrayLike,
    q0: ArrayLike = (1.0, 0.0, 0.0, 0.0),
    rate_hz: float = 200.0,
) -> Trajectory:
    """Rotation at a constant body rate ``omega_body`` (rad/s) from ``q0``, sampled at ``rate_hz``:
    q(t) = q0 ⊗ exp(ω t), exact."""
    if duration_s <= 0 or rate_hz <= 0:
        raise ValueError("duration_s and rate_hz must be positive")
    w = attitude.check_finite("omega_body", omega_body).reshape(3)
    t = np.arange(round(duration_s * rate_hz) + 1) / rate_hz
    q = attitude.multiply(attitude.normalize(q0, "q0"), _quat_exp(t[:, None] * w))
    n = len(t)
    return Trajectory(t, q, np.tile(w, (n, 1)), np.zeros((n, 3)))


def table_yaw_trajectory(
    t: ArrayLike,
    tilt_rad: float,
    yaw_rad: ArrayLike,
    yaw_rate_rad_s: ArrayLike,
    yaw_acc_rad_s2: ArrayLike | None = None,
) -> Trajectory:
    """The seed's §5.3 bench motion: the rotor held at a tilt about the stator Y axis while a
    rotary table turns it about the stator Z axis, R(t) = Rz(γ(t)) Ry(β).

    Body rate ω = γ̇ Ry(β)ᵀ e_Z = γ̇ (-sin β, 0, cos β); ω̇ = γ̈ (-sin β, 0, cos β).
    ``yaw_acc_rad_s2`` None means zero.
    """
    t = attitude.check_finite("t", t).reshape(-1)
    g = attitude.check_finite("yaw_rad", yaw_rad).reshape(-1)
    gd = attitude.check_finite("yaw_rate_rad_s", yaw_rate_rad_s).reshape(-1)
    gdd = (
        np.zeros_like(t)
        if yaw_acc_rad_s2 is None
        else attitude.check_finite("yaw_acc_rad_s2", yaw_acc_rad_s2).reshape(-1)
    )
    if not (len(g) == len(gd) == len(gdd) == len(t)):
        raise ValueError("t, yaw_rad, yaw_rate_rad_s and yaw_acc_rad_s2 must have equal lengths")
    axis = np.array([-math.sin(tilt_rad), 0.0, math.cos(tilt_rad)])
    qy = attitude.axis_angle([0, 1, 0], tilt_rad)
    qz = np.stack([np.cos(g / 2), 0 * g, 0 * g, np.sin(g / 2)], axis=-1)
    return Trajectory(t, attitude.multiply(qz, qy), gd[:, None] * axis, gdd[:, None] * axis)


# --------------------------------------------------------------------------------------------
# IMU simulation
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ImuSamples:
    """IMU output at the sample times, with the ground truth that produced it.

    Attributes
    ----------
    t : (K,) sample times, s.
    gyro : (K, 3) measured body rate, rad/s.
    accel : (K, 3) measured specific force, body frame, m/s².
    q_true : (K, 4) true attitude at the sample times.
    omega_true : (K, 3) true body rate, rad/s.
    specific_force_true : (K, 3) true specific force at the sensor, body frame, m/s².
    gyro_bias : (K, 3) true total gyro bias (turn-on + instability + random walk), rad/s.
    accel_bias : (K, 3) true total accelerometer bias, m/s².
    gyro_scale : (3,) true per-axis gyro scale factor (1 + error).
    gyro_saturated, accel_saturated : (K, 3) bool, the channel was clipped at full scale.
    """

    t: NDArray[np.float64]
    gyro: NDArray[np.float64]
    accel: NDArray[np.float64]
    q_true: NDArray[np.float64]
    omega_true: NDArray[np.float64]
    specific_force_true: NDArray[np.float64]
    gyro_bias: NDArray[np.float64]
    accel_bias: NDArray[np.float64]
    gyro_scale: NDArray[np.float64]
    gyro_saturated: NDArray[np.bool_]
    accel_saturated: NDArray[np.bool_]


def _resample(
    traj: Trajectory, ts: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Truth at times ``ts``: slerp for q, linear for ω and ω̇. Times within 1e-9 s of a truth
    sample take that sample exactly."""
    t = traj.t
    j = np.clip(np.searchsorted(t, ts, side="right") - 1, 0, len(t) - 2)
    s = (ts - t[j]) / (t[j + 1] - t[j])
    s[np.abs(ts - t[j]) < 1e-9] = 0.0
    exact_next = np.abs(ts - t[j + 1]) < 1e-9
    s[exact_next] = 1.0
    q0, q1 = traj.q[j], traj.q[j + 1]
    rel = _quat_log(attitude.multiply(attitude.conjugate(q0), q1))
    q = attitude.multiply(q0, _quat_exp(s[:, None] * rel))
    q[exact_next] = q1[exact_next]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)

    def lerp(a: NDArray[np.float64]) -> NDArray[np.float64]:
        return (1.0 - s)[:, None] * a[j] + s[:, None] * a[j + 1]

    omega_dot = traj.omega_dot
    if omega_dot is None:
        omega_dot = np.gradient(traj.omega, t, axis=0)
    return q, lerp(traj.omega), lerp(omega_dot)


def _quantize_saturate(
    x: NDArray[np.float64], full_scale: float, lsb: float, bits: int, quantize: bool
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Clip ``x`` to the output range and (optionally) round it to the output code."""
    if quantize:
        code = np.round(x / lsb)
        lo, hi = -(2.0 ** (bits - 1)), 2.0 ** (bits - 1) - 1
        sat = (code < lo) | (code > hi)
        return np.clip(code, lo, hi) * lsb, sat
    sat = np.abs(x) > full_scale
    return np.clip(x, -full_scale, full_scale), sat


def _checked_trajectory(t: ArrayLike, q: ArrayLike, omega: ArrayLike,
                        omega_dot: ArrayLike | None) -> Trajectory:
    """The truth of ``simulate_imu`` checked: finite, unit quaternions, >= 2 rows of equal
    length, strictly increasing times; ``ValueError`` naming the bad argument otherwise."""
    t = attitude.check_finite("t", t).reshape(-1)
    q = attitude.normalize(np.asarray(q, dtype=float).reshape(-1, 4), "q")
    omega = attitude.check_finite("omega", omega).reshape(-1, 3)
    if len(t) < 2 or not (len(q) == len(omega) == len(t)):
        raise ValueError(
            f"t, q, omega need >= 2 rows of equal length, got {len(t)}, {len(q)}, {len(omega)}"
        )
    if np.any(np.diff(t) <= 0):
        raise ValueError("t must be strictly increasing")
    wd = None
    if omega_dot is not None:
        wd = attitude.check_finite("omega_dot", omega_dot).reshape(-1, 3)
        if len(wd) != len(t):
            raise ValueError("omega_dot must have one row per time")
    return Trajectory(t, q, omega, wd)


def simulate_imu(
    t: ArrayLike,
    q: ArrayLike,
    omega: ArrayLike,
    config: ImuConfig | None = None,
    seed: int | np.random.Generator = 0,
    omega_dot: ArrayLike | None = None,
) -> ImuSamples:
    """IMU samples for a truth trajectory (seed 000 §5, Table 2; model in the module docstring).

    Parameters
    ----------
    t : (N,) strictly increasing truth times, s (e.g. every physics step of
        ``plant.dynamics.MujocoPlant``, or an analytic trajectory).
    q : (N, 4) true attitude (w, x, y, z), rotor to stator.
    omega : (N, 3) true body-frame angular velocity, rad/s.
    config : the IMU; default ``ImuConfig()``.
    seed : int or numpy Generator; the same seed gives the same samples.
    omega_dot : (N, 3) body angular acceleration, rad/s²; None differentiates ``omega``
        (second-order finite differences). Only needed for a sensor off the centre.

    Returns
    -------
    ImuSamples at t[0] + k/rate_hz for every such time within [t[0], t[-1]] (truth between its
    samples by slerp / linear interpolation).
    """
    cfg = config or ImuConfig()
    truth = _checked_trajectory(t, q, omega, omega_dot)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)

    dt = cfg.dt_s
    n = int(math.floor((truth.t[-1] - truth.t[0]) / dt + 1e-9)) + 1
    ts = truth.t[0] + np.arange(n) * dt
    q_s, w_s, wd_s = _resample(truth, ts)

    # Specific force at the sensor, body frame.
    r = np.asarray(cfg.position_m, dtype=float)
    f_true = (
        np.cross(wd_s, r)
        + np.cross(w_s, np.cross(w_s, r))
        + _rotate_to_body(q_s, [0.0, 0.0, cfg.gravity_m_s2])
    )

    # All random numbers are drawn in a fixed order whatever the configuration, so that two
    # configurations with the same seed share their noise realisations.
    g_turn_on = cfg.gyro_turn_on_bias * rng.standard_normal(3)
    g_scale = 1.0 + 0.01 * cfg.gyro_scale_error_pct * rng.standard_normal(3)
    a_turn_on = cfg.accel_turn_on_bias * rng.standard_normal(3)
    gm0 = rng.standard_normal(3)
    w_gyro, w_gm, w_rrw = (rng.standard_normal((n, 3)) for _ in range(3))
    w_acc, w_arw = (rng.standard_normal((n, 3)) for _ in range(2))

    sqrt_fs = math.sqrt(cfg.rate_hz)
    sigma_gm, tau = cfg.gyro_gauss_markov_sigma, cfg.gyro_bias_correlation_time_s
    phi = math.exp(-dt / tau)
    # b_k = φ b_{k-1} + σ sqrt(1 - φ²) w_k, stationary from b_{-1} ~ N(0, σ²)
    b_gm = lfilter(
        [sigma_gm * math.sqrt(1.0 - phi * phi)],
        [1.0, -phi],
        w_gm,
        axis=0,
        zi=phi * sigma_gm * gm0[None, :],
    )[0]
    b_rrw = cfg.gyro_rate_random_walk * math.sqrt(dt) * np.cumsum(w_rrw, axis=0)
    b_rrw -= b_rrw[0]  # the random walk starts at 0 at the first sample
    b_gyro = g_turn_on + b_gm + b_rrw
    b_arw = cfg.accel_bias_random_walk * math.sqrt(dt) * np.cumsum(w_arw, axis=0)
    b_acc = a_turn_on + b_arw - b_arw[0]

    gyro_raw = g_scale * w_s + b_gyro + cfg.gyro_noise_density * sqrt_fs * w_gyro
    acc_raw = f_true + b_acc + cfg.accel_noise_density * sqrt_fs * w_acc
    gyro, g_sat = _quantize_saturate(
        gyro_raw, cfg.gyro_range_rad_s, cfg.gyro_lsb_rad_s, cfg.adc_bits, cfg.quantize
    )
    acc, a_sat = _quantize_saturate(
        acc_raw, cfg.accel_range_m_s2, cfg.accel_lsb_m_s2, cfg.adc_bits, cfg.quantize
    )
    return ImuSamples(
        t=ts,
        gyro=gyro,
        accel=acc,
        q_true=q_s,
        omega_true=w_s,
        specific_force_true=f_true,
        gyro_bias=b_gyro,
        accel_bias=b_acc,
        gyro_scale=g_scale,
        gyro_saturated=g_sat,
        accel_saturated=a_sat,
    )


def simulate_imu_from(
    traj: Trajectory, config: ImuConfig | None = None, seed: int | np.random.Generator = 0
) -> ImuSamples:
    """``simulate_imu`` for a ``Trajectory``."""
    return simulate_imu(traj.t, traj.q, traj.omega, config, seed, traj.omega_dot)


# --------------------------------------------------------------------------------------------
# The estimator
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
