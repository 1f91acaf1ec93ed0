"""Margins of the hybrid exact-delay loop, confirmed by the Nyquist count, and the jitter margin
(Kao & Lincoln, Automatica 40(8), 2004); ``lti_margins`` for any python-control plant and
controller."""

from __future__ import annotations

import math
from numbers import Real

import control as ct
import numpy as np
import scipy.linalg
import scipy.optimize
from numpy.typing import ArrayLike

from latency.margins.grid import _grid
from latency.margins.model import LoopModel, loop_model
from latency.margins.nyquist import nyquist_count
from latency.margins.result import Margins, _crossings, _scalar, margins_from_crossings


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
    w = (_grid(model.response, model.features_rad_s) if omega is None
         else np.asarray(omega, dtype=float))
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
    return margins_from_crossings(
        cr, stable=stable, unstable_poles=max(Z, 0), delay_s=model.delay_s, formulation=formulation,
        confirmation=conf, jitter=jitter_margin(model, w) if stable else (math.nan, math.nan),
        notes=tuple(notes),
    )


def lti_margins(
    plant: ct.LTI,
    controller: ct.LTI | float,
    *,
    delay_s: float = 0.0,
    sample_period_s: float | None = None,
) -> Margins:
    """Gain, phase and delay margins of any python-control loop with an exact delay.

    The loop is ``L(s) = C(s) H_T(s) P(s) e^{-s tau}`` in the negative-feedback convention
    ``u = -C y`` (:func:`loop_model`): ``P`` any continuous SISO python-control LTI system,
    ``C`` one too (continuous, or discrete, then evaluated at ``z = e^{sT}``) or a float (a
    gain), ``tau`` the exact delay (never a Padé approximation; ``control.margin`` has no
    delay), and ``H_T`` the zero-order hold at ``sample_period_s`` (default: a discrete
    controller's sample time; None with a continuous one: no hold). The margins come from
    :func:`loop_margins`: every gain and phase crossover, the critical phase margin, the gain
    margin, the delay margin (the extra constant delay the loop tolerates, so ``delay_s``
    lowers it one for one) and the jitter margin, with the Nyquist count on the exact-delay
    response as the stability verdict.

    Parameters
    ----------
    plant : LTI
        Continuous-time SISO plant (transfer function, state space, ...).
    controller : LTI or float
        SISO controller, or a gain.
    delay_s : float
        Constant loop delay (s), >= 0.
    sample_period_s : float, optional
        Period of the sample-and-hold (s), > 0.

    Returns
    -------
    Margins

    Raises
    ------
    ValueError
        Naming the argument: a plant or controller that is not a python-control LTI system (or,
        for the controller, a finite number), MIMO, a discrete plant, a negative delay, a
        period <= 0 or one that differs from the controller's sample time, poles on the
        imaginary axis away from the origin, or a loop that is not strictly proper.
    """
    if not isinstance(plant, ct.LTI):
        raise ValueError(f"plant must be a python-control LTI system, got {type(plant).__name__}")
    if isinstance(controller, Real) and not isinstance(controller, bool):
        if not math.isfinite(controller):
            raise ValueError(f"controller gain must be finite, got {controller}")
        controller = float(controller)
    elif not isinstance(controller, ct.LTI):
        raise ValueError("controller must be a python-control LTI system or a gain (float), "
                         f"got {type(controller).__name__}")
    return loop_margins(loop_model(plant, controller, delay_s=delay_s,
                                   sample_period_s=sample_period_s))
