"""The steady-state constant-velocity pixel Kalman filter as a linear system, and the loop
margins with it in the loop (``experiments.tuning``)."""

from __future__ import annotations

from functools import lru_cache
from typing import Literal

import control as ct
import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from controller.pid import PIDController
from controller.registry import PIDSpec
from experiments.tuning.objective import TuningObjective, _ratio
from latency import Scenario
from latency.margins import Margins, attitude_plant, loop_margins, loop_model, sampled_margins
from latency.pipeline import FrameScheduler, PipelineConfig
from observer.gk.pixel_kalman import F_CV_AXIS, H_CV_AXIS

# --------------------------------------------------------------------------------------------
# The steady-state filter and the loop margins
# --------------------------------------------------------------------------------------------


def kalman_steady_state(q: float, r: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Steady-state gain and prior covariance of the CV pixel Kalman filter, per coordinate.

    With ``Q = q·I4``, ``R = r·I2`` the filter of (u, v, u̇, v̇) splits into two identical
    filters of (u, u̇) with ``F = [[1, 1], [0, 1]]``, ``H = [1, 0]``, ``Q1 = q·I2``, ``R1 = r``.
    The prior covariance solves the filter Riccati equation
    ``P = F P Fᵀ − F P Hᵀ (H P Hᵀ + R1)⁻¹ H P Fᵀ + Q1`` (``scipy.linalg.solve_discrete_are`` on
    the dual pair ``(Fᵀ, Hᵀ)``), and ``K = P Hᵀ (H P Hᵀ + R1)⁻¹``.

    Parameters
    ----------
    q : process-noise scale, sensor px² (position) and (sensor px/frame)² (velocity).
    r : measurement-noise variance, sensor px².

    Returns
    -------
    K : (2, 1) gain, dimensionless and 1/frame.
    P : (2, 2) steady-state prior covariance, sensor px units.
    """
    if not (q > 0 and r > 0 and np.isfinite(q) and np.isfinite(r)):
        raise ValueError(f"q and r must be finite and > 0, got q={q}, r={r}")
    P = scipy.linalg.solve_discrete_are(F_CV_AXIS.T, H_CV_AXIS.T, q * np.eye(2), np.array([[r]]))
    K = P @ H_CV_AXIS.T / (H_CV_AXIS @ P @ H_CV_AXIS.T + r)
    return K, P


def kalman_filter_ss(q: float, r: float, dt_s: float) -> ct.StateSpace:
    """The steady-state CV pixel Kalman filter as a discrete system at ``dt_s`` (s, one
    processed frame): input the measured pixel coordinate, output the filtered (posterior)
    one, both sensor px. ``x_k = A x_{k-1} + K z_k`` with ``A = (I − K H) F`` and output
    ``H x_k``, so ``y_k = H A x_{k-1} + H K z_k``."""
    K, _ = kalman_steady_state(q, r)
    A = (np.eye(2) - K @ H_CV_AXIS) @ F_CV_AXIS
    return ct.ss(A, K, H_CV_AXIS @ A, H_CV_AXIS @ K, dt_s)


def kalman_transfer_function(q: float, r: float, dt_s: float) -> ct.TransferFunction:
    """Transfer function ``F(z)`` from measured to filtered pixel of the steady-state filter
    (``kalman_filter_ss``) at ``dt_s`` (s). Unit DC gain; it also passes ramps without a
    steady-state error (constant-velocity model)."""
    return ct.tf(kalman_filter_ss(q, r, dt_s))


def filter_noise_gain(q: float, r: float) -> float:
    """RMS of the filtered pixel per unit RMS of white measurement noise (dimensionless):
    ``sqrt(Σ h_k²)`` of the filter's impulse response, from the discrete Lyapunov equation."""
    sys = kalman_filter_ss(q, r, 1.0)
    A, B, C, D = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (sys.A, sys.B, sys.C, sys.D))
    W = scipy.linalg.solve_discrete_lyapunov(A, B @ B.T)
    return float(np.sqrt((D @ D.T + C @ W @ C.T)[0, 0]))


def processed_frame_period(pipeline: PipelineConfig, n_frames: int = 64) -> float:
    """Median interval (s) between the exposures of frames the observer processes (the rate
    at which the filter and the controller run): the frame period, or a multiple of it when a
    sequential observer drops frames. Latency drawn from the pipeline's model (seeded)."""
    sched = FrameScheduler(pipeline, np.random.default_rng(0))
    t = [f.t_exposure for f in (sched.next_frame() for _ in range(n_frames)) if not f.dropped]
    if len(t) < 2:
        raise ValueError("fewer than two processed frames: cannot tell the update period")
    return float(np.median(np.diff(t)))


def filter_loop_margins(
    objective: TuningObjective,
    q: float,
    r: float,
    *,
    axis: int = 1,
    formulation: Literal["sampled", "hybrid"] = "sampled",
) -> tuple[Margins, dict[str, float]]:
    """Margins of the per-axis attitude loop with the steady-state pixel filter of (q, r).

    ``L = C(z) F(z) P_d(z; tau)``: the PID's discrete transfer function
    (``PIDController.discrete_transfer_function``) and the filter ``F(z)``
    (``kalman_transfer_function``), both at the processed-frame period ``T``, on
    ``P = 1/(J s² + b s)`` (J about body ``axis``, b the rotor's viscous damping) with the
    total delay ``tau = exposure/2 + readout + objective.delay_s`` (mid-exposure to release,
    from the pipeline's ``latency.pipeline.loop_timing``; the controller latency is taken as
    zero, as in the objective's scenario). Small-signal: the
    attitude solver maps the filtered pixels linearly to the angle, so the pixel filter acts on
    the angle with the same ``F(z)``.

    Returns the ``Margins`` and a dict with ``period_s``, ``delay_total_s``,
    ``filter_lag_deg`` (phase lag of F at the crossover, deg) and ``noise_gain``.
    """
    scen = Scenario.model_validate(
        objective.scenario_dict(q, r, objective.seeds[0], objective.references[0])
    )
    if not isinstance(scen.controller, PIDSpec):
        raise ValueError("filter_loop_margins needs a PID controller")
    p = scen.plant
    T = processed_frame_period(scen.pipeline)
    tau = scen.pipeline.timing(vision_delay_s=objective.delay_s).delay_s
    pid = PIDController(scen.controller.config, p)
    C = pid.discrete_transfer_function(T, axis=axis)
    Fz = kalman_transfer_function(q, r, T)
    plant = attitude_plant(float(pid.J[axis]), p.rotor.viscous_Nms_per_rad)
    if formulation == "sampled":
        m = sampled_margins(plant, C, delay_s=tau, observer=Fz)
    else:
        m = loop_margins(loop_model(plant, C, delay_s=tau, sample_period_s=T, observer=Fz))
    lag = float("nan")
    if np.isfinite(m.crossover_rad_s):
        zc = np.exp(1j * m.crossover_rad_s * T)
        num, den = np.asarray(Fz.num[0][0], float), np.asarray(Fz.den[0][0], float)
        lag = -float(np.degrees(np.angle(np.polyval(num, zc) / np.polyval(den, zc))))
    extra = {
        "period_s": T,
        "delay_total_s": tau,
        "filter_lag_deg": lag,
        "noise_gain": filter_noise_gain(q, r),
    }
    return m, extra


def margin_columns(objective: TuningObjective, q: float, r: float) -> dict[str, float]:
    """``filter_loop_margins`` as flat table columns (ms, Hz, deg).

    Cached per objective and ``q/r``: the steady-state filter depends on the ratio only
    (module docstring), so the points on a diagonal of a log-grid share one computation."""
    return dict(_margin_columns(objective.model_dump_json(), _ratio(q, r)))


@lru_cache(maxsize=4096)
def _margin_columns(objective_json: str, ratio: float) -> tuple[tuple[str, float], ...]:
    objective = TuningObjective.model_validate_json(objective_json)
    m, x = filter_loop_margins(objective, ratio, 1.0)
    return tuple(
        {
            "stable": bool(m.stable),
            "phase_margin_deg": m.phase_margin_deg,
            "delay_margin_ms": m.delay_margin_s * 1e3,
            "gain_margin": m.gain_margin,
            "crossover_hz": m.crossover_rad_s / (2 * np.pi),
            "filter_lag_deg": x["filter_lag_deg"],
            "noise_gain": x["noise_gain"],
            "update_period_ms": x["period_s"] * 1e3,
            "loop_delay_ms": x["delay_total_s"] * 1e3,
        }.items()
    )
