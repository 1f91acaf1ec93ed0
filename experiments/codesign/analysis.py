"""The exact analysis of a design: the per-axis loop as it runs, with its exact delay.

For the PID the loop is ``L = C(z) F(z) P_d(z; τ)`` (``latency.margins.as_run_margins``): the
discrete PID at the processed-frame period ``T`` of the design's pipeline, the steady-state
pixel Kalman filter ``F(z)`` when the observer is the pixel filter
(``experiments.tuning.filter.kalman_transfer_function``; the least-squares solver and the AEKF
enter as ``F = 1``), on ``P = 1/(J s² + b s)`` about body axis 1 with the loop's delay
``τ = exposure/2 + readout + tracker latency + controller compute`` (``latency.pipeline``).
For the MPC, its linearised delay-aware law (``latency.mpc_law``) on the same plant.

Two figures constrain a design (docs/codesign.md):

* the **critical phase margin** (deg), at the gain crossover where ``L`` comes closest to -1;
* the **delay headroom** (s): the extra tracker latency the loop tolerates before it becomes
  unstable, scanned through the pipeline (a sequential observer's update period grows with
  its latency), as the study computes it.

The AEKF's prediction across the delay is not in this model: its margins are those of the
uncompensated loop.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import control as ct

from controller.mpc_config import MPCConfig
from controller.pid import PIDConfig, PIDController
from experiments.codesign.space import Design, compute_per_frame_s, plant_of, tracker_of
from experiments.codesign.spec import CodesignSpec
from experiments.tuning.filter import kalman_transfer_function
from latency.margins import attitude_plant, first_unstable_delay
from latency.margins.sampled import sampled_margins, sampled_spectral_radius, sampled_stable
from latency.mpc_law import mpc_discrete_law, mpc_state_gain
from latency.pipeline import LoopTiming, PipelineConfig

#: Largest extra delay scanned for the headroom, s (our choice: far beyond any constraint);
#: a design that tolerates more reports this.
HEADROOM_LIMIT_S = 0.05
#: Scan step of the headroom before bisection to ``HEADROOM_TOL_S``, s (our choice: each step
#: is an eigenvalue problem whose size grows with the delay in frames; an unstable pocket
#: narrower than a step between two stable steps would be missed).
HEADROOM_STEP_S = 2.5e-3
HEADROOM_TOL_S = 0.1e-3
#: Body axis analysed (1: the tilt axis about y, as the study's margins).
AXIS = 1


@dataclass(frozen=True)
class Analysis:
    """The analysis of one design.

    Attributes
    ----------
    stable : the nominal loop is stable.
    phase_margin_deg : critical phase margin, deg (NaN when unstable).
    headroom_s : extra tracker latency before instability, s (0 when unstable; capped at
        ``HEADROOM_LIMIT_S``).
    crossover_rad_s : critical gain crossover, rad/s.
    update_period_s, delay_s : the processed-frame period and the loop delay, s.
    growth_rate_per_s : ``ln(ρ) / T`` of the closed loop's spectral radius ``ρ`` at the update
        period ``T``, 1/s: how fast its slowest-decaying mode grows (> 0, unstable) or decays
        (< 0) in the linear model.
    """

    stable: bool
    phase_margin_deg: float
    headroom_s: float
    crossover_rad_s: float
    update_period_s: float
    delay_s: float
    growth_rate_per_s: float

    def meets(self, spec: CodesignSpec) -> bool:
        """The analysis constraints of ``spec`` hold (design requirements: a design that fails
        them is infeasible, whatever its Monte Carlo)."""
        c = spec.constraints
        return (self.stable and self.phase_margin_deg >= c.min_phase_margin_deg
                and self.headroom_s * 1e3 >= c.min_delay_headroom_ms)

    def prunable(self, spec: CodesignSpec) -> bool:
        """The design may skip its Monte Carlo: its linear loop grows at least as fast as
        ``search.prune_growth_rate_per_s``. Narrower than failing ``meets``: a loop that is
        stable with a small margin, or unstable but growing slowly, stays in control in the
        simulation (Coulomb friction damps a small oscillation, saturation bounds it), so
        only the Monte Carlo can tell whether it loses control."""
        limit = spec.search.prune_growth_rate_per_s
        return limit is not None and self.growth_rate_per_s >= limit


def _controller_law(spec: CodesignSpec, design: Design):
    """``law(timing) -> (C(z), F(z) or None)`` of the design's controller and observer."""
    params = plant_of(spec, design)
    if design.controller == "pid":
        pid = PIDController(PIDConfig(crossover_rad_s=design.crossover_rad_s,
                                      zero_ratio=design.zero_ratio,
                                      integral_ratio=design.integral_ratio), params)

        def law(t: LoopTiming) -> tuple[ct.LTI, ct.LTI | None]:
            C = pid.discrete_transfer_function(t.update_period_s, axis=AXIS)
            F = (kalman_transfer_function(design.q_scale, design.r_scale, t.update_period_s)
                 if design.observer == "pixel_kalman" else None)
            return C, F

        return law, float(pid.J[AXIS])
    mpc = MPCConfig(horizon_steps=design.mpc_horizon_steps,
                    bandwidth_rad_s=design.mpc_bandwidth_rad_s)
    K = mpc_state_gain(mpc, params)
    J = float(params.rotor.inertia_about_centre_kgm2[AXIS, AXIS])
    b = params.rotor.viscous_Nms_per_rad

    def mpc_law(t: LoopTiming) -> tuple[ct.LTI, ct.LTI | None]:
        C = mpc_discrete_law((K[AXIS, AXIS], K[AXIS, 3 + AXIS]), inertia_kgm2=J,
                             damping_Nms_per_rad=b, period_s=t.update_period_s,
                             delay_s=t.delay_s)
        return C, None

    return mpc_law, J


def analyse(spec: CodesignSpec, design: Design) -> Analysis:
    """Critical phase margin and delay headroom of ``design`` (module docstring)."""
    params = plant_of(spec, design)
    mode = design.camera_mode(spec)
    latency_s = tracker_of(spec, design).latency_model().mean_s
    compute_s = compute_per_frame_s(spec, design) - latency_s  # the controller's part
    pipe = PipelineConfig.from_camera(params.camera, mode=design.pipeline,
                                      readout_s=mode.readout_s)
    law, J = _controller_law(spec, design)
    plant = attitude_plant(J, params.rotor.viscous_Nms_per_rad)

    def timing(d: float) -> LoopTiming:
        return pipe.timing(compute_s, vision_delay_s=d)

    @functools.cache
    def stable_at(d: float) -> bool:
        t = timing(d)
        C, F = law(t)
        return sampled_stable(plant, C, delay_s=t.delay_s, observer=F)

    t0 = timing(latency_s)
    C, F = law(t0)
    # The exact sampled loop (as ``as_run_margins``); its own constant-delay scan is skipped,
    # the headroom below scans the delay through the pipeline instead.
    m = sampled_margins(plant, C, delay_s=t0.delay_s, observer=F, max_extra_delay_s=0.0)
    rho = sampled_spectral_radius(plant, C, delay_s=t0.delay_s, observer=F)
    first = first_unstable_delay(stable_at, latency_s, step_s=HEADROOM_STEP_S,
                                 limit_s=latency_s + HEADROOM_LIMIT_S, tol_s=HEADROOM_TOL_S)
    headroom = 0.0 if not m.stable else min(first - latency_s, HEADROOM_LIMIT_S)
    return Analysis(
        stable=bool(m.stable),
        phase_margin_deg=float(m.phase_margin_deg) if m.stable else math.nan,
        headroom_s=float(headroom),
        crossover_rad_s=float(m.crossover_rad_s),
        update_period_s=t0.update_period_s,
        delay_s=t0.delay_s,
        growth_rate_per_s=math.log(rho) / t0.update_period_s,
    )
