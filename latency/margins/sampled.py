"""The exact sampled loop: zero-order hold with a fractional input delay (Åström & Wittenmark,
*Computer-Controlled Systems*, 3rd ed., §2.3) and its eigenvalue-confirmed margins."""

from __future__ import annotations

import math

import control as ct
import numpy as np
from numpy.typing import NDArray

from latency.margins.grid import _refine
from latency.margins.model import _check_delay
from latency.margins.result import Margins, _Crossings, _crossings, margins_from_crossings
from latency.zoh import zoh_integrals


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
    A, B, C = _continuous_matrices(plant)
    return ct.ss(*_sampled_matrices(A, B, C, float(period_s), delay_s), float(period_s))


def _continuous_matrices(
    plant: ct.LTI,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(A, B, C) of a continuous, strictly proper plant (ValueError otherwise)."""
    if plant.isdtime(strict=True):
        raise ValueError("plant must be continuous")
    sys = ct.ss(plant)
    A, B, C, D = (np.atleast_2d(np.asarray(M, dtype=float)) for M in (sys.A, sys.B, sys.C, sys.D))
    if np.any(D != 0.0):
        raise ValueError("plant must be strictly proper (D = 0)")
    return A, B, C


def _sampled_matrices(
    A: NDArray[np.float64], B: NDArray[np.float64], C: NDArray[np.float64], T: float,
    delay_s: float,
) -> tuple[NDArray[np.float64], ...]:
    """(Ad, Bd, Cd, Dd) of :func:`sampled_plant` for the continuous (A, B, C), period T (s)
    and delay (s)."""
    _check_delay(delay_s)
    n, nu = B.shape
    m = int(math.floor(delay_s / T + 1e-12))
    frac = delay_s - m * T
    if frac < 1e-12 * T:
        frac = 0.0

    Phi, _ = zoh_integrals(A, B, T)
    Phi_a, Gamma0 = zoh_integrals(A, B, T - frac)
    _, G1 = zoh_integrals(A, B, frac)
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
    return Ad, Bd, Cd, np.zeros((C.shape[0], nu))


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
    loop = _SampledLoop(plant, controller, observer)
    return ct.ss(*loop.matrices(delay_s), loop.T)


class _SampledLoop:
    """The loop of :func:`sampled_loop` as matrices at any delay: the plant (with a continuous
    observer in series) and the discrete parts (the controller, then a discrete observer) are
    converted to state space once, so a scan over the delay only samples the plant again and
    chains the parts (series: ``A = [[A1, 0], [B2 C1, A2]]``, ``B = [B1; B2 D1]``,
    ``C = [D2 C1, C2]``, ``D = D2 D1``)."""

    def __init__(self, plant: ct.LTI, controller: ct.LTI, observer: ct.LTI | None) -> None:
        if not isinstance(controller, ct.LTI) or not controller.isdtime(strict=True):
            raise ValueError("controller must be discrete (python-control LTI with dt > 0)")
        if controller.dt is True:
            raise ValueError("controller has an unspecified sample time (dt=True)")
        #: The sample time, s (the controller's).
        self.T = float(controller.dt)
        cont_plant = plant
        parts = [controller]
        if observer is not None:
            if observer.isdtime(strict=True):
                if not math.isclose(float(observer.dt), self.T, rel_tol=1e-9):
                    raise ValueError("observer and controller sample times differ")
                parts.append(observer)
            else:
                cont_plant = ct.series(plant, observer)
        self.plant = _continuous_matrices(cont_plant)
        self.parts = [tuple(np.atleast_2d(np.asarray(M, dtype=float))
                            for M in (s.A, s.B, s.C, s.D)) for s in map(ct.ss, parts)]

    def matrices(self, delay_s: float) -> tuple[NDArray[np.float64], ...]:
        """(A, B, C, D) of ``L_d`` at the delay ``delay_s`` (s)."""
        A, B, C, D = _sampled_matrices(*self.plant, self.T, delay_s)
        for A2, B2, C2, D2 in self.parts:
            A = np.block([[A, np.zeros((A.shape[0], A2.shape[0]))], [B2 @ C, A2]])
            B, C, D = np.vstack([B, B2 @ D]), np.hstack([D2 @ C, C2]), D2 @ D
        return A, B, C, D

    def radius(self, delay_s: float) -> float:
        """Spectral radius of the closed loop (unit negative feedback, ``A - B (I + D)^-1 C``)
        at the delay ``delay_s`` (s)."""
        A, B, C, D = self.matrices(delay_s)
        A_cl = A - B @ np.linalg.solve(np.eye(D.shape[0]) + D, C)
        return float(np.max(np.abs(np.linalg.eigvals(A_cl))))


def sampled_spectral_radius(
    plant: ct.LTI, controller: ct.LTI, *, delay_s: float = 0.0, observer: ct.LTI | None = None
) -> float:
    """Spectral radius of the closed loop of :func:`sampled_loop` (the largest closed-loop
    eigenvalue magnitude): below 1 the loop is stable; its slowest mode (the fastest growing
    one, above 1) scales by this factor per sample."""
    return _SampledLoop(plant, controller, observer).radius(delay_s)


def sampled_stable(
    plant: ct.LTI, controller: ct.LTI, *, delay_s: float = 0.0, observer: ct.LTI | None = None
) -> bool:
    """Closed-loop stability of :func:`sampled_loop` (spectral radius below 1), without the
    margins: the cheap test for scanning a delay."""
    return sampled_spectral_radius(plant, controller, delay_s=delay_s,
                                   observer=observer) < 1.0 - 1e-10


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
    loop = _SampledLoop(plant, controller, observer)
    L = ct.ss(*loop.matrices(delay_s), loop.T)
    T = loop.T
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
    dm = None
    if stable:
        dm = _delay_margin(loop, delay_s, cr, max_extra_delay_s)
    return margins_from_crossings(
        cr, stable=stable, unstable_poles=Z, delay_s=float(delay_s), formulation="sampled",
        confirmation=conf, delay_margin_s=dm,
    )


def _delay_margin(
    loop: _SampledLoop, delay_s: float, cr: _Crossings, max_extra_delay_s: float | None
) -> float:
    """Extra delay (s) at which the sampled loop's spectral radius first reaches 1: a scan in
    steps of ``T/16`` up to ``max_extra_delay_s`` (default ``max(20 T, 4 x`` the phase
    estimate of the crossings``)``), then bisection to 1e-9 T; ``inf`` if none."""
    T = loop.T
    est = min(
        ((p % (2 * np.pi)) / x for p, x in zip(cr.pm, cr.wc, strict=True)), default=math.inf
    )
    limit = max_extra_delay_s
    if limit is None:
        limit = max(20 * T, 4 * est) if np.isfinite(est) else 20 * T

    def rho_at(extra: float) -> float:
        return loop.radius(delay_s + extra)

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
            return 0.5 * (lo + hi)
        prev = x
        x += step
    return math.inf
