"""One validated object per closed-loop scenario, loadable from YAML, and the code that runs it.

A ``Scenario`` holds everything a run needs: the plant, the camera pipeline and its latency, the
front end (measurement model or rendered images), the observer, the controller, the reference,
the duration and the seed. ``build_loop`` turns it into a ``latency.loop.ClosedLoop``;
``run_summary`` runs a scenario given as a dict and returns its summary metrics (the sweep
runner's run function).

Wrong fields or values fail at load time with a message that names the field and the allowed
range (pydantic), and so do combinations that cannot run (an ORB observer without rendered
frames, marker observers on the textured rotor, a measured latency without compute).

Defaults that depend on other fields are resolved at validation, so that a dumped scenario shows
what ran: the MPC's compute latency (its median call time measured here, ``MPC_CALL_MEDIAN_S``),
the textured rotor and the measured observer latency for the ORB observers.
"""

from __future__ import annotations

import functools
import json
import re
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from controller.mpc import MPCConfig, MPCController
from controller.pid import PIDConfig, PIDController
from controller.pid import reach_warnings as pid_reach_warnings
from controller.reference import Cone, Ramp, RandomSmooth, SeedSteps, Steps, pure_tilt
from experiments.config_files import load_mapping
from experiments.user_files import plant_from_files
from latency import compiled
from latency.batched import run_batched
from latency.frontends import (
    ImageFrontEnd,
    MeasurementConfig,
    MeasurementFrontEnd,
    OrbFrontEnd,
    orb_reference,
)
from latency.image_engine import run_images
from latency.loop import ClosedLoop, LoopConfig, LoopResult
from latency.models import Constant, LatencyModel
from latency.pipeline import PipelineConfig
from observer.aekf import AEKFConfig
from observer.cor_model import CorModel
from observer.cor_solver import CorSolver
from observer.gk.pixel_kalman import R_MIN_PX2, PixelKalmanConfig
from observer.orb import OrbConfig
from observer.orb_observer import OrbObserver, orb_filter_config
from observer.pixel_observer import FilterObserver, PixelKalmanObserver, SolverObserver
from observer.trackers import make_pair_tracker
from plant import attitude
from plant.params import PlantParams
from plant.texture import TextureParams


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class PIDSpec(_Model):
    kind: Literal["pid"] = "pid"
    config: PIDConfig = PIDConfig()


class MPCSpec(_Model):
    kind: Literal["mpc"] = "mpc"
    config: MPCConfig = MPCConfig()


ControllerSpec = Annotated[PIDSpec | MPCSpec, Field(discriminator="kind")]


#: Observer kinds of the textured rotor (``observer.orb_observer.OrbObserver``): ORB
#: alone (a direct solve per frame), ORB-EKF and ORB-AEKF (seed 001 Table 2).
ORB_KINDS = {"orb": "orb", "orb_ekf": "ekf", "orb_aekf": "aekf"}


def _kind(value) -> str | None:
    """The ``kind`` of a spec given as a model or a mapping (None if there is none)."""
    if isinstance(value, BaseModel | dict):
        kind = value.get("kind") if isinstance(value, dict) else getattr(value, "kind", None)
        return kind if isinstance(kind, str) else None
    return None


class ObserverSpec(_Model):
    """The attitude back end.

    Marker rotor: ``aekf``/``ekf`` (quaternion filter, optionally predicting across the
    latency), ``solver`` (per-frame least squares), or ``pixel_kalman`` (the seed's pixel Kalman
    filter on each marker, then the solver).

    Textured rotor (image mode only): ``orb`` (ORB alone, a direct solve per frame),
    ``orb_ekf`` and ``orb_aekf`` (the quaternion EKF/AEKF on the matched points, seed 001); the
    front end is ``latency.frontends.OrbFrontEnd`` with the ORB settings ``orb``.
    """

    kind: Literal["aekf", "ekf", "solver", "pixel_kalman", "orb", "orb_ekf", "orb_aekf"] = "aekf"
    compensate_delay: bool = Field(
        True, description="aekf/ekf/orb_ekf/orb_aekf: predict to the release time."
    )
    aekf: AEKFConfig = Field(
        default_factory=AEKFConfig,
        description="Filter settings (its ``adaptive`` is set by the kind); default "
        "AEKFConfig(), or orb_filter_config() for the ORB kinds.",
    )
    pixel_q_scale: float = Field(
        0.01, gt=0.0, description="pixel_kalman: Q = q·I4; seed 000 §3.2.1: 0.01."
    )
    pixel_r_scale: float = Field(
        0.1, ge=R_MIN_PX2, description="pixel_kalman: R = r·I2, at least "
        "``observer.gk.pixel_kalman.R_MIN_PX2``; seed 000 §3.2.1: 0.1."
    )
    orb: OrbConfig = Field(
        default_factory=OrbConfig, description="ORB kinds: keypoints, matching, RANSAC."
    )
    orb_max_coast_s: float = Field(
        0.5,
        gt=0.0,
        description="ORB kinds: the estimate is invalid after this long without an accepted "
        "measurement, s (our choice, OrbObserver's default).",
    )

    @model_validator(mode="before")
    @classmethod
    def _orb_filter_default(cls, data):
        """The ORB filters default to ``orb_filter_config`` (seed 001's ϑ = 0.8, window
        N = 10; each point's σ from the front end)."""
        if isinstance(data, dict) and "aekf" not in data and data.get("kind") in ORB_KINDS:
            data = {**data, "aekf": orb_filter_config()}
        return data

    @property
    def is_orb(self) -> bool:
        return self.kind in ORB_KINDS


class TiltStepSpec(_Model):
    """A pure tilt step (no turn about the shaft) at ``t_step_s``."""

    kind: Literal["tilt_step"] = "tilt_step"
    tilt_deg: float = Field(5.0, ge=0.0, le=15.0)
    azimuth_deg: float = 30.0
    t_step_s: float = Field(0.1, ge=0.0)
    step_metrics: bool = Field(
        True, description="Measure the step (overshoot, settling time, steady-state error; "
        "latency.metrics). Our choice: on."
    )

    @property
    def measures_steps(self) -> bool:
        """Whether the run's summary measures the step (``LoopConfig.step_metrics``)."""
        return self.step_metrics

    def build(self) -> Steps:
        q1 = pure_tilt(np.deg2rad(self.tilt_deg), np.deg2rad(self.azimuth_deg))
        return Steps(times_s=(0.0, self.t_step_s), attitudes=((1.0, 0.0, 0.0, 0.0), tuple(q1)))


@functools.lru_cache(maxsize=64)
def _built_reference(kind: str, args_json: str):
    """The generator ``kind`` with the fields ``args_json``, built once per process: the
    generators are immutable, and a sweep validates and builds the same reference for every
    seed (RandomSmooth scales its shape on a 16,384-point grid, ~20 ms)."""
    cls = {"seed_steps": SeedSteps, "ramp": Ramp, "cone": Cone, "random": RandomSmooth}
    return cls[kind].model_validate(json.loads(args_json))


#: The piecewise-constant generators of ``RefSpec`` (the others are smooth).
STEP_KINDS = ("seed_steps",)


class RefSpec(_Model):
    """Any generator of ``controller.reference`` by name, with its fields in ``args``."""

    kind: Literal["seed_steps", "ramp", "cone", "random"]
    args: dict = Field(default_factory=dict)
    step_metrics: bool | None = Field(
        None,
        description="Measure the step after the reference's last change (overshoot, settling "
        "time, steady-state error). None: on for the piecewise-constant seed_steps, off for "
        "the smooth kinds (ramp, cone, random), which have no step; true on a smooth kind is "
        "an error.",
    )

    def build(self):
        return _built_reference(self.kind, json.dumps(self.args, sort_keys=True))

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


#: Median whole-call time of the MPC (``MPCController.command``: prediction, parameters and
#: solve), s, measured on this 2-core machine by ``python benchmarks/bench_controllers.py``
#: (``mpc_<solver>_command_median_s``, 2026-11-22, before the compiled derivatives; N = 15
#: steps of 10 ms, 400 solves per variant): our default for the MPC's controller latency, per
#: (solver, hessian). The compiled derivatives cut the default's call to 1.39 ms (2026-12-02,
#: docs/controllers.md); the constants are kept, on the safe side, so that results stay
#: comparable. A constant keeps sweeps reproducible; use ``controller_latency: measured`` for
#: the wall-clock time of each call instead.
MPC_CALL_MEDIAN_S: dict[tuple[str, str], float] = {
    ("sqp_hpipm", "gauss_newton"): 0.0039982,  # the default solver: 4.00 ms
    ("sqp_qpoases", "gauss_newton"): 0.0092908,
    ("sqp_qrqp", "gauss_newton"): 0.0057612,
    ("sqp_osqp", "gauss_newton"): 0.0063489,
    ("ipopt", "gauss_newton"): 0.0112397,
    ("ipopt", "exact"): 0.0213719,
}
_UNMEASURED = "unmeasured MPC settings"


def _mpc_latency_default(controller) -> LatencyModel | str | None:
    """The MPC's default controller latency: a constant, its measured median call time for the
    solver (``MPC_CALL_MEDIAN_S``); None if ``controller`` is not a valid MPC spec (the field
    then keeps its default and validation reports what is wrong)."""
    if _kind(controller) != "mpc":
        return None
    try:
        spec = MPCSpec.model_validate(controller)
    except ValidationError:
        return None
    key = (spec.config.solver, spec.config.hessian)
    if key not in MPC_CALL_MEDIAN_S:
        return _UNMEASURED  # rejected by the field's validator, with the reason
    return Constant(value_s=MPC_CALL_MEDIAN_S[key])


def _non_finite(value, path: str = "") -> str | None:
    """Dotted path of the first infinite or NaN number in a raw configuration, else None."""
    if isinstance(value, float) and not np.isfinite(value):
        return path or "(top level)"
    if isinstance(value, dict):
        items = value.items()
    elif isinstance(value, list | tuple):
        items = enumerate(value)
    else:
        return None
    for k, v in items:
        found = _non_finite(v, f"{path}.{k}" if path else str(k))
        if found is not None:
            return found
    return None


#: Reference samples per run checked against the tilt stop at validation (our choice: fine
#: enough for every generator's shortest feature, cheap at validation).
_TILT_CHECK_SAMPLES = 500


class Scenario(_Model):
    """A closed-loop scenario. Defaults: GK-TransT's seed latency, measurement model, AEKF with
    delay compensation, PID, a 5° tilt step.

    The ORB observer kinds (``observer.kind``: ``orb``, ``orb_ekf``, ``orb_aekf``) need
    ``mode: image``; they put the printed pattern ``texture`` on the rotor in place of the
    markers (default ``TextureParams()``, seed 0) and take the ORB front end's measured
    per-frame time as the observer latency (``observer_latency: measured``; set ``model`` to
    use ``pipeline.observer`` instead, e.g. a profile from
    ``latency.profile.measure_orb_latency``, for reproducible runs).

    A user's motor and camera: ``motor_file`` and ``camera_file`` (paths of the YAML files of
    ``plant.motor_file`` and ``plant.camera_file``, e.g. ``examples/motor.yaml`` and the
    ``camera.yaml`` of ``pmspm calibrate``) in place of ``plant``
    (``experiments.user_files.plant_from_files``).
    """

    name: str = Field(
        "scenario",
        description="Names the output folder: letters, digits, '_', '.', '+', '-' (no path).",
    )
    duration_s: float = Field(2.0, gt=0.0, le=3600.0)
    seed: int = Field(0, ge=0, description="Random seed (numpy needs it >= 0).")
    mode: Literal["measurement", "image"] = "measurement"
    renderer: Literal["analytic", "mujoco"] = "analytic"
    tracker: Literal["kcf", "csrt", "transt", "dual_transt", "k2cf"] = Field(
        "kcf",
        description="Image mode, marker observers: the red marker's tracker inside the GK "
        "assistance (observer.trackers.make_pair_tracker): OpenCV KCF or CSRT, or the "
        "shipped TransT network ('transt': GK-TransT, seed 000 §3.2); or 'dual_transt', "
        "one TransT per marker without the GK assistance (seed 000's dual TransT); or "
        "'k2cf', the kinematic Kalman correlation filter on both markers.",
    )
    plant: PlantParams = PlantParams()
    pipeline: PipelineConfig = PipelineConfig()
    measurement: MeasurementConfig = Field(
        MeasurementConfig(),
        description="The measurement model's noise and loss (mode: measurement); its region "
        "of interest ``roi`` is also read in image mode (latency.frontends.ImageFrontEnd).",
    )
    observer: ObserverSpec = ObserverSpec()
    texture: TextureParams | None = Field(
        None,
        description="The rotor's printed pattern (seed and shapes) instead of the two "
        "markers; default on for the ORB observer kinds, off otherwise.",
    )
    observer_latency: Literal["model", "measured"] = Field(
        "model",
        description="Observer latency from pipeline.observer ('model', reproducible) or the "
        "front end's measured compute time per frame ('measured', image mode); default "
        "'measured' for the ORB kinds, 'model' otherwise.",
    )
    controller: ControllerSpec = PIDSpec()
    reference: ReferenceSpec = TiltStepSpec()
    controller_rate_hz: float | None = Field(
        None, gt=0.0, description="None: control on each new estimate; a rate (Hz): a fixed "
        "controller clock on the latest estimate (latency.loop.LoopConfig)."
    )
    controller_latency: LatencyModel | Literal["measured"] = Field(
        default_factory=lambda: Constant(value_s=0.0),
        description="Controller compute latency in the loop: a model, or 'measured' (the "
        "wall-clock time of each command() call). Default: 0 for PID (its call takes 0.2 ms, "
        "bench_controllers.json; our choice to neglect it); for MPC a constant, its median "
        "call time measured here (MPC_CALL_MEDIAN_S, 4.0 ms for SQP + HPIPM).",
    )

    @model_validator(mode="before")
    @classmethod
    def _finite_numbers(cls, data):
        """Every number is finite: an infinite gain, rate or latency cannot run (an infinite
        controller rate never leaves its first instant)."""
        where = _non_finite(data)
        if where is not None:
            raise ValueError(f"{where} must be a finite number (got inf or nan)")
        return data

    @field_validator("name")
    @classmethod
    def _folder_name(cls, v: str) -> str:
        """The name becomes a folder under ``--out``: no path separators, no '..'."""
        if not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.+-]{0,99}", v) or ".." in v:
            raise ValueError(
                f"name {v!r} must be 1-100 letters, digits, '_', '.', '+' or '-', not start "
                "with '.' or '-', and hold no '/' or '..' (it names a folder under --out)"
            )
        return v

    @model_validator(mode="before")
    @classmethod
    def _dependent_defaults(cls, data):
        """Fill in the defaults that depend on other fields (when those are valid): the MPC's
        measured controller latency; the print and the measured latency of the ORB kinds."""
        if not isinstance(data, dict):
            return data
        # ``motor_file`` / ``camera_file`` (a user's motor and camera YAML) give ``plant``
        # first, so the camera timing below comes from the user's camera.
        data = plant_from_files(dict(data))
        if "controller_latency" not in data:
            latency = _mpc_latency_default(data.get("controller"))
            if latency is not None:
                data["controller_latency"] = latency
        if _kind(data.get("observer")) in ORB_KINDS:
            data.setdefault("texture", TextureParams())
            data.setdefault("observer_latency", "measured")
        plant, pipeline = data.get("plant"), data.get("pipeline", {})
        if isinstance(plant, PlantParams):
            plant = plant.model_dump()
        camera = plant.get("camera") if isinstance(plant, dict) else None
        if isinstance(camera, dict) and isinstance(pipeline, dict):
            # One timing source: the camera's frame rate and exposure unless the pipeline
            # names its own (then the check below requires them to agree).
            data["pipeline"] = {
                **{k: camera[k] for k in ("frame_rate_hz", "exposure_s") if k in camera},
                **pipeline,
            }
        return data

    @model_validator(mode="after")
    def _one_camera_timing(self) -> Scenario:
        cam, pipe = self.plant.camera, self.pipeline
        for key in ("frame_rate_hz", "exposure_s"):
            if not np.isclose(getattr(cam, key), getattr(pipe, key), rtol=1e-12, atol=0.0):
                raise ValueError(
                    f"pipeline.{key} = {getattr(pipe, key)} differs from plant.camera.{key} = "
                    f"{getattr(cam, key)}: motion blur and the frame timeline would use "
                    "different cameras; set plant.camera only"
                )
        return self

    @field_validator("observer")
    @classmethod
    def _observer_fits_the_mode(cls, v: ObserverSpec, info: ValidationInfo) -> ObserverSpec:
        mode = info.data.get("mode")
        if v.is_orb and mode != "image":
            raise ValueError(
                f"kind {v.kind!r} (ORB on the textured rotor) needs mode: image, got mode: "
                f"{mode!r}; the measurement model has no ORB matches"
            )
        return v

    @model_validator(mode="after")
    def _tracker_fits(self) -> Scenario:
        if self.tracker != "kcf" and (self.mode != "image" or self.observer.is_orb):
            raise ValueError(
                f"tracker {self.tracker!r} needs mode: image with a marker observer (aekf, ekf, "
                f"solver, pixel_kalman); got mode {self.mode!r}, observer {self.observer.kind!r}"
            )
        return self

    @model_validator(mode="after")
    def _roi_fits(self) -> Scenario:
        if self.measurement.roi is not None and self.observer.is_orb:
            raise ValueError(
                f"measurement.roi: the ORB front end reads the whole sensor; remove roi for "
                f"observer.kind {self.observer.kind!r}"
            )
        return self

    @field_validator("texture")
    @classmethod
    def _texture_fits_the_observer(
        cls, v: TextureParams | None, info: ValidationInfo
    ) -> TextureParams | None:
        obs = info.data.get("observer")
        if isinstance(obs, ObserverSpec):
            if v is not None and not obs.is_orb:
                raise ValueError(
                    f"the textured rotor has no markers for observer.kind {obs.kind!r}; use an "
                    f"ORB kind ({', '.join(ORB_KINDS)}) or remove texture"
                )
            if v is None and obs.is_orb:
                raise ValueError(
                    f"observer.kind {obs.kind!r} needs the textured rotor: set texture (e.g. "
                    "{seed: 0}) or leave it out for the default print"
                )
        return v

    @field_validator("observer_latency")
    @classmethod
    def _measured_needs_images(cls, v: str, info: ValidationInfo) -> str:
        # (An observer that failed validation has its own error: an ORB kind without images.)
        valid_observer = "observer" in info.data
        if v == "measured" and info.data.get("mode") == "measurement" and valid_observer:
            raise ValueError(
                "'measured' needs mode: image; the measurement model computes nothing (its "
                "compute time is 0), use 'model' with pipeline.observer"
            )
        return v

    @field_validator("controller_latency", mode="before")
    @classmethod
    def _known_mpc_time(cls, v, info: ValidationInfo):
        if isinstance(v, str) and v == _UNMEASURED:
            c = info.data["controller"].config
            measured = ", ".join(f"{a}/{b}" for a, b in MPC_CALL_MEDIAN_S)
            raise ValueError(
                f"no measured MPC call time for solver {c.solver!r} with hessian {c.hessian!r} "
                f"(measured: {measured}); set controller_latency to a model or 'measured'"
            )
        return v

    @model_validator(mode="after")
    def _runnable(self) -> Scenario:
        """Combinations that would fail, hang or silently do nothing once the run has started:
        the loop's own checks (latencies not shorter than the run, a frame period shorter than
        the exposure), a controller clock faster than the physics, a reference that starts
        after the run or goes beyond the tilt stop."""
        where = _non_finite(self.model_dump())  # also infinities given as text ("inf")
        if where is not None:
            raise ValueError(f"{where} must be a finite number (got inf or nan)")
        try:
            self.loop_config()
        except ValidationError as exc:
            raise ValueError(
                "; ".join(e["msg"].removeprefix("Value error, ") for e in exc.errors())
            ) from None
        phys = self.plant.physics_dt_s
        if self.controller_rate_hz is not None and self.controller_rate_hz * phys > 1.0:
            raise ValueError(
                f"controller_rate_hz = {self.controller_rate_hz:g} is faster than the physics "
                f"(1 / plant.physics_dt_s = {1.0 / phys:g} Hz)"
            )
        ref_spec = self.reference
        start_s = (
            ref_spec.t_step_s
            if isinstance(ref_spec, TiltStepSpec)
            else float(ref_spec.args.get("t_start_s", 0.0))
        )
        if start_s >= self.duration_s:
            raise ValueError(
                f"the reference starts at {start_s:g} s, not before the run ends (duration_s = "
                f"{self.duration_s:g} s): the run would only hold the initial attitude"
            )
        stop = self.plant.rotor.tilt_stop_deg
        ref = ref_spec.build()
        times = np.linspace(0.0, self.duration_s, _TILT_CHECK_SAMPLES)
        tilt_deg = float(np.max(np.degrees(attitude.to_zyz_array(ref.sample_many(times).q)[:, 1])))
        if tilt_deg > stop + 1e-9:
            raise ValueError(
                f"the reference reaches {tilt_deg:.3g}° of tilt, beyond the tilt stop "
                f"plant.rotor.tilt_stop_deg = {stop:g}°"
            )
        return self

    def reach_warnings(self) -> list[str]:
        """Reasons why the controller's crossover (PID) or bandwidth (MPC) is far outside what
        the plant and the camera can do (``controller.pid.reach_warnings``); empty if none."""
        if isinstance(self.controller, PIDSpec):
            pid = PIDController(self.controller.config, self.plant)
            return pid_reach_warnings(pid, self.pipeline.frame_rate_hz)
        wn, nyquist = self.controller.config.bandwidth_rad_s, np.pi * self.pipeline.frame_rate_hz
        if wn > nyquist:
            return [
                f"MPC bandwidth {wn:g} rad/s is above the camera's Nyquist frequency pi x "
                f"{self.pipeline.frame_rate_hz:g} Hz = {nyquist:.4g} rad/s"
            ]
        return []

    def loop_config(self) -> LoopConfig:
        """The closed loop's settings of this scenario."""
        return LoopConfig(
            duration_s=self.duration_s,
            pipeline=self.pipeline,
            seed=self.seed,
            controller_rate_hz=self.controller_rate_hz,
            controller_latency=self.controller_latency,
            observer_latency=self.observer_latency,
            step_metrics=self.reference.measures_steps,
        )

    @classmethod
    def from_yaml(cls, path: str | Path) -> Scenario:
        """Load a scenario file; missing fields keep their defaults (``ConfigFileError`` for a
        file that is not a YAML mapping, ``experiments.config_files``)."""
        return cls.model_validate(load_mapping(path))


def _renderer(s: Scenario):
    """The scenario's renderer, with the textured rotor when ``s.texture`` is set."""
    if s.renderer == "analytic":
        from plant.render_analytic import AnalyticRenderer, AnalyticRenderOptions

        options = AnalyticRenderOptions(texture=s.texture)
        return AnalyticRenderer(s.plant, options=options, seed=s.seed)
    from plant.render_mujoco import MujocoRenderer

    return MujocoRenderer(s.plant, texture=s.texture)


#: The scenario's tracker names -> ``observer.trackers.make_pair_tracker`` names.
PAIR_TRACKER_OF = {"kcf": "kcf_gk", "csrt": "csrt_gk", "transt": "gk_transt",
                   "dual_transt": "dual_transt", "k2cf": "k2cf"}


def build_loop(s: Scenario, clock: Callable[[], float] = time.perf_counter) -> ClosedLoop:
    """The closed loop of a scenario.

    ``clock`` (seconds, default ``time.perf_counter``) times every measured compute time: the
    observer's front end and back end, the controller's calls and the loop's timer around them.
    Tests inject a stand-in so that the ``measured`` latencies do not depend on machine load.
    """
    p = s.plant
    rng = np.random.default_rng([s.seed, 1])
    o = s.observer
    if o.is_orb:  # the textured rotor: rendered frames matched to a reference view
        renderer = _renderer(s)
        observer = OrbObserver(
            p,
            orb_reference(p, renderer, s.texture, config=o.orb),
            method=ORB_KINDS[o.kind],
            orb_config=o.orb,
            filter_config=o.aekf,
            compensate_delay=o.compensate_delay,
            max_coast_s=o.orb_max_coast_s,
            clock=clock,
        )
        front = OrbFrontEnd(renderer, observer)
    else:
        if s.mode == "measurement":
            front = MeasurementFrontEnd(p, s.measurement, rng)
        else:
            front = ImageFrontEnd(
                p, _renderer(s), make_pair_tracker(PAIR_TRACKER_OF[s.tracker], p, clock=clock),
                roi=s.measurement.roi,
            )
        if o.kind in ("aekf", "ekf"):
            cfg = o.aekf.model_copy(update={"adaptive": o.kind == "aekf"})
            observer = FilterObserver(p, cfg, compensate_delay=o.compensate_delay)
        elif o.kind == "solver":
            observer = SolverObserver(CorSolver(CorModel.nominal(p)))
        else:
            pk = PixelKalmanConfig(
                Q=(o.pixel_q_scale * np.eye(4)).tolist(), R=(o.pixel_r_scale * np.eye(2)).tolist()
            )
            observer = PixelKalmanObserver(CorSolver(CorModel.nominal(p)), pk)
    if isinstance(s.controller, PIDSpec):
        controller = PIDController(s.controller.config, p, clock)
    else:
        mpc = s.controller.config
        if mpc.compute_latency_s is None and s.controller_latency != "measured":
            # The MPC's delay compensation must assume the latency the loop applies.
            mpc = mpc.model_copy(update={"compute_latency_s": s.controller_latency.mean_s})
        controller = MPCController(mpc, p, clock)
    return ClosedLoop(p, controller, s.reference.build(), front, observer, s.loop_config(), clock)


#: The two engines: ``latency.batched`` (many measurement-model runs advanced together) and the
#: event loop (``ClosedLoop.run``, one run at a time).
Engine = Literal["batched", "event"]


def default_engine(s: Scenario) -> Engine:
    """Measurement-model work runs batched, image-in-the-loop work on the event loop (a single
    image run gains nothing from the image engine; ``run_many`` with ``engine="batched"``
    batches many)."""
    return "batched" if s.mode == "measurement" else "event"


def check_engine(s: Scenario, engine: Engine) -> None:
    """``ValueError`` if ``engine`` cannot run ``s``: the batched image engine needs model
    latencies (``latency.image_engine``) and the marker front end."""
    if engine == "batched" and s.mode == "image":
        if s.observer.is_orb:
            raise ValueError(f"scenario {s.name!r}: the batched image engine runs marker "
                             "trackers, not the ORB observer; use --engine event")
        if s.observer_latency == "measured" or s.controller_latency == "measured":
            raise ValueError(f"scenario {s.name!r}: the batched image engine needs model "
                             "latencies (observer_latency: model and a controller_latency "
                             "model); use --engine event to measure them")


def describe_path(s: Scenario, engine: Engine | None = None) -> str:
    """Which engine and, on the batched engine, which path computes ``s``, with the reason
    when it is not the compiled run loop (``latency.compiled.coverage``), in words."""
    e = engine or default_engine(s)
    if e == "event":
        return "engine: event loop"
    cov = compiled.coverage(build_loop(s))
    if cov.path == "compiled":
        return "engine: batched, compiled run loop"
    return f"engine: batched, not the compiled run loop ({cov.reason})"


def run(s: Scenario, progress: bool = False, engine: Engine | None = None) -> LoopResult:
    """Run a scenario on ``engine`` (default ``default_engine(s)``)."""
    return run_many([s], progress, engine)[0]


def run_many(
    scenarios: list[Scenario], progress: bool = False, engine: Engine | None = None,
    tables: bool = True,
) -> list[LoopResult]:
    """Run scenarios, in order: on the batched engines those that take them (measurement-model
    runs together in ``latency.batched``; image runs together in this process on
    ``latency.image_engine``, their network calls batched), the others one by one on the event
    loop. ``engine`` None: each scenario's ``default_engine``. ``tables=False`` allows results
    without their steps, frames and events tables (``latency.batched.run_batched``) where only
    the summaries are wanted."""
    engines = [engine or default_engine(s) for s in scenarios]
    for s, e in zip(scenarios, engines, strict=True):
        check_engine(s, e)
    out: list[LoopResult | None] = [None] * len(scenarios)
    batched = [i for i, e in enumerate(engines) if e == "batched"]
    measured = [i for i in batched if scenarios[i].mode == "measurement"]
    images = [i for i in batched if scenarios[i].mode == "image"]
    for i, res in zip(measured, run_batched([build_loop(scenarios[i]) for i in measured],
                                            progress, tables), strict=True):
        out[i] = res
    for i, res in zip(images, run_images(build_loop, [scenarios[i] for i in images], workers=1,
                                         progress=progress), strict=True):
        out[i] = res
    for i, e in enumerate(engines):
        if e == "event":
            out[i] = build_loop(scenarios[i]).run(progress=progress)
    return [r for r in out if r is not None]


def run_summary(config: dict) -> dict:
    """Sweep entry point: run the scenario given as a dict on the event loop, return its
    summary metrics."""
    return run(Scenario.model_validate(config), engine="event").summary


def run_summaries(configs: list[dict]) -> list[dict | Exception]:
    """Batched sweep entry point: the summaries of the scenarios given as dicts, each on its
    default engine (measurement-model runs together); an invalid config gives its exception
    in its place."""
    scenarios: list[Scenario] = []
    out: list[dict | Exception] = []
    for c in configs:
        try:
            scenarios.append(Scenario.model_validate(c))
            out.append({})
        except ValidationError as exc:
            out.append(exc)
    results = iter(run_many(scenarios, tables=False))
    return [o if isinstance(o, Exception) else next(results).summary for o in out]
