"""Calibrate a tracker's loss model on its own image-in-the-loop runs (``pmspm calibrate-loss``).

The design (``CalibrationDesign``): image-mode runs of the tracker in closed loop (PID, the
per-frame solver observer, the analytic renderer) on smooth random references of several peak
rates and reference seeds, at several constant vision delays, run by the batched image engine
(``latency.image_engine``). Each processed frame gives one record: the conditions the
measurement front end can compute (``latency.loss_model``: the prediction's miss, the blur,
the frames lost in a row), whether the loop counted the frame lost (the tracker said so, or a
centre lay more than 20 px from the truth), and the centre error. The fit
(``latency.loss_model.fit_logistic``) takes the records of the fit rates and seeds; the
held-out rates and reference seeds are run again with the calibrated measurement model, and the
two sides' lost-frame fraction and loss-of-control rate are compared point by point with their
95 % intervals (``validation`` in the file, ``docs/closed_loop.md``).

Resumable: the records of each batch of runs are written to ``<work>/records-<k>.parquet``
(through a temporary file); a new call with the same work folder and design skips the batches
already there. The model is written atomically (``latency.loss_model.write_loss_model``).
"""

from __future__ import annotations

import contextlib
import datetime as dt
import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator
from tqdm import tqdm

from experiments.intervals import (
    bootstrap_mean_ci,
    frame_fraction_ci,
    intervals_overlap,
    wilson_ci,
)
from latency import Scenario, build_loop, simulate_many
from latency.frontends import MarkerPrediction
from latency.image_engine import ImagePool, check_workers, run_images
from latency.loop_config import LoopResult
from latency.loss_model import (
    BASELINE_SCENE,
    FORMAT_VERSION,
    LossModelFile,
    blur_travel_px,
    check_tracker,
    current_weights_sha256,
    design_matrices,
    fit_logistic,
    prediction_offset_px,
    write_loss_model,
)
from latency.models import SEED_LATENCY_S
from plant.params import PlantParams

#: Scene appearances of the design (``Scenario.camera_effects``), our choices after the
#: tracking benchmark's hard cases that last a whole run: the nominal scene; ``dim``, the ring
#: light at 35 % with the gain doubled (darker markers, twice the read noise; the ``dark``
#: case); ``highlights``, four stationary specular highlights; ``distractor_red``, a red
#: sticker of marker size on the rotor; ``uneven_light``, a light gradient, vignetting and an
#: off-axis light spot (the held-out lighting's kind of change). Transient occluders are not
#: among them: the renderer draws a scene, not a finger entering it.
APPEARANCES: dict[str, dict] = {
    BASELINE_SCENE: {},
    "dim": {"illumination": 0.35, "gain": 2.0},
    "highlights": {"n_highlights": 4},
    "distractor_red": {"colour_distractor": "red"},
    "uneven_light": {"light_gradient": 0.5, "vignetting": 0.4, "light_spot": 0.6},
}


class CameraSetting(BaseModel):
    """One camera of the design: frame rate and exposure (``plant.camera``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    frame_rate_hz: float = Field(gt=0.0, description="Frames per second, Hz.")
    exposure_ms: float = Field(gt=0.0, description="Exposure time, ms (the motion blur).")


class CalibrationDesign(BaseModel):
    """The motions and cameras a tracker is calibrated on. Defaults are our choice: the study's
    rates and delays bracketed (the seed's two latencies included); the seed's camera (36 Hz,
    2 ms) and three others (60 Hz; 6 ms exposures); every (delay, rate, camera) point of a
    reference seed in one of ``appearances``, turned by one per point so that each appearance
    meets every delay, rate and camera across seeds; 4 s runs (144 frames at 36 Hz, 240 at
    60 Hz, of which the loop processes every second or third at the delays beyond a frame
    period). The defaults give 384 fit runs of 53,376 processed frames and 96 held-out runs."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    fit_rates_rad_s: tuple[float, ...] = Field((1.0, 3.0, 6.0, 9.0), description="Peak rates "
                                               "of the random references the fit uses, rad/s.")
    holdout_rates_rad_s: tuple[float, ...] = Field(
        (2.0, 4.5), description="Peak rates held out for validation, rad/s.")
    delays_ms: tuple[float, ...] = Field(
        (0.0, SEED_LATENCY_S["gk_transt"] * 1e3, SEED_LATENCY_S["dual_transt"] * 1e3, 45.0),
        description="Constant vision delays, ms.")
    fit_seeds: int = Field(6, ge=1, description="Reference seeds per fit point (0, 1, ...).")
    holdout_seeds: int = Field(3, ge=1, description="Reference seeds per held-out point "
                               "(holdout_first_seed, +1, ...).")
    holdout_first_seed: int = Field(1000, ge=0, description="First held-out reference seed "
                                    "(above the fit's 0 .. fit_seeds - 1).")
    model_replicas: int = Field(4, ge=1, description="Measurement-model runs per held-out "
                                "image run (other noise seeds, the same reference).")
    cameras: tuple[CameraSetting, ...] = Field(
        (CameraSetting(frame_rate_hz=36.0, exposure_ms=2.0),
         CameraSetting(frame_rate_hz=36.0, exposure_ms=6.0),
         CameraSetting(frame_rate_hz=60.0, exposure_ms=2.0),
         CameraSetting(frame_rate_hz=60.0, exposure_ms=6.0)),
        min_length=1, description="Cameras (frame rate, exposure); every point runs on each.")
    appearances: tuple[str, ...] = Field(
        tuple(APPEARANCES), min_length=1,
        description="Scene appearances (APPEARANCES), one per point in turn.")
    duration_s: float = Field(4.0, gt=0.5, description="Simulated time per run, s.")
    crossover_rad_s: float = Field(10.0, gt=0.0, description="PID crossover (rad/s).")

    @field_validator("appearances")
    @classmethod
    def _known_appearances(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        bad = [a for a in v if a not in APPEARANCES]
        if bad:
            raise ValueError(f"unknown appearance(s) {bad}; choose among {list(APPEARANCES)}")
        return v

    def points(self, holdout: bool) -> list[RunPoint]:
        """The runs of the fit (``holdout`` False) or the held-out part, seed by seed (each seed
        covers every delay, rate and camera, so a partial collection is balanced)."""
        rates = self.holdout_rates_rad_s if holdout else self.fit_rates_rad_s
        seeds = [self.holdout_first_seed + i for i in range(self.holdout_seeds)] if holdout \
            else list(range(self.fit_seeds))
        grid = [(d, r, c) for d in self.delays_ms for r in rates for c in self.cameras]
        n_app = len(self.appearances)
        return [RunPoint(delay_ms=d, rate_rad_s=r, camera=c, reference_seed=s,
                         appearance=self.appearances[(j + s) % n_app])
                for s in seeds for j, (d, r, c) in enumerate(grid)]

    @model_validator(mode="after")
    def _baseline_scene_and_seeds_apart(self) -> CalibrationDesign:
        if BASELINE_SCENE not in self.appearances:
            raise ValueError(f"appearances must include {BASELINE_SCENE!r}, the scene the "
                             "model's intercepts describe")
        if self.holdout_first_seed < self.fit_seeds:
            raise ValueError(f"holdout_first_seed {self.holdout_first_seed} is among the fit's "
                             f"reference seeds 0 .. {self.fit_seeds - 1}")
        return self

    def scenarios(self, tracker: str, holdout: bool) -> list[Scenario]:
        """The image-mode scenarios of ``points(holdout)``."""
        return [pt.scenario(tracker, self, "image") for pt in self.points(holdout)]


class RunPoint(BaseModel):
    """One run of the design: motion, delay, camera, scene and reference seed."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    delay_ms: float
    rate_rad_s: float
    camera: CameraSetting
    appearance: str
    reference_seed: int

    @property
    def name(self) -> str:
        """The run's name: delay, peak rate, camera, scene and reference seed."""
        c = self.camera
        return (f"{self.delay_ms:g}ms-{self.rate_rad_s:g}rad_s-{c.frame_rate_hz:g}hz-"
                f"{c.exposure_ms:g}ms_exp-{self.appearance}-r{self.reference_seed}")

    def run_name(self, tracker: str) -> str:
        """The name of ``tracker``'s run of this point (its scenario's, the records' ``run``)."""
        return f"{tracker}-{self.name}"

    def scenario(self, tracker: str, design: CalibrationDesign, mode: str,
                 loss: dict | None = None, noise_seed: int | None = None) -> Scenario:
        """The tracker's image run of this point, or its measurement-model twin (``loss`` the
        twin's loss model, ``noise_seed`` its own noise)."""
        c = self.camera
        body: dict = {
            "name": self.run_name(tracker),
            "duration_s": design.duration_s,
            "seed": self.reference_seed if noise_seed is None else noise_seed,
            "mode": mode,
            "plant": {"camera": {"frame_rate_hz": c.frame_rate_hz,
                                 "exposure_s": c.exposure_ms / 1e3}},
            "observer": {"kind": "solver"},
            "controller": {"kind": "pid", "config": {"crossover_rad_s": design.crossover_rad_s}},
            "reference": {"kind": "random", "args": {"max_rate_rad_s": self.rate_rad_s,
                                                     "seed": self.reference_seed}},
            "pipeline": {"observer": {"kind": "constant", "value_s": self.delay_ms / 1e3}},
        }
        if mode == "image":
            body["tracker"] = tracker
            body["camera_effects"] = APPEARANCES[self.appearance]
        if loss is not None:
            body["measurement"] = {"loss": loss}
        return Scenario.model_validate(body)


def frame_records(res: LoopResult, params: PlantParams) -> pd.DataFrame:
    """One row per processed frame of an image run: the loss model's conditions
    (``offset_px``, ``blur_px``, ``frames_lost``), the loop's ``lost`` flag and the centre
    errors (``err_*_px``, measured minus true, sensor px). The prediction is the measurement
    front end's (``MarkerPrediction``), advanced as it would be by the frames the loop kept,
    so the conditions are those the calibrated model sees when it runs."""
    fr = res.frames[~res.frames["dropped"].astype(bool)].reset_index(drop=True)
    steps = res.steps
    h = float(steps["t_s"].iloc[1] - steps["t_s"].iloc[0])
    q = steps[["qw", "qx", "qy", "qz"]].to_numpy()
    w = steps[["omega_x_rad_s", "omega_y_rad_s", "omega_z_rad_s"]].to_numpy()
    truth = fr[["true_red_u_px", "true_red_v_px", "true_yellow_u_px",
                "true_yellow_v_px"]].to_numpy().reshape(-1, 2, 2)
    meas = fr[["meas_red_u_px", "meas_red_v_px", "meas_yellow_u_px",
               "meas_yellow_v_px"]].to_numpy()
    lost = fr["lost"].to_numpy(dtype=bool)
    pred = MarkerPrediction(use_motion=True)
    rows, n_lost = [], 0
    for k in range(len(fr)):
        i = min(int(round(fr["t_exposure_s"].iloc[k] / h)), len(q) - 1)
        offset = prediction_offset_px(truth[k], pred.predicted_px)
        pred.frame()
        rows.append((offset, blur_travel_px(params, q[i], w[i]), n_lost, lost[k]))
        if lost[k]:
            n_lost += 1
        else:
            pred.measured(truth[k])
            n_lost = 0
    out = pd.DataFrame(rows, columns=["offset_px", "blur_px", "frames_lost", "lost"])
    err = meas - truth.reshape(-1, 4)
    for j, name in enumerate(("red_u", "red_v", "yellow_u", "yellow_v")):
        out[f"err_{name}_px"] = err[:, j]
    return out


def _run_records(tracker: str, design: CalibrationDesign, points: list[RunPoint], *,
                 workers: int | None = None, pool: ImagePool | None = None) -> pd.DataFrame:
    """The records of the image runs of ``points`` (``run_images``' ``workers`` or ``pool``),
    with each run's bookkeeping."""
    scenarios = [pt.scenario(tracker, design, "image") for pt in points]
    results = run_images(build_loop, scenarios, workers=workers, pool=pool)
    parts = []
    for pt, s, res in zip(points, scenarios, results, strict=True):
        rec = frame_records(res, s.plant)
        rec["delay_ms"] = pt.delay_ms
        rec["rate_rad_s"] = pt.rate_rad_s
        rec["frame_rate_hz"] = pt.camera.frame_rate_hz
        rec["exposure_ms"] = pt.camera.exposure_ms
        rec["appearance"] = pt.appearance
        rec["reference_seed"] = pt.reference_seed
        rec["run_lost_frame_fraction"] = res.summary["lost_frame_fraction"]
        rec["run_loss_of_control"] = res.summary["loss_of_control"]
        rec["run"] = s.name
        parts.append(rec)
    return pd.concat(parts, ignore_index=True)


def collect(tracker: str, design: CalibrationDesign, work: Path, workers: int = 2,
            batch_runs: int = 32, progress: bool = True) -> pd.DataFrame:
    """Run (or resume) the design's image runs; the records of all of them (``holdout``
    says which part). Batches already in ``work`` are read, not run again. ``workers``: the
    image engine's processes (1: in this process)."""
    check_workers(workers)
    work.mkdir(parents=True, exist_ok=True)
    stamp = work / "design.json"
    text = json.dumps({"tracker": tracker, "design": design.model_dump(mode="json")},
                      sort_keys=True)
    if stamp.exists() and stamp.read_text() != text:
        raise ValueError(f"{work} holds a calibration of another design or tracker; use "
                         "another --work folder or delete it")
    stamp.write_text(text)
    parts = []
    jobs = [(False, pt) for pt in design.points(False)] + \
        [(True, pt) for pt in design.points(True)]
    batches = [jobs[i : i + batch_runs] for i in range(0, len(jobs), batch_runs)]
    # one pool for every batch: its workers start (seconds each) once, not once a batch
    with ImagePool(workers) if workers > 1 else contextlib.nullcontext() as pool:
        for k, batch in enumerate(tqdm(batches, desc=f"calibrating {tracker}", unit="batch",
                                       disable=not progress)):
            path = work / f"records-{k:03d}.parquet"
            if not path.exists():
                rec = _run_records(tracker, design, [pt for _, pt in batch],
                                   workers=None if pool else 1, pool=pool)
                rec["holdout"] = rec["run"].map({pt.run_name(tracker): h for h, pt in batch})
                tmp = path.with_suffix(".tmp")
                rec.to_parquet(tmp)
                os.replace(tmp, path)
            parts.append(pd.read_parquet(path))
    return pd.concat(parts, ignore_index=True)


def robust_sigma_px(errors: np.ndarray) -> float:
    """1.4826 x the median absolute deviation of the finite errors (a Gaussian's sigma)."""
    e = errors[np.isfinite(errors)]
    if e.size == 0:
        return float("nan")
    return float(1.4826 * np.median(np.abs(e - np.median(e))))


def fit(tracker: str, records: pd.DataFrame, design: CalibrationDesign) -> LossModelFile:
    """The loss model of the fit part of ``records`` (see the module docstring)."""
    r = records[~records["holdout"]]
    Xh, Xp = design_matrices(r["offset_px"], r["blur_px"], r["frames_lost"])
    # one indicator per scene other than the baseline: its offset on both intercepts
    scenes = [a for a in design.appearances if a != BASELINE_SCENE]
    D = np.column_stack([(r["appearance"] == a).to_numpy(dtype=float) for a in scenes]) \
        if scenes else np.empty((len(r), 0))
    Xh, Xp = np.hstack([Xh, D]), np.hstack([Xp, D])
    after_tracked = r["frames_lost"].to_numpy() == 0
    lost = r["lost"].to_numpy(dtype=float)
    hazard = fit_logistic(Xh[after_tracked], lost[after_tracked])
    if np.any(~after_tracked):
        persistence = fit_logistic(Xp[~after_tracked], lost[~after_tracked])
    else:  # never lost in the design: a loss would last one frame
        persistence = np.r_[-20.0, np.zeros(Xp.shape[1])]
    k = len(scenes)
    offsets = {a: (float(hazard[-k + i]), float(persistence[-k + i]))
               for i, a in enumerate(scenes)}
    hazard, persistence = hazard[: len(hazard) - k], persistence[: len(persistence) - k]
    ok = ~r["lost"].to_numpy(dtype=bool)
    errs = r.loc[ok, [c for c in r.columns if c.startswith("err_")]].to_numpy().ravel()
    return LossModelFile(
        format_version=FORMAT_VERSION, tracker=tracker,
        weights_sha256=current_weights_sha256(tracker),
        hazard=tuple(float(x) for x in hazard), persistence=tuple(float(x) for x in persistence),
        noise_sigma_px=robust_sigma_px(errs), n_frames=len(r), n_runs=int(r["run"].nunique()),
        design=design.model_dump(mode="json"), scene_offsets=offsets,
        lost_by_condition=lost_by_condition(r),
        created_utc=dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
    )


def lost_by_condition(records: pd.DataFrame) -> list[dict]:
    """Lost-frame fraction and frame count of ``records`` per camera (frame rate, exposure) and
    per appearance: what the three-condition model averages over."""
    return [row for keys in (["frame_rate_hz", "exposure_ms"], ["appearance"])
            for row in records.groupby(keys)["lost"]
            .agg(frames="size", lost_frame_fraction="mean").reset_index().to_dict("records")]


def validate(tracker: str, records: pd.DataFrame, design: CalibrationDesign) -> list[dict]:
    """Held-out agreement per (delay, rate): the image runs' lost-frame fraction and
    loss-of-control rate against the calibrated measurement model's on the same references
    (``model_replicas`` noise seeds each), each with its 95 % interval (the image runs' lost
    frames counted from their records, ``frame_fraction_ci``); ``agree`` when both pairs of
    intervals overlap. Needs the model file written."""
    by_run = records[records["holdout"]].groupby("run")
    lost_by_run = by_run.first().assign(frames=by_run.size(), lost_frames=by_run["lost"].sum())
    twins, keys, image = [], [], []
    for pt in design.points(True):
        name = pt.run_name(tracker)
        if name not in lost_by_run.index:
            continue
        image.append((pt.delay_ms, pt.rate_rad_s, *lost_by_run.loc[name, [
            "lost_frames", "frames", "run_loss_of_control"]]))
        loss = {"kind": "calibrated", "tracker": tracker, "scene": pt.appearance}
        for m in range(design.model_replicas):
            twins.append(pt.scenario(tracker, design, "measurement", loss,
                                     noise_seed=pt.reference_seed + 10_000 * (m + 1)))
            keys.append((pt.delay_ms, pt.rate_rad_s))
    runs = pd.DataFrame(image, columns=["delay_ms", "rate_rad_s", "lost_frames", "frames",
                                        "run_loss_of_control"])
    model_runs = pd.DataFrame([(*k, r.summary["lost_frame_fraction"],
                                r.summary["loss_of_control"])
                               for k, r in zip(keys, simulate_many(twins, tables=False),
                                               strict=True)],
                              columns=["delay_ms", "rate_rad_s", "lost", "loc"])
    out = []
    for (d, rate), g in runs.groupby(["delay_ms", "rate_rad_s"]):
        m = model_runs[(model_runs["delay_ms"] == d) & (model_runs["rate_rad_s"] == rate)]
        img_lost = frame_fraction_ci(g["lost_frames"], g["frames"])
        mod_lost = bootstrap_mean_ci(m["lost"])
        img_loc = wilson_ci(int((g["run_loss_of_control"] > 0.5).sum()), len(g))
        mod_loc = wilson_ci(int((m["loc"] > 0.5).sum()), len(m))
        out.append({
            "delay_ms": float(d), "rate_rad_s": float(rate), "image_runs": len(g),
            "model_runs": len(m),
            "image_lost_frame_fraction": img_lost, "model_lost_frame_fraction": mod_lost,
            "image_loss_of_control": img_loc, "model_loss_of_control": mod_loc,
            "agree": intervals_overlap(img_lost, mod_lost) and intervals_overlap(img_loc, mod_loc),
        })
    return out


def calibrate(tracker: str, design: CalibrationDesign | None = None, work: Path | None = None,
              workers: int = 2, progress: bool = True) -> tuple[Path, LossModelFile]:
    """Collect (or resume), fit, write (``latency.loss_model.MODELS_DIR``), validate and write
    again with the validation rows; returns the file and its content."""
    check_tracker(tracker)
    design = design or CalibrationDesign()
    work = work or Path("runs") / f"calibrate-loss-{tracker}"
    records = collect(tracker, design, work, workers, progress=progress)
    data = fit(tracker, records, design)
    write_loss_model(data)
    data = data.model_copy(update={"validation": validate(tracker, records, design)})
    return write_loss_model(data), data
