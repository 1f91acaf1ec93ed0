"""One point of the co-design space (``Design``), the seed's design, how optuna proposes a
design (``suggest``), and the scenarios that evaluate it (``scenario_dict``)."""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, Literal

from pydantic import BaseModel, ConfigDict, Field

from experiments.codesign.spec import CodesignSpec, FloatRange, TrackerModel
from experiments.tuning.objective import SEED_Q_SCALE, SEED_R_SCALE
from latency import Scenario
from plant.camera_mode import CameraMode
from plant.params import PlantParams

if TYPE_CHECKING:
    from optuna.trial import BaseTrial


class Design(BaseModel):
    """A complete design: camera mode, tracker, observer and controller.

    Fields a design does not use (the pixel filter's q and r for another observer, the MPC's
    settings for a PID) keep their defaults and have no effect.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    rows: int = Field(2048, ge=16, description="ROI rows, sensor px.")
    cols: int = Field(2448, ge=16, description="ROI columns, sensor px.")
    follow: bool = Field(False, description="ROI follows the predicted markers.")
    binning: int = Field(1, ge=1, le=4)
    exposure_s: float = Field(2.0e-3, gt=0.0)
    frame_rate_hz: float | None = Field(None, gt=0.0, description="None: the mode's fastest.")
    tracker: str = "gk_transt"
    pipeline: Literal["sequential", "pipelined"] = "sequential"
    observer: Literal["pixel_kalman", "solver", "aekf"] = "pixel_kalman"
    q_scale: float = Field(SEED_Q_SCALE, gt=0.0)
    r_scale: float = Field(SEED_R_SCALE, gt=0.0)
    compensate_delay: bool = True
    controller: Literal["pid", "mpc"] = "pid"
    crossover_rad_s: float = Field(10.0, gt=0.0)
    zero_ratio: float = Field(3.0, gt=1.0)
    integral_ratio: float = Field(10.0, gt=0.0)
    mpc_horizon_steps: int = Field(15, ge=2)
    mpc_bandwidth_rad_s: float = Field(15.0, gt=0.0)

    def camera_mode(self, spec: CodesignSpec) -> CameraMode:
        """The camera mode of this design on the spec's sensor."""
        return CameraMode(rows=self.rows, cols=self.cols, follow=self.follow,
                          binning=self.binning, exposure_s=self.exposure_s,
                          frame_rate_hz=self.frame_rate_hz, sensor=spec.camera.sensor)

    def label(self) -> str:
        """A short description, e.g. for a table."""
        obs = {"pixel_kalman": f"pixel KF q={self.q_scale:.3g} r={self.r_scale:.3g}",
               "solver": "least squares",
               "aekf": f"AEKF{' +comp' if self.compensate_delay else ''}"}[self.observer]
        ctl = (f"PID {self.crossover_rad_s:.3g} rad/s a={self.zero_ratio:.2g} "
               f"b={self.integral_ratio:.2g}" if self.controller == "pid" else
               f"MPC N={self.mpc_horizon_steps} {self.mpc_bandwidth_rad_s:.3g} rad/s")
        roi = f"{self.rows}x{self.cols}{' follow' if self.follow else ''}"
        return (f"{roi} bin{self.binning} {self.exposure_s * 1e3:.2g} ms; {self.tracker} "
                f"{self.pipeline}; {obs}; {ctl}")


def seed_design() -> Design:
    """The seed's design: the whole sensor at 36 frames/s (seed 000 §5) with a 2 ms exposure,
    GK-TransT (16.33 ms, seed 000 Table 1) in the sequential host loop, the pixel Kalman filter
    with Q = 0.01·I4 and R = 0.1·I2 (seed 000 §3.2.1), and the default PID."""
    return Design(frame_rate_hz=36.0)


def _float(trial: BaseTrial, name: str, r: FloatRange) -> float:
    return r.low if r.fixed else trial.suggest_float(name, r.low, r.high, log=r.log)


def _pick(trial: BaseTrial, name: str, options: list) -> object:
    return options[0] if len(options) == 1 else trial.suggest_categorical(name, options)


def suggest(trial: BaseTrial, spec: CodesignSpec) -> Design:
    """The design optuna's ``trial`` proposes in the spec's space (define-by-run: only the
    variables the design uses are asked, e.g. q and r only for the pixel filter)."""
    c, o, k = spec.camera, spec.observer, spec.controller
    values: dict = {
        "rows": _pick(trial, "rows", c.rows), "cols": _pick(trial, "cols", c.cols),
        "binning": _pick(trial, "binning", c.binning),
        "exposure_s": _float(trial, "exposure_s", c.exposure_s),
        "tracker": _pick(trial, "tracker", spec.trackers),
        "pipeline": _pick(trial, "pipeline", o.pipeline),
        "observer": _pick(trial, "observer", o.kind),
        "controller": _pick(trial, "controller", k.kind),
    }
    sensor = spec.camera.sensor
    if values["rows"] < sensor.height_px or values["cols"] < sensor.width_px:
        values["follow"] = _pick(trial, "follow", c.follow)
    if values["observer"] == "pixel_kalman":
        values["q_scale"] = _float(trial, "q_scale", o.q_scale)
        values["r_scale"] = _float(trial, "r_scale", o.r_scale)
    if values["observer"] == "aekf":
        values["compensate_delay"] = _pick(trial, "compensate_delay", o.compensate_delay)
    if values["controller"] == "pid":
        for name in ("crossover_rad_s", "zero_ratio", "integral_ratio"):
            values[name] = _float(trial, name, getattr(k, name))
        if values["zero_ratio"] * values["integral_ratio"] <= 1.0:  # the rule's stability
            values["integral_ratio"] = 1.01 / values["zero_ratio"]
    else:
        values["mpc_horizon_steps"] = _pick(trial, "mpc_horizon_steps", k.mpc_horizon_steps)
        values["mpc_bandwidth_rad_s"] = _float(trial, "mpc_bandwidth_rad_s",
                                               k.mpc_bandwidth_rad_s)
    return Design(**values)


def _range_text(r: FloatRange) -> str:
    return f"{r.low:g}" if r.fixed else f"[{r.low:g}, {r.high:g}]{' log' if r.log else ''}"


def tracker_of(spec: CodesignSpec, design: Design) -> TrackerModel:
    """The tracker model of the design (``ValueError`` naming it if the spec lacks it)."""
    try:
        return spec.tracker_models[design.tracker]
    except KeyError:
        raise ValueError(f"tracker {design.tracker!r} not in tracker_models") from None


def plant_of(spec: CodesignSpec, design: Design) -> PlantParams:
    """The spec's plant with the design's camera timing (frame rate, exposure)."""
    camera = design.camera_mode(spec).camera_params(spec.plant.camera)
    return spec.plant.model_copy(update={"camera": camera})


def scenario_dict(spec: CodesignSpec, design: Design, seed: int, reference_index: int) -> dict:
    """The measurement-model scenario of one run of ``design`` (a JSON-able dict): the camera
    mode's timing, noise and region of interest, the tracker's latency and loss model, the
    observer and the controller. A ``random`` reference without a seed takes the run's."""
    mode = design.camera_mode(spec)
    tracker = tracker_of(spec, design)
    ref = spec.references[reference_index].model_dump(mode="json")
    if ref.get("kind") == "random":
        ref.setdefault("args", {}).setdefault("seed", int(seed))
    sigma = mode.sigma_px * tracker.noise_scale
    never = math.ceil(spec.duration_s * mode.rate_hz) + 1  # more frames than the run has
    observer: dict = {"kind": design.observer}
    if design.observer == "pixel_kalman":
        observer |= {"pixel_q_scale": design.q_scale, "pixel_r_scale": design.r_scale}
    elif design.observer == "aekf":
        observer |= {"compensate_delay": design.compensate_delay,
                     "aekf": {"sigma_px": max(sigma, 0.05)}}
    if design.controller == "pid":
        controller = {"kind": "pid", "config": {
            "crossover_rad_s": design.crossover_rad_s, "zero_ratio": design.zero_ratio,
            "integral_ratio": design.integral_ratio}}
    else:
        controller = {"kind": "mpc", "config": {
            "horizon_steps": design.mpc_horizon_steps,
            "bandwidth_rad_s": design.mpc_bandwidth_rad_s}}
    roi = mode.roi
    d = {
        "name": spec.name,
        "duration_s": spec.duration_s,
        "seed": int(seed),
        "mode": "measurement",
        "plant": plant_of(spec, design).model_dump(mode="json"),
        "pipeline": {"observer": tracker.latency_model().model_dump(mode="json"),
                     "mode": design.pipeline, "readout_s": mode.readout_s},
        "measurement": {
            "sigma_px": sigma, "dropout_prob": tracker.dropout_prob,
            "loss": {"kind": "search_window", "search_radius_px": tracker.search_radius_px,
                     "reacquire_after_frames": never if tracker.reacquire_after_frames is None
                     else tracker.reacquire_after_frames,
                     "blur_limit_px": tracker.blur_limit_px},
            "roi": None if roi is None else roi.model_dump(mode="json"),
        },
        "observer": observer,
        "controller": controller,
        "reference": ref,
    }
    return json.loads(json.dumps(d))


def compute_per_frame_s(spec: CodesignSpec, design: Design) -> float:
    """Compute per processed frame, s: the tracker's mean latency plus the controller's compute
    latency as the scenario applies it (the MPC's measured call time; 0 for the PID)."""
    s = Scenario.model_validate(scenario_dict(spec, design, spec.seeds[0], 0))
    return s.pipeline.observer.mean_s + s.controller_latency.mean_s


def space_summary(spec: CodesignSpec) -> list[str]:
    """One line per variable of the spec's space, for the report."""
    c, o, k = spec.camera, spec.observer, spec.controller
    return [
        f"camera rows {c.rows}, cols {c.cols}, follow {c.follow}, binning {c.binning}, "
        f"exposure {_range_text(c.exposure_s)} s",
        f"trackers {spec.trackers}",
        f"observer pipeline {o.pipeline}, back end {o.kind}, q {_range_text(o.q_scale)}, "
        f"r {_range_text(o.r_scale)}, delay compensation {o.compensate_delay}",
        f"controller {k.kind}: PID crossover {_range_text(k.crossover_rad_s)} rad/s, zero ratio "
        f"{_range_text(k.zero_ratio)}, integral ratio {_range_text(k.integral_ratio)}; MPC "
        f"horizon {k.mpc_horizon_steps}, bandwidth {_range_text(k.mpc_bandwidth_rad_s)} rad/s",
    ]
