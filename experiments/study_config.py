"""The headline study's settings (``StudyConfig``), the plant it studies and its fixed
numbers: the seed's two tracker latencies, the trackers' display names and the sweep's batch
size (``experiments.study``)."""

from __future__ import annotations

import itertools
import warnings
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from experiments.intervals import widest_wilson_width
from latency import Engine
from latency.loss_model import check_tracker
from latency.models import SEED_LATENCY_S
from plant.params import PlantParams
from plant.user_files import plant_from_files

GK_MS = SEED_LATENCY_S["gk_transt"] * 1e3
DUAL_MS = SEED_LATENCY_S["dual_transt"] * 1e3
#: Display names of the trackers.
TRACKER_NAMES = {"gk_transt": "GK-TransT", "dual_transt": "dual TransT", "kcf_gk": "KCF+GK",
                 "k2cf": "K²CF"}
#: Each tracker's own latency in the seed (Table 1), where the study has one.
OWN_DELAY_MS = {"gk_transt": GK_MS, "dual_transt": DUAL_MS}
#: Most runs per batch of the batched engine in the study's sweep (``run_sweep`` makes the
#: number of batches a multiple of the workers). Our choice: 128, the engine's best batch size
#: measured (docs/closed_loop.md: 45x real time against 40x at 256).
STUDY_BATCH = 128
#: What ``pmspm study --full`` changes (our choice, within its 30-minute budget on two cores,
#: docs/closed_loop.md): every closed-loop point of the sweep and of the image-engine section
#: at 32 reference seeds (a probability of loss of control then has a 95 % Wilson interval at
#: most 33 % wide, against 53 % with the default's 10 seeds), and every tracker's image runs
#: at both of the seed's latencies.
FULL_STUDY = {"n_seeds": 32, "image_loop_n_seeds": 32, "image_loop_delays": "both"}


class StudyConfig(BaseModel):
    """Size of the study. The defaults run in minutes on two cores (docs/closed_loop.md)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    delays_ms: tuple[float, ...] = Field(
        (0.0, GK_MS, 24.0, DUAL_MS, 40.0, 50.0, 60.0),
        description="Observer latencies of the sweep, ms (seed 000 Table 1 values included). "
        "Our choice: below one frame period (27.8 ms, where the sequential observer starts to "
        "drop frames) 0, 16.33 and 24 ms; a 32-seed study with 8 ms as well lost control in "
        "none of its runs from 0 to 24 ms, and every metric there lay between its values at "
        "0 and 16.33 ms (docs/closed_loop.md), so 8 ms was dropped to keep `make study` "
        "under 10 minutes; the points go where loss of control sets in (31.23-60 ms).",
    )
    max_rates_rad_s: tuple[float, ...] = Field(
        (1.0, 3.0, 6.0), description="Peak angular rates of the random references, rad/s."
    )
    duration_s: float = Field(
        12.0, gt=0.5,
        description="Simulated time per sweep run, s. Our choice: 12 s, the length at which "
        "the loss-of-control verdict detects every run of the PID 20 ms beyond its stability "
        "boundary (200 of 200; 94.5 % at 8 s, 68.5 % at 4 s: an oscillation held back by "
        "Coulomb friction takes seconds to grow; benchmarks/bench_verdict.py, "
        "docs/closed_loop.md).",
    )
    reference_mode: Literal["per_seed", "fixed"] = Field(
        "per_seed",
        description="Random references: 'per_seed', each run's reference drawn from its own "
        "seed (``reference_seed`` = the run's seed), so that a point's intervals are over "
        "references and noise together; 'fixed', every run of every point on the one reference "
        "of seed ``FIXED_REFERENCE_SEED`` (noise-only spread: pixel noise and latency draws).",
    )
    n_seeds: int = Field(
        10,
        ge=1,
        description="Seeds per closed-loop point of the sweep (seeds 0..n-1), every point the "
        "same; each seed draws its own random reference (``reference_mode``). Our choice: 10, "
        "to keep `make study` near its 10-minute budget with runs of 12 s: 133 points x 10 "
        "seeds = 1,330 runs, 15,960 s simulated, of which the MPC's runs take nearly 90 % of "
        "the sweep's time (README: the measured times). A Wilson interval at 0 of 10 runs "
        "reaches 28 % (0 of 32: 11 %); the loss-of-control curves pool the references, 40 runs "
        "per delay (0 of 40: 9 %). `pmspm study --full` runs 32 (``FULL_STUDY``); raise it "
        "for narrower intervals (``loss_interval_width`` says how many).",
    )
    loss_interval_width: float | None = Field(
        None,
        gt=0.0,
        le=1.0,
        description="The widest 95 % interval of a point's probability of loss of control "
        "wanted (Wilson over the point's ``n_seeds`` runs, at its widest: half the runs "
        "lost). None: no check; else a warning names the width ``n_seeds`` achieves when it "
        "is wider.",
    )
    trackers: tuple[str, ...] = Field(
        ("gk_transt", "dual_transt"),
        description="Trackers whose own loss the sweep models (a calibrated loss model each, "
        "``latency.loss_model``; the sweep's ``tracker`` column): every tracker on the PID and "
        "MPC random-reference points, the first on the step and the controller variants.",
    )
    loss_model: Literal["calibrated", "search_window"] = Field(
        "calibrated", description="The sweep's tracking loss: each tracker's calibrated model, "
        "or the hand-set search window of ``search_radius_px`` (the same for every tracker).",
    )
    image_loop_n_seeds: int = Field(
        8,
        ge=1,
        description="Reference seeds per point of the image-engine section (every frame "
        "rendered and tracked by the tracker's networks; ``latency.image_engine``). Our "
        "choice: 8 in the default study (its budget), 32 with `pmspm study --full`.",
    )
    image_loop_rates_rad_s: tuple[float, ...] = Field(
        (1.0, 3.0, 6.0), description="Peak rates of the image-engine section's random "
        "references, rad/s (PID, at the seed's two latencies, each tracker).",
    )
    image_loop_duration_s: float = Field(
        2.0, gt=0.5, description="Simulated time per image-engine run, s (our choice: 72 "
        "frames at 36 Hz, to keep the default study in its budget).",
    )
    image_loop_delays: Literal["own", "both"] = Field(
        "own", description="Delays of the image-engine section: each tracker at its own seed "
        "latency (GK-TransT 16.33 ms, dual TransT 31.23 ms; the default study's budget), or "
        "every tracker at both (`pmspm study --full`).",
    )
    friction_compensation_Nm: float = Field(
        2.0e-3, ge=0.0, description="The PID variant's friction compensation, N·m (our "
        "choice: two thirds of the modelled Coulomb torque; the full 3 mN·m overcompensates)."
    )
    crossover_rad_s: float = Field(10.0, gt=0.0, description="PID crossover (PIDConfig default).")
    search_radius_px: float = Field(
        240.0, gt=0.0, description="Tracker search window radius, sensor px (our choice: KCF-like)."
    )
    sigma_px: float = Field(0.5, ge=0.0, description="Pixel noise, sensor px.")
    latency_frames: int = Field(
        30, ge=5, description="Frames per tracker for the latencies measured here."
    )
    margin_step_ms: float = Field(
        1.0, gt=0.0, le=30.0,
        description="Step of the margin tables' vision-delay grid from 0 to 60 ms, ms (the "
        "seed's two latencies are always in it). Our choice: 1 ms, fine enough for the curves "
        "to show each crossover's jumps.",
    )
    workers: int | None = None
    scheduler: str | None = None
    engine: Engine = Field(
        "batched", description="Closed-loop engine of the sweep and the time series (both "
        "measurement-model): batched (auto means the same here), or the event loop."
    )
    motor_file: Path | None = Field(
        None, description="The user's motor YAML (plant.motor_file); None: the seed's motor."
    )
    camera_file: Path | None = Field(
        None, description="The user's camera YAML (plant.camera_file, e.g. from pmspm "
        "calibrate); None: the default camera."
    )
    image_loop: bool = Field(
        True, description="Close the loop in image mode too (the batched image engine): "
        "tracking loss from the trackers themselves at the seed's two latencies, beside the "
        "calibrated models' (``image_loop_n_seeds``)."
    )

    @model_validator(mode="after")
    def _known_trackers(self) -> StudyConfig:
        """Trackers that have a calibrated loss model (``latency.loss_model``)."""
        if not self.trackers:
            raise ValueError("trackers must name at least one tracker")
        for t in self.trackers:
            check_tracker(t)
        return self

    @model_validator(mode="after")
    def _warn_wide_intervals(self) -> StudyConfig:
        """Warn when ``n_seeds`` cannot give intervals as narrow as ``loss_interval_width``."""
        if self.loss_interval_width is None:
            return self
        width = widest_wilson_width(self.n_seeds)
        if width > self.loss_interval_width:
            need = next(n for n in itertools.count(self.n_seeds)
                        if widest_wilson_width(n) <= self.loss_interval_width)
            warnings.warn(
                f"n_seeds = {self.n_seeds} gives 95 % intervals of the probability of loss of "
                f"control up to {width:.3f} wide, not the {self.loss_interval_width:g} of "
                f"loss_interval_width (it needs n_seeds >= {need})", stacklevel=2)
        return self


def study_plant(cfg: StudyConfig) -> PlantParams:
    """The plant the study analyses and simulates: the motor and camera files of ``cfg``
    (``plant.user_files.plant_from_files``; ``ValueError`` naming the file and the
    field), else ``PlantParams()``."""
    files = {k: str(v) for k, v in (("motor_file", cfg.motor_file),
                                     ("camera_file", cfg.camera_file)) if v is not None}
    return plant_from_files(files).get("plant", PlantParams())

