"""The co-design spec file: what may be designed, how designs are scored and searched.

Loaded strictly (``plant.config_files.load_mapping``) and validated by pydantic: an
unknown field, a value out of range or an inconsistent range fails before any work, with a
message that names the field. The plant comes from ``plant``, or from ``motor_file`` /
``camera_file`` as in a scenario (``plant.user_files.plant_from_files``).

Each variable of the design space is a ``FloatRange`` (``[low, high]``, sampled on a log scale
when ``log``; a single number fixes it) or a list of choices (one element fixes it).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from controller.registry import ReferenceSpec, RefSpec, TiltStepSpec
from experiments.codesign.catalogue import catalogue_figures
from latency import Scenario
from latency.models import Constant, Empirical, LatencyModel
from observer.trackers import TRACKERS
from plant.camera_mode import SensorTiming
from plant.config_files import load_mapping
from plant.params import PlantParams
from plant.user_files import plant_from_files


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def _as_range(value):
    """A number -> a fixed range; a two-element list -> ``[low, high]``."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        return {"low": value, "high": value}
    if isinstance(value, list | tuple) and len(value) == 2:
        return {"low": value[0], "high": value[1]}
    return value


class _Range(_Model):
    low: float = Field(gt=0.0)
    high: float = Field(gt=0.0)
    log: bool = True

    @model_validator(mode="after")
    def _ordered(self) -> _Range:
        if self.high < self.low:
            raise ValueError(f"high ({self.high:g}) must be >= low ({self.low:g})")
        return self

    @property
    def fixed(self) -> bool:
        return self.low == self.high


#: A continuous variable: ``[low, high]`` (log-uniform by default), or one number (fixed).
FloatRange = Annotated[_Range, BeforeValidator(_as_range)]


def _choices(kind):
    return Annotated[list[kind], Field(min_length=1)]


class CameraSpace(_Model):
    """Camera modes (``plant.camera_mode.CameraMode``): ROI rows and columns (sensor px; the
    sensor's size reads the whole sensor), ROI following the predicted markers, binning,
    exposure (s)."""

    rows: _choices(Annotated[int, Field(ge=16)]) = Field(default_factory=lambda: [2048, 1024, 512])
    cols: _choices(Annotated[int, Field(ge=16)]) = Field(default_factory=lambda: [2448, 1024])
    follow: _choices(bool) = Field(default_factory=lambda: [False, True])
    binning: _choices(Annotated[int, Field(ge=1, le=4)]) = Field(default_factory=lambda: [1, 2])
    exposure_s: FloatRange = Field(default_factory=lambda: _Range(low=0.5e-3, high=4e-3))
    sensor: SensorTiming = SensorTiming()


class ObserverSpace(_Model):
    """Observer choices: pipeline semantics, back end, pixel-Kalman Q = q·I4 / R = r·I2 (sensor
    px²), the AEKF's delay compensation."""

    pipeline: _choices(Literal["sequential", "pipelined"]) = Field(
        default_factory=lambda: ["sequential", "pipelined"]
    )
    kind: _choices(Literal["pixel_kalman", "solver", "aekf"]) = Field(
        default_factory=lambda: ["pixel_kalman", "solver", "aekf"]
    )
    q_scale: FloatRange = Field(default_factory=lambda: _Range(low=1e-4, high=1.0))
    r_scale: FloatRange = Field(default_factory=lambda: _Range(low=1e-3, high=10.0))
    compensate_delay: _choices(bool) = Field(default_factory=lambda: [True, False])


class ControllerSpace(_Model):
    """Controller choices: the PID's crossover (rad/s), zero and integral ratios
    (``controller.pid.tuning_rule``), or the MPC's horizon (steps) and bandwidth (rad/s)."""

    kind: _choices(Literal["pid", "mpc"]) = Field(default_factory=lambda: ["pid"])
    crossover_rad_s: FloatRange = Field(default_factory=lambda: _Range(low=4.0, high=25.0))
    zero_ratio: FloatRange = Field(default_factory=lambda: _Range(low=2.0, high=5.0))
    integral_ratio: FloatRange = Field(default_factory=lambda: _Range(low=5.0, high=20.0))
    mpc_horizon_steps: _choices(Annotated[int, Field(ge=2, le=200)]) = Field(
        default_factory=lambda: [10, 15])
    mpc_bandwidth_rad_s: FloatRange = Field(default_factory=lambda: _Range(low=8.0, high=25.0))


class TrackerModel(_Model):
    """A tracker as the measurement model sees it: its latency, accuracy and loss behaviour.

    ``latency`` is a latency model (``latency.models``), or ``latency_file`` a profile written
    by ``pmspm measure-latency`` (an ``Empirical`` JSON). Accuracy: the camera mode's noise
    times ``noise_scale``. Loss: the search window, re-detection and blur limit of
    ``latency.frontends.MeasurementConfig``, plus random dropouts. ``image_tracker`` is the
    scenario tracker that runs it on rendered frames (None: no image-in-the-loop check).
    """

    latency: LatencyModel | None = None
    latency_file: Path | None = None
    noise_scale: float = Field(1.0, gt=0.0)
    search_radius_px: float | None = Field(240.0, gt=0.0)
    reacquire_after_frames: int | None = Field(
        5, ge=1, description="Processed frames until a lost marker is re-detected; None: never "
        "(it stays lost for the rest of the run).")
    blur_limit_px: float | None = Field(48.0, gt=0.0)
    dropout_prob: float = Field(0.0, ge=0.0, le=1.0)
    image_tracker: str | None = Field(
        None, description="The tracker (observer.trackers.TRACKERS) that runs it on rendered "
        "frames; None: no image-in-the-loop check.")

    @field_validator("image_tracker")
    @classmethod
    def _known_tracker(cls, v: str | None) -> str | None:
        return None if v is None else TRACKERS.canonical(v)

    @model_validator(mode="after")
    def _one_latency(self) -> TrackerModel:
        if (self.latency is None) == (self.latency_file is None):
            raise ValueError("give exactly one of latency and latency_file")
        if self.latency_file is not None and not self.latency_file.is_file():
            raise ValueError(f"latency_file: no such file: {self.latency_file}")
        return self

    def latency_model(self) -> LatencyModel:
        """The latency model (the profile read from ``latency_file`` if given)."""
        return self.latency if self.latency is not None else Empirical.load(self.latency_file)


def default_trackers() -> dict[str, TrackerModel]:
    """The catalogue: GK-TransT, dual TransT, KCF and CSRT inside the GK assistance, and K²CF,
    with the latencies, noise scales, re-detection and image-in-the-loop trackers of
    ``experiments.codesign.catalogue`` (seed 000 Table 1 and this project's tracking
    benchmark); search window and blur limit: ``TrackerModel``'s defaults."""
    return {name: TrackerModel(latency=Constant(value_s=f["latency_s"]),
                               noise_scale=f["noise_scale"],
                               reacquire_after_frames=f["reacquire_after_frames"],
                               image_tracker=f["image_tracker"])
            for name, f in catalogue_figures().items()}


class Constraints(_Model):
    """Constraints on a design; the first two from the exact analysis, the others from Monte
    Carlo, on the means over the runs or (``bound: upper``) on the upper ends of their 95 %
    intervals (Wilson for the loss of control, bootstrap for the lost frames)."""

    min_phase_margin_deg: float = Field(30.0, description="Critical phase margin, deg.")
    min_delay_headroom_ms: float = Field(5.0, description="Extra vision delay tolerated, ms.")
    max_loss_of_control: float = Field(0.001, ge=0.0, le=1.0, description="Fraction of runs.")
    max_lost_frames: float = Field(0.01, ge=0.0, le=1.0, description="Lost / processed frames.")
    bound: Literal["mean", "upper"] = Field(
        "mean", description="Monte-Carlo constraints on the means or the intervals' upper ends "
        "(with a few seeds the upper end of a loss probability stays far above 0.1 %)."
    )


class SearchSettings(_Model):
    """The optuna study."""

    sampler: Literal["nsga2", "tpe"] = "nsga2"
    n_trials: int = Field(48, ge=1, description="Complete trials the study should have.")
    batch_size: int = Field(
        12, ge=1, description="Designs asked at a time; their runs share one batched call."
    )
    seed: int = Field(0, ge=0, description="Sampler seed.")
    prune_growth_rate_per_s: float | None = Field(
        2.0, gt=0.0, description="Designs whose linear loop is unstable with a growth rate "
        "(``Analysis.growth_rate_per_s``, 1/s) of at least this get no Monte Carlo (pruned); "
        "None: none. The default is above every growth rate the Monte Carlo accepted on the "
        "grid of docs/codesign.md, 'Pruning' (1.5/s).")
    storage: str | None = Field(None, description="None: sqlite:///<out>/codesign.db.")
    study_name: str | None = Field(None, description="None: the spec's name.")


class ImageCheck(_Model):
    """The image-in-the-loop re-run of the recommended design (event loop, rendered frames,
    the tracker's ``image_tracker``)."""

    enabled: bool = True
    seeds: _choices(int) = Field(default_factory=lambda: [0, 1])
    duration_s: float = Field(2.0, gt=0.0)
    renderer: Literal["analytic", "mujoco"] = "analytic"


class CodesignSpec(_Model):
    """A co-design problem (module docstring)."""

    name: str = Field("codesign", pattern=r"^[A-Za-z0-9_][A-Za-z0-9_.+-]{0,99}$")
    plant: PlantParams = PlantParams()
    duration_s: float = Field(2.0, gt=0.0, le=60.0, description="Length of each run, s.")
    seeds: _choices(int) = Field(default_factory=lambda: [0, 1, 2, 3])
    references: Annotated[list[ReferenceSpec], Field(min_length=1)] = Field(
        default_factory=lambda: [TiltStepSpec(tilt_deg=5.0),
                                 RefSpec(kind="random", args={"max_rate_rad_s": 1.0})]
    )
    camera: CameraSpace = CameraSpace()
    trackers: _choices(str) = Field(default_factory=lambda: ["gk_transt", "kcf_gk"])
    tracker_models: dict[str, TrackerModel] = Field(default_factory=default_trackers)
    observer: ObserverSpace = ObserverSpace()
    controller: ControllerSpace = ControllerSpace()
    constraints: Constraints = Constraints()
    search: SearchSettings = SearchSettings()
    image_check: ImageCheck = ImageCheck()

    @model_validator(mode="before")
    @classmethod
    def _files_and_catalogue(cls, data):
        """``motor_file`` / ``camera_file`` give ``plant``; ``tracker_models`` entries are
        added to (or replace) the seed's catalogue."""
        if not isinstance(data, dict):
            return data
        data = plant_from_files(dict(data))
        extra = data.get("tracker_models")
        if isinstance(extra, dict):
            data["tracker_models"] = {**default_trackers(), **extra}
        return data

    @model_validator(mode="after")
    def _consistent(self) -> CodesignSpec:
        unknown = [t for t in self.trackers if t not in self.tracker_models]
        if unknown:
            raise ValueError(f"trackers: {unknown} not in tracker_models "
                             f"({sorted(self.tracker_models)})")
        cam, sensor = self.plant.camera, self.camera.sensor
        if (cam.sensor_width_px, cam.sensor_height_px) != (sensor.width_px, sensor.height_px):
            raise ValueError(
                f"camera.sensor: {sensor.width_px} x {sensor.height_px} px differs from the "
                f"plant's camera {cam.sensor_width_px} x {cam.sensor_height_px} px"
            )
        for i, r in enumerate(self.references):  # run length and tilt stop, as in a scenario
            try:
                Scenario.model_validate({"plant": self.plant, "duration_s": self.duration_s,
                                         "reference": r})
            except ValidationError as exc:
                msg = "; ".join(e["msg"].removeprefix("Value error, ") for e in exc.errors())
                raise ValueError(f"references[{i}]: {msg}") from None
        return self

    @classmethod
    def from_yaml(cls, path: str | Path) -> CodesignSpec:
        """Load a spec file (``ConfigFileError`` for a file that is not a YAML mapping)."""
        return cls.model_validate(load_mapping(path))
