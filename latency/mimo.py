"""MIMO check of the three-axis attitude loop with the exact vision delay.

The per-axis analysis (:func:`latency.margins.attitude_margins`) treats the body axes as three
independent loops ``P_i = 1/(J_ii s² + b s)``. They are coupled when the centre of mass sits off
the pivot O: the inertia about O then has products of inertia (parallel-axis theorem) and the
gravity torque of the offset depends on the attitude. This module linearises the rotor about an
operating attitude, closes all three axes at once and asks the per-axis questions of the MIMO
loop.

Linearisation (body frame, about ``q_op`` at rest)
--------------------------------------------------
Write ``q = q_op ⊗ exp(δθ/2)`` (body-frame rotation vector δθ, rad), so
``R(q) ≈ R_op (I + [δθ]×)``. Euler's equations of the twin (``plant.twin``),
``J_O ω̇ = R(q)ᵀ T + d × (R(q)ᵀ m g) − b ω − ω × J_O ω``, with the gravity force in the body
frame ``g_b = R_opᵀ m g`` give, to first order::

    d × (R(q)ᵀ m g) ≈ d × g_b + [d]× [g_b]× δθ                 (gravity stiffness)

The PID (``controller.pid``) computes a body torque ``τ`` from the rotation-vector error and
sends ``T = R(q_est) τ``; the plant turns it back with the true attitude,
``R(q)ᵀ R(q_est) τ ≈ τ + [τ]× δθ − [τ]× δθ_est``. About the equilibrium torque
``τ_eq = −d × g_b`` (the PID's integrator holds it) this makes the linear loop::

    δθ̇ = ω,    J_O ω̇ = δτ + G δθ − b ω,    G = [d]× [g_b]× + [τ_eq]×      (N·m/rad)
    δτ  = −(C(s) + [τ_eq]×) · F H_T e^{−sτ} · δθ                            (negative feedback)

with ``C(s) = diag(C_x, C_y, C_z)`` the per-axis controllers, ``F`` the (scalar) observer, ``H_T``
the sample-and-hold and ``e^{−sτ}`` the exact delay; the last three act on every axis alike (one
camera). The gyroscopic term is of second order at rest. Coulomb friction is a nonlinearity and
is left out, as in the per-axis analysis. With ``d = 0`` the loop is three decoupled copies of
the per-axis loop; ``tests/test_mimo.py`` checks both this and the linearisation against the
CasADi twin's Jacobian.

The loop transfer broken at the plant input is the 3 × 3 matrix
``L(s) = (C(s) + [τ_eq]×) F(s) H_T(s) e^{−sτ} P(s)``, ``P(s) = (J_O s² + b s − G)⁻¹``.

Verdict and margins
-------------------
- **Stability**: the generalised Nyquist criterion (MacFarlane & Postlethwaite, 1977): the closed
  loop has ``Z = P_ol + N`` poles in the open right half-plane, ``N`` the clockwise encirclements
  of the origin by ``det(I + L(s))`` along the D-contour of :func:`latency.margins.nyquist_count`
  (indented to the right of the origin) and ``P_ol`` the open-loop poles in the open RHP.
- **Phase, gain and delay margins of the common loop**: the delay, the hold and the observer are
  scalars, so they multiply every eigenvalue ``λ_k(jω)`` of ``L(jω)`` alike. A common extra delay
  ``Δ`` destabilises first where a characteristic locus ``λ_k`` crosses the unit circle:
  ``Δ = min_k (PM_k mod 2π)/ω_ck``. Likewise a common gain ``g`` destabilises where a locus crosses
  the negative real axis, ``g = 1/|λ_k|``. These are exact for perturbations of the form
  ``g e^{−jωΔ} I``, which is what a change of vision latency or of loop gain is; they say nothing
  about perturbations that differ between axes. Each delay margin is confirmed by the Nyquist
  count just below and just above it.

References
----------
A. G. J. MacFarlane and I. Postlethwaite, "The generalized Nyquist stability criterion and
multivariable root loci", Int. J. Control 25(1), 81-127, 1977.
S. Skogestad and I. Postlethwaite, *Multivariable Feedback Control*, 2nd ed., Wiley, 2005, §4.9.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import control as ct
import numpy as np
from numpy.typing import ArrayLike, NDArray

from latency.margins import Margins, attitude_margins, nyquist_count
from latency.margins.model import _as_factor, _check_delay, _common_period, _Factor, _features, _zoh
from plant import attitude
from plant.params import PlantParams

__all__ = [
    "MimoLoop",
    "MimoMargins",
    "RotorLinearisation",
    "mimo_loop",
    "mimo_margins",
    "rotor_linearisation",
]


def _skew(v: ArrayLike) -> NDArray[np.float64]:
    x, y, z = np.asarray(v, dtype=float)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


@dataclass(frozen=True)
class RotorLinearisation:
    """The rotor linearised about an operating attitude at rest (module docstring).

    Attributes
    ----------
    q_op : (4,) operating attitude (w, x, y, z), rotor to stator.
    J_O : (3, 3) inertia about the pivot O, kg·m² (body frame).
    b : viscous damping, N·m·s/rad.
    G : (3, 3) stiffness ``[d]× [g_b]× + [τ_eq]×``, N·m/rad (body frame).
    tau_eq : (3,) body torque that holds ``q_op`` against gravity, N·m.
    """

    q_op: NDArray[np.float64]
    J_O: NDArray[np.float64]
    b: float
    G: NDArray[np.float64]
    tau_eq: NDArray[np.float64]

    def state_space(self) -> ct.StateSpace:
        """``x = (δθ, ω)``, input ``δτ`` (N·m, body), output ``δθ`` (rad): continuous, 3 × 3."""
        Ji = np.linalg.inv(self.J_O)
        A = np.block([[np.zeros((3, 3)), np.eye(3)], [Ji @ self.G, -self.b * Ji]])
        B = np.vstack([np.zeros((3, 3)), Ji])
        C = np.hstack([np.eye(3), np.zeros((3, 3))])
        return ct.ss(A, B, C, np.zeros((3, 3)))

    def response(self, s: NDArray[np.complex128]) -> NDArray[np.complex128]:
        """``P(s) = (J_O s² + b s − G)⁻¹`` at complex ``s`` (rad/s), shape ``s.shape + (3, 3)``."""
        s = np.asarray(s, dtype=complex)[..., None, None]
        M = self.J_O * s**2 + self.b * s * np.eye(3) - self.G
        return np.linalg.inv(M)


def rotor_linearisation(
    params: PlantParams | None = None, q_op: ArrayLike = (1.0, 0.0, 0.0, 0.0)
) -> RotorLinearisation:
    """Linearise the rotor of ``params`` about ``q_op`` at rest (module docstring).

    ``J_O`` is ``RotorParams.inertia_about_centre_kgm2`` (parallel-axis theorem). Coulomb
    friction is not part of the model.
    """
    p = params or PlantParams()
    r = p.rotor
    q = attitude.normalize(q_op, "q_op")
    d = np.asarray(r.com_offset_m, dtype=float)
    J_O = r.inertia_about_centre_kgm2
    g_b = attitude.to_matrix(q).T @ (r.mass_kg * np.array([0.0, 0.0, -r.gravity_m_s2]))
    tau_eq = -np.cross(d, g_b)
    G = _skew(d) @ _skew(g_b) + _skew(tau_eq)
    return RotorLinearisation(q, J_O, float(r.viscous_Nms_per_rad), G, tau_eq)


@dataclass(frozen=True)
class MimoLoop:
    """``L(s) = (C(s) + [τ_eq]×) F(s) H_T(s) e^{−sτ} P(s)``, 3 × 3, loop broken at the plant
    input (module docstring). Build with :func:`mimo_loop`; calling it evaluates ``L`` at complex
    ``s`` (rad/s), shape ``s.shape + (3, 3)``.

    Attributes
    ----------
    rotor : RotorLinearisation
    controllers : the three per-axis SISO factors ``C_i`` (``u = −C y``).
    observer : the scalar observer factor, or None.
    delay_s : constant delay τ (s).
    sample_period_s : period T (s) of the sample-and-hold, or None.
    open_loop_rhp_poles : open-loop poles in the open right half-plane.
    """

    rotor: RotorLinearisation
    controllers: tuple[_Factor, _Factor, _Factor]
    observer: _Factor | None
    delay_s: float
    sample_period_s: float | None
    open_loop_rhp_poles: int
    features_rad_s: tuple[float, ...]
    controller_lti: tuple[ct.LTI, ct.LTI, ct.LTI] = field(repr=False)
    observer_lti: ct.LTI | None = field(default=None, repr=False)

    def scalar(self, s: NDArray[np.complex128]) -> NDArray[np.complex128]:
        """The factor common to all axes, ``F(s) H_T(s) e^{−sτ}``."""
        s = np.asarray(s, dtype=complex)
        out = np.ones(s.shape, dtype=complex)
        if self.observer is not None:
            out = out * self.observer(s)
        if self.sample_period_s is not None:
            out = out * _zoh(s * self.sample_period_s)
        if self.delay_s > 0.0:
            out = out * np.exp(-s * self.delay_s)
        return out

    def __call__(self, s: ArrayLike) -> NDArray[np.complex128]:
        s = np.asarray(s, dtype=complex)
        Cs = np.zeros(s.shape + (3, 3), dtype=complex)
        for i, c in enumerate(self.controllers):
            Cs[..., i, i] = c(s)
        Cs = Cs + _skew(self.rotor.tau_eq)
        return (Cs * self.scalar(s)[..., None, None]) @ self.rotor.response(s)

    def with_delay(self, delay_s: float) -> MimoLoop:
        """The same loop with the constant delay replaced by ``delay_s`` (s)."""
        _check_delay(delay_s)
        return mimo_loop(
            self.rotor,
            self.controller_lti,
            delay_s=delay_s,
            sample_period_s=self.sample_period_s,
            observer=self.observer_lti,
        )

    def with_gain(self, gain: float) -> _DetModel:
        """``det(I + gain L(s)) − 1`` in the shape :func:`latency.margins.nyquist_count` takes."""
        return _DetModel(self, float(gain))


@dataclass(frozen=True)
class _DetModel:
    """``g(s) = det(I + k L(s)) − 1``: the Nyquist count of :mod:`latency.margins` on ``1 + g``
    is the generalised Nyquist count of the MIMO loop."""

    loop: MimoLoop
    gain: float = 1.0

    @property
    def open_loop_rhp_poles(self) -> int:
        return self.loop.open_loop_rhp_poles

    @property
    def features_rad_s(self) -> tuple[float, ...]:
        return self.loop.features_rad_s

    def __call__(self, s: ArrayLike) -> NDArray[np.complex128]:
        L = self.loop(np.asarray(s, dtype=complex).ravel())
        return np.linalg.det(np.eye(3) + self.gain * L) - 1.0

    def response(self, omega: ArrayLike) -> NDArray[np.complex128]:
        return self(1j * np.asarray(omega, dtype=float))


def mimo_loop(
    rotor: RotorLinearisation,
    controllers: ct.LTI | Sequence[ct.LTI],
    *,
    delay_s: float = 0.0,
    sample_period_s: float | None = None,
    observer: ct.LTI | None = None,
) -> MimoLoop:
    """Build the three-axis loop of :class:`MimoLoop`.

    Parameters
    ----------
    rotor : RotorLinearisation
        From :func:`rotor_linearisation`.
    controllers : LTI or sequence of three LTI
        Per-axis SISO controllers ``C_i`` (torque N·m per attitude error rad, ``u = −C y``),
        continuous or discrete at ``sample_period_s`` (e.g. ``PIDController.transfer_function``
        for each axis); one LTI is used on all three axes.
    delay_s : float
        Total constant vision-to-actuation delay τ (s), exact.
    sample_period_s : float, optional
        Sample-and-hold period T (s); defaults to the discrete parts' sample time.
    observer : LTI, optional
        Scalar observer/filter ``F`` applied to every axis.
    """
    _check_delay(delay_s)
    ctrl = tuple(controllers) if isinstance(controllers, Sequence) else (controllers,) * 3
    if len(ctrl) != 3:
        raise ValueError(f"controllers must be one LTI or three, got {len(ctrl)}")
    factors = [_as_factor(c, f"controllers[{i}]") for i, c in enumerate(ctrl)]
    obs = None if observer is None else _as_factor(observer, "observer")
    parts = factors + ([obs] if obs is not None else [])
    T = _common_period(parts, sample_period_s)
    rhp = 0
    for f in parts:
        poles = np.roots(f.den) if f.den.size > 1 else np.zeros(0)
        if f.dt is None:
            rhp += int(np.sum(poles.real > 1e-12 * np.maximum(1.0, np.abs(poles))))
        elif np.any(np.abs(poles[np.abs(poles - 1.0) > 1e-9]) >= 1.0 - 1e-12):
            raise ValueError("a discrete part has poles outside the unit circle (other than z = 1)")
    A = rotor.state_space().A
    eig = np.linalg.eigvals(A)
    rhp += int(np.sum(eig.real > 1e-9 * max(1.0, float(np.max(np.abs(eig))))))
    feats = list(_features(parts, float(delay_s), T))
    feats += [float(abs(e)) for e in eig if abs(e) > 1e-9]
    return MimoLoop(
        rotor,
        (factors[0], factors[1], factors[2]),
        obs,
        float(delay_s),
        None if T is None else float(T),
        rhp,
        tuple(sorted(feats)),
        (ctrl[0], ctrl[1], ctrl[2]),
        observer,
    )


# --- characteristic loci ---------------------------------------------------------------------
_PERMS = tuple(itertools.permutations(range(3)))


def _match(prev: NDArray[np.complex128], cur: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """Reorder the three eigenvalues ``cur`` to follow ``prev`` (least total distance)."""
    best = min(_PERMS, key=lambda p: float(np.sum(np.abs(cur[list(p)] - prev))))
    return cur[list(best)]


def _loci(loop: MimoLoop, w: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """Characteristic loci ``λ_k(jω)`` (n, 3) on a grid refined until each locus moves less than
    a tenth of its distance to −1 and of its own size between neighbours."""
    w = np.asarray(w, dtype=float)
    lam = np.linalg.eigvals(loop(1j * w))
    for _ in range(30):
        for i in range(1, len(w)):
            lam[i] = _match(lam[i - 1], lam[i])
        step = np.abs(np.diff(lam, axis=0))
        scale = np.minimum(np.abs(1.0 + lam[:-1]), np.maximum(np.abs(lam[:-1]), 1e-3))
        bad = np.any(step > 0.1 * scale, axis=1) & (np.diff(w) > 1e-12 * w[1:])
        if not np.any(bad):
            break
        idx = np.nonzero(bad)[0]
        mid = np.sqrt(w[idx] * w[idx + 1])
        w = np.insert(w, idx + 1, mid)
        lam = np.insert(lam, idx + 1, np.linalg.eigvals(loop(1j * mid)), axis=0)
    return w, lam


def _bisect_locus(loop: MimoLoop, wa: float, wb: float, la: complex, lb: complex,
                  crit, iters: int = 60) -> tuple[float, complex]:
    """Bisection on a branch of the loci between (wa, la) and (wb, lb) for ``crit(λ) = 0``, the
    branch followed by nearest eigenvalue to the linear interpolation."""
    fa = crit(la)
    for _ in range(iters):
        wm = math.sqrt(wa * wb)
        t = (wm - wa) / (wb - wa)
        guess = la + t * (lb - la)
        ev = np.linalg.eigvals(loop(np.array([1j * wm]))[0])
        lm = complex(ev[int(np.argmin(np.abs(ev - guess)))])
        fm = crit(lm)
        if (fm < 0) == (fa < 0):
            wa, la, fa = wm, lm, fm
        else:
            wb, lb = wm, lm
        if wb - wa <= 1e-13 * wb:
            break
    return math.sqrt(wa * wb), la


@dataclass(frozen=True)
class MimoMargins:
    """Margins of the three-axis loop against common (all-axis) perturbations.

    Attributes
    ----------
    stable : bool
        Generalised Nyquist verdict on ``det(I + L)``.
    unstable_poles : int
        Closed-loop poles in the open right half-plane.
    phase_margin_deg : float
        Smallest ``180° + arg λ_k(jω_c)`` over the unit-circle crossings of the characteristic
        loci (wrapped to (−180°, 180°]); ``inf`` without crossing; ``nan`` when unstable.
    crossover_rad_s : float
        The crossing that sets it (rad/s).
    gain_margin : float
        Smallest common gain factor > 1 that destabilises (``1/|λ_k|`` at negative-real crossings
        of a locus); ``inf`` if none; ``nan`` when unstable.
    delay_margin_s : float
        Extra common constant delay (s) on top of ``delay_s`` that destabilises,
        ``min_k (PM_k mod 2π)/ω_ck``; ``nan`` when unstable.
    delay_s : float
        Constant delay already in the loop (s).
    crossovers_rad_s, phase_margins_deg : every locus's unit-circle crossings and their margins.
    delay_margin_confirmed : bool
        The Nyquist count says stable at ``0.98 ×`` and unstable at ``1.02 ×`` the delay margin.
    per_axis : tuple of three ``Margins``
        The per-axis analysis (:func:`latency.margins.attitude_margins` with ``J_ii`` and the
        axis controller, coupling ignored), for comparison.
    confirmation : str
    """

    stable: bool
    unstable_poles: int
    phase_margin_deg: float
    crossover_rad_s: float
    gain_margin: float
    delay_margin_s: float
    delay_s: float
    crossovers_rad_s: tuple[float, ...]
    phase_margins_deg: tuple[float, ...]
    delay_margin_confirmed: bool
    per_axis: tuple[Margins, ...]
    confirmation: str

    def summary(self) -> str:
        """One line; says "unstable" when the closed loop is."""
        if not self.stable:
            return f"MIMO loop unstable ({self.confirmation}; delay {self.delay_s * 1e3:.2f} ms)"
        axis_dm = min(m.delay_margin_s for m in self.per_axis)
        return (
            f"MIMO loop stable: PM {self.phase_margin_deg:.2f} deg at "
            f"{self.crossover_rad_s:.4g} rad/s, common GM {self.gain_margin:.4g}, delay margin "
            f"{self.delay_margin_s * 1e3:.3f} ms (per-axis analysis: {axis_dm * 1e3:.3f} ms); "
            f"delay {self.delay_s * 1e3:.2f} ms; {self.confirmation}"
        )


def _count(loop: MimoLoop, gain: float = 1.0) -> int:
    Z, _, _, _ = nyquist_count(loop.with_gain(gain))  # type: ignore[arg-type]
    return Z


def mimo_margins(loop: MimoLoop) -> MimoMargins:
    """Generalised Nyquist verdict and common-perturbation margins of ``loop`` (module docstring).
    """
    Z, N, w, _ = nyquist_count(loop.with_gain(1.0))  # type: ignore[arg-type]
    stable = Z == 0
    conf = f"generalised Nyquist on det(I + L): N={N}, P={loop.open_loop_rhp_poles}, Z={Z}"
    w, lam = _loci(loop, w)
    mag = np.abs(lam)
    wc: list[float] = []
    pm: list[float] = []
    wpc_gain: list[float] = []
    for k in range(3):
        m = np.log(np.maximum(mag[:, k], 1e-300))
        for i in np.nonzero(np.sign(m[:-1]) * np.sign(m[1:]) < 0)[0]:
            x, lx = _bisect_locus(loop, w[i], w[i + 1], lam[i, k], lam[i + 1, k],
                                  lambda v: math.log(max(abs(v), 1e-300)))
            wc.append(x)
            pm.append(float(np.angle(-lx)))
        im = lam[:, k].imag
        for i in np.nonzero(np.sign(im[:-1]) * np.sign(im[1:]) < 0)[0]:
            if lam[i, k].real + lam[i + 1, k].real >= 0.0 or max(mag[i, k], mag[i + 1, k]) < 1e-3:
                continue
            _, lx = _bisect_locus(loop, w[i], w[i + 1], lam[i, k], lam[i + 1, k],
                                  lambda v: v.imag / abs(v))
            if lx.real < 0.0 and abs(lx) < 1.0:
                wpc_gain.append(1.0 / abs(lx))
    order = np.argsort(wc)
    wc = [wc[i] for i in order]
    pm = [pm[i] for i in order]
    per_axis = tuple(
        attitude_margins(
            loop.controller_lti[i],
            inertia_kgm2=float(loop.rotor.J_O[i, i]),
            damping_Nms_per_rad=loop.rotor.b,
            frame_period_s=loop.sample_period_s,
            delay_s=loop.delay_s,
            observer=loop.observer_lti,
        )
        for i in range(3)
    )
    confirmed = False
    if stable:
        if wc:
            k = int(np.argmin(pm))
            pm_deg, w_c = math.degrees(pm[k]), wc[k]
            dm = min((p % (2 * math.pi)) / x for p, x in zip(pm, wc, strict=True))
        else:
            pm_deg, w_c, dm = math.inf, math.nan, math.inf
        gm = min(wpc_gain, default=math.inf)
        if math.isfinite(dm):
            below = _count(loop.with_delay(loop.delay_s + 0.98 * dm))
            above = _count(loop.with_delay(loop.delay_s + 1.02 * dm))
            confirmed = below == 0 and above > 0
            conf += f"; Nyquist at 0.98/1.02 x the delay margin: Z={below}/{above}"
    else:
        pm_deg = gm = dm = math.nan
        w_c = wc[int(np.argmin(pm))] if wc else math.nan
    return MimoMargins(
        stable=stable,
        unstable_poles=Z,
        phase_margin_deg=pm_deg,
        crossover_rad_s=w_c,
        gain_margin=gm,
        delay_margin_s=dm,
        delay_s=loop.delay_s,
        crossovers_rad_s=tuple(wc),
        phase_margins_deg=tuple(math.degrees(p) for p in pm),
        delay_margin_confirmed=confirmed,
        per_axis=per_axis,
        confirmation=conf,
    )
