"""The hybrid loop model ``L(s) = C(s) F(s) H_T(s) P(s) e^{-s tau}`` with the exact delay:
rational factors, the sample-and-hold and the loop object (see :mod:`latency.margins`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from numbers import Real

import control as ct
import numpy as np
from numpy.typing import ArrayLike, NDArray

from latency.margins.grid import _grid


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
        if float(sys) == 0.0:
            raise ValueError(f"{name} is zero: the loop is open, it has no margins")
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
    if not (np.all(np.isfinite(num)) and np.all(np.isfinite(den))):
        raise ValueError(f"{name} has non-finite coefficients (inf or nan)")
    if num.size == 0:
        raise ValueError(f"{name} is zero: the loop is open, it has no margins")
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
        w = (_grid(self.response, self.features_rad_s) if omega is None
             else np.asarray(omega, dtype=float))
        return ct.frd(self.response(w), w)


def _check_delay(delay_s: float) -> None:
    if isinstance(delay_s, bool) or not isinstance(delay_s, Real):
        raise ValueError(f"delay_s must be a number of seconds, got {type(delay_s).__name__}")
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


def _pole_counts(name: str, f: _Factor) -> tuple[int, int, int]:
    """The poles of factor ``f`` (of the part ``name``) that the hybrid model counts: those in
    the open right half-plane, those at the origin (``s = 0``, or ``z = 1`` for a discrete
    factor), and its relative degree (continuous factors; a discrete factor's is 0).
    ``ValueError`` for poles the model cannot count: continuous poles on the imaginary axis
    away from the origin, a repeated pole at ``z = 1``, or discrete poles on or outside the
    unit circle."""
    poles = _roots(f.den)
    if f.dt is None:
        scale = max(1.0, float(np.max(np.abs(poles)))) if poles.size else 1.0
        at0 = np.abs(poles) <= 1e-9 * scale
        rest = poles[~at0]
        on_axis = np.abs(rest.real) <= 1e-12 * np.maximum(1.0, np.abs(rest))
        if np.any(on_axis):
            raise ValueError(f"{name} has poles on the imaginary axis away from the origin")
        return int(np.sum(rest.real > 0.0)), int(np.sum(at0)), f.den.size - f.num.size
    at1 = np.abs(poles - 1.0) <= 1e-9
    if int(np.sum(at1)) > 1:
        raise ValueError(f"{name} has a repeated pole at z = 1; use sampled_margins")
    others = poles[~at1]
    if np.any(np.abs(others) >= 1.0 - 1e-12):
        raise ValueError(
            f"{name} has poles on or outside the unit circle (other than z = 1): the "
            "hybrid model cannot count them; use sampled_margins"
        )
    return 0, int(np.sum(at1)), 0


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

    rhp = origin = rel_deg = 0
    for (name, _), f in zip(parts, factors, strict=True):
        f_rhp, f_origin, f_rel_deg = _pole_counts(name, f)
        rhp, origin, rel_deg = rhp + f_rhp, origin + f_origin, rel_deg + f_rel_deg
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
