"""The margins of one loop (:class:`Margins`) and the search for gain and phase crossovers."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.optimize
from numpy.typing import NDArray

from latency.margins.grid import _SMALL_GAIN


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
        Phase margin ``180° + arg L(jw_c)``, wrapped to (-180°, 180°], at the *critical* gain
        crossover: the one where ``L`` comes closest to -1 (smallest ``|PM|``; the distance
        from -1 is ``2 sin(|PM|/2)``). A loop with several crossovers may show a large negative
        margin at another crossover far from -1 (``phase_margins_deg``); that crossover is not
        the one a small phase error would destabilise. ``inf`` without a crossover; ``nan``
        when unstable.
    gain_margin : float
        Factor by which the loop gain can grow before instability: smallest ``1/|L(jw_pc)|`` > 1
        over the phase crossovers (``L`` on the negative real axis); ``inf`` if none; ``nan`` when
        unstable. Phase crossovers with ``|L| < 1e-3`` are not resolved.
    gain_margin_lower : float
        Factor by which it can shrink (largest ``1/|L|`` < 1; 0 if none; ``nan`` when unstable).
        A value above 0 makes the loop *conditionally stable* (:attr:`conditionally_stable`).
    crossover_rad_s : float
        The critical gain-crossover frequency, which sets the phase margin (rad/s); ``nan`` if
        none.
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

    @property
    def critical_crossover(self) -> int | None:
        """Index into ``crossovers_rad_s`` of the critical crossover (None without one)."""
        if not self.crossovers_rad_s:
            return None
        return int(np.argmin(np.abs(self.phase_margins_deg)))

    @property
    def conditionally_stable(self) -> bool:
        """Stable, and unstable again if the loop gain shrinks enough: a lower gain margin
        exists (``0 < gain_margin_lower < 1``)."""
        return bool(self.stable and 0.0 < self.gain_margin_lower < 1.0)

    def crossover_lines(self) -> list[str]:
        """One line per gain crossover with its phase margin, the critical one marked."""
        k = self.critical_crossover
        return [
            f"gain crossover {w:.4g} rad/s: phase margin {pm:+.2f} deg"
            + (" (critical: closest to -1)" if i == k else "")
            for i, (w, pm) in enumerate(
                zip(self.crossovers_rad_s, self.phase_margins_deg, strict=True)
            )
        ]

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
        n = len(self.crossovers_rad_s)
        several = f" (critical of {n} gain crossovers)" if n > 1 else ""
        lower = (
            f", lower GM {self.gain_margin_lower:.4g} (conditionally stable)"
            if self.conditionally_stable else ""
        )
        return (
            f"stable: PM {self.phase_margin_deg:.2f} deg at {self.crossover_rad_s:.4g} rad/s"
            f"{several}, GM {self.gain_margin:.4g}{lower}, delay margin "
            f"{self.delay_margin_s * 1e3:.3f} ms, "
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
            "gain_margin_lower": self.gain_margin_lower,
            "n_crossovers": len(self.crossovers_rad_s),
            "conditionally_stable": self.conditionally_stable,
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
    # An integrator makes L(0) infinite; evaluated at z = 1 it comes out as a huge rounding
    # residue, which is a pole, not a phase crossover: |L(0)| above 1/_SMALL_GAIN is not one.
    finite = np.isfinite(v0) and abs(v0) <= 1.0 / _SMALL_GAIN
    if finite and v0.real < 0 and abs(v0.imag) <= 1e-12 * abs(v0):
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
    # A grid point exactly on the negative real axis (no sign change to bracket).
    on_axis = (im == 0.0) & (Lw.real < 0) & (w > 0) & (mag >= _SMALL_GAIN)
    for i in np.nonzero(on_axis)[0]:
        wpc.append(float(w[i]))
        gpc.append(float(mag[i]))
    order = np.argsort(wpc)
    return _Crossings(
        tuple(wc), pm, tuple(wpc[i] for i in order), tuple(gpc[i] for i in order)
    )


def _margins_from_crossings(cr: _Crossings) -> tuple[float, float, float, float, float, float]:
    """(pm_deg, wc, gm, wpc, gm_lower, delay_margin_s) from the crossings of a stable loop."""
    if cr.wc:
        k = int(np.argmin(np.abs(cr.pm)))  # the critical crossover: L closest to -1
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


def margins_from_crossings(
    cr: _Crossings,
    *,
    stable: bool,
    unstable_poles: int,
    delay_s: float,
    formulation: str,
    confirmation: str,
    delay_margin_s: float | None = None,
    jitter: tuple[float, float] = (math.nan, math.nan),
    notes: tuple[str, ...] = (),
) -> Margins:
    """The :class:`Margins` of a loop (``stable`` or not, with ``unstable_poles`` closed-loop
    poles) from its crossings: phase, gain and delay margins of the crossings
    (``delay_margin_s`` in place of theirs when the formulation finds it otherwise), ``jitter``
    = (margin s, frequency rad/s) when it has one. An unstable loop reports ``nan`` margins and
    its critical crossover."""
    if stable:
        pm_deg, wc, gm, wpc, gm_lower, dm = _margins_from_crossings(cr)
        dm = dm if delay_margin_s is None else delay_margin_s
        jm, wj = jitter
    else:
        pm_deg = gm = gm_lower = dm = wpc = jm = wj = math.nan
        wc = cr.wc[int(np.argmin(np.abs(cr.pm)))] if cr.wc else math.nan
    return Margins(
        stable=stable,
        unstable_poles=unstable_poles,
        phase_margin_deg=pm_deg,
        gain_margin=gm,
        gain_margin_lower=gm_lower,
        crossover_rad_s=wc,
        phase_crossover_rad_s=wpc,
        delay_margin_s=dm,
        delay_s=delay_s,
        jitter_margin_s=jm,
        jitter_frequency_rad_s=wj,
        crossovers_rad_s=cr.wc,
        phase_margins_deg=tuple(math.degrees(p) for p in cr.pm),
        phase_crossovers_rad_s=cr.wpc,
        phase_crossover_gains=cr.gpc,
        formulation=formulation,
        confirmation=confirmation,
        notes=notes,
    )
