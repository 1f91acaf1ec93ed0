"""One validated object per closed-loop scenario, loadable from YAML.

A ``Scenario`` holds everything a run needs: the plant, the camera pipeline and its latency, the
front end (measurement model or rendered images), the observer, the controller, the reference,
the duration and the seed. Its parts are named from their families' registries
(``controller.registry``, ``observer.registry``, ``observer.trackers.registry``,
``latency.models``, ``latency.frontends``, ``plant.renderers``; ``pmspm parts`` lists them).
``latency.simulation`` runs it.

Wrong fields or values fail at load time with a message that names the field and the allowed
range (pydantic), and so do unknown part names (listing the registered ones) and combinations
that cannot run (an ORB observer without rendered frames, marker observers on the textured
rotor, a measured latency without compute).

Defaults that depend on other fields are resolved at validation, so that a dumped scenario shows
what ran: the MPC's compute latency (its median call time measured here, ``MPC_CALL_MEDIAN_S``),
the textured rotor and the measured observer latency for the ORB observers.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path
from typing import Literal

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

from controller.pid import PIDController
from controller.pid import reach_warnings as pid_reach_warnings
from controller.registry import (
    CONTROLLERS,
    REFERENCES,
    ControllerSpec,
    MPCSpec,
    PIDSpec,
    ReferenceSpec,
    TiltStepSpec,
)
from latency.frontends import LOSS_MODELS, MeasurementConfig
from latency.loop_config import LoopConfig
from latency.models import LATENCY_MODELS, Constant, LatencyModel
from latency.pipeline import PipelineConfig
from observer.registry import OBSERVERS, FilterObserverSpec, ObserverSpec
from observer.trackers import TRACKERS
from plant import attitude
from plant.config_files import load_mapping
from plant.params import PlantParams
from plant.render_analytic import AnalyticRenderOptions
from plant.renderers import RENDERERS
from plant.texture import TextureParams
from plant.user_files import plant_from_files


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _kind(value) -> str | None:
    """The ``kind`` of a spec given as a model or a mapping (None if there is none)."""
    if isinstance(value, BaseModel | dict):
        kind = value.get("kind") if isinstance(value, dict) else getattr(value, "kind", None)
        return kind if isinstance(kind, str) else None
    return None


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


#: The scenario's fields that name a part by ``kind``, with their families.
_KIND_FIELDS = (("controller", CONTROLLERS), ("observer", OBSERVERS), ("reference", REFERENCES),
                ("controller_latency", LATENCY_MODELS))


def _check_kinds(data: dict) -> None:
    """``ValueError`` naming the field and the registered parts for an unknown ``kind``."""
    for field, registry in _KIND_FIELDS:
        kind = _kind(data.get(field))
        if kind is not None and kind not in registry:
            raise ValueError(f"{field}.kind: {registry.unknown(kind)}")
    measurement = data.get("measurement")
    kind = _kind(measurement.get("loss")) if isinstance(measurement, dict) else None
    if kind is not None and kind not in LOSS_MODELS:
        raise ValueError(f"measurement.loss.kind: {LOSS_MODELS.unknown(kind)}")


#: Fields whose value is a discriminated union: pydantic puts the member's tag after them in an
#: error's location (``observer.aekf.aekf.sigma_px``), which ``field_path`` leaves out.
_UNION_FIELDS = {"observer", "controller", "reference", "controller_latency", "loss"}


def field_path(loc: tuple[int | str, ...]) -> str:
    """The dotted path of a validation error's location as a user writes it in a scenario file,
    without the union tags pydantic inserts (``observer.aekf.sigma_px``)."""
    parts: list[str] = []
    for i, p in enumerate(loc):
        if i > 0 and isinstance(loc[i - 1], str) and loc[i - 1] in _UNION_FIELDS and \
                i + 1 < len(loc) and isinstance(p, str):
            continue
        parts.append(str(p))
    return ".".join(parts)


#: Tracker names whose meaning changed: in scenarios they named the GK-assisted tracker.
_ASSISTED_BEFORE = {"kcf": "kcf_gk", "csrt": "csrt_gk"}


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
    (``plant.user_files.plant_from_files``).
    """

    name: str = Field(
        "scenario",
        description="Names the output folder: letters, digits, '_', '.', '+', '-' (no path).",
    )
    duration_s: float = Field(2.0, gt=0.0, le=3600.0)
    seed: int = Field(0, ge=0, description="Random seed (numpy needs it >= 0).")
    mode: Literal["measurement", "image"] = "measurement"
    renderer: str = Field("analytic", description="Image mode: the camera "
                          "(plant.renderers.RENDERERS: analytic or mujoco).")
    tracker: str = Field(
        "kcf_gk",
        description="Image mode, marker observers: the marker-pair tracker "
        "(observer.trackers.TRACKERS): 'gk_transt' (the shipped TransT network inside the GK "
        "assistance, seed 000 §3.2), 'dual_transt' (one network per marker, seed 000's dual "
        "TransT), 'kcf_gk' or 'csrt_gk' (OpenCV's tracker inside the GK assistance), 'kcf', "
        "'csrt' or 'kcf_numpy' alone on each marker, or 'k2cf'. Our default: kcf_gk.",
    )
    plant: PlantParams = PlantParams()
    pipeline: PipelineConfig = PipelineConfig()
    measurement: MeasurementConfig = Field(
        MeasurementConfig(),
        description="The measurement model's noise and loss (mode: measurement); its region "
        "of interest ``roi`` is also read in image mode (latency.frontends.ImageFrontEnd).",
    )
    observer: ObserverSpec = FilterObserverSpec()
    texture: TextureParams | None = Field(
        None,
        description="The rotor's printed pattern (seed and shapes) instead of the two "
        "markers; default on for the ORB observer kinds, off otherwise.",
    )
    camera_effects: AnalyticRenderOptions | None = Field(
        None,
        description="Image mode, analytic renderer: the camera's effects and distractors "
        "(plant.render_analytic.AnalyticRenderOptions: illumination, gain, read noise, "
        "specular highlights, a colour distractor, light gradient, vignetting, defocus, JPEG); "
        "None: its defaults. The rotor's print is ``texture``, not set here.",
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
        "controller clock on the latest estimate (latency.loop_config.LoopConfig)."
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

    @field_validator("seed", mode="before")
    @classmethod
    def _seed_not_bool(cls, v):
        """A seed is an integer; ``true``/``false`` (a YAML slip) is refused, not read as 1/0."""
        if isinstance(v, bool):
            raise ValueError(f"seed must be an integer >= 0, got {v!r}")
        return v

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
        """Fill in the defaults that depend on other fields (when those are valid): the
        observer's kind (aekf) when its mapping names none; the MPC's measured controller
        latency; the print and the measured latency of the ORB kinds."""
        if not isinstance(data, dict):
            return data
        _check_kinds(data)
        if isinstance(data.get("observer"), dict) and "kind" not in data["observer"]:
            data["observer"] = {"kind": "aekf", **data["observer"]}  # the default kind
        # ``motor_file`` / ``camera_file`` (a user's motor and camera YAML) give ``plant``
        # first, so the camera timing below comes from the user's camera.
        data = plant_from_files(dict(data))
        if "controller_latency" not in data:
            latency = _mpc_latency_default(data.get("controller"))
            if latency is not None:
                data["controller_latency"] = latency
        observer = OBSERVERS.get(_kind(data.get("observer")) or "aekf").settings
        if observer.is_orb:  # type: ignore[union-attr]
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

    @field_validator("tracker")
    @classmethod
    def _known_tracker(cls, v: str) -> str:
        """A registered tracker (a former name is accepted with a warning); ``kcf`` and ``csrt``
        now name the tracker alone, with a warning saying so."""
        if v in _ASSISTED_BEFORE:
            warnings.warn(f"tracker {v!r} is OpenCV's {v.upper()} alone on each marker; "
                          f"scenarios used to mean it inside the GK assistance, now "
                          f"{_ASSISTED_BEFORE[v]!r}", FutureWarning, stacklevel=2)
        return TRACKERS.canonical(v)

    @field_validator("renderer")
    @classmethod
    def _known_renderer(cls, v: str) -> str:
        return RENDERERS.canonical(v)

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
        default = type(self).model_fields["tracker"].default
        if self.tracker != default and (self.mode != "image" or self.observer.is_orb):
            raise ValueError(
                f"tracker {self.tracker!r} needs mode: image with a marker observer (aekf, ekf, "
                f"solver, pixel_kalman); got mode {self.mode!r}, observer {self.observer.kind!r}"
            )
        return self

    @model_validator(mode="after")
    def _camera_effects_fit(self) -> Scenario:
        fx = self.camera_effects
        if fx is None:
            return self
        if self.mode != "image" or self.renderer != "analytic":
            raise ValueError(
                f"camera_effects are the analytic renderer's: they need mode: image and "
                f"renderer: analytic, got mode {self.mode!r}, renderer {self.renderer!r}"
            )
        if fx.texture is not None:
            raise ValueError("camera_effects.texture: set the rotor's print with the "
                             "scenario's texture field")
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
        if isinstance(obs, BaseModel):
            if v is not None and not obs.is_orb:
                raise ValueError(
                    f"the textured rotor has no markers for observer.kind {obs.kind!r}; use an "
                    "ORB kind (orb, orb_ekf, orb_aekf) or remove texture"
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
        start_s = ref_spec.start_s
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
        file that is not a YAML mapping, ``plant.config_files``)."""
        return cls.model_validate(load_mapping(path))


