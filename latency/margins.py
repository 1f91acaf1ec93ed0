"""Frequency-domain margins of a vision-in-the-loop control loop with an exact time delay.

The loop is broken at the plant input. With negative feedback ``u = -C F y`` the loop transfer is

    L(s) = C(s) F(s) H_T(s) P(s) e^{-s tau}

where

- ``P`` is the plant (continuous LTI, input torque N·m, output angle rad),
- ``F`` an optional observer/filter (continuous, or discrete at the sampling period),
- ``C`` the controller (continuous, or discrete with sampling period ``T``); a discrete factor
  ``G(z)`` is evaluated at ``z = e^{sT}``,
- ``H_T(s) = (1 - e^{-sT}) / (sT)`` the sample-and-hold at period ``T`` (omitted when the loop is
  not sampled). It is the ``k = 0`` term of the impulse-modulation (Poisson) sum that gives the
  exact sampled loop, ``L_d(e^{jwT}) = C(e^{jwT}) F(e^{jwT}) sum_k H_T(jw_k) P(jw_k)
  e^{-jw_k tau}``, ``w_k = w + 2 pi k / T``: the *hybrid* formulation below neglects the aliasing
  terms ``k != 0``. They are small when ``|P(j(w - 2pi/T))| << |P(jw)|``, i.e. well below the
  Nyquist frequency ``pi/T`` for a low-pass plant. For a double integrator at ``wT = 0.5`` the
  neglected terms are about 0.1 % of ``|L|``.
- ``e^{-s tau}`` the *exact* sensor-to-actuator delay ``tau`` (s), never a Padé approximation
  (Padé is offered only as a comparison, :func:`loop_pade`, :func:`pade_margins`).

Two formulations are offered:

``hybrid`` (:func:`loop_model`, :func:`loop_margins`)
    The formula above evaluated at ``s = jw``. Stability is decided by the Nyquist criterion
    applied to the exact-delay response (encirclement count of -1 along a D-contour indented to
    the right of poles at the origin). Gives the jitter margin.
``sampled`` (:func:`sampled_loop`, :func:`sampled_margins`)
    The exact discrete-time loop at the sample instants for a discrete controller: the plant is
    discretised with a zero-order hold and the fractional delay ``tau = m T + tau'`` by the
    modified z-transform (Åström & Wittenmark, *Computer-Controlled Systems*, 3rd ed., §2.3):
    ``x[k+1] = Phi x[k] + Gamma_0 u[k-m] + Gamma_1 u[k-m-1]``. Stability is decided by the
    closed-loop eigenvalues; the delay margin by scanning the delay with eigenvalues. Valid for
    frequencies in ``(0, pi/T]``; exact at the sample instants for the timing model "sample at
    ``kT``, actuate at ``kT + tau``, hold for ``T``".

Conventions: frequencies in rad/s, times in s, phases in rad inside; the phase margin is reported
in degrees as ``phase_margin_deg``; gain margins are plain ratios (not dB).

Every margin is accompanied by a stability verdict that does not rely on the phase (python-control's
``stability_margins`` wraps the phase and can report a large positive phase margin for an unstable
loop). When the closed loop is unstable, the headline margins are ``nan`` and
:meth:`Margins.summary` says "unstable".

References
----------
C.-Y. Kao and B. Lincoln, "Simple stability criteria for systems with time-varying delays",
Automatica 40(8), 1429-1434, 2004 (the jitter margin).
K. J. Åström and B. Wittenmark, *Computer-Controlled Systems*, 3rd ed., Prentice Hall, 1997
(sampling with a fractional delay; the sampled frequency response).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import control as ct
import numpy as np
import pandas as pd
import scipy.linalg
import scipy.optimize
from matplotlib.figure import Figure
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "LoopModel",
    "Margins",
    "attitude_delay_sweep",
    "attitude_margins",
    "attitude_plant",
    "bode_data",
    "jitter_margin",
    "loop_frd",
    "loop_margins",
    "loop_model",
    "loop_pade",
    "nyquist_count",
    "nyquist_data",
    "pade_margins",
    "plot_bode",
    "plot_nyquist",
    "sampled_loop",
    "sampled_margins",
    "sampled_plant",
]

_SMALL_GAIN = 1e-3  # |L| below this cannot wind around -1 and sets gain margins > 60 dB
_PHASE_STEP = np.pi / 8  # largest phase step between grid points where |L| >= _SMALL_GAIN
_CLOSE_STEP = 0.25  # largest |dL| relative to the distance to -1


# --------------------------------------------------------------------------------------------
# Rational factors
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Factor:
    """One SISO rational factor: ``num(x)/den(x)`` with ``x = s`` (continuous) or ``x = e^{sT}``
    (discrete, ``dt = T``). Coefficients in decreasing powers, as python-control stores them."""

    num: NDArray[np.float64]
    den: NDArray[np.float64]
    dt: float | None  # None: continuous

    def __call__(self, s: NDArray[np.complex128]) -> NDArray[np.complex128]:
        x = s if self.dt is None else np.exp(s * self.dt)
        return np.polyval(self.num, x) / np.polyval(self.den, x)


def _as_factor(sys: ct.LTI | float, name: str) -> _Factor:
    """Convert a SISO LTI object (or a number) to a rational factor, checking its shape."""
    if np.isscalar(sys):
        return _Factor(np.array([float(sys)]), np.array([1.0]), None)
    if not isinstance(sys, ct.LTI):
        raise TypeError(f"{name} must be a python-control LTI object or a number, got {type(sys)}")
    if sys.ninputs != 1 or sys.noutputs != 1:
        raise ValueError(f"{name} must be SISO (per-axis loop); got {sys.noutputs}x{sys.ninputs}")
    tf = ct.tf(sys)
    num = np.atleast_1d(np.asarray(tf.num[0][0], dtype=float))
    den = np.atleast_1d(np.asarray(tf.den[0][0], dtype=float))
    num = np.trim_zeros(num, "f")
    den = np.trim_zeros(den, "f")
    if num.size == 0:
        num = np.array([0.0])
    if den.size == 0:
        raise ValueError(f"{name} has a zero denominator")
    if num.size > den.size and sys.isdtime(strict=True):
        raise ValueError(f"{name} is a non-causal discrete system")
    dt = None
    if sys.isdtime(strict=True):
        if sys.dt is True:
            raise ValueError(f"{name} is discrete with an unspecified sample time (dt=True)")
        dt = float(sys.dt)
    return _Factor(num, den, dt)


def _roots(p: NDArray[np.float64]) -> NDArray[np.complex128]:
    return np.roots(p) if p.size > 1 else np.zeros(0, dtype=complex)


def _zoh(x: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """``(1 - e^{-x}) / x`` with its limit 1 at ``x = 0``."""
    x = np.asarray(x, dtype=complex)
    out = np.ones_like(x)
    nz = np.abs(x) > 1e-8
    out[nz] = -np.expm1(-x[nz]) / x[nz]
    out[~nz] = 1.0 - x[~nz] / 2.0
    return out


# --------------------------------------------------------------------------------------------
# The hybrid loop model
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LoopModel:
    """Loop transfer ``L(s) = C(s) F(s) H_T(s) P(s) e^{-s tau}`` with the exact delay.

    Build with :func:`loop_model`. Calling the object evaluates ``L`` at complex ``s`` (rad/s),
    which is analytic in the open right half-plane, so it serves both the frequency response
    (``s = jw``) and the indentation of the Nyquist contour.

    Attributes
    ----------
    delay_s : float
        Constant sensor-to-actuator delay ``tau`` (s) included in ``L``.
    sample_period_s : float or None
        Sampling period ``T`` (s) of the sample-and-hold, or None for a continuous loop.
    open_loop_rhp_poles : int
        Number of poles of ``L`` in the open right half-plane (the ``P`` of Nyquist's
        ``Z = N + P``).
    origin_poles : int
        Number of poles of ``L`` at ``s = 0`` (integrators), excluded by the indentation.
    """

    factors: tuple[_Factor, ...]
    delay_s: float
    sample_period_s: float | None
    open_loop_rhp_poles: int
    origin_poles: int
    features_rad_s: tuple[float, ...]
    relative_degree: int

    def __call__(self, s: ArrayLike) -> NDArray[np.complex128]:
        s = np.asarray(s, dtype=complex)
        shape = s.shape
        s = s.ravel()
        out = np.ones(s.shape, dtype=complex)
        for f in self.factors:
            out = out * f(s)
        if self.sample_period_s is not None:
            out = out * _zoh(s * self.sample_period_s)
        if self.delay_s > 0.0:
            out = out * np.exp(-s * self.delay_s)
        return out.reshape(shape)

    def response(self, omega: ArrayLike) -> NDArray[np.complex128]:
        """``L(jw)`` at angular frequencies ``omega`` (rad/s)."""
        return self(1j * np.asarray(omega, dtype=float))

    def with_delay(self, delay_s: float) -> LoopModel:
        """The same loop with the constant delay replaced by ``delay_s`` (s)."""
        _check_delay(delay_s)
        return LoopModel(
            self.factors,
            float(delay_s),
            self.sample_period_s,
            self.open_loop_rhp_poles,
            self.origin_poles,
            _features(self.factors, float(delay_s), self.sample_period_s),
            self.relative_degree,
        )

    @property
    def nyquist_rad_s(self) -> float:
        """Nyquist frequency ``pi/T`` (rad/s), ``inf`` for a continuous loop."""
        return math.inf if self.sample_period_s is None else math.pi / self.sample_period_s

    def frd(self, omega: ArrayLike | None = None) -> ct.FrequencyResponseData:
        """The loop as python-control FRD data on ``omega`` (rad/s; default: the analysis grid)."""
        w = _grid(self) if omega is None else np.asarray(omega, dtype=float)
        return ct.frd(self.response(w), w)


def _check_delay(delay_s: float) -> None:
    if not np.isfinite(delay_s) or delay_s < 0.0:
        raise ValueError(f"delay_s must be finite and >= 0, got {delay_s}")


def _features(factors: Sequence[_Factor], delay_s: float, T: float | None) -> tuple[float, ...]:
    """Characteristic frequencies (rad/s): non-zero pole and zero magnitudes, 1/tau, pi/T."""
    feats: list[float] = []
    for f in factors:
        for r in np.concatenate([_roots(f.num), _roots(f.den)]):
            if f.dt is None:
                mag = abs(r)
            else:
                if abs(r) < 1e-12 or abs(r - 1.0) < 1e-9:
                    continue
                mag = abs(np.log(complex(r))) / f.dt
            if mag > 1e-12:
                feats.append(float(mag))
    if delay_s > 0.0:
        feats.append(1.0 / delay_s)
    if T is not None:
        feats.append(math.pi / T)
    return tuple(sorted(feats)) if feats else (1.0,)


def _common_period(factors: Sequence[_Factor], sample_period_s: float | None) -> float | None:
    """The loop's sample-and-hold period: ``sample_period_s``, or the discrete factors' common
    ``dt`` when it is None; ``ValueError`` for mismatched sample times or a period <= 0."""
    dts = {f.dt for f in factors if f.dt is not None}
    if len(dts) > 1:
        raise ValueError(f"discrete parts have different sample times {sorted(dts)}")
    T = sample_period_s
    if dts:
        (dt,) = dts
        if T is None:
            T = dt
        elif not math.isclose(T, dt, rel_tol=1e-9):
            raise ValueError(f"sample_period_s = {T} differs from the discrete parts' dt = {dt}")
    if T is not None and (not np.isfinite(T) or T <= 0.0):
        raise ValueError(f"sample_period_s must be > 0, got {T}")
    return T


def loop_model(
    plant: ct.LTI,
    controller: ct.LTI | float,
    *,
    delay_s: float = 0.0,
    sample_period_s: float | None = None,
    observer: ct.LTI | None = None,
) -> LoopModel:
    """Build the hybrid loop ``L(s) = C(s) F(s) H_T(s) P(s) e^{-s tau}`` (exact delay).

    Parameters
    ----------
    plant : LTI
        Continuous-time SISO plant ``P`` (from actuator command to measured output).
    controller : LTI or float
        SISO controller ``C`` in the negative-feedback convention ``u = -C y``: continuous, or
        discrete with sample time ``T`` (then evaluated at ``z = e^{jwT}``).
    delay_s : float
        Constant sensor-to-actuator delay ``tau`` (s), >= 0, included exactly as ``e^{-s tau}``.
    sample_period_s : float, optional
        Period ``T`` (s) of the sample-and-hold ``(1 - e^{-sT})/(sT)``. Defaults to the sample time
        of a discrete controller or observer; None with continuous ones means a continuous loop.
        A continuous controller with a given ``T`` is the usual emulation approximation.
    observer : LTI, optional
        SISO observer/filter ``F`` in series with the controller (continuous, or discrete at ``T``),
        e.g. the steady-state Kalman filter from measured to estimated angle.

    Returns
    -------
    LoopModel

    Raises
    ------
    ValueError
        For MIMO parts, a discrete plant, mismatched sample times, a negative delay, poles on the
        imaginary axis other than at the origin, or discrete poles outside the unit circle (use
        :func:`sampled_margins` for an unstable discrete controller).
    """
    _check_delay(delay_s)
    if not isinstance(plant, ct.LTI) or plant.isdtime(strict=True):
        raise ValueError("plant must be a continuous-time python-control LTI object")
    parts = [("plant", plant), ("controller", controller)]
    if observer is not None:
        parts.append(("observer", observer))
    factors = [_as_factor(sys, name) for name, sys in parts]
    T = _common_period(factors, sample_period_s)

    rhp = 0
    origin = 0
    rel_deg = 0
    for (name, _), f in zip(parts, factors, strict=True):
        poles = _roots(f.den)
        if f.dt is None:
            scale = max(1.0, float(np.max(np.abs(poles)))) if poles.size else 1.0
            at0 = np.abs(poles) <= 1e-9 * scale
            origin += int(np.sum(at0))
            rest = poles[~at0]
            on_axis = np.abs(rest.real) <= 1e-12 * np.maximum(1.0, np.abs(rest))
            if np.any(on_axis):
                raise ValueError(f"{name} has poles on the imaginary axis away from the origin")
            rhp += int(np.sum(rest.real > 0.0))
            rel_deg += f.den.size - f.num.size
        else:
            at1 = np.abs(poles - 1.0) <= 1e-9
            if int(np.sum(at1)) > 1:
                raise ValueError(f"{name} has a repeated pole at z = 1; use sampled_margins")
            origin += int(np.sum(at1))
            others = poles[~at1]
            if np.any(np.abs(others) >= 1.0 - 1e-12):
                raise ValueError(
                    f"{name} has poles on or outside the unit circle (other than z = 1): the "
                    "hybrid model cannot count them; use sampled_margins"
                )
    if T is not None:
        rel_deg += 1
    if rel_deg < 1:
        raise ValueError(
            "the loop must be strictly proper (|L(jw)| -> 0): add a derivative filter to C"
        )
    return LoopModel(
        tuple(factors),
        float(delay_s),
        None if T is None else float(T),
        rhp,
        origin,
        _features(factors, float(delay_s), T),
        rel_deg,
    )


def loop_frd(
    plant: ct.LTI,
    controller: ct.LTI | float,
    *,
    delay_s: float = 0.0,
    sample_period_s: float | None = None,
    observer: ct.LTI | None = None,
    omega: ArrayLike | None = None,
) -> ct.FrequencyResponseData:
    """The loop's frequency response ``L(jw)`` (exact delay) as python-control FRD data.

    Arguments as in :func:`loop_model`; ``omega`` (rad/s) defaults to the analysis grid. Note
    that python-control's ``stability_margins`` on this FRD wraps the phase; use
    :func:`loop_margins` for margins that are checked against the Nyquist criterion.
    """
    model = loop_model(
        plant, controller, delay_s=delay_s, sample_period_s=sample_period_s, observer=observer
    )
    return model.frd(omega)


# --------------------------------------------------------------------------------------------
# Frequency grid and Nyquist count
# --------------------------------------------------------------------------------------------


def _base_grid(model: LoopModel, per_decade: int = 60) -> NDArray[np.float64]:
    feats = model.features_rad_s
    w_lo = 1e-3 * feats[0]
    w_hi = 1e3 * feats[-1]
    for _ in range(12):
        tail = np.logspace(np.log10(w_hi / 10.0), np.log10(w_hi), 40)
        if np.max(np.abs(model.response(tail))) < _SMALL_GAIN:
            break
        w_hi *= 10.0
    else:
        raise ValueError("|L(jw)| does not fall below 1e-3 at high frequency")
    n = int(np.ceil(per_decade * np.log10(w_hi / w_lo))) + 1
    return np.logspace(np.log10(w_lo), np.log10(w_hi), n)


def _refine(
    fun: Callable[[NDArray[np.float64]], NDArray[np.complex128]],
    w: NDArray[np.float64],
    max_rounds: int = 40,
    geometric: bool = True,
) -> tuple[NDArray[np.float64], NDArray[np.complex128]]:
    """Insert midpoints (geometric for frequencies, arithmetic for angles) until the phase of
    ``L`` moves less than pi/8 between points (where ``|L| >= 1e-3``) and ``L`` moves less than a
    quarter of its distance to -1."""
    Lw = fun(w)
    for _ in range(max_rounds):
        a, b = Lw[:-1], Lw[1:]
        with np.errstate(divide="ignore", invalid="ignore"):
            dphi = np.abs(np.angle(b / a))
        dphi = np.where(np.isfinite(dphi), dphi, np.pi)
        big = np.maximum(np.abs(a), np.abs(b)) >= _SMALL_GAIN
        dist = np.minimum(np.abs(1.0 + a), np.abs(1.0 + b))
        bad = (big & (dphi > _PHASE_STEP)) | (np.abs(b - a) > _CLOSE_STEP * dist)
        bad &= (w[1:] - w[:-1]) > 1e-12 * np.maximum(np.abs(w[1:]), 1e-300)
        if not np.any(bad):
            break
        idx = np.nonzero(bad)[0]
        mid = np.sqrt(w[idx] * w[idx + 1]) if geometric else 0.5 * (w[idx] + w[idx + 1])
        w = np.insert(w, idx + 1, mid)
        Lw = np.insert(Lw, idx + 1, fun(mid))
    return w, Lw


def _grid(model: LoopModel) -> NDArray[np.float64]:
    w, _ = _refine(model.response, _base_grid(model))
    return w


def nyquist_count(
    model: LoopModel, omega: ArrayLike | None = None
) -> tuple[int, int, NDArray[np.float64], NDArray[np.complex128]]:
    """Nyquist criterion on the exact-delay loop: closed-loop poles in the open right half-plane.

    The D-contour runs up the imaginary axis from ``j eps`` to ``j w_max``, closes through the
    right half-plane (where ``|L| < 1e-3``), returns along ``-j w`` and is indented to the right of
    the origin by the half circle ``s = eps e^{j theta}``, ``theta`` from -pi/2 to pi/2 (so poles
    at the origin count as stable open-loop poles). ``eps`` is 1e-3 times the smallest
    characteristic frequency of the loop. The winding number of ``1 + L`` is accumulated from the
    phase of ``(1 + L_{i+1}) / (1 + L_i)`` on a grid refined until each step is small; by
    conjugate symmetry the lower half contributes as much as the upper half. For the delayed loop
    (retarded, strictly proper) this is the Nyquist criterion for ``1 + L(s) = 0``.

    Parameters
    ----------
    model : LoopModel
    omega : array_like, optional
        Starting grid (rad/s); it is refined. Default: 1e-3 x the smallest to 1e3 x the largest
        characteristic frequency, 60 points per decade, extended until ``|L| < 1e-3``. A grid
        given here must start below every pole/zero magnitude (its first point is the
        indentation radius) and end where ``|L| < 1e-3``.

    Returns
    -------
    Z : int
        Closed-loop poles in the open right half-plane, ``Z = P + N``; stable iff ``Z == 0``.
    N : int
        Clockwise encirclements of -1 by ``L`` along the contour.
    omega : ndarray
        The refined grid (rad/s).
    L : ndarray
        ``L(j omega)`` on it.
    """
    w0 = _base_grid(model) if omega is None else np.sort(np.asarray(omega, dtype=float))
    eps = float(w0[0])
    w, Lw = _refine(model.response, w0)
    g = 1.0 + Lw
    upper = float(np.sum(np.angle(g[1:] / g[:-1])))
    # closing arc at |s| = w_max (|L| < 1e-3 there): from 1 + L(jw_max) to its conjugate
    close = float(np.angle(np.conj(g[-1]) / g[-1]))
    # indentation: theta from -pi/2 to pi/2, from s = -j eps to s = +j eps
    _, L_arc = _refine(
        lambda th: model(eps * np.exp(1j * th)),
        np.linspace(-np.pi / 2, np.pi / 2, 401),
        geometric=False,
    )
    arc = 1.0 + L_arc
    arc_phase = float(np.sum(np.angle(arc[1:] / arc[:-1])))
    total = 2.0 * upper + close + arc_phase
    winding = total / (2.0 * np.pi)  # counter-clockwise turns of 1 + L along a clockwise contour
    W = int(round(winding))
    if abs(winding - W) > 1e-3:
        raise RuntimeError(f"Nyquist winding number {winding:.4f} is not an integer")
    Z = model.open_loop_rhp_poles - W
    N = -W
    return Z, N, w, Lw


# --------------------------------------------------------------------------------------------
# Margins
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Margins:
    """Stability margins of one loop, with a stability verdict that does not rely on the phase.

    Attributes
    ----------
    stable : bool
        Closed-loop stability, from the Nyquist count on the exact-delay response (hybrid), the
        closed-loop eigenvalues (sampled) or the closed-loop poles (Padé).
    unstable_poles : int
        Closed-loop poles in the open right half-plane (continuous) or on/outside the unit circle
        (sampled).
    phase_margin_deg : float
        Smallest phase margin over all gain crossovers, ``180° + arg L(jw_c)`` wrapped to
        (-180°, 180°]; ``inf`` without a crossover; ``nan`` when unstable.
    gain_margin : float
        Factor by which the loop gain can grow before instability: smallest ``1/|L(jw_pc)|`` > 1
        over the phase crossovers (``L`` on the negative real axis); ``inf`` if none; ``nan`` when
        unstable. Phase crossovers with ``|L| < 1e-3`` are not resolved.
    gain_margin_lower : float
        Factor by which it can shrink (largest ``1/|L|`` < 1; 0 if none; ``nan`` when unstable).
    crossover_rad_s : float
        The gain-crossover frequency that sets the phase margin (rad/s); ``nan`` if none.
    phase_crossover_rad_s : float
        The phase-crossover frequency that sets ``gain_margin`` (rad/s); ``nan`` if none.
    delay_margin_s : float
        Extra constant delay (s) on top of ``delay_s`` at which the loop loses stability:
        ``min_i (PM_i mod 2 pi) / w_ci`` over all crossovers (hybrid) or an eigenvalue scan
        (sampled); ``inf`` without a crossover; ``nan`` when unstable.
    delay_s : float
        The constant delay already in the loop (s).
    jitter_margin_s : float
        Largest ``delta`` (s) such that Kao & Lincoln's sufficient condition holds: the loop stays
        stable for any time-varying extra delay in ``[0, delta]`` on top of ``delay_s``
        (hybrid only; ``nan`` otherwise or when unstable).
    jitter_frequency_rad_s : float
        Frequency (rad/s) at which ``w |T(jw)|`` peaks.
    crossovers_rad_s, phase_margins_deg : tuple of float
        All gain crossovers and the wrapped phase margin at each (reported even when unstable).
    phase_crossovers_rad_s, phase_crossover_gains : tuple of float
        All resolved phase crossovers and ``|L|`` there.
    formulation : str
        "hybrid", "continuous", "sampled" or "pade-<order>".
    confirmation : str
        How stability was decided, in words.
    notes : tuple of str
        Warnings (e.g. a crossover above the Nyquist frequency).
    """

    stable: bool
    unstable_poles: int
    phase_margin_deg: float
    gain_margin: float
    gain_margin_lower: float
    crossover_rad_s: float
    phase_crossover_rad_s: float
    delay_margin_s: float
    delay_s: float
    jitter_margin_s: float
    jitter_frequency_rad_s: float
    crossovers_rad_s: tuple[float, ...]
    phase_margins_deg: tuple[float, ...]
    phase_crossovers_rad_s: tuple[float, ...]
    phase_crossover_gains: tuple[float, ...]
    formulation: str
    confirmation: str
    notes: tuple[str, ...] = field(default=())

    def summary(self) -> str:
        """One line; says "unstable" (and no margin) when the closed loop is unstable."""
        if not self.stable:
            return (
                f"unstable ({self.unstable_poles} unstable closed-loop pole(s); "
                f"{self.confirmation}; delay {self.delay_s * 1e3:.2f} ms)"
            )
        jitter = (
            f"jitter margin {self.jitter_margin_s * 1e3:.3f} ms "
            if np.isfinite(self.jitter_margin_s)
            else ""
        )
        return (
            f"stable: PM {self.phase_margin_deg:.2f} deg at {self.crossover_rad_s:.4g} rad/s, "
            f"GM {self.gain_margin:.4g}, delay margin {self.delay_margin_s * 1e3:.3f} ms, "
            f"{jitter}(delay {self.delay_s * 1e3:.2f} ms; {self.formulation}; "
            f"{self.confirmation})"
        )

    def as_row(self) -> dict[str, float | bool]:
        """The headline numbers as a flat dict (a DataFrame row)."""
        return {
            "delay_s": self.delay_s,
            "phase_margin_deg": self.phase_margin_deg,
            "gain_margin": self.gain_margin,
            "crossover_rad_s": self.crossover_rad_s,
            "delay_margin_s": self.delay_margin_s,
            "jitter_margin_s": self.jitter_margin_s,
            "stable": self.stable,
        }


@dataclass(frozen=True)
class _Crossings:
    wc: tuple[float, ...]
    pm: tuple[float, ...]  # rad, wrapped to (-pi, pi]
    wpc: tuple[float, ...]
    gpc: tuple[float, ...]


def _scalar(fun: Callable[[NDArray[np.float64]], NDArray[np.complex128]], w: float) -> complex:
    return complex(fun(np.array([w]))[0])


def _crossings(
    fun: Callable[[NDArray[np.float64]], NDArray[np.complex128]],
    w: NDArray[np.float64],
    Lw: NDArray[np.complex128],
) -> _Crossings:
    """All gain and phase crossovers on the grid, refined with Brent's method on ``fun``."""
    mag = np.abs(Lw)
    logm = np.log(np.maximum(mag, 1e-300))
    wc: list[float] = []
    for i in np.nonzero(np.sign(logm[:-1]) * np.sign(logm[1:]) < 0)[0]:
        root = scipy.optimize.brentq(
            lambda x: math.log(max(abs(_scalar(fun, x)), 1e-300)),
            w[i],
            w[i + 1],
            xtol=1e-14 * w[i],
            rtol=1e-13,
        )
        wc.append(float(root))
    for i in np.nonzero(logm == 0.0)[0]:
        wc.append(float(w[i]))
    wc.sort()
    pm = tuple(float(np.angle(-_scalar(fun, x))) for x in wc)

    wpc: list[float] = []
    gpc: list[float] = []
    with np.errstate(divide="ignore", invalid="ignore"):
        v0 = complex(fun(np.array([0.0]))[0])  # L(0) is real; a crossover when it is negative
    if np.isfinite(v0) and v0.real < 0 and abs(v0.imag) <= 1e-12 * abs(v0):
        wpc.append(0.0)
        gpc.append(abs(v0))
    im = Lw.imag
    flips = np.sign(im[:-1]) * np.sign(im[1:]) < 0
    cand = np.nonzero(flips & (Lw.real[:-1] + Lw.real[1:] < 0))[0]
    for i in cand:
        if max(mag[i], mag[i + 1]) < _SMALL_GAIN:
            continue

        def im_norm(x: float) -> float:
            v = _scalar(fun, x)
            return v.imag / abs(v)

        root = scipy.optimize.brentq(im_norm, w[i], w[i + 1], xtol=1e-14 * w[i], rtol=1e-13)
        v = _scalar(fun, root)
        if v.real < 0:
            wpc.append(float(root))
            gpc.append(abs(v))
    return _Crossings(tuple(wc), pm, tuple(wpc), tuple(gpc))


def _margins_from_crossings(cr: _Crossings) -> tuple[float, float, float, float, float, float]:
    """(pm_deg, wc, gm, wpc, gm_lower, delay_margin_s) from the crossings of a stable loop."""
    if cr.wc:
        k = int(np.argmin(cr.pm))
        pm_deg = math.degrees(cr.pm[k])
        wc = cr.wc[k]
        dm = min((p % (2 * np.pi)) / x for p, x in zip(cr.pm, cr.wc, strict=True))
    else:
        pm_deg, wc, dm = math.inf, math.nan, math.inf
    up = [(1.0 / g, x) for g, x in zip(cr.gpc, cr.wpc, strict=True) if g < 1.0]
    down = [1.0 / g for g in cr.gpc if g > 1.0]
    gm, wpc = min(up) if up else (math.inf, math.nan)
    gm_lower = max(down) if down else 0.0
    return pm_deg, wc, gm, wpc, gm_lower, dm


def jitter_margin(model: LoopModel, omega: ArrayLike | None = None) -> tuple[float, float]:
    """Kao & Lincoln's jitter margin of a loop that is stable with its constant delay.

    Kao & Lincoln (Automatica 40(8), 2004): if the loop ``L`` is closed-loop stable, it stays
    stable when the plant input is delayed by a further time-varying ``delta(t)`` with
    ``0 <= delta(t) <= delta_max`` (any rate of change: the operator
    ``v -> int_{t-delta(t)}^t v`` has L2 gain at most ``delta_max``), provided

        |T(jw)| < 1 / (delta_max w)   for all w > 0,   T = L / (1 + L),

    here with ``L`` already containing the constant delay ``tau``. So

        delta_max = 1 / sup_w (w |T(jw)|).

    The supremum is taken on the refined grid and polished with a bounded scalar search around
    each local maximum. The condition is sufficient, not necessary: ``delta_max`` is never larger
    than the constant-delay margin.

    Returns
    -------
    delta_max_s : float
        The jitter margin (s).
    w_peak : float
        The frequency (rad/s) of the supremum.
    """
    w = _grid(model) if omega is None else np.asarray(omega, dtype=float)
    Lw = model.response(w)
    h = w * np.abs(Lw / (1.0 + Lw))
    best_h, best_w = -1.0, math.nan
    peaks = [i for i in range(1, len(w) - 1) if h[i] >= h[i - 1] and h[i] >= h[i + 1]]
    peaks = sorted(peaks, key=lambda i: -h[i])[:5] or [int(np.argmax(h))]
    for i in peaks:
        lo, hi = np.log(w[max(i - 1, 0)]), np.log(w[min(i + 1, len(w) - 1)])

        def neg(lw: float) -> float:
            x = math.exp(lw)
            v = _scalar(model.response, x)
            return -x * abs(v / (1.0 + v))

        res = scipy.optimize.minimize_scalar(
            neg, bounds=(lo, hi), method="bounded", options={"xatol": 1e-10}
        )
        cand = max((-float(res.fun), math.exp(float(res.x))), (float(h[i]), float(w[i])))
        if cand[0] > best_h:
            best_h, best_w = cand
    if h[-1] >= best_h:  # still rising at the top of the grid: supremum at w -> inf
        best_h, best_w = float(h[-1]), float(w[-1])
    return 1.0 / best_h, best_w


def loop_margins(model: LoopModel, omega: ArrayLike | None = None) -> Margins:
    """Margins of the hybrid exact-delay loop, confirmed by the Nyquist encirclement count.

    Gain crossovers ``|L(jw_c)| = 1`` and phase crossovers (``L`` on the negative real axis) are
    located on a dense logarithmic grid (refined where the phase of ``L`` moves fast or ``L``
    comes near -1) and polished with Brent's method on the analytic ``L(jw)``. See
    :class:`Margins` for the definitions and :func:`nyquist_count` for the stability test.

    Parameters
    ----------
    model : LoopModel
        From :func:`loop_model`.
    omega : array_like, optional
        Starting frequency grid (rad/s); refined automatically.

    Returns
    -------
    Margins
        With ``formulation`` "hybrid" (sampled) or "continuous".
    """
    Z, N, w, Lw = nyquist_count(model, omega)
    cr = _crossings(model.response, w, Lw)
    stable = Z == 0
    notes: list[str] = []
    conf = (
        f"Nyquist on the exact-delay response: P={model.open_loop_rhp_poles} open-loop RHP "
        f"pole(s), {model.origin_poles} at the origin (indented), N={N} clockwise "
        f"encirclement(s) of -1, Z={Z}"
    )
    formulation = "continuous" if model.sample_period_s is None else "hybrid"
    if any(x > model.nyquist_rad_s for x in cr.wc):
        notes.append("a gain crossover lies above the Nyquist frequency pi/T: hybrid model invalid")
    if stable:
        pm_deg, wc, gm, wpc, gm_lower, dm = _margins_from_crossings(cr)
        jm, wj = jitter_margin(model, w)
    else:
        pm_deg = gm = gm_lower = dm = jm = math.nan
        wc = cr.wc[int(np.argmin(cr.pm))] if cr.wc else math.nan
        wpc = wj = math.nan
    return Margins(
        stable=stable,
        unstable_poles=max(Z, 0),
        phase_margin_deg=pm_deg,
        gain_margin=gm,
        gain_margin_lower=gm_lower,
        crossover_rad_s=wc,
        phase_crossover_rad_s=wpc,
        delay_margin_s=dm,
        delay_s=model.delay_s,
        jitter_margin_s=jm,
        jitter_frequency_rad_s=wj,
        crossovers_rad_s=cr.wc,
        phase_margins_deg=tuple(math.degrees(p) for p in cr.pm),
        phase_crossovers_rad_s=cr.wpc,
        phase_crossover_gains=cr.gpc,
        formulation=formulation,
        confirmation=conf,
        notes=tuple(notes),
    )


# --------------------------------------------------------------------------------------------
# Padé comparison
# --------------------------------------------------------------------------------------------


def _pade_poly(T: float, order: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    num, den = ct.pade(T, order)
    return np.asarray(num, dtype=float), np.asarray(den, dtype=float)


def _padd(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.polyadd(a, b)


def loop_pade(model: LoopModel, order: int = 6) -> ct.TransferFunction:
    """A rational approximation of ``L``, for comparison only.

    Every exponential is replaced by its ``(order, order)`` Padé approximant
    ``e^{-s h} ~ n_h(s)/d_h(s)``: the delay (``h = tau``), the hold
    ``(1 - e^{-sT})/(sT) ~ (d_T - n_T) / (s T d_T)`` (``d_T - n_T`` has an exact root at 0, which
    cancels the ``s``) and, in a discrete factor ``G(z)``, ``z^{-1} = e^{-sT} ~ n_T/d_T``.

    Returns
    -------
    TransferFunction
        Continuous-time SISO.
    """
    num = np.array([1.0])
    den = np.array([1.0])
    T = model.sample_period_s
    nT = dT = None
    if T is not None:
        nT, dT = _pade_poly(T, order)
    for f in model.factors:
        if f.dt is None:
            num, den = np.polymul(num, f.num), np.polymul(den, f.den)
            continue
        assert nT is not None and dT is not None
        n = max(f.num.size, f.den.size) - 1
        b = np.concatenate([np.zeros(n + 1 - f.num.size), f.num])  # coefficients of z^n..z^0
        a = np.concatenate([np.zeros(n + 1 - f.den.size), f.den])
        # G = sum_k b[k] z^{n-k} / sum_k a[k] z^{n-k} = sum_k b[k] q^k / sum_k a[k] q^k, q = z^-1
        gn = np.array([0.0])
        gd = np.array([0.0])
        for k in range(n + 1):
            term = np.array([1.0])
            for _ in range(k):
                term = np.polymul(term, nT)
            for _ in range(n - k):
                term = np.polymul(term, dT)
            gn = _padd(gn, b[k] * term)
            gd = _padd(gd, a[k] * term)
        num, den = np.polymul(num, gn), np.polymul(den, gd)
    if T is not None:
        assert nT is not None and dT is not None
        diff = np.polysub(dT, nT)
        zoh_num = diff[:-1]  # divide by s: the constant term is zero
        num, den = np.polymul(num, zoh_num), np.polymul(den, T * dT)
    if model.delay_s > 0.0:
        nd, dd = _pade_poly(model.delay_s, order)
        num, den = np.polymul(num, nd), np.polymul(den, dd)
    return ct.tf(np.trim_zeros(num, "f"), np.trim_zeros(den, "f"))


def pade_margins(model: LoopModel, order: int = 6) -> Margins:
    """Margins of the Padé approximation :func:`loop_pade`, stability from its closed-loop poles.

    For comparison with :func:`loop_margins`: the margins come from the same crossing search on
    the rational response, the verdict from the roots of ``den + num`` of ``L``.
    """
    Lr = loop_pade(model, order)
    num = np.asarray(Lr.num[0][0], dtype=float)
    den = np.asarray(Lr.den[0][0], dtype=float)
    poles = np.roots(np.polyadd(den, num))
    Z = int(np.sum(poles.real > 0.0))

    def fun(w: NDArray[np.float64]) -> NDArray[np.complex128]:
        s = 1j * np.asarray(w, dtype=float)
        return np.polyval(num, s) / np.polyval(den, s)

    w, Lw = _refine(fun, _base_grid(model))
    cr = _crossings(fun, w, Lw)
    stable = Z == 0
    if stable:
        pm_deg, wc, gm, wpc, gm_lower, dm = _margins_from_crossings(cr)
    else:
        pm_deg = gm = gm_lower = dm = wpc = math.nan
        wc = math.nan
    return Margins(
        stable=stable,
        unstable_poles=Z,
        phase_margin_deg=pm_deg,
        gain_margin=gm,
        gain_margin_lower=gm_lower,
        crossover_rad_s=wc,
        phase_crossover_rad_s=wpc,
        delay_margin_s=dm,
        delay_s=model.delay_s,
        jitter_margin_s=math.nan,
        jitter_frequency_rad_s=math.nan,
        crossovers_rad_s=cr.wc,
        phase_margins_deg=tuple(math.degrees(p) for p in cr.pm),
        phase_crossovers_rad_s=cr.wpc,
        phase_crossover_gains=cr.gpc,
        formulation=f"pade-{order}",
        confirmation=f"closed-loop poles of the Padé-{order} loop: {Z} in the RHP",
    )


# --------------------------------------------------------------------------------------------
# The exact sampled loop
# --------------------------------------------------------------------------------------------


def sampled_plant(plant: ct.LTI, period_s: float, delay_s: float = 0.0) -> ct.StateSpace:
    """Zero-order-hold discretisation of a continuous plant with a fractional input delay.

    Timing model: the output is sampled at ``t = kT``; the command computed from that sample is
    applied at ``kT + tau`` and held until ``(k+1)T + tau``. With ``tau = m T + tau'``,
    ``0 <= tau' < T`` (Åström & Wittenmark, §2.3)::

        x[k+1] = Phi x[k] + Gamma_0 u[k-m] + Gamma_1 u[k-m-1],   y[k] = C x[k]
        Phi = e^{AT},  Gamma_0 = int_0^{T-tau'} e^{As} ds B,
        Gamma_1 = e^{A(T-tau')} int_0^{tau'} e^{As} ds B.

    The past commands ``u[k-1] .. u[k-m-1]`` are appended to the state.

    Parameters
    ----------
    plant : LTI
        Continuous, strictly proper, SISO.
    period_s : float
        Sampling period ``T`` (s).
    delay_s : float
        Delay ``tau`` (s), >= 0.

    Returns
    -------
    StateSpace
        Discrete with ``dt = T``, input ``u[k]``, output ``y[k]``.
    """
    _check_delay(delay_s)
    if period_s <= 0.0 or not np.isfinite(period_s):
        raise ValueError(f"period_s must be > 0, got {period_s}")
    if plant.isdtime(strict=True):
        raise ValueError("plant must be continuous")
    sys = ct.ss(plant)
    A, B, C, D = (np.atleast_2d(np.asarray(M, dtype=float)) for M in (sys.A, sys.B, sys.C, sys.D))
    if np.any(D != 0.0):
        raise ValueError("plant must be strictly proper (D = 0)")
    n, nu = B.shape
    T = float(period_s)
    m = int(math.floor(delay_s / T + 1e-12))
    frac = delay_s - m * T
    if frac < 1e-12 * T:
        frac = 0.0

    def phi_gamma(h: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        M = np.zeros((n + nu, n + nu))
        M[:n, :n] = A
        M[:n, n:] = B
        E = scipy.linalg.expm(M * h)
        return E[:n, :n], E[:n, n:]

    Phi, _ = phi_gamma(T)
    Phi_a, Gamma0 = phi_gamma(T - frac)
    _, G1 = phi_gamma(frac)
    Gamma1 = Phi_a @ G1
    d = m + 1  # delay-line length: u[k-1] .. u[k-m-1]
    N = n + d * nu
    Ad = np.zeros((N, N))
    Bd = np.zeros((N, nu))
    Ad[:n, :n] = Phi

    def slot(i: int) -> slice:  # u[k-i], i >= 1
        return slice(n + (i - 1) * nu, n + i * nu)

    if m == 0:
        Bd[:n] = Gamma0
    else:
        Ad[:n, slot(m)] = Gamma0
    Ad[:n, slot(m + 1)] = Gamma1
    Bd[slot(1)] = np.eye(nu)
    for i in range(1, d):
        Ad[slot(i + 1), slot(i)] = np.eye(nu)
    Cd = np.hstack([C, np.zeros((C.shape[0], d * nu))])
    return ct.ss(Ad, Bd, Cd, np.zeros((C.shape[0], nu)), T)


def sampled_loop(
    plant: ct.LTI,
    controller: ct.LTI,
    *,
    delay_s: float = 0.0,
    observer: ct.LTI | None = None,
) -> ct.StateSpace:
    """The exact discrete loop transfer ``L_d(z) = C(z) F(z) P_d(z; tau)`` (negative feedback).

    ``P_d`` is :func:`sampled_plant` at the controller's sample time. A continuous ``observer``
    is placed in series with the plant before sampling; a discrete one must share ``dt``.
    """
    if not isinstance(controller, ct.LTI) or not controller.isdtime(strict=True):
        raise ValueError("controller must be discrete (python-control LTI with dt > 0)")
    if controller.dt is True:
        raise ValueError("controller has an unspecified sample time (dt=True)")
    T = float(controller.dt)
    cont_plant = plant
    parts = [ct.ss(controller)]
    if observer is not None:
        if observer.isdtime(strict=True):
            if not math.isclose(float(observer.dt), T, rel_tol=1e-9):
                raise ValueError("observer and controller sample times differ")
            parts.append(ct.ss(observer))
        else:
            cont_plant = ct.series(plant, observer)
    Pd = sampled_plant(cont_plant, T, delay_s)
    L = Pd
    for p in parts:
        L = ct.series(L, p)
    return L


def _spectral_radius_closed(L: ct.StateSpace) -> float:
    cl = ct.feedback(L, 1)
    return float(np.max(np.abs(np.linalg.eigvals(np.atleast_2d(cl.A)))))


def sampled_margins(
    plant: ct.LTI,
    controller: ct.LTI,
    *,
    delay_s: float = 0.0,
    observer: ct.LTI | None = None,
    max_extra_delay_s: float | None = None,
) -> Margins:
    """Margins of the exact sampled loop (:func:`sampled_loop`), stability from eigenvalues.

    Phase and gain margins and crossovers come from ``L_d(e^{jwT})`` on ``0 < w <= pi/T``. The
    delay margin is exact for the sampled-data loop: the extra delay at which the spectral radius
    of the closed loop first reaches 1, found by scanning the delay in steps of ``T/16`` and
    bisecting (to 1e-9 T). The jitter margin is not defined here (``nan``; use
    :func:`loop_margins`).

    Parameters
    ----------
    max_extra_delay_s : float, optional
        Scan limit for the delay margin (s); default ``max(20 T, 4 x the phase estimate)``.
        ``inf`` is reported if the loop is still stable there.
    """
    L = sampled_loop(plant, controller, delay_s=delay_s, observer=observer)
    T = float(L.dt)
    cl_poles = np.linalg.eigvals(np.atleast_2d(ct.feedback(L, 1).A))
    rho = float(np.max(np.abs(cl_poles)))
    Z = int(np.sum(np.abs(cl_poles) >= 1.0 - 1e-10))
    stable = Z == 0
    tf = ct.tf(L)
    num = np.asarray(tf.num[0][0], dtype=float)
    den = np.asarray(tf.den[0][0], dtype=float)

    def fun(w: NDArray[np.float64]) -> NDArray[np.complex128]:
        z = np.exp(1j * np.asarray(w, dtype=float) * T)
        return np.polyval(num, z) / np.polyval(den, z)

    wn = math.pi / T
    w0 = np.logspace(np.log10(wn) - 6, np.log10(wn), 600)
    w, Lw = _refine(fun, w0)
    cr = _crossings(fun, w, Lw)
    conf = f"closed-loop eigenvalues of the sampled loop: spectral radius {rho:.6f}"
    if stable:
        pm_deg, wc, gm, wpc, gm_lower, _ = _margins_from_crossings(cr)
        est = min(
            ((p % (2 * np.pi)) / x for p, x in zip(cr.pm, cr.wc, strict=True)), default=math.inf
        )
        limit = max_extra_delay_s
        if limit is None:
            limit = max(20 * T, 4 * est) if np.isfinite(est) else 20 * T

        def rho_at(extra: float) -> float:
            Lx = sampled_loop(plant, controller, delay_s=delay_s + extra, observer=observer)
            return _spectral_radius_closed(Lx)

        dm = math.inf
        step = T / 16
        prev = 0.0
        x = step
        while x <= limit + 1e-15:
            if rho_at(x) >= 1.0:
                lo, hi = prev, x
                while hi - lo > 1e-9 * T:
                    mid = 0.5 * (lo + hi)
                    if rho_at(mid) >= 1.0:
                        hi = mid
                    else:
                        lo = mid
                dm = 0.5 * (lo + hi)
                break
            prev = x
            x += step
    else:
        pm_deg = gm = gm_lower = dm = wpc = math.nan
        wc = cr.wc[int(np.argmin(cr.pm))] if cr.wc else math.nan
    return Margins(
        stable=stable,
        unstable_poles=Z,
        phase_margin_deg=pm_deg,
        gain_margin=gm,
        gain_margin_lower=gm_lower,
        crossover_rad_s=wc,
        phase_crossover_rad_s=wpc,
        delay_margin_s=dm,
        delay_s=float(delay_s),
        jitter_margin_s=math.nan,
        jitter_frequency_rad_s=math.nan,
        crossovers_rad_s=cr.wc,
        phase_margins_deg=tuple(math.degrees(p) for p in cr.pm),
        phase_crossovers_rad_s=cr.wpc,
        phase_crossover_gains=cr.gpc,
        formulation="sampled",
        confirmation=conf,
    )


# --------------------------------------------------------------------------------------------
# Bode and Nyquist data and plots
# --------------------------------------------------------------------------------------------


def bode_data(
    model: LoopModel, omega: ArrayLike | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """``(omega_rad_s, magnitude, phase_deg)`` of ``L(jw)``.

    The phase is continuous along the grid and starts in (-360°, 0°] at the lowest frequency.
    The linear phase ``-w (tau + T/2)`` of the delay and the hold is added analytically, so it
    stays right where the grid is too coarse to unwrap it; the remainder is unwrapped (it jumps
    by ±180° where the hold's ``sin(wT/2)`` changes sign, at multiples of the sampling rate)."""
    w = _grid(model) if omega is None else np.asarray(omega, dtype=float)
    Lw = model.response(w)
    lin = model.delay_s + (0.0 if model.sample_period_s is None else 0.5 * model.sample_period_s)
    ph = np.unwrap(np.angle(Lw * np.exp(1j * w * lin)))
    ph -= 2 * np.pi * np.ceil(ph[0] / (2 * np.pi))  # first value in (-2 pi, 0]
    ph = ph - w * lin
    return w, np.abs(Lw), np.degrees(ph)


def nyquist_data(
    model: LoopModel, omega: ArrayLike | None = None
) -> tuple[NDArray[np.float64], NDArray[np.complex128]]:
    """``(omega_rad_s, L(j omega))`` on the refined grid, positive frequencies only."""
    if omega is None:
        _, _, w, Lw = nyquist_count(model)
        return w, Lw
    w = np.asarray(omega, dtype=float)
    return w, model.response(w)


def plot_bode(
    model: LoopModel, margins: Margins | None = None, omega: ArrayLike | None = None
) -> Figure:
    """Bode plot of ``L(jw)`` (frequency in Hz on the axis), crossovers marked; a new Figure."""
    w, mag, ph = bode_data(model, omega)
    fig = Figure(figsize=(7, 6), layout="constrained")
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    f = w / (2 * np.pi)
    ax1.loglog(f, mag)
    ax1.axhline(1.0, color="0.5", lw=0.8)
    ax1.set_ylabel("|L|")
    ax2.semilogx(f, ph)
    for k in range(-20, 1):
        if ph.min() - 360 < -180 + 360 * k < ph.max() + 360:
            ax2.axhline(-180 + 360 * k, color="0.5", lw=0.8)
    ax2.set_ylabel("arg L (deg)")
    ax2.set_xlabel("frequency (Hz)")
    if model.sample_period_s is not None:
        for ax in (ax1, ax2):
            ax.axvline(0.5 / model.sample_period_s, color="C3", ls=":", lw=0.8)
    if margins is not None:
        for x in margins.crossovers_rad_s:
            ax1.axvline(x / (2 * np.pi), color="C1", ls="--", lw=0.8)
        ax1.set_title(margins.summary(), fontsize=7, wrap=True)
    return fig


def plot_nyquist(
    model: LoopModel,
    margins: Margins | None = None,
    omega: ArrayLike | None = None,
    radius: float = 3.0,
) -> Figure:
    """Nyquist plot of ``L(jw)`` for ``w > 0`` (solid) and its mirror (dashed), the point -1 and
    the unit circle, zoomed to ``|L| <= radius``; a new Figure."""
    _, Lw = nyquist_data(model, omega)
    fig = Figure(figsize=(6, 6), layout="constrained")
    ax = fig.subplots()
    Lc = np.where(np.abs(Lw) <= radius * 1.5, Lw, np.nan)
    ax.plot(Lc.real, Lc.imag, "C0")
    ax.plot(Lc.real, -Lc.imag, "C0--", lw=0.8)
    th = np.linspace(0, 2 * np.pi, 200)
    ax.plot(np.cos(th), np.sin(th), color="0.6", lw=0.8)
    ax.plot([-1], [0], "r+", ms=12)
    ax.set_xlim(-radius, radius)
    ax.set_ylim(-radius, radius)
    ax.set_aspect("equal")
    ax.set_xlabel("Re L")
    ax.set_ylabel("Im L")
    if margins is not None:
        ax.set_title(margins.summary(), fontsize=7, wrap=True)
    return fig


# --------------------------------------------------------------------------------------------
# The per-axis attitude loop
# --------------------------------------------------------------------------------------------


def attitude_plant(inertia_kgm2: float, damping_Nms_per_rad: float) -> ct.TransferFunction:
    """Per-axis rotor ``P(s) = 1 / (J s^2 + b s)`` from torque (N·m) to angle (rad)."""
    if inertia_kgm2 <= 0.0 or damping_Nms_per_rad < 0.0:
        raise ValueError("need inertia_kgm2 > 0 and damping_Nms_per_rad >= 0")
    return ct.tf([1.0], [inertia_kgm2, damping_Nms_per_rad, 0.0])


def attitude_margins(
    controller: ct.LTI,
    *,
    inertia_kgm2: float,
    damping_Nms_per_rad: float,
    frame_period_s: float | None,
    delay_s: float,
    observer: ct.LTI | None = None,
    formulation: str = "hybrid",
) -> Margins:
    """Margins of the per-axis attitude loop ``P = 1/(J s^2 + b s)`` with controller ``C``.

    Parameters
    ----------
    controller : LTI
        ``u = -C y`` (torque from angle), continuous or discrete at ``frame_period_s``.
    inertia_kgm2, damping_Nms_per_rad : float
        ``J`` (kg·m²) and viscous ``b`` (N·m·s/rad) about the axis.
    frame_period_s : float or None
        Camera/observer period ``T`` (s) of the sample-and-hold; None for a continuous loop.
    delay_s : float
        Total constant vision-to-actuation delay ``tau`` (s).
    observer : LTI, optional
        Observer/filter transfer in series.
    formulation : {"hybrid", "sampled"}
        "hybrid": :func:`loop_margins` (exact delay, Nyquist, jitter margin); "sampled":
        :func:`sampled_margins` (needs a discrete controller).
    """
    P = attitude_plant(inertia_kgm2, damping_Nms_per_rad)
    if formulation == "hybrid":
        model = loop_model(
            P, controller, delay_s=delay_s, sample_period_s=frame_period_s, observer=observer
        )
        return loop_margins(model)
    if formulation == "sampled":
        if frame_period_s is not None and controller.isdtime(strict=True):
            if not math.isclose(float(controller.dt), frame_period_s, rel_tol=1e-9):
                raise ValueError("frame_period_s differs from the controller's dt")
        return sampled_margins(P, controller, delay_s=delay_s, observer=observer)
    raise ValueError(f"formulation must be 'hybrid' or 'sampled', got {formulation!r}")


def attitude_delay_sweep(
    controller: ct.LTI,
    *,
    inertia_kgm2: float,
    damping_Nms_per_rad: float,
    frame_period_s: float | None,
    delays_s: ArrayLike | None = None,
    observer: ct.LTI | None = None,
    formulation: str = "hybrid",
) -> pd.DataFrame:
    """:func:`attitude_margins` over constant delays (default 0-60 ms in 1 ms steps).

    Returns
    -------
    DataFrame
        One row per delay with columns ``delay_s``, ``phase_margin_deg``, ``gain_margin``,
        ``crossover_rad_s``, ``delay_margin_s``, ``jitter_margin_s``, ``stable`` (margins are
        ``nan`` where ``stable`` is False).
    """
    rows = [
        attitude_margins(
            controller,
            inertia_kgm2=inertia_kgm2,
            damping_Nms_per_rad=damping_Nms_per_rad,
            frame_period_s=frame_period_s,
            delay_s=float(d),
            observer=observer,
            formulation=formulation,
        ).as_row()
        for d in (np.linspace(0.0, 0.060, 61) if delays_s is None else np.asarray(delays_s, float))
    ]
    return pd.DataFrame(rows)
