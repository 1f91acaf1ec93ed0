"""The IMU of the MEMS baseline (seed 000 §5): an ICM42605-class sensor on the rotor, simulated
from a true trajectory (its estimator is ``observer.mems``).

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
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field
from scipy.signal import lfilter

from plant import attitude

Vec3 = Annotated[tuple[float, float, float], Field(description="3-vector")]

#: One degree in rad.
DEG = math.pi / 180.0
#: Standard gravity (m/s²), the unit "g" of datasheet accelerometer figures.
G0 = 9.80665


class StrictSettings(BaseModel):
    """Settings that reject unknown fields and cannot change once made."""

    model_config = ConfigDict(extra="forbid", frozen=True)


# --------------------------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------------------------
class ImuConfig(StrictSettings):
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


def _errors(
    cfg: ImuConfig, rng: np.random.Generator, n: int,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
           NDArray[np.float64]]:
    """The sensor errors of ``n`` samples (module docstring): the gyro scale factors (3,), the
    gyro bias (n, 3), rad/s (turn-on + Gauss-Markov + rate random walk), the accelerometer
    bias (n, 3), m/s² (turn-on + random walk), and the unit white noises (n, 3) of the gyro
    and the accelerometer."""
    # All random numbers are drawn in a fixed order whatever the configuration, so that two
    # configurations with the same seed share their noise realisations.
    g_turn_on = cfg.gyro_turn_on_bias * rng.standard_normal(3)
    g_scale = 1.0 + 0.01 * cfg.gyro_scale_error_pct * rng.standard_normal(3)
    a_turn_on = cfg.accel_turn_on_bias * rng.standard_normal(3)
    gm0 = rng.standard_normal(3)
    w_gyro, w_gm, w_rrw = (rng.standard_normal((n, 3)) for _ in range(3))
    w_acc, w_arw = (rng.standard_normal((n, 3)) for _ in range(2))

    dt = cfg.dt_s
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

    return g_scale, b_gyro, b_acc, w_gyro, w_acc


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

    g_scale, b_gyro, b_acc, w_gyro, w_acc = _errors(cfg, rng, n)
    sqrt_fs = math.sqrt(cfg.rate_hz)
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
