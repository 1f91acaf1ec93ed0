"""The settings of the attitude MPC (``MPCConfig``; the controller is ``controller.mpc``) and
which of them the controller reads at run time (``RUNTIME_FIELDS``) rather than the
optimisation problem."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from controller.base import InvalidCommand

Solver = Literal["sqp_hpipm", "sqp_qpoases", "sqp_qrqp", "sqp_osqp", "ipopt"]


class MPCConfig(BaseModel):
    """MPC settings; an inconsistent configuration raises ``ValueError`` naming the field."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    horizon_steps: int = Field(15, ge=2, le=200, description="Our choice: N = 15.")
    step_s: float = Field(0.01, gt=0.0, le=0.1, description="Our choice: h = 10 ms (150 ms).")
    rk4_substeps: int = Field(
        1,
        ge=1,
        le=20,
        description="Our choice: one RK4 step per interval. The smooth Coulomb law has a rate "
        "~ tau_c/(J omega_s) = 136 1/s near omega = 0 (plant/params.py); RK4 is stable for "
        "h_sub < 2.78/136 s = 20 ms, and 2 sub-steps changed the closed-loop step response "
        "by less than 0.01° while doubling the Jacobian cost (docs/controllers.md).",
    )
    bandwidth_rad_s: float = Field(
        15.0,
        gt=0.0,
        description="Our choice: ω_n = 15 rad/s (loop crossover ≈ 1.7 ω_n = 25 rad/s at ζ = 0.8). "
        "At 10 rad/s Coulomb friction left a 0.08–0.17° offset after a 5° step; at 15 rad/s "
        "0.007–0.021° (docs/controllers.md).",
    )
    damping: float = Field(
        0.8, ge=0.5**0.5, description="Our choice: ζ = 0.8 (ζ >= 1/√2 keeps q_ω >= 0)."
    )
    model_coulomb_smoothing_rad_s: float | None = Field(
        0.1,
        gt=0.0,
        description="Our choice: the prediction model inside the optimisation smooths the "
        "Coulomb law over 0.1 rad/s instead of the plant's 0.01 rad/s (plant/params.py); the "
        "friction torques differ only below ~0.3 rad/s, and resting on the tilt constraint "
        "the SQP then needs 2 iterations instead of hitting the cap of 8 (docs/controllers.md)."
        " None: the plant's law. The delay compensation always uses the plant's law.",
    )
    tilt_max_deg: float = Field(
        14.5,
        gt=0.0,
        le=15.0,
        description="Our choice: 0.5° inside the 15° stop (seed 000 §2.4), room for model and "
        "estimation error so that the rotor does not touch the stop.",
    )
    tilt_slack_l1: float = Field(1.0e3, gt=0.0, description="Our choice: exact-penalty weight ρ1.")
    tilt_slack_l2: float = Field(1.0e4, ge=0.0, description="Our choice: quadratic weight ρ2.")
    torque_limit_Nm: float | None = Field(
        None, gt=0.0, description="None: margin x the worst-direction capacity (as the PID)."
    )
    torque_limit_margin: float = Field(0.95, gt=0.0, le=1.0, description="Our choice (as PID).")
    solver: Solver = Field(
        "sqp_hpipm",
        description="Chosen by measurement (docs/controllers.md): SQP with the structure-"
        "exploiting QP solver HPIPM was the fastest of IPOPT and SQP + HPIPM/qpOASES/qrqp/OSQP.",
    )
    max_iter: int = Field(
        8,
        ge=1,
        description="Our choice: SQP iteration cap per solve. Warm-started solves take 1–3; on an "
        "active tilt constraint the Gauss-Newton SQP converges linearly (halving the residual "
        "per iteration), and 8 iterations leave < 1e-5 rad of dynamics gap. 1 is the "
        "real-time iteration: measured, 0.6x the solve time but a different closed loop near "
        "the stability boundary (docs/controllers.md).",
    )
    tol_pr: float = Field(1e-5, gt=0.0, description="Our choice: primal tolerance (gap, rad).")
    tol_du: float = Field(1e-4, gt=0.0, description="Our choice: dual tolerance (cost units).")
    hessian: Literal["gauss_newton", "exact"] = Field(
        "gauss_newton",
        description="Our choice, by measurement: the exact Lagrangian Hessian took 2.1 ms per "
        "evaluation, the Gauss-Newton one 0.15 ms (docs/controllers.md).",
    )
    codegen: bool = Field(
        True,
        description="Our choice, by measurement (docs/controllers.md): the SQP's Jacobian and "
        "Gauss-Newton Hessian compiled to machine code with the system C compiler "
        "(controller.codegen: compiled once, cached on disk; 2-3 s the first time) instead of "
        "CasADi's virtual machine, and the prediction's RK4 steps; the same functions to "
        "rounding, the solve 1.6-2.7x faster. With IPOPT only the prediction is compiled; "
        "without a C compiler nothing is.",
    )
    delay_aware: bool = Field(True, description="Predict the estimate forward (module docstring).")
    reference_preview: bool = Field(
        True,
        description="Our choice: the horizon follows the reference's future (the MPC starts "
        "moving before a step). False: the reference sampled at the call time is held over the "
        "horizon with zero rate, as a controller that cannot see ahead (a fair comparison "
        "with a PID).",
    )
    compute_latency_s: float | None = Field(
        None, ge=0.0, description="None: median of the measured call durations (last 20)."
    )
    actuation_delay_s: float = Field(
        0.0, ge=0.0, description="Our choice: 0 (ideal current drive, plant/params.py)."
    )
    prediction_step_s: float = Field(
        1.0e-3, gt=0.0, description="Our choice: 1 ms, the physics step (plant/params.py)."
    )
    invalid_command: InvalidCommand = Field(
        "hold", description="Our choice: hold the last command while the estimate is invalid "
        "(controller.base: the one invalid-estimate policy)."
    )

    @model_validator(mode="after")
    def _consistent(self) -> MPCConfig:
        if self.step_s / self.rk4_substeps > 2.78 / 136.0:
            raise ValueError(
                f"rk4_substeps = {self.rk4_substeps} is too few for step_s = {self.step_s}: "
                "sub-steps above 20 ms make RK4 unstable on the Coulomb law"
            )
        if self.bandwidth_rad_s * self.step_s > 1.0:
            raise ValueError(
                f"bandwidth_rad_s = {self.bandwidth_rad_s} is too high for step_s = {self.step_s}"
                " (need bandwidth * step <= 1 for the sampled design)"
            )
        return self


#: MPCConfig fields that the controller reads at run time; every other field shapes the
#: optimisation problem (``controller.mpc_problem.MPCProblem``) and is part of its cache key.
RUNTIME_FIELDS = frozenset({"delay_aware", "reference_preview", "compute_latency_s",
                            "actuation_delay_s", "prediction_step_s", "invalid_command"})
