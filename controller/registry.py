"""The controller and reference families: every controller and reference generator a scenario
can name, with its settings (pydantic) and its builder (``plant.registry``).

Controllers (``CONTROLLERS``): ``pid`` and ``mpc``; a scenario's ``controller`` is one of
``ControllerSpec``. References (``REFERENCES``): ``tilt_step`` and the generators of
``controller.reference`` by name (``seed_steps``, ``ramp``, ``cone``, ``random``, their fields in
``args``); a scenario's ``reference`` is one of ``ReferenceSpec``.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from controller.base import Controller, Reference
from controller.mpc import MPCConfig, MPCController
from controller.pid import PIDConfig, PIDController
from controller.reference import Cone, Ramp, RandomSmooth, SeedSteps, Steps, pure_tilt
from plant.params import PlantParams
from plant.registry import Registry


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class PIDSpec(_Model):
    """The PID on the SO(3) attitude error (``controller.pid``), its settings in ``config``."""

    kind: Literal["pid"] = "pid"
    config: PIDConfig = PIDConfig()


class MPCSpec(_Model):
    """The MPC (``controller.mpc``), its settings in ``config``."""

    kind: Literal["mpc"] = "mpc"
    config: MPCConfig = MPCConfig()


ControllerSpec = Annotated[PIDSpec | MPCSpec, Field(discriminator="kind")]


def _build_pid(spec: PIDSpec, plant: PlantParams, clock: Callable[[], float],
               latency_s: float | None) -> Controller:
    """The PID of ``spec`` (it does not predict across its latency: ``latency_s`` unused)."""
    return PIDController(spec.config, plant, clock)


def _build_mpc(spec: MPCSpec, plant: PlantParams, clock: Callable[[], float],
               latency_s: float | None) -> Controller:
    """The MPC of ``spec``; its delay compensation assumes the loop's controller latency
    ``latency_s`` (s, None when measured) unless ``config.compute_latency_s`` sets one."""
    mpc = spec.config
    if mpc.compute_latency_s is None and latency_s is not None:
        mpc = mpc.model_copy(update={"compute_latency_s": latency_s})
    return MPCController(mpc, plant, clock)


CONTROLLERS = Registry(
    "controller",
    "the attitude law: estimate and reference in, stator-frame torque (N·m) out",
    "(spec, plant, clock, latency_s) -> controller.base.Controller",
    "controller: {kind: NAME, config: {...}}",
)
CONTROLLERS.register("pid", "PID on the SO(3) attitude error, tuned to a crossover (seed 000 "
                     "§4)", _build_pid, PIDSpec)
CONTROLLERS.register("mpc", "model-predictive control over the rigid rotor, predicting across "
                     "its latency (CasADi)", _build_mpc, MPCSpec)


def build_controller(spec: PIDSpec | MPCSpec, plant: PlantParams, clock: Callable[[], float],
                     latency_s: float | None) -> Controller:
    """The controller of ``spec`` (``CONTROLLERS``), timed by ``clock``; ``latency_s`` is the
    loop's controller latency (s, None when measured per call)."""
    return CONTROLLERS.get(spec.kind).build(spec, plant, clock, latency_s)


class TiltStepSpec(_Model):
    """A pure tilt step (no turn about the shaft) at ``t_step_s``."""

    kind: Literal["tilt_step"] = "tilt_step"
    tilt_deg: float = Field(5.0, ge=0.0, le=15.0, description="Step size, deg (our choice).")
    azimuth_deg: float = Field(30.0, description="Direction of the tilt, deg (our choice).")
    t_step_s: float = Field(0.1, ge=0.0, description="Time of the step, s (our choice).")
    step_metrics: bool = Field(
        True, description="Measure the step (overshoot, settling time, steady-state error; "
        "latency.metrics). Our choice: on."
    )

    @property
    def measures_steps(self) -> bool:
        """Whether the run's summary measures the step (``LoopConfig.step_metrics``)."""
        return self.step_metrics

    @property
    def start_s(self) -> float:
        """When the reference first moves, s."""
        return self.t_step_s

    def build(self) -> Reference:
        """The step as a ``controller.reference.Steps``."""
        q1 = pure_tilt(np.deg2rad(self.tilt_deg), np.deg2rad(self.azimuth_deg))
        return Steps(times_s=(0.0, self.t_step_s), attitudes=((1.0, 0.0, 0.0, 0.0), tuple(q1)))


#: The generators ``RefSpec`` names, by kind.
GENERATORS: dict[str, type[BaseModel]] = {
    "seed_steps": SeedSteps, "ramp": Ramp, "cone": Cone, "random": RandomSmooth,
}
#: The piecewise-constant generators of ``RefSpec`` (the others are smooth).
STEP_KINDS = ("seed_steps",)


@functools.lru_cache(maxsize=64)
def _built_reference(kind: str, args_json: str) -> Reference:
    """The generator ``kind`` with the fields ``args_json``, built once per process: the
    generators are immutable, and a sweep validates and builds the same reference for every
    seed (RandomSmooth scales its shape on a 16,384-point grid, ~20 ms)."""
    return GENERATORS[kind].model_validate(json.loads(args_json))  # type: ignore[return-value]


class RefSpec(_Model):
    """Any generator of ``controller.reference`` by name, with its fields in ``args``."""

    kind: Literal["seed_steps", "ramp", "cone", "random"]
    args: dict = Field(default_factory=dict, description="The generator's fields "
                       "(pmspm parts reference lists them).")
    step_metrics: bool | None = Field(
        None,
        description="Measure the step after the reference's last change (overshoot, settling "
        "time, steady-state error). None: on for the piecewise-constant seed_steps, off for "
        "the smooth kinds (ramp, cone, random), which have no step; true on a smooth kind is "
        "an error.",
    )

    def build(self) -> Reference:
        """The generator, built once per process for equal fields."""
        return _built_reference(self.kind, json.dumps(self.args, sort_keys=True))

    @property
    def start_s(self) -> float:
        """When the reference first moves, s (its ``t_start_s``, default 0)."""
        return float(self.args.get("t_start_s", 0.0))

    @model_validator(mode="after")
    def _steps_to_measure(self) -> RefSpec:
        if self.step_metrics and self.kind not in STEP_KINDS:
            raise ValueError(
                f"reference {self.kind!r}: step_metrics needs a piecewise-constant reference "
                f"({', '.join(('tilt_step', *STEP_KINDS))}); a {self.kind} reference changes "
                "continuously and has no step to measure overshoot, settling time or "
                "steady-state error against (its RMS and maximum error, lost frames and loss "
                "of control are always reported); leave step_metrics out"
            )
        return self

    @property
    def measures_steps(self) -> bool:
        """Whether the run's summary measures the step (``LoopConfig.step_metrics``)."""
        return self.kind in STEP_KINDS if self.step_metrics is None else self.step_metrics

    @model_validator(mode="after")
    def _args_build(self) -> RefSpec:
        """Wrong or missing ``args`` fail here, naming the generator's field."""
        try:
            self.build()
        except ValidationError as exc:
            problems = "; ".join(
                (f"args.{'.'.join(str(p) for p in e['loc'])}: " if e["loc"] else "")
                + e["msg"].removeprefix("Value error, ")
                for e in exc.errors()
            )
            raise ValueError(f"reference {self.kind!r}: {problems}") from None
        return self


ReferenceSpec = Annotated[TiltStepSpec | RefSpec, Field(discriminator="kind")]


def _build_reference(spec: TiltStepSpec | RefSpec) -> Reference:
    """The reference generator of ``spec``."""
    return spec.build()


REFERENCES = Registry(
    "reference",
    "the attitude the loop follows, as a function of time",
    "(spec) -> controller.base.Reference",
    "reference: {kind: tilt_step, ...} or {kind: NAME, args: {...}}",
)
REFERENCES.register("tilt_step", "a pure tilt step at t_step_s", _build_reference, TiltStepSpec)
_SUMMARIES = {
    "seed_steps": "the step protocol of seed 000 §5: single-axis steps with a dwell after each",
    "ramp": "the Z-Y-Z angles move linearly between two attitudes over duration_s",
    "cone": "yaw sweeping at a set rate at a fixed tilt",
    "random": "a seeded, smooth, periodic random trajectory with a set peak rate (our "
              "construction)",
}
for _kind, _cls in GENERATORS.items():
    REFERENCES.register(_kind, _SUMMARIES[_kind], _build_reference, _cls, prefix="args.")
