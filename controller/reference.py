"""Reference trajectories for the attitude loop: ``sample(t) -> RefSample`` (controller/base.py).

Every generator here returns the desired attitude q (w, x, y, z; rotor to stator), the desired
body rate omega (rad/s, in the desired rotor frame) and the desired body angular acceleration
alpha (rad/s², same frame), with omega and alpha the exact derivatives of q.

How the rates are computed (no finite differences). Each smooth trajectory is a product of
rotations about fixed unit axes, ``R(t) = exp(θ1 [a1]) exp(θ2 [a2]) ... exp(θn [an])``, whose
angles θi(t) are known with their first and second derivatives. With ``M_i = R_{i+1} ... R_n``
(M_n = I) the body rate and acceleration are

    omega = Σ_i M_i^T a_i θi'
    alpha = Σ_i ( M_i^T a_i θi'' - w_i × (M_i^T a_i) θi' ),   w_i = Σ_{j>i} M_j^T a_j θj'

(w_i is the body rate of M_i; ``d/dt (M^T v) = -w × M^T v`` for a constant v). The seed's Z-Y-Z
angles are such a product, ``R = Rz(yaw γ) Ry(tilt β) Rz(spin α)`` (seed 000 §2.1, see
docs/plant.md), as is the X-Y-Z product used for the random trajectories.

Generators (pydantic models; angles at the edges in degrees, in fields that say so):

* ``Steps``: piecewise-constant attitudes at given times (omega = alpha = 0).
* ``SeedSteps``: the step protocol of seed 000 §5 (spin 0–75° by 10°, tilt 0–15° by 5°, yaw by
  10° at 15° tilt, 5 s dwell).
* ``Ramp``: the three Z-Y-Z angles move linearly from a start to a stop set, then hold.
* ``Cone``: yaw sweeping at a constant rate at a fixed tilt.
* ``RandomSmooth``: a seeded smooth periodic trajectory with a set peak angular rate that stays
  inside the tilt workspace.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, model_validator

from controller.base import RefSample
from plant import attitude

#: Seed 000 §2.4: the tilt range of the motor is 0–15° (mechanical stop).
TILT_WORKSPACE_DEG = 15.0

_EX = np.array([1.0, 0.0, 0.0])
_EY = np.array([0.0, 1.0, 0.0])
_EZ = np.array([0.0, 0.0, 1.0])


def _cross(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float]:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _rotate_back(axis: Sequence[float], angle: float, v: Sequence[float]) -> tuple:
    """``exp(angle [axis])^T v`` for a unit axis (Rodrigues' formula with -angle)."""
    c, s = np.cos(angle), -np.sin(angle)
    kv = axis[0] * v[0] + axis[1] * v[1] + axis[2] * v[2]
    kxv = _cross(axis, v)
    return tuple(v[j] * c + kxv[j] * s + axis[j] * kv * (1.0 - c) for j in range(3))


def chain_sample(
    axes: Sequence[NDArray[np.float64]],
    theta: Sequence[float],
    dtheta: Sequence[float],
    ddtheta: Sequence[float],
) -> RefSample:
    """Attitude, body rate (rad/s) and body acceleration (rad/s²) of
    ``R = exp(θ1 a1) ... exp(θn an)`` from the angles (rad) and their first two time derivatives
    (rad/s, rad/s²). Formulas in the module docstring. (Plain floats: this runs once per MPC
    node, where numpy's per-call overhead on 3-vectors dominated.)"""
    n = len(axes)
    ax = [tuple(float(c) for c in a) for a in axes]
    th = [float(x) for x in theta]
    q = (1.0, 0.0, 0.0, 0.0)
    for a, t in zip(ax, th, strict=True):
        c, s = np.cos(0.5 * t), np.sin(0.5 * t)
        w, x, y, z = q
        bx, by, bz = s * a[0], s * a[1], s * a[2]
        q = (
            w * c - x * bx - y * by - z * bz,
            w * bx + x * c + y * bz - z * by,
            w * by - x * bz + y * c + z * bx,
            w * bz + x * by - y * bx + z * c,
        )
    # Walk from the last factor to the first: v_i = M_i^T a_i with M_i = R_{i+1} ... R_n, and
    # w_M the body rate of M_i. M_{i-1}^T u = M_i^T R_i^T u, so each v_i is a_i rotated back
    # through the factors after it.
    omega = [0.0, 0.0, 0.0]
    alpha = [0.0, 0.0, 0.0]
    w_M = (0.0, 0.0, 0.0)
    for i in range(n - 1, -1, -1):
        v = ax[i]
        for j in range(i + 1, n):
            v = _rotate_back(ax[j], th[j], v)
        wxv = _cross(w_M, v)
        d1, d2 = float(dtheta[i]), float(ddtheta[i])
        for j in range(3):
            omega[j] += v[j] * d1
            alpha[j] += v[j] * d2 - wxv[j] * d1
        w_M = (w_M[0] + v[0] * d1, w_M[1] + v[1] * d1, w_M[2] + v[2] * d1)
    return RefSample(q=np.array(q), omega=np.array(omega), alpha=np.array(alpha))


def _rotate_back_many(
    axis: NDArray[np.float64], angle: NDArray[np.float64], v: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``exp(angle_k [axis])^T v_k`` for a unit axis (3,), angles (n,) and vectors (n, 3)
    (Rodrigues' formula with -angle)."""
    c, s = np.cos(angle)[:, None], -np.sin(angle)[:, None]
    kv = (v @ axis)[:, None]
    return v * c + np.cross(axis, v) * s + axis * kv * (1.0 - c)


def chain_sample_many(
    axes: Sequence[NDArray[np.float64]],
    theta: NDArray[np.float64],
    dtheta: NDArray[np.float64],
    ddtheta: NDArray[np.float64],
) -> RefSample:
    """``chain_sample`` at n times at once: the angles (rad) and their derivatives (rad/s,
    rad/s²) are (len(axes), n); returns q (n, 4), omega (n, 3), alpha (n, 3). The same
    formulas (module docstring), as arrays over the times."""
    ax = [np.asarray(a, dtype=float) for a in axes]
    th, d1, d2 = (np.asarray(x, dtype=float) for x in (theta, dtheta, ddtheta))
    n = th.shape[1]
    q = np.zeros((n, 4))
    q[:, 0] = 1.0
    for a, t in zip(ax, th, strict=True):
        factor = np.concatenate([np.cos(0.5 * t)[:, None], np.sin(0.5 * t)[:, None] * a], axis=1)
        q = attitude.multiply(q, factor)
    omega, alpha, w_M = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    for i in range(len(ax) - 1, -1, -1):
        v = np.broadcast_to(ax[i], (n, 3))
        for j in range(i + 1, len(ax)):
            v = _rotate_back_many(ax[j], th[j], v)
        wxv = np.cross(w_M, v)
        omega += v * d1[i][:, None]
        alpha += v * d2[i][:, None] - wxv * d1[i][:, None]
        w_M = w_M + v * d1[i][:, None]
    return RefSample(q=q, omega=omega, alpha=alpha)


def zyz_sample_many(
    angles: NDArray[np.float64], rates: NDArray[np.float64], accels: NDArray[np.float64]
) -> RefSample:
    """``zyz_sample`` at n times: (spin, tilt, yaw) and their derivatives as (3, n) arrays."""
    order = [2, 1, 0]  # the product Rz(yaw) Ry(tilt) Rz(spin)
    a, r, c = (np.asarray(x, dtype=float)[order] for x in (angles, rates, accels))
    return chain_sample_many((_EZ, _EY, _EZ), a, r, c)


def zyz_sample(
    angles: Sequence[float], rates: Sequence[float], accels: Sequence[float]
) -> RefSample:
    """Sample from the seed's (spin α, tilt β, yaw γ) in rad with their rates (rad/s) and
    accelerations (rad/s²); ``R = Rz(γ) Ry(β) Rz(α)`` (seed 000 §2.1)."""
    a, b, g = angles
    da, db, dg = rates
    dda, ddb, ddg = accels
    return chain_sample((_EZ, _EY, _EZ), (g, b, a), (dg, db, da), (ddg, ddb, dda))


def pure_tilt(tilt_rad: float, azimuth_rad: float = 0.0) -> NDArray[np.float64]:
    """Attitude tilted by ``tilt_rad`` toward azimuth ``azimuth_rad`` with no turn about the shaft:
    ``from_zyz(-γ, β, γ)`` (docs/plant.md)."""
    return attitude.from_zyz(-azimuth_rad, tilt_rad, azimuth_rad)


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Steps(_Model):
    """Piecewise-constant attitudes: ``attitudes[k]`` from ``times_s[k]`` on (the first one also
    before ``times_s[0]``). Rates and accelerations are zero (a step has no finite derivative)."""

    times_s: tuple[float, ...] = Field(min_length=1, description="Switching times, s, increasing.")
    attitudes: tuple[tuple[float, float, float, float], ...] = Field(
        min_length=1, description="Unit quaternions (w, x, y, z), one per switching time."
    )
    # The attitudes normalised and the times as arrays, once (sample runs at every grid point).
    _unit: NDArray[np.float64] = PrivateAttr()
    _times: NDArray[np.float64] = PrivateAttr()

    @model_validator(mode="after")
    def _check(self) -> Steps:
        if len(self.times_s) != len(self.attitudes):
            raise ValueError(
                f"attitudes has {len(self.attitudes)} entries but times_s has {len(self.times_s)}"
            )
        if not np.all(np.isfinite(self.times_s)) or np.any(np.diff(self.times_s) <= 0):
            raise ValueError(f"times_s must be finite and strictly increasing, got {self.times_s}")
        self._unit = np.array(
            [attitude.normalize(q, f"attitudes[{k}]") for k, q in enumerate(self.attitudes)]
        )
        self._times = np.asarray(self.times_s, dtype=float)
        return self

    def sample(self, t: float) -> RefSample:
        """The attitude active at ``t`` (s); zero rate and acceleration."""
        k = max(int(np.searchsorted(self._times, t, side="right")) - 1, 0)
        return RefSample(q=self._unit[k].copy())

    def sample_many(self, t: NDArray[np.float64]) -> RefSample:
        """The attitudes active at the times ``t`` (n,), s; zero rates and accelerations."""
        t = np.asarray(t, dtype=float).reshape(-1)
        k = np.maximum(np.searchsorted(self._times, t, side="right") - 1, 0)
        return RefSample(q=self._unit[k], omega=np.zeros((len(t), 3)),
                         alpha=np.zeros((len(t), 3)))

    @property
    def duration_s(self) -> float:
        """Time of the last switch, s (the last attitude holds from then on)."""
        return float(self.times_s[-1])


class SeedSteps(_Model):
    """The step protocol of seed 000 §5: single-axis steps with a dwell after each.

    * ``axis="spin"``: spin 0–75° by 10° (0, 10, ..., 70°) at zero tilt, ``R = Rz(α)`` (§5.1).
    * ``axis="tilt"``: tilt 0–15° by 5° toward azimuth ``azimuth_deg`` (default 0: about the stator
      Y axis, as the seed's fixture), no turn about the shaft, ``from_zyz(-γ, β, γ)`` (§5.2).
    * ``axis="yaw"``: yaw by 10° at ``tilt_deg`` = 15° (§5.3). The seed turns the whole tilted rotor
      about the global Z axis with a rotary table, ``R = Rz(γ) Ry(β)`` = ``from_zyz(0, β, γ)``
      (``turn_shaft=True``). With ``turn_shaft=False`` the shaft direction sweeps the same cone
      without turning about itself, ``from_zyz(-γ, β, γ)``. The seed does not give the yaw range;
      0–90° is our choice.

    Each value holds for ``dwell_s`` (seed 000 §5: 5 s), the first one from t = ``t_start_s``
    (and before it).
    """

    axis: Literal["spin", "tilt", "yaw"]
    values_deg: tuple[float, ...] | None = Field(
        None,
        description="Step values, deg. None: the seed's (spin 0–70 by 10, tilt 0–15 by 5; "
        "yaw 0–90 by 10 is our choice).",
    )
    dwell_s: float = Field(5.0, gt=0.0, description="Seed 000 §5: 5 s dwell after each step.")
    t_start_s: float = Field(0.0, description="Our choice: the first value from t = 0.")
    tilt_deg: float = Field(
        15.0, ge=0.0, le=TILT_WORKSPACE_DEG, description="Yaw test tilt; seed 000 §5.3: 15°."
    )
    azimuth_deg: float = Field(0.0, description="Tilt test azimuth; our choice: 0 (about +Y).")
    turn_shaft: bool = Field(
        True, description="Yaw test: rotate rigidly about Z like the seed's rotary table (§5.3)."
    )

    @model_validator(mode="after")
    def _check(self) -> SeedSteps:
        vals = self.values()
        if self.axis == "tilt" and (np.any(vals < 0) or np.any(vals > TILT_WORKSPACE_DEG)):
            raise ValueError(
                f"values_deg: tilt steps must lie in [0, {TILT_WORKSPACE_DEG}]° "
                f"(seed 000 §2.4), got {vals}"
            )
        if not np.all(np.isfinite(vals)) or len(vals) == 0:
            raise ValueError(f"values_deg must be finite and non-empty, got {vals}")
        return self

    def values(self) -> NDArray[np.float64]:
        """The step values, deg."""
        if self.values_deg is not None:
            return np.asarray(self.values_deg, dtype=float)
        stop = {"spin": 75.0, "tilt": 15.0, "yaw": 90.0}[self.axis]
        inc = {"spin": 10.0, "tilt": 5.0, "yaw": 10.0}[self.axis]
        return np.arange(0.0, stop + 1e-9, inc)

    def attitude_of(self, value_deg: float) -> NDArray[np.float64]:
        """The attitude of one step value (deg)."""
        v = np.deg2rad(value_deg)
        if self.axis == "spin":
            return attitude.from_zyz(v, 0.0, 0.0)
        if self.axis == "tilt":
            return pure_tilt(v, np.deg2rad(self.azimuth_deg))
        beta = np.deg2rad(self.tilt_deg)
        return attitude.from_zyz(0.0 if self.turn_shaft else -v, beta, v)

    def steps(self) -> Steps:
        """The protocol as a ``Steps`` reference."""
        vals = self.values()
        times = self.t_start_s + self.dwell_s * np.arange(len(vals))
        qs = tuple(tuple(float(c) for c in self.attitude_of(v)) for v in vals)
        return Steps(times_s=tuple(float(t) for t in times), attitudes=qs)

    _steps: Steps = PrivateAttr()

    def model_post_init(self, __context: object) -> None:
        """Build the step list once (the model is frozen)."""
        self._steps = self.steps()

    def sample(self, t: float) -> RefSample:
        """The step attitude at ``t`` (s)."""
        return self._steps.sample(t)

    def sample_many(self, t: NDArray[np.float64]) -> RefSample:
        """The step attitudes at the times ``t`` (n,), s."""
        return self._steps.sample_many(t)

    @property
    def duration_s(self) -> float:
        """End of the last dwell, s."""
        return self.t_start_s + self.dwell_s * len(self.values())


class Ramp(_Model):
    """The Z-Y-Z angles (spin, tilt, yaw) move linearly from ``start_deg`` to ``stop_deg`` over
    ``duration_s`` from ``t_start_s``, holding before and after (rates jump at the corners, where
    alpha is an impulse that we report as 0). A pure tilt ramp toward azimuth γ is
    ``start_deg=(-γ, 0, γ)``, ``stop_deg=(-γ, β, γ)``."""

    start_deg: tuple[float, float, float] = Field(description="(spin, tilt, yaw) at the start.")
    stop_deg: tuple[float, float, float] = Field(description="(spin, tilt, yaw) at the end.")
    t_start_s: float = Field(0.0, description="Ramp start, s (our choice: 0).")
    duration_s: float = Field(gt=0.0, description="Ramp duration, s.")

    @model_validator(mode="after")
    def _check(self) -> Ramp:
        for name, v in (("start_deg", self.start_deg), ("stop_deg", self.stop_deg)):
            if not np.all(np.isfinite(v)):
                raise ValueError(f"{name} must be finite, got {v}")
            if not 0.0 <= v[1] <= TILT_WORKSPACE_DEG:
                raise ValueError(
                    f"{name}: tilt {v[1]}° is outside the 0–{TILT_WORKSPACE_DEG}° workspace "
                    "(seed 000 §2.4)"
                )
        return self

    @property
    def rate_rad_s(self) -> NDArray[np.float64]:
        """Angle rates (spin, tilt, yaw), rad/s, during the ramp."""
        return np.deg2rad(np.subtract(self.stop_deg, self.start_deg)) / self.duration_s

    def sample(self, t: float) -> RefSample:
        """The ramp at ``t`` (s)."""
        s = float(np.clip(t - self.t_start_s, 0.0, self.duration_s))
        moving = self.t_start_s < t < self.t_start_s + self.duration_s
        rates = self.rate_rad_s if moving else np.zeros(3)
        angles = np.deg2rad(self.start_deg) + self.rate_rad_s * s
        return zyz_sample(angles, rates, (0.0, 0.0, 0.0))

    def sample_many(self, t: NDArray[np.float64]) -> RefSample:
        """The ramp at the times ``t`` (n,), s."""
        t = np.asarray(t, dtype=float).reshape(-1)
        s = np.clip(t - self.t_start_s, 0.0, self.duration_s)
        moving = (self.t_start_s < t) & (t < self.t_start_s + self.duration_s)
        rate = self.rate_rad_s[:, None]
        angles = np.deg2rad(self.start_deg)[:, None] + rate * s
        return zyz_sample_many(angles, rate * moving, np.zeros_like(angles))


class Cone(_Model):
    """Yaw sweeping at ``yaw_rate_rad_s`` at a fixed tilt from ``t_start_s`` (holding the start
    attitude before). With yaw γ(t) = yaw0 + rate (t - t_start):

    * ``turn_shaft=True``: the tilted rotor turns rigidly about the stator Z axis (the seed's
      rotary-table yaw, seed 000 §5.3), ``from_zyz(spin0, β, γ)``;
    * ``turn_shaft=False``: the shaft sweeps the cone without turning about itself, a pure
      tilt toward γ after a fixed turn spin0 about the shaft, ``from_zyz(spin0 - γ, β, γ)``.
    """

    tilt_deg: float = Field(ge=0.0, le=TILT_WORKSPACE_DEG, description="Cone half-angle, deg.")
    yaw_rate_rad_s: float = Field(description="Yaw rate, rad/s (sign = direction).")
    yaw0_deg: float = Field(0.0, description="Yaw at the start, deg (our choice: 0).")
    spin0_deg: float = Field(0.0, description="Spin offset, deg (our choice: 0).")
    t_start_s: float = Field(0.0, description="Start of the sweep, s (our choice: 0).")
    turn_shaft: bool = Field(True, description="Seed 000 §5.3 rotary-table motion.")

    def sample(self, t: float) -> RefSample:
        """The cone at ``t`` (s)."""
        dg = self.yaw_rate_rad_s if t > self.t_start_s else 0.0
        g = np.deg2rad(self.yaw0_deg) + self.yaw_rate_rad_s * max(t - self.t_start_s, 0.0)
        a0 = np.deg2rad(self.spin0_deg)
        a, da = (a0, 0.0) if self.turn_shaft else (a0 - g, -dg)
        return zyz_sample((a, np.deg2rad(self.tilt_deg), g), (da, 0.0, dg), (0.0, 0.0, 0.0))

    def sample_many(self, t: NDArray[np.float64]) -> RefSample:
        """The cone at the times ``t`` (n,), s."""
        t = np.asarray(t, dtype=float).reshape(-1)
        dg = np.where(t > self.t_start_s, self.yaw_rate_rad_s, 0.0)
        g = np.deg2rad(self.yaw0_deg) + self.yaw_rate_rad_s * np.maximum(t - self.t_start_s, 0.0)
        a0 = np.full_like(t, np.deg2rad(self.spin0_deg))
        a, da = (a0, np.zeros_like(t)) if self.turn_shaft else (a0 - g, -dg)
        zero = np.zeros_like(t)
        return zyz_sample_many(np.stack([a, np.full_like(t, np.deg2rad(self.tilt_deg)), g]),
                               np.stack([da, zero, dg]), np.zeros((3, len(t))))


class RandomSmooth(_Model):
    """A seeded, smooth, periodic random trajectory with a set peak angular rate inside the tilt
    workspace (our construction).

    ``R(t) = Rx(a(t)) Ry(b(t)) Rz(c(t))``: a and b tilt the shaft (tilt = arccos(cos a cos b)),
    c turns it about itself. Each angle is a sum of ``n_harmonics`` sines of a base frequency Ω,
    ``Σ_k A_k (sin(k Ω t + φ_k) - sin φ_k)`` with ``A_k ~ N(0, 1)/k`` and ``φ_k ~ U(0, 2π)``, so
    the trajectory starts at the identity and repeats with period 2π/Ω. The (a, b) amplitudes are
    scaled so that the peak tilt over a period is ``tilt_max_deg``, c so that its peak is
    ``spin_max_deg``, then Ω so that the peak of |omega| over a period is ``max_rate_rad_s`` (body
    rates scale linearly with Ω at fixed shape). The peaks are taken on a grid of
    ``4096 * n_harmonics`` points per period; the grid error is second order in the spacing
    (relative error < 1e-5 for the defaults).
    """

    seed: int = Field(0, ge=0, description="Random seed (same seed, same trajectory).")
    max_rate_rad_s: float = Field(gt=0.0, description="Peak body angular rate, rad/s.")
    tilt_max_deg: float = Field(
        12.0,
        gt=0.0,
        le=TILT_WORKSPACE_DEG,
        description="Peak tilt, deg. Our choice: 12°, 3° inside the 15° stop (seed 000 §2.4) "
        "to leave room for tracking errors.",
    )
    spin_max_deg: float = Field(45.0, ge=0.0, description="Peak |spin angle c|, deg (our choice).")
    n_harmonics: int = Field(4, ge=1, le=32, description="Sines per angle (our choice: 4).")

    _A: NDArray[np.float64] = PrivateAttr()  # (3, n) amplitudes, rad
    _phi: NDArray[np.float64] = PrivateAttr()  # (3, n) phases, rad
    _Omega: float = PrivateAttr()  # base frequency, rad/s

    def model_post_init(self, __context: object) -> None:
        """Draw the harmonics' amplitudes and phases from ``seed`` and scale them to the peak
        rate and tilt (once: the model is frozen)."""
        rng = np.random.default_rng(self.seed)
        k = np.arange(1, self.n_harmonics + 1)
        A = rng.normal(size=(3, self.n_harmonics)) / k
        self._phi = rng.uniform(0.0, 2.0 * np.pi, size=(3, self.n_harmonics))
        self._A, self._Omega = A, 1.0
        # Shapes at Ω = 1 on one period; scale a, b together for the tilt and c alone.
        s = np.linspace(0.0, 2.0 * np.pi, 4096 * self.n_harmonics, endpoint=False)
        th, _, _ = self._angles_on(s)
        A[0:2] *= self._tilt_scale(th[0], th[1], np.deg2rad(self.tilt_max_deg))
        c_peak = np.abs(th[2]).max()
        A[2] *= np.deg2rad(self.spin_max_deg) / c_peak if c_peak > 0 else 0.0
        # Peak |omega| at Ω = 1 (closed form of the X-Y-Z body rate), then set Ω.
        th, dth, _ = self._angles_on(s)
        a_d, b_d, c_d = dth
        b = th[1]
        rate = np.sqrt((np.cos(b) * a_d) ** 2 + b_d**2 + (np.sin(b) * a_d + c_d) ** 2)
        self._Omega = self.max_rate_rad_s / rate.max()

    def _angles_on(self, t: NDArray[np.float64]) -> tuple[NDArray, NDArray, NDArray]:
        """Angles (3, n), rates and accelerations on a time grid ``t`` (n,)."""
        k = np.arange(1, self.n_harmonics + 1)
        W = k * self._Omega  # (n_h,)
        arg = W[None, :, None] * t[None, None, :] + self._phi[:, :, None]  # (3, n_h, n)
        A = self._A[:, :, None]
        th = (A * (np.sin(arg) - np.sin(self._phi)[:, :, None])).sum(1)
        dth = (A * W[None, :, None] * np.cos(arg)).sum(1)
        ddth = -(A * (W**2)[None, :, None] * np.sin(arg)).sum(1)
        return th, dth, ddth

    @staticmethod
    def _tilt_scale(a: NDArray[np.float64], b: NDArray[np.float64], target: float) -> float:
        """Factor λ with max_t arccos(cos λa cos λb) = target (bisection; the tilt grows
        monotonically with λ while |λa|, |λb| < π/2)."""
        lo, hi = 0.0, (np.pi / 2) / max(np.abs(a).max(), np.abs(b).max())
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            peak = np.arccos(np.clip(np.cos(mid * a) * np.cos(mid * b), -1.0, 1.0)).max()
            lo, hi = (mid, hi) if peak < target else (lo, mid)
        return lo

    @property
    def period_s(self) -> float:
        """Period of the trajectory, s."""
        return 2.0 * np.pi / self._Omega

    def angles(self, t: float) -> tuple[NDArray, NDArray, NDArray]:
        """(a, b, c) in rad with their first (rad/s) and second (rad/s²) derivatives at ``t``."""
        th, dth, ddth = self._angles_on(np.array([float(t)]))
        return th[:, 0], dth[:, 0], ddth[:, 0]

    def sample(self, t: float) -> RefSample:
        """The trajectory at ``t`` (s)."""
        th, dth, ddth = self.angles(t)
        return chain_sample((_EX, _EY, _EZ), th, dth, ddth)

    def sample_many(self, t: NDArray[np.float64]) -> RefSample:
        """The trajectory at the times ``t`` (n,), s."""
        th, dth, ddth = self._angles_on(np.asarray(t, dtype=float).reshape(-1))
        return chain_sample_many((_EX, _EY, _EZ), th, dth, ddth)
