"""One validated object per closed-loop scenario, loadable from YAML, and the code that runs it.

A ``Scenario`` holds everything a run needs: the plant, the camera pipeline and its latency, the
front end (measurement model or rendered images), the observer, the controller, the reference,
the duration and the seed. ``build_loop`` turns it into a ``latency.loop.ClosedLoop``;
``run_summary`` runs a scenario given as a dict and returns its summary metrics (the sweep
runner's run function).

Wrong fields or values fail at load time with a message that names the field and the allowed
range (pydantic).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field

from controller.mpc import MPCConfig, MPCController
from controller.pid import PIDConfig, PIDController
from controller.reference import Cone, Ramp, RandomSmooth, SeedSteps, Steps, pure_tilt
from latency.frontends import ImageFrontEnd, MeasurementConfig, MeasurementFrontEnd
from latency.loop import ClosedLoop, LoopConfig, LoopResult
from latency.models import Constant, LatencyModel
from latency.pipeline import PipelineConfig
from observer.aekf import AEKFConfig
from observer.cor_model import CorModel
from observer.cor_solver import CorSolver
from observer.gk.pixel_kalman import PixelKalmanConfig
from observer.pixel_observer import FilterObserver, PixelKalmanObserver, SolverObserver
from plant.params import PlantParams


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class PIDSpec(_Model):
    kind: Literal["pid"] = "pid"
    config: PIDConfig = PIDConfig()


class MPCSpec(_Model):
    kind: Literal["mpc"] = "mpc"
    config: MPCConfig = MPCConfig()


ControllerSpec = Annotated[PIDSpec | MPCSpec, Field(discriminator="kind")]


class ObserverSpec(_Model):
    """The attitude back end: ``aekf``/``ekf`` (quaternion filter, optionally predicting across
    the latency), ``solver`` (per-frame least squares), or ``pixel_kalman`` (the seed's pixel
    Kalman filter on each marker, then the solver)."""

    kind: Literal["aekf", "ekf", "solver", "pixel_kalman"] = "aekf"
    compensate_delay: bool = Field(True, description="aekf/ekf: predict to the release time.")
    aekf: AEKFConfig = AEKFConfig()
    pixel_q_scale: float = Field(
        0.01, gt=0.0, description="pixel_kalman: Q = q·I4; seed 000 §3.2.1: 0.01."
    )
    pixel_r_scale: float = Field(
        0.1, gt=0.0, description="pixel_kalman: R = r·I2; seed 000 §3.2.1: 0.1."
    )


class TiltStepSpec(_Model):
    """A pure tilt step (no turn about the shaft) at ``t_step_s``."""

    kind: Literal["tilt_step"] = "tilt_step"
    tilt_deg: float = Field(5.0, ge=0.0, le=15.0)
    azimuth_deg: float = 30.0
    t_step_s: float = Field(0.1, ge=0.0)

    def build(self) -> Steps:
        q1 = pure_tilt(np.deg2rad(self.tilt_deg), np.deg2rad(self.azimuth_deg))
        return Steps(times_s=(0.0, self.t_step_s), attitudes=((1.0, 0.0, 0.0, 0.0), tuple(q1)))


class RefSpec(_Model):
    """Any generator of ``controller.reference`` by name, with its fields in ``args``."""

    kind: Literal["seed_steps", "ramp", "cone", "random"]
    args: dict = Field(default_factory=dict)

    def build(self):
        cls = {"seed_steps": SeedSteps, "ramp": Ramp, "cone": Cone, "random": RandomSmooth}
        return cls[self.kind](**self.args)


ReferenceSpec = Annotated[TiltStepSpec | RefSpec, Field(discriminator="kind")]


class Scenario(_Model):
    """A closed-loop scenario. Defaults: GK-TransT's seed latency, measurement model, AEKF with
    delay compensation, PID, a 5° tilt step."""

    name: str = "scenario"
    duration_s: float = Field(2.0, gt=0.0, le=3600.0)
    seed: int = 0
    mode: Literal["measurement", "image"] = "measurement"
    renderer: Literal["analytic", "mujoco"] = "analytic"
    plant: PlantParams = PlantParams()
    pipeline: PipelineConfig = PipelineConfig()
    measurement: MeasurementConfig = MeasurementConfig()
    observer: ObserverSpec = ObserverSpec()
    controller: ControllerSpec = PIDSpec()
    reference: ReferenceSpec = TiltStepSpec()
    on_invalid: Literal["zero", "hold"] = "hold"
    controller_latency: LatencyModel | Literal["measured"] = Field(
        default_factory=lambda: Constant(value_s=0.0),
        description="Controller compute latency in the loop; 'measured' uses the wall clock.",
    )

    @classmethod
    def from_yaml(cls, path: str | Path) -> Scenario:
        """Load a scenario file; missing fields keep their defaults."""
        with open(path) as fh:
            return cls.model_validate(yaml.safe_load(fh) or {})


def build_loop(s: Scenario) -> ClosedLoop:
    """The closed loop of a scenario."""
    p = s.plant
    rng = np.random.default_rng([s.seed, 1])
    if s.mode == "measurement":
        front = MeasurementFrontEnd(p, s.measurement, rng)
    else:
        if s.renderer == "analytic":
            from plant.render_analytic import AnalyticRenderer

            renderer = AnalyticRenderer(p, seed=s.seed)
        else:
            from plant.render_mujoco import MujocoRenderer

            renderer = MujocoRenderer(p)
        front = ImageFrontEnd(p, renderer)
    o = s.observer
    if o.kind in ("aekf", "ekf"):
        cfg = o.aekf.model_copy(update={"adaptive": o.kind == "aekf"})
        observer = FilterObserver(p, cfg, compensate_delay=o.compensate_delay)
    else:
        solver = CorSolver(CorModel.nominal(p))
        if o.kind == "solver":
            observer = SolverObserver(solver)
        else:
            pk = PixelKalmanConfig(
                Q=(o.pixel_q_scale * np.eye(4)).tolist(), R=(o.pixel_r_scale * np.eye(2)).tolist()
            )
            observer = PixelKalmanObserver(solver, pk)
    if isinstance(s.controller, PIDSpec):
        controller = PIDController(s.controller.config, p)
    else:
        mpc = s.controller.config
        if mpc.compute_latency_s is None and s.controller_latency != "measured":
            # The MPC's delay compensation must assume the latency the loop applies.
            mpc = mpc.model_copy(update={"compute_latency_s": s.controller_latency.mean_s})
        controller = MPCController(mpc, p)
    config = LoopConfig(
        duration_s=s.duration_s,
        pipeline=s.pipeline,
        seed=s.seed,
        on_invalid=s.on_invalid,
        controller_latency=s.controller_latency,
    )
    return ClosedLoop(p, controller, s.reference.build(), front, observer, config)


def run(s: Scenario, progress: bool = False) -> LoopResult:
    """Run a scenario."""
    return build_loop(s).run(progress=progress)


def run_summary(config: dict) -> dict:
    """Sweep entry point: run the scenario given as a dict, return its summary metrics."""
    return run(Scenario.model_validate(config)).summary
