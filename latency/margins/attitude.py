"""The per-axis attitude loop ``P(s) = 1/(J s^2 + b s)`` and its margins against delay."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import control as ct
import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from latency.margins.hybrid import loop_margins
from latency.margins.model import loop_model
from latency.margins.result import Margins
from latency.margins.sampled import sampled_margins


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


def as_run_margins(
    controller: ct.LTI,
    *,
    inertia_kgm2: float,
    damping_Nms_per_rad: float,
    delay_s: float,
    observer: ct.LTI | None = None,
) -> Margins:
    """Margins of the per-axis loop with the controller exactly as it runs.

    ``controller`` is the discrete ``C(z)`` at its update period ``T`` (its ``dt``). Stability,
    the crossovers, the phase, gain and delay margins come from the exact sampled loop
    (:func:`sampled_margins`). The jitter margin (Kao & Lincoln) comes from the hybrid model of
    the *same* ``C(z)`` evaluated at ``z = e^{jwT}`` with the hold at ``T``
    (:func:`loop_margins`), not from a continuous ``C(s)``: a continuous controller lacks the
    phase lag of the discrete one and overstates the margin at long update periods.
    """
    if not controller.isdtime(strict=True):
        raise ValueError("controller must be discrete (the law as it runs)")
    P = attitude_plant(inertia_kgm2, damping_Nms_per_rad)
    sampled = sampled_margins(P, controller, delay_s=delay_s, observer=observer)
    if not sampled.stable:
        return sampled
    hybrid = loop_margins(loop_model(P, controller, delay_s=delay_s, observer=observer))
    jm = hybrid.jitter_margin_s if hybrid.stable else math.nan
    return dataclasses.replace(
        sampled,
        jitter_margin_s=jm,
        jitter_frequency_rad_s=hybrid.jitter_frequency_rad_s,
        formulation="sampled (jitter margin: hybrid with the same C(z))",
        notes=sampled.notes + hybrid.notes,
    )


def first_unstable_delay(
    stable_at: Callable[[float], bool],
    start_s: float,
    *,
    step_s: float = 0.5e-3,
    limit_s: float = 0.3,
    tol_s: float = 1e-6,
) -> float:
    """Smallest delay above ``start_s`` (s) at which ``stable_at`` first says unstable.

    Scans the multiples of ``step_s`` above ``start_s`` up to ``limit_s`` and bisects the first
    unstable step to ``tol_s``. ``stable_at`` may change the whole loop with the delay (e.g. the
    update period of a sequential observer, which drops frames once the delay exceeds a frame
    period), so the boundary may be a jump rather than a zero crossing; the bisection finds
    either. Returns ``inf`` if the loop is stable at every scanned delay.
    """
    if not stable_at(start_s):
        return float(start_s)
    # The scan points are whole multiples of step_s, so scans from different starts share
    # them (a caching stable_at then evaluates each once).
    prev, k = float(start_s), math.floor(start_s / step_s + 1e-9) + 1
    while k * step_s <= limit_s + 1e-15:
        x = k * step_s
        if not stable_at(x):
            lo, hi = prev, x
            while hi - lo > tol_s:
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if stable_at(mid) else (lo, mid)
            return hi
        prev, k = x, k + 1
    return math.inf
