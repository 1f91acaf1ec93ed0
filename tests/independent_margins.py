"""The per-axis PID loop's margins derived from first principles, for tests that check the
study's headline numbers. Nothing here calls ``latency.margins``, ``latency.pipeline`` or the
controller's transfer functions: only the tuned gains, the rotor's inertia and damping and the
camera's frame rate and exposure are read from the project.

The loop, as the simulation runs it
-----------------------------------
* Plant ``J theta'' + b theta' = u`` (the rigid rotor about one body axis, torque N·m, angle rad).
* The camera exposes frame k from ``k T_f`` to ``k T_f + t_exp``; its measurement belongs to
  mid-exposure. A *sequential* observer takes a frame only when it is idle (frames that become
  ready while it is busy are dropped): :func:`frames_per_update` replays that rule frame by
  frame. A *pipelined* one takes every frame. The update period is ``T = m T_f``.
* The measurement ``theta(k T)`` reaches the controller ``tau = t_exp/2 + d`` later (``d`` the
  vision delay), and the torque is held from ``k T + tau`` until the next one (zero-order hold).
* The PID runs once per measurement with the difference equations of
  ``PIDController.command`` on a constant reference (error ``e = -theta``):
  ``I[k+1] = I[k] + Ki T e[k]`` (forward Euler with the previous error),
  ``x[k] = (e[k] - e[k-1]) / T`` (the backward difference of the measured attitude),
  ``f[k] = beta f[k-1] + (1 - beta) x[k]``, ``beta = exp(-T / tau_f)`` (the exact discrete
  low-pass), ``u[k] = Kp e[k] + I[k] + Kd f[k]``.

Two independent routes
----------------------
* **Frequency response** (:func:`loop_response`): the plant's pulse response at the sample
  instants, ``g[n] = s(n T - tau) - s(n T - tau - T)`` with the closed-form step response
  ``s(t) = (t - (1 - e^{-a t}) / a) / b``, ``a = b / J``, summed to ``G(z) = sum g[n] z^-n`` in
  closed form (the tail is a constant plus a geometric series), times the PID's ``C(z)``
  written from the difference equations. The gain crossovers are the roots of ``|L| = 1`` on
  ``(0, pi/T]`` (Brent's method on a dense bracket); the phase margin is ``180° + arg L`` wrapped
  to (-180°, 180°] at the crossover where ``L`` is closest to -1.
* **Stability** (:func:`spectral_radius`): the closed loop as one linear map per update period,
  state ``[theta, omega, u[k-1], ..., u[k-M], I, f, e[k-1]]``, built with matrix exponentials of
  the rotor's equations over the parts of the period in which each held torque acts; stable when
  every eigenvalue lies inside the unit circle. The headroom is the smallest extra vision delay
  at which that fails, found by a scan and bisection through :func:`frames_per_update` (the
  update period changes with the delay).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.optimize

from controller.pid import PIDConfig, PIDController
from plant.params import PlantParams


@dataclass(frozen=True)
class Axis:
    """One body axis of the loop: rotor, PID gains and camera (SI units)."""

    J: float
    b: float
    Kp: float
    Ki: float
    Kd: float
    tau_f: float
    frame_period_s: float
    exposure_s: float

    @classmethod
    def of(cls, params: PlantParams, crossover_rad_s: float, axis: int = 1) -> Axis:
        """The axis as tuned: the PID's gains, the rotor's inertia about the centre and its
        viscous damping, the camera's frame period and exposure."""
        g = PIDController(PIDConfig(crossover_rad_s=crossover_rad_s), params).gains[axis]
        return cls(
            J=float(params.rotor.inertia_about_centre_kgm2[axis, axis]),
            b=float(params.rotor.viscous_Nms_per_rad), Kp=g.Kp, Ki=g.Ki, Kd=g.Kd,
            tau_f=g.tau_f, frame_period_s=1.0 / params.camera.frame_rate_hz,
            exposure_s=params.camera.exposure_s,
        )


def frames_per_update(vision_delay_s: float, frame_period_s: float, exposure_s: float,
                      mode: str) -> int:
    """Camera frames per processed frame: the observer's schedule replayed for 40 frames
    (a sequential observer takes frame k when it is ready no earlier than the observer is idle
    again, to 1 ns)."""
    if mode == "pipelined":
        return 1
    busy_until, taken = -math.inf, []
    for k in range(40):
        ready = k * frame_period_s + exposure_s
        if ready >= busy_until - 1e-9:
            taken.append(k)
            busy_until = ready + vision_delay_s
    gaps = set(np.diff(taken).tolist())
    assert len(gaps) == 1, gaps  # a constant latency gives a regular schedule
    return int(gaps.pop())


def timing(ax: Axis, vision_delay_s: float, mode: str) -> tuple[float, float]:
    """(update period T, loop delay tau), s."""
    m = frames_per_update(vision_delay_s, ax.frame_period_s, ax.exposure_s, mode)
    return m * ax.frame_period_s, 0.5 * ax.exposure_s + vision_delay_s


def _step(ax: Axis, t: np.ndarray) -> np.ndarray:
    """Angle (rad) of the rotor at rest at t = 0 under a unit torque from t = 0 (0 before)."""
    a = ax.b / ax.J
    t = np.maximum(t, 0.0)
    return (t + np.expm1(-a * t) / a) / ax.b


def pid_response(ax: Axis, T: float, z: np.ndarray) -> np.ndarray:
    """C(z) of the difference equations (module docstring): torque per error."""
    beta = math.exp(-T / ax.tau_f)
    return ax.Kp + ax.Ki * T / (z - 1.0) + ax.Kd * (1.0 - beta) * (z - 1.0) / (T * (z - beta))


def plant_response(ax: Axis, T: float, tau: float, z: np.ndarray) -> np.ndarray:
    """Pulse transfer function ``G(z) = sum_n g[n] z^-n`` of the held, delayed rotor."""
    a = ax.b / ax.J
    n0 = int(math.floor(tau / T)) + 2  # from n0 on, the pulse ended before n T
    n = np.arange(n0)
    g = _step(ax, n * T - tau) - _step(ax, n * T - tau - T)
    head = sum(gi * z ** (-int(i)) for i, gi in zip(n, g, strict=True))
    # n >= n0: g[n] = T / b - c e^{-a n T}, c = e^{a tau} (e^{a T} - 1) / (a b)
    c = math.exp(a * tau) * math.expm1(a * T) / (a * ax.b)
    r = math.exp(-a * T)
    tail = (T / ax.b) * z ** (-n0) / (1.0 - 1.0 / z) - c * r**n0 * z ** (-n0) / (1.0 - r / z)
    return head + tail


def loop_response(ax: Axis, T: float, tau: float, w: np.ndarray) -> np.ndarray:
    """L(e^{j w T}) = C(z) G(z) at the angular frequencies ``w`` (rad/s)."""
    z = np.exp(1j * np.asarray(w, dtype=float) * T)
    return pid_response(ax, T, z) * plant_response(ax, T, tau, z)


@dataclass(frozen=True)
class Derived:
    """Margins derived here. ``phase_margin_deg`` and ``crossover_rad_s`` at the critical
    crossover; ``headroom_s`` the extra vision delay before instability; ``T``, ``tau`` the
    update period and loop delay (s)."""

    phase_margin_deg: float
    crossover_rad_s: float
    headroom_s: float
    T: float
    tau: float


def crossovers(ax: Axis, T: float, tau: float) -> list[tuple[float, float]]:
    """Every gain crossover on (0, pi/T]: (frequency rad/s, phase margin deg)."""
    wn = math.pi / T
    w = np.geomspace(wn * 1e-5, wn, 20001)
    logm = np.log(np.abs(loop_response(ax, T, tau, w)))
    out = []
    for i in np.nonzero(np.sign(logm[:-1]) != np.sign(logm[1:]))[0]:
        wc = scipy.optimize.brentq(
            lambda x: math.log(abs(loop_response(ax, T, tau, np.array([x]))[0])),
            w[i], w[i + 1], xtol=1e-13, rtol=1e-14,
        )
        pm = math.degrees(np.angle(-loop_response(ax, T, tau, np.array([wc]))[0]))
        out.append((wc, pm))
    return out


def closed_loop_map(ax: Axis, T: float, tau: float) -> np.ndarray:
    """The closed loop's state transition over one update period (module docstring)."""
    A = np.array([[0.0, 1.0], [0.0, -ax.b / ax.J]])
    B = np.array([0.0, 1.0 / ax.J])
    M = int(math.floor(tau / T)) + 1  # torques still to act: u[k-1] .. u[k-M]
    phi = tau - (M - 1) * T  # within the period [kT, kT+T): u[k-M] until kT+phi, then u[k-M+1]

    def flow(h: float) -> tuple[np.ndarray, np.ndarray]:
        """(e^{A h}, integral_0^h e^{A s} B ds)."""
        aug = np.zeros((3, 3))
        aug[:2, :2], aug[:2, 2] = A, B
        E = scipy.linalg.expm(aug * h)
        return E[:2, :2], E[:2, 2]

    beta = math.exp(-T / ax.tau_f)
    n = 2 + M + 3
    iu, iI, iF, iE = 2, 2 + M, 3 + M, 4 + M  # u[k-1] at iu, u[k-j] at iu + j - 1
    # The torque computed at k from theta[k] and the controller state (e = -theta):
    #   e = -theta, x = (e - e_prev)/T, f' = beta f + (1 - beta) x, u = Kp e + I + Kd f'
    u_row = np.zeros(n)
    f_row = np.zeros(n)
    f_row[iF] = beta
    f_row[0] += -(1.0 - beta) / T
    f_row[iE] += -(1.0 - beta) / T
    u_row[0] = -ax.Kp
    u_row[iI] = 1.0
    u_row += ax.Kd * f_row
    # Plant over [kT, kT + T): u[k-M] acts for phi, then u[k-M+1] (u[k] itself when M = 1)
    E1, G1 = flow(phi)
    E2, G2 = flow(T - phi)
    new_first = u_row if M == 1 else _unit(n, iu + M - 2)
    F = np.zeros((n, n))
    F[:2, :2] = E2 @ E1
    F[:2] += np.outer(E2 @ G1, _unit(n, iu + M - 1)) + np.outer(G2, new_first)
    # torque history shifts: u[k] becomes u[k-1]
    F[iu] = u_row
    for j in range(1, M):
        F[iu + j] = _unit(n, iu + j - 1)
    F[iI] = _unit(n, iI)
    F[iI, 0] += -ax.Ki * T
    F[iF] = f_row
    F[iE] = -_unit(n, 0)
    return F


def _unit(n: int, i: int) -> np.ndarray:
    v = np.zeros(n)
    v[i] = 1.0
    return v


def spectral_radius(ax: Axis, T: float, tau: float) -> float:
    return float(np.max(np.abs(np.linalg.eigvals(closed_loop_map(ax, T, tau)))))


def stable(ax: Axis, vision_delay_s: float, mode: str) -> bool:
    T, tau = timing(ax, vision_delay_s, mode)
    return spectral_radius(ax, T, tau) < 1.0


def headroom_s(ax: Axis, vision_delay_s: float, mode: str, step_s: float = 0.25e-3) -> float:
    """Smallest extra vision delay (s) at which the loop is unstable: a scan in ``step_s``
    then bisection to 1e-8 s (the update period may jump inside the last step, so the boundary
    may be a jump; bisection finds it either way)."""
    assert stable(ax, vision_delay_s, mode)
    lo = vision_delay_s
    hi = lo + step_s
    while stable(ax, hi, mode):
        lo, hi = hi, hi + step_s
        assert hi < 1.0, "no instability below 1 s of vision delay"
    while hi - lo > 1e-8:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if stable(ax, mid, mode) else (lo, mid)
    return 0.5 * (lo + hi) - vision_delay_s


def derive(params: PlantParams, crossover_rad_s: float, vision_delay_s: float,
           mode: str) -> Derived:
    """The margins of the loop at this vision delay (s) and observer ``mode``."""
    ax = Axis.of(params, crossover_rad_s)
    T, tau = timing(ax, vision_delay_s, mode)
    cr = crossovers(ax, T, tau)
    assert cr, "no gain crossover"
    wc, pm = min(cr, key=lambda c: abs(c[1]))
    return Derived(pm, wc, headroom_s(ax, vision_delay_s, mode), T, tau)
