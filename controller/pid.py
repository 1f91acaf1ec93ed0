"""PID attitude control on SO(3) with a crossover-based tuning rule.

Control law (per body axis i of the *estimated* rotor frame)
------------------------------------------------------------
The attitude error is the rotation vector of ``q_e = q_est^-1 ⊗ q_ref`` (rad, estimated body
frame), the geodesic error on SO(3), never a difference of Euler angles. With the reference rate
``omega_r = R(q_e) omega_ref`` and acceleration ``alpha_r = R(q_e) alpha_ref`` moved into the
estimated body frame,

    tau_i = Kp_i e_i + I_i + Kd_i d_i + tau_ff,i
    d     = first-order low-pass (time constant tau_f) of (omega_r - omega_meas)
    dI_i/dt = Ki_i e_i  (+ anti-windup term)
    tau_ff = J alpha_r + omega_r × J omega_r          (reference feedforward; optional)

The derivative acts on the measurement (the rate), not on the error, so a reference step gives no
derivative kick (Åström & Murray, *Feedback Systems*, 2nd ed., §11.3). ``omega_meas`` is
``estimate.omega`` when it is finite, else the finite difference of successive measured attitudes,
``rotvec(q_prev^-1 ⊗ q) / (t - t_prev)`` with t the estimates' ``state_time``; the low-pass then
makes it the filtered derivative of the measured attitude. The body torque is turned into the
stator frame, ``T = R(q_est) tau``, and limited *as a vector* to ``|T| <= T_lim`` (direction
kept, as the allocator does, plant/torque.py).

Torque limit
------------
The allocator can deliver every torque inside the zonotope ``{K(q) I : |I_k| <= i_max}``. The
largest torque available in *every* direction at one attitude is the zonotope's inradius about
the origin, ``min_n i_max Σ_k |n · k_k|`` over unit n, attained at a facet normal
``n ∝ k_a × k_b`` (a 3-D zonotope's facets are spanned by pairs of generators). ``T_lim`` defaults
to ``margin`` times the minimum of that inradius over a grid of the tilt workspace
(``plant.torque.worst_case_capacity``); tests/test_pid.py checks the inradius against the LP
capacity of tests/test_torque.py.

Tuning rule (our formulation of a symmetric-optimum-like rule for ``P(s) = 1/(J s²)``)
-----------------------------------------------------------------------------------------
Given the crossover ω_c and two ratios a > 1, b > 0, write the controller in series form

    C(s) = k (1 + s/ω_d) / (1 + s/ω_f) · (1 + ω_i/s),   ω_d = ω_c/a,  ω_f = a ω_c,  ω_i = ω_c/b.

The lead network's zero and pole sit symmetrically about ω_c (geometric mean), where its phase
lead is largest (the symmetric optimum of Kessler for a double integrator), and the integral
corner sits a factor b below. At ω = ω_c the phases add to

    PM = atan(a) - atan(1/a) - atan(1/b)                   (phase margin, rad)

because the plant contributes -180°. |C(jω_c) P(jω_c)| = 1 gives

    k = J ω_c² / (a sqrt(1 + 1/b²))

using |1 + j a| / |1 + j/a| = a. In the parallel form ``Kp + Ki/s + Kd s/(tau_f s + 1)`` with
tau_f = 1/ω_f:

    Ki = k ω_i,   Kp = k (1 + ω_i/ω_d - ω_i/ω_f),   Kd = k/ω_d - Kp tau_f.

PM > 0 needs a b > 1, which also makes Kp, Kd > 0. The defaults a = 3, b = 10 give
PM = 71.57° - 18.43° - 5.71° = 47.42°. ``transfer_function(axis)`` returns this C(s) for the
margin analysis.

Anti-windup
-----------
``back_calculation`` (Åström & Murray §11.3): ``dI/dt = Ki e + (tau_sat - tau)/T_t`` with the
tracking time ``T_t = sqrt(Ti Td)`` (Ti = Kp/Ki, Td = Kd/Kp; their rule of thumb) unless set.
``conditional``: integration stops on an axis while the output is saturated and the error would
drive that axis further into saturation (clamping). ``none``: plain integration (for comparison).

Discretisation: the controller runs at the times it is called. The integrator is forward Euler
over the elapsed time; the derivative filter is the exact zero-order-hold discretisation
``d += (1 - exp(-dt/tau_f)) (x - d)``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

from controller.base import Controller, InvalidCommand, Reference
from plant import attitude
from plant.estimate import Estimate
from plant.params import PlantParams
from plant.torque import worst_case_capacity

if TYPE_CHECKING:  # python-control (and the scipy.signal it loads, about 1.5 s) only where used
    import control


def limit_vector(T: NDArray[np.float64], limit: float) -> tuple[NDArray[np.float64], bool]:
    """Scale ``T`` down to norm ``limit`` if it is longer (direction kept); also say whether it
    was scaled."""
    n = float(np.linalg.norm(T))
    if n > limit:
        return T * (limit / n), True
    return T, False


class RateFromAttitude:
    """Body rate (rad/s) from successive attitude measurements:
    ``rotvec(q_prev^-1 ⊗ q) / (t - t_prev)``; NaN until two distinct times have been seen."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the previous measurement."""
        self._q: NDArray[np.float64] | None = None
        self._t = -np.inf
        self._omega = np.full(3, np.nan)

    def update(self, q: NDArray[np.float64], t_exposure: float) -> NDArray[np.float64]:
        """Feed the attitude measured at ``t_exposure`` (s); return the rate estimate.

        Mirrored in ``latency.compiled.pid._attitude_rate``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        if self._q is not None and t_exposure > self._t:
            dq = attitude.multiply(attitude.conjugate(self._q), q)
            self._omega = attitude.to_rotvec(dq) / (t_exposure - self._t)
        if self._q is None or t_exposure > self._t:
            self._q, self._t = q, t_exposure
        return self._omega


def estimate_usable(estimate: Estimate) -> bool:
    """The estimate is flagged valid and carries a finite unit quaternion."""
    if not estimate.valid:
        return False
    q = np.asarray(estimate.q, dtype=float)
    return q.shape == (4,) and bool(np.all(np.isfinite(q))) and abs(np.linalg.norm(q) - 1) < 1e-3


# --------------------------------------------------------------------------------------------
# Tuning rule
# --------------------------------------------------------------------------------------------


class PIDGains(BaseModel):
    """Parallel-form gains of one axis: ``C(s) = Kp + Ki/s + Kd s / (tau_f s + 1)``."""

    model_config = ConfigDict(frozen=True)

    Kp: float = Field(description="N·m/rad")
    Ki: float = Field(description="N·m/(rad·s)")
    Kd: float = Field(description="N·m·s/rad")
    tau_f: float = Field(description="derivative filter time constant, s")

    def transfer_function(self) -> control.TransferFunction:
        """C(s) as a python-control TransferFunction (continuous, filter included)."""
        import control

        num = [self.Kp * self.tau_f + self.Kd, self.Kp + self.Ki * self.tau_f, self.Ki]
        return control.tf(num, [self.tau_f, 1.0, 0.0])


def phase_margin_of_rule(zero_ratio: float, integral_ratio: float) -> float:
    """Phase margin (rad) of the rule on ``1/(J s²)``: ``atan(a) - atan(1/a) - atan(1/b)``."""
    a, b = zero_ratio, integral_ratio
    return float(np.arctan(a) - np.arctan(1.0 / a) - np.arctan(1.0 / b))


def tuning_rule(
    J_kgm2: float, crossover_rad_s: float, zero_ratio: float = 3.0, integral_ratio: float = 10.0
) -> PIDGains:
    """Gains that put the crossover of ``C(s)/(J s²)`` at ``crossover_rad_s`` (module docstring).

    J in kg·m², ω_c in rad/s; a = ``zero_ratio`` (PD zero at ω_c/a, filter pole at a ω_c),
    b = ``integral_ratio`` (integral corner at ω_c/b).
    """
    if not (J_kgm2 > 0 and crossover_rad_s > 0 and zero_ratio > 1 and integral_ratio > 0):
        raise ValueError(
            f"need J > 0, crossover > 0, zero_ratio > 1, integral_ratio > 0; got J={J_kgm2}, "
            f"crossover={crossover_rad_s}, zero_ratio={zero_ratio}, integral_ratio={integral_ratio}"
        )
    a, b, wc = zero_ratio, integral_ratio, crossover_rad_s
    k = J_kgm2 * wc**2 / (a * np.sqrt(1.0 + 1.0 / b**2))
    w_d, w_f, w_i = wc / a, a * wc, wc / b
    tau_f = 1.0 / w_f
    Ki = k * w_i
    Kp = k * (1.0 + w_i / w_d - w_i / w_f)
    Kd = k / w_d - Kp * tau_f
    return PIDGains(Kp=float(Kp), Ki=float(Ki), Kd=float(Kd), tau_f=float(tau_f))


# --------------------------------------------------------------------------------------------
# Configuration and controller
# --------------------------------------------------------------------------------------------


class PIDConfig(BaseModel):
    """PID settings. An unstable rule (phase margin <= 0), inconsistent limits or a number
    that is not finite raise ``ValueError`` naming the field."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    crossover_rad_s: float = Field(
        10.0,
        gt=0.0,
        description="Our choice: 10 rad/s. At 36 frames/s (seed 000 §5) with GK-TransT's "
        "16.33 ms latency (seed 000 Table 1) plus half a frame of hold, the delay costs "
        "about 17° of phase at 10 rad/s, leaving ~30° of the rule's 47°.",
    )
    zero_ratio: float = Field(
        3.0, gt=1.0, description="Our choice: a = 3, lead of 53° at the crossover."
    )
    integral_ratio: float = Field(
        10.0, gt=0.0, description="Our choice: b = 10, the integral costs 5.7° at the crossover."
    )
    torque_limit_Nm: float | None = Field(
        None, gt=0.0, description="None: margin x the worst-direction capacity of the motor."
    )
    torque_limit_margin: float = Field(
        0.95,
        gt=0.0,
        le=1.0,
        description="Our choice: 5 % below the grid minimum of the capacity (a grid can miss "
        "the true minimum slightly).",
    )
    anti_windup: Literal["back_calculation", "conditional", "none"] = Field(
        "back_calculation", description="Our choice: back-calculation (Åström & Murray §11.3)."
    )
    tracking_time_s: float | None = Field(
        None, gt=0.0, description="Back-calculation T_t; None: sqrt(Ti Td) (Åström & Murray)."
    )
    feedforward: bool = Field(True, description="Our choice: add J alpha_r + omega_r x J omega_r.")
    friction_compensation_Nm: float = Field(
        0.0,
        ge=0.0,
        description="Coulomb friction compensation: adds F tanh(e / w) per axis, the friction "
        "torque F (N·m; e.g. PlantParams.rotor.coulomb_Nm) in the direction the error asks the "
        "rotor to move, so the integral need not wind up to break the rotor free (0 = off).",
    )
    friction_compensation_width_deg: float = Field(
        0.05, gt=0.0, description="Our choice: the error w (deg) over which tanh goes to ±1."
    )
    invalid_command: InvalidCommand = Field(
        "hold", description="Our choice: hold the last command while the estimate is invalid "
        "(controller.base: the one invalid-estimate policy)."
    )
    inertia_kgm2: tuple[float, float, float] | None = Field(
        None, description="Design inertia per body axis; None: the plant's J about O (diagonal)."
    )

    @model_validator(mode="after")
    def _stable(self) -> PIDConfig:
        pm = phase_margin_of_rule(self.zero_ratio, self.integral_ratio)
        if pm <= 0:
            raise ValueError(
                f"integral_ratio = {self.integral_ratio} with zero_ratio = {self.zero_ratio} "
                f"gives a phase margin of {np.degrees(pm):.1f}° <= 0: the loop is unstable "
                "(need zero_ratio * integral_ratio > 1)"
            )
        if self.inertia_kgm2 is not None and min(self.inertia_kgm2) <= 0:
            raise ValueError(f"inertia_kgm2 must be positive, got {self.inertia_kgm2}")
        return self

    @property
    def phase_margin_rad(self) -> float:
        """Phase margin of the rule on the rigid inertia, rad (no delay)."""
        return phase_margin_of_rule(self.zero_ratio, self.integral_ratio)


class PIDController(Controller):
    """PID on the SO(3) attitude error with derivative on measurement and anti-windup.

    ``command(estimate, reference, t)`` returns the stator-frame torque (N·m) to apply from ``t``.
    Attributes after each call: ``last_torque`` (N·m, stator), ``last_saturated``,
    ``last_compute_time_s`` and ``compute_times_s`` (wall clock per call, s), ``invalid_count``.
    ``clock`` (default ``time.perf_counter``, s) times the calls; tests inject a stand-in so that
    the timing does not depend on machine load.
    """

    def __init__(
        self,
        config: PIDConfig | None = None,
        params: PlantParams | None = None,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.config = cfg = config or PIDConfig()
        self.clock = clock
        self.params = params or PlantParams()
        J = (
            np.asarray(cfg.inertia_kgm2, dtype=float)
            if cfg.inertia_kgm2 is not None
            else np.diag(self.params.rotor.inertia_about_centre_kgm2).copy()
        )
        self.J = J
        self.gains = tuple(
            tuning_rule(J[i], cfg.crossover_rad_s, cfg.zero_ratio, cfg.integral_ratio)
            for i in range(3)
        )
        self.Kp = np.array([g.Kp for g in self.gains])
        self.Ki = np.array([g.Ki for g in self.gains])
        self.Kd = np.array([g.Kd for g in self.gains])
        self.tau_f = self.gains[0].tau_f
        if cfg.tracking_time_s is not None:
            self.T_t = np.full(3, cfg.tracking_time_s)
        else:
            self.T_t = np.sqrt((self.Kp / self.Ki) * (self.Kd / self.Kp))
        if cfg.torque_limit_Nm is not None:
            self.torque_limit = float(cfg.torque_limit_Nm)
        else:
            cap = worst_case_capacity(self.params.motor, self.params.rotor.tilt_stop_deg)
            self.torque_limit = cfg.torque_limit_margin * cap
        self.compute_times_s: list[float] = []
        self.reset()

    # --- public --------------------------------------------------------------------------------
    def transfer_function(self, axis: int = 0) -> control.TransferFunction:
        """C(s) of body axis ``axis`` (0, 1, 2 = x, y, z): torque (N·m) per attitude error (rad),
        continuous, derivative filter included (module docstring)."""
        return self.gains[axis].transfer_function()

    def discrete_transfer_function(
        self, period_s: float, axis: int = 0
    ) -> control.TransferFunction:
        """C(z) of body axis ``axis`` exactly as ``command`` runs it when called every
        ``period_s`` seconds on estimates without a rate, linearised about a constant reference:

            C(z) = Kp + Ki T/(z - 1) + Kd (1 - beta)(z - 1) / (T (z - beta)),  beta = exp(-T/tau_f)

        (the forward-Euler integrator that uses the previous error, the backward difference of
        the measured attitude, and the exact discrete first-order low-pass). Torque per attitude
        error, for the exact sampled-loop margins of ``latency.margins.sampled_margins``."""
        if not period_s > 0:
            raise ValueError(f"period_s must be positive, got {period_s}")
        import control

        g, T = self.gains[axis], float(period_s)
        beta = float(np.exp(-T / g.tau_f))
        integral = control.tf([g.Ki * T], [1.0, -1.0], T)
        derivative = control.tf([g.Kd * (1 - beta) / T, -g.Kd * (1 - beta) / T], [1.0, -beta], T)
        return control.tf([g.Kp], [1.0], T) + integral + derivative

    def reset(self) -> None:
        """Clear the integrator, the derivative filter, the rate estimator and the hold value."""
        self.integral = np.zeros(3)
        self._pending = np.zeros(3)  # dI/dt from the last call, body frame, N·m/s
        self._d = np.zeros(3)
        self._d_init = False
        self._t_prev: float | None = None
        self._rate = RateFromAttitude()
        self.last_torque = np.zeros(3)
        self.last_saturated = False
        self.last_compute_time_s = 0.0
        self.invalid_count = 0

    def command(self, estimate: Estimate, reference: Reference, t: float) -> NDArray[np.float64]:
        """Stator-frame torque (N·m) from time ``t`` (s); see the module docstring.

        Mirrored in ``latency.compiled.pid._pid``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        t0 = self.clock()
        try:
            return self._command(estimate, reference, float(t))
        finally:
            self.last_compute_time_s = self.clock() - t0
            self.compute_times_s.append(self.last_compute_time_s)

    # --- internals -----------------------------------------------------------------------------
    def _safe(self, t: float) -> NDArray[np.float64]:
        """The configured safe command; the integrator neither runs during the outage nor
        integrates the last valid error over it afterwards."""
        self.invalid_count += 1
        self._pending = np.zeros(3)
        self._t_prev = t
        if self.config.invalid_command == "zero":
            self.last_torque = np.zeros(3)
        return self.last_torque.copy()

    def _command(self, est: Estimate, reference: Reference, t: float) -> NDArray[np.float64]:
        # The discrete dynamics (integrator, derivative filter) advance by the time between the
        # samples the estimates describe, not between the calls: with a jittery observer the
        # calls are irregular while the frames are not.
        t_sample = est.state_time if np.isfinite(est.state_time) else t
        if not estimate_usable(est):
            return self._safe(t_sample)
        dt = 0.0 if self._t_prev is None else max(t_sample - self._t_prev, 0.0)
        self._t_prev = t_sample
        q = attitude.normalize(est.q, "estimate.q")
        ref = reference.sample(t)
        q_e = attitude.multiply(attitude.conjugate(q), attitude.normalize(ref.q, "reference.q"))
        e = attitude.to_rotvec(q_e)
        R_e = attitude.to_matrix(q_e)
        w_r = R_e @ np.asarray(ref.omega, dtype=float)
        a_r = R_e @ np.asarray(ref.alpha, dtype=float)

        omega_meas = np.asarray(est.omega, dtype=float)
        rate_from_q = self._rate.update(q, est.state_time)
        if omega_meas.shape != (3,) or not np.all(np.isfinite(omega_meas)):
            omega_meas = rate_from_q
        if np.all(np.isfinite(omega_meas)):
            x = w_r - omega_meas
            if not self._d_init:
                self._d, self._d_init = x.copy(), True
            else:
                self._d += (1.0 - np.exp(-dt / self.tau_f)) * (x - self._d)

        # Integrator: forward Euler with the rate decided at the previous call.
        self.integral = self.integral + self._pending * dt

        tau = self.Kp * e + self.integral + self.Kd * self._d
        if self.config.friction_compensation_Nm > 0.0:
            width = np.radians(self.config.friction_compensation_width_deg)
            tau = tau + self.config.friction_compensation_Nm * np.tanh(e / width)
        if self.config.feedforward:
            Jw = self.J * w_r  # omega_r x J omega_r written out (np.cross is slow on 3-vectors)
            gyro = np.array([w_r[1] * Jw[2] - w_r[2] * Jw[1], w_r[2] * Jw[0] - w_r[0] * Jw[2],
                             w_r[0] * Jw[1] - w_r[1] * Jw[0]])
            tau = tau + self.J * a_r + gyro
        R = attitude.to_matrix(q)
        T, saturated = limit_vector(R @ tau, self.torque_limit)
        tau_sat = R.T @ T

        rate = self.Ki * e
        mode = self.config.anti_windup
        if mode == "back_calculation":
            rate = rate + (tau_sat - tau) / self.T_t
        elif mode == "conditional" and saturated:
            pushing = np.sign(e) == np.sign(tau - tau_sat)
            rate = np.where(pushing & (np.abs(tau - tau_sat) > 0), 0.0, rate)
        self._pending = rate
        self.last_torque, self.last_saturated = T, saturated
        return T.copy()


def reach_warnings(pid: PIDController, frame_rate_hz: float) -> list[str]:
    """Reasons why the crossover of ``pid`` is far outside what the plant and the camera can
    do (empty if none). Such a loop still runs, but its linear design (the margins) does not
    describe it.

    * Above the Nyquist frequency of the camera, ``π · frame_rate_hz`` (rad/s): a loop sampled
      at the frame rate cannot place its crossover there.
    * ``Kp`` times a 1° error (N·m) above the torque limit: the loop saturates on small errors.
    * ``Kp`` times the whole tilt range (the stop, ``RotorParams.tilt_stop_deg``) below the
      bearing's dry friction ``RotorParams.coulomb_Nm``: the proportional action cannot move
      the rotor, only the integral does.
    """
    wc = pid.config.crossover_rad_s
    rotor = pid.params.rotor
    kp = float(np.max(pid.Kp))
    nyquist = np.pi * frame_rate_hz
    out = []
    if wc > nyquist:
        out.append(
            f"crossover {wc:g} rad/s is above the camera's Nyquist frequency pi x {frame_rate_hz:g}"
            f" Hz = {nyquist:.4g} rad/s: a loop sampled at the frame rate cannot cross over there"
        )
    if kp * np.radians(1.0) > pid.torque_limit:
        out.append(
            f"crossover {wc:g} rad/s asks {kp * np.radians(1.0):.3g} N·m for a 1° error, more "
            f"than the torque limit {pid.torque_limit:.3g} N·m: the loop saturates on small errors"
        )
    if kp * np.radians(rotor.tilt_stop_deg) < rotor.coulomb_Nm:
        out.append(
            f"crossover {wc:g} rad/s asks {kp * np.radians(rotor.tilt_stop_deg):.3g} N·m for an "
            f"error of the whole tilt range ({rotor.tilt_stop_deg:g}°), less than the bearing's "
            f"dry friction {rotor.coulomb_Nm:g} N·m: only the integral moves the rotor"
        )
    return out


def truth_estimate(
    q: ArrayLike, omega: ArrayLike | None, t_exposure: float, t_available: float | None = None
) -> Estimate:
    """An ``Estimate`` built from a true state (for ground-truth loops and tests): attitude ``q``
    (w, x, y, z), body rate ``omega`` (rad/s, or None for NaN), times in s."""
    q = attitude.normalize(q)
    w = np.full(3, np.nan) if omega is None else attitude.check_finite("omega", omega)
    return Estimate(
        t_exposure=float(t_exposure),
        t_available=float(t_exposure if t_available is None else t_available),
        q=q,
        euler_zyz=np.array(attitude.to_zyz(q)),
        marker_px=np.zeros((0, 2)),
        covariance=np.zeros((3, 3)),
        valid=True,
        omega=w,
    )
