"""The headline study: what does vision delay do to the PMSpM attitude loop?

One module of about 780 lines: its parts (margins, sweep, time series, image loop, summary) read
one configuration and each other's tables; the plots are in ``study_plots``, the page in
``report``.

``run_study`` answers the design card's questions on the embedded default, or on the user's
motor and camera (``StudyConfig.motor_file``, ``camera_file``), and writes a report
folder (``runs/<timestamp>-study/``) with ``report.md``, ``report.html``, PNG plots and Parquet
tables:

1. **Margins against delay** (analysis, no simulation): critical phase margin, delay margin,
   headroom and jitter margin of the per-axis PID loop as it runs (and of the MPC's linearised
   law) against the vision delay 0–60 ms, for the sequential observer of the seed (a frame that
   arrives while the observer is busy is dropped, so a slower observer also lowers the update
   rate) and for a pipelined observer (no drops), with the timing of ``latency.pipeline``.
   GK-TransT's 16.33 ms, the dual TransT's 31.23 ms (seed 000 Table 1) and both trackers'
   latencies measured here are marked.
2. **Closed-loop sweep** (measurement-model loop through ``experiments.sweep``), ``n_seeds``
   seeds per point with 95 % intervals (``experiments.intervals``): RMS attitude error,
   lost-frame fraction and probability of loss of control against delay and against the
   reference's aggressiveness (peak angular rate of a smooth random trajectory), for PID and
   MPC; tilt-step metrics against the commanded step for every controller variant (PID with and
   without reference feedforward and with friction compensation, MPC with and without reference
   preview); the predicted stability boundary over the simulated loss of control.
   With ``image_loop`` (``pmspm study --full``): the loop closed in image mode with GK-TransT
   and with the dual TransT, each at its latency measured here, lost frames, error and loss of
   control with intervals (not in the default study: it takes minutes per run; the default
   report says how to get it).
3. **Time series** of a 5° tilt step at 16.33 ms and at 31.23 ms, PID and MPC side by side.
4. A plain-language **summary** generated from the numbers and the facts measured in the run.

Delay convention: "vision delay" is the observer's processing latency (the seed's Table 1 figure);
the loop's total delay adds half the exposure (mid-exposure time stamp).
"""
from __future__ import annotations

import datetime as dt
import functools
import itertools
import json
import os
import platform
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Literal

import control as ct
import numpy as np
import pandas as pd
from pydantic import BaseModel, ConfigDict, Field, model_validator

from controller.mpc import MPCConfig
from controller.pid import PIDConfig, PIDController
from controller.registry import MPCSpec, PIDSpec
from experiments.intervals import intervals_overlap, seed_intervals, widest_wilson_width
from experiments.report import write_report
from experiments.study_plots import (
    CONTROLLER_STYLE,
    plot_boundary_overlay,
    plot_margins,
    plot_pm_pid_vs_mpc,
    plot_steps,
    plot_sweep,
    plot_time_series,
)
from experiments.sweep import run_sweep
from latency import Engine, Scenario, build_loop, simulate, simulate_many
from latency.image_engine import run_images
from latency.loss_model import check_tracker, load_loss_model
from latency.margins import (
    Margins,
    as_run_margins,
    attitude_plant,
    first_unstable_delay,
    sampled_margins,
    sampled_stable,
)
from latency.metrics import SETTLE_BAND_DEG
from latency.models import SEED_LATENCY_S
from latency.mpc_law import mpc_discrete_law, mpc_state_gain
from latency.pipeline import LoopTiming, PipelineConfig, PipelineMode
from latency.profile import measure_pair_tracker_latency
from latency.scenario import MPC_CALL_MEDIAN_S
from latency.simulation import run_summaries
from plant.params import PlantParams
from plant.user_files import plant_from_files

GK_MS = SEED_LATENCY_S["gk_transt"] * 1e3
DUAL_MS = SEED_LATENCY_S["dual_transt"] * 1e3
#: Display names of the trackers.
TRACKER_NAMES = {"gk_transt": "GK-TransT", "dual_transt": "dual TransT", "kcf_gk": "KCF+GK",
                 "k2cf": "K²CF"}
#: Each tracker's own latency in the seed (Table 1), where the study has one.
OWN_DELAY_MS = {"gk_transt": GK_MS, "dual_transt": DUAL_MS}
#: Most runs per batch of the batched engine in the study's sweep (the runs are spread evenly
#: over the workers first). Our choice: 128, the engine's best batch size measured
#: (docs/closed_loop.md: 45x real time against 40x at 256), and 28 batches for the default
#: sweep's 3,584 runs instead of 14, so the last batch, which one worker runs while the other
#: may be done, is half as long.
STUDY_BATCH = 128


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
        "to keep the simulated time of the former default (32 seeds of 4 s, a sweep of about "
        "6 min on two idle cores, docs/closed_loop.md) with runs of 12 s: 91 points x 10 "
        "seeds = 910 runs, 10,920 s simulated against 11,648 s (not yet timed at this "
        "length). A Wilson interval at 0 of 10 runs reaches 28 % (0 of 32: 11 %); the "
        "loss-of-control curves pool the references, 40 runs per delay (0 of 40: 9 %). "
        "Raise it for narrower intervals (``loss_interval_width`` says how many).",
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


# --- 1. margins -----------------------------------------------------------------------------
OBSERVER_MODES: tuple[PipelineMode, ...] = ("sequential", "pipelined")


def _vision_delays_ms() -> list[float]:
    """The margin tables' vision delays: 0-60 ms by 1 ms and the seed's two latencies."""
    return np.linspace(0.0, 60.0, 61).tolist() + [GK_MS, DUAL_MS]


def loop_timing_for(
    params: PlantParams, vision_delay_s: float, mode: PipelineMode, compute_s: float = 0.0
) -> LoopTiming:
    """Update period and loop delay of the camera of ``params`` (``latency.pipeline``)."""
    pipe = PipelineConfig.from_camera(params.camera, mode=mode)
    return pipe.timing(compute_s, vision_delay_s)


def pid_axis_margins(
    params: PlantParams, crossover_rad_s: float, vision_delay_s: float, mode: PipelineMode,
    axis: int = 1,
) -> tuple[LoopTiming, Margins]:
    """Margins of one axis of the PID loop as it runs: its discrete ``C(z)`` at the update
    period of the observer ``mode`` for this vision delay (s), on ``1/(J s² + b s)``
    (``latency.margins.as_run_margins``). The CLI, the study and the notebook call this."""
    pid = PIDController(PIDConfig(crossover_rad_s=crossover_rad_s), params)
    timing = loop_timing_for(params, vision_delay_s, mode)
    m = as_run_margins(
        pid.discrete_transfer_function(timing.update_period_s, axis=axis),
        inertia_kgm2=float(pid.J[axis]), damping_Nms_per_rad=params.rotor.viscous_Nms_per_rad,
        delay_s=timing.delay_s,
    )
    return timing, m


def _headroom_column(
    vision_delays_s: list[float], stable_at: Callable[[float], bool]
) -> list[float]:
    """Extra vision delay (s) each row tolerates before the loop is unstable, scanned through
    the pipeline (``stable_at`` rebuilds the loop with the update period of that delay); NaN
    where the row itself is unstable."""
    cached = functools.cache(stable_at)
    out = []
    for d in vision_delays_s:
        first = first_unstable_delay(cached, d)
        out.append(first - d if first > d else np.nan)
    return out


def _pid_stable_at(
    params: PlantParams, crossover_rad_s: float, mode: PipelineMode
) -> Callable[[float], bool]:
    """Stability of the axis-1 PID loop as it runs, as a function of the vision delay (s)."""
    pid = PIDController(PIDConfig(crossover_rad_s=crossover_rad_s), params)
    plant = attitude_plant(float(pid.J[1]), params.rotor.viscous_Nms_per_rad)

    def stable_at(d: float) -> bool:
        t = loop_timing_for(params, d, mode)
        C = pid.discrete_transfer_function(t.update_period_s, axis=1)
        return sampled_stable(plant, C, delay_s=t.delay_s)

    return stable_at


def pid_headroom_s(
    params: PlantParams, crossover_rad_s: float, vision_delay_s: float, mode: PipelineMode
) -> float:
    """Extra vision delay (s) the PID loop tolerates, scanned through the pipeline."""
    stable_at = _pid_stable_at(params, crossover_rad_s, mode)
    return _headroom_column([vision_delay_s], stable_at)[0]


def margins_table(
    params: PlantParams, cfg: StudyConfig, modes: tuple[PipelineMode, ...] = OBSERVER_MODES
) -> pd.DataFrame:
    """Per-axis PID margins against the vision delay (ms) for the observer ``modes``.

    Columns: the timing (``update_period_s``, ``loop_delay_s``), stability, the critical
    crossover's phase margin and frequency, gain margins, the number of gain crossovers, the
    constant-delay margin at the row's fixed update period, the jitter margin of the discrete
    law and ``headroom_s``, the extra vision delay before instability scanned through the
    pipeline (the update period of a sequential observer grows with the delay)."""
    rows = []
    for mode in modes:
        delays = _vision_delays_ms()
        stable_at = _pid_stable_at(params, cfg.crossover_rad_s, mode)
        head = _headroom_column([d / 1e3 for d in delays], stable_at)
        for d_ms, h in zip(delays, head, strict=True):
            timing, m = pid_axis_margins(params, cfg.crossover_rad_s, d_ms / 1e3, mode)
            rows.append(_margin_row(d_ms, timing, m) | {"headroom_s": h})
    return pd.DataFrame(rows).sort_values(["observer", "vision_delay_ms"]).reset_index(drop=True)


def _margin_row(d_ms: float, timing: LoopTiming, m: Margins) -> dict:
    """One row of a margin table; margins NaN where the loop is unstable."""
    ok = bool(m.stable)

    def v(x: float) -> float:
        return float(x) if ok else np.nan

    return {
        "vision_delay_ms": d_ms, "observer": timing.mode,
        "update_period_s": timing.update_period_s, "loop_delay_s": timing.delay_s,
        "stable": ok, "phase_margin_deg": v(m.phase_margin_deg),
        "crossover_rad_s": v(m.crossover_rad_s), "gain_margin": v(m.gain_margin),
        "gain_margin_lower": v(m.gain_margin_lower), "n_crossovers": len(m.crossovers_rad_s),
        "conditionally_stable": m.conditionally_stable,
        "delay_margin_s": v(m.delay_margin_s), "jitter_margin_s": v(m.jitter_margin_s),
    }


class _MPCLoop:
    """The axis-1 loop of the MPC's linearised law (``latency.mpc_law``) on ``params``: the
    plant ``1/(J s² + b s)``, the law at a loop timing, the MPC's compute time (s) that the
    loop's delay adds (``latency.scenario.MPC_CALL_MEDIAN_S``, measured here)."""

    def __init__(self, params: PlantParams, mpc: MPCConfig) -> None:
        self.params = params
        self.compute_s = MPC_CALL_MEDIAN_S[(mpc.solver, mpc.hessian)]
        self.K = mpc_state_gain(mpc, params)
        self.J = float(params.rotor.inertia_about_centre_kgm2[1, 1])
        self.b = params.rotor.viscous_Nms_per_rad
        self.plant = attitude_plant(self.J, self.b)

    def law(self, t: LoopTiming, aware: bool) -> ct.StateSpace:
        """The law at the timing ``t``, delay-aware (the MPC knows its latency) or not."""
        return mpc_discrete_law((self.K[1, 1], self.K[1, 4]), inertia_kgm2=self.J,
                                damping_Nms_per_rad=self.b, period_s=t.update_period_s,
                                delay_s=t.delay_s, delay_aware=aware)

    def stable_at(self, mode: PipelineMode, aware: bool) -> Callable[[float], bool]:
        """Stability as a function of the vision delay (s), scanned through the pipeline."""
        def stable(d: float) -> bool:
            t = loop_timing_for(self.params, d, mode, self.compute_s)
            return sampled_stable(self.plant, self.law(t, aware), delay_s=t.delay_s)

        return stable


def mpc_headroom_s(
    params: PlantParams, vision_delay_s: float, mode: PipelineMode, mpc: MPCConfig | None = None
) -> float:
    """Extra vision delay (s) the delay-aware MPC's linearised law tolerates, scanned through
    the pipeline (NaN where it is unstable): :func:`pid_headroom_s` for the MPC."""
    loop = _MPCLoop(params, mpc or MPCConfig())
    return _headroom_column([vision_delay_s], loop.stable_at(mode, True))[0]


def mpc_margins_table(
    params: PlantParams, cfg: StudyConfig, mpc: MPCConfig | None = None
) -> pd.DataFrame:
    """Per-axis margins of the MPC's linearised law (``latency.mpc_law``) against the vision
    delay (ms), sequential and pipelined observer, delay-aware (the MPC knows its latency) and,
    for comparison, without the delay compensation. Same columns as :func:`margins_table` plus
    ``delay_aware`` (no jitter margin: the law's state-space form is analysed sampled only).
    The loop's delay adds the MPC's own compute time, as the scenarios do
    (``latency.scenario.MPC_CALL_MEDIAN_S``, measured here), and the MPC predicts across it."""
    loop = _MPCLoop(params, mpc or MPCConfig())
    rows = []
    for mode in OBSERVER_MODES:
        for aware in (True, False):
            delays = _vision_delays_ms()
            head = _headroom_column([d / 1e3 for d in delays], loop.stable_at(mode, aware))
            for d_ms, h in zip(delays, head, strict=True):
                t = loop_timing_for(params, d_ms / 1e3, mode, loop.compute_s)
                mg = sampled_margins(loop.plant, loop.law(t, aware), delay_s=t.delay_s)
                rows.append(_margin_row(d_ms, t, mg)
                            | {"delay_aware": aware, "headroom_s": h, "jitter_margin_s": np.nan})
    return (pd.DataFrame(rows).sort_values(["observer", "delay_aware", "vision_delay_ms"])
            .reset_index(drop=True))


# --- 2. closed-loop sweep -------------------------------------------------------------------
def _controller_spec(name: str, cfg: StudyConfig) -> PIDSpec | MPCSpec:
    """The sweep's controller variants (``study_plots.CONTROLLER_STYLE``)."""
    pid = {"crossover_rad_s": cfg.crossover_rad_s}
    specs = {
        "pid": lambda: PIDSpec(config=PIDConfig(**pid)),
        "pid_noff": lambda: PIDSpec(config=PIDConfig(**pid, feedforward=False)),
        "pid_friction": lambda: PIDSpec(config=PIDConfig(
            **pid, friction_compensation_Nm=cfg.friction_compensation_Nm)),
        "mpc": lambda: MPCSpec(),
        "mpc_nopreview": lambda: MPCSpec(config=MPCConfig(reference_preview=False)),
    }
    return specs[name]()


#: Controllers of the sweep: every variant on the fastest random reference, every variant but
#: the PID without reference feedforward on the step (the step's feedforward is zero, so those
#: runs would repeat the PID's bit for bit: 256 runs of the default study), PID and MPC on the
#: other random references.
VARIANTS = ("pid", "pid_noff", "pid_friction", "mpc", "mpc_nopreview")
STEP_CONTROLLERS = tuple(c for c in VARIANTS if c != "pid_noff")
RANDOM_CONTROLLERS = ("pid", "mpc")


STEP_REFERENCE = ("tilt_step_5deg", {"kind": "tilt_step", "tilt_deg": 5.0, "t_step_s": 0.1}, 0.0)
#: The random references' seed in the fixed-reference mode (``StudyConfig.reference_mode``).
FIXED_REFERENCE_SEED = 7


def _random_reference(rate_rad_s: float) -> tuple[str, dict, float]:
    """A smooth random reference of peak rate ``rate_rad_s``: (name, spec, rate); its seed is
    set per run (``_with_reference_seed``)."""
    return (f"random_{rate_rad_s:g}rad_s",
            {"kind": "random", "args": {"max_rate_rad_s": rate_rad_s}}, rate_rad_s)


def reference_seed(cfg: StudyConfig, seed: int) -> int:
    """The random reference's seed of the run with seed ``seed``: the run's own seed
    (``reference_mode`` 'per_seed') or ``FIXED_REFERENCE_SEED`` ('fixed')."""
    return seed if cfg.reference_mode == "per_seed" else FIXED_REFERENCE_SEED


def _with_reference_seed(ref: dict, cfg: StudyConfig, seed: int) -> tuple[dict, float]:
    """The reference spec ``ref`` of the run with seed ``seed`` and its reference seed (NaN
    for a reference that draws nothing, the step)."""
    if ref["kind"] != "random":
        return ref, float("nan")
    r = reference_seed(cfg, seed)
    return {**ref, "args": {**ref["args"], "seed": r}}, float(r)


def _loss(cfg: StudyConfig, tracker: str) -> dict:
    """The sweep's ``measurement.loss`` for ``tracker`` (``StudyConfig.loss_model``)."""
    if cfg.loss_model == "calibrated":
        return {"kind": "calibrated", "tracker": tracker}
    return {"kind": "search_window", "search_radius_px": cfg.search_radius_px}


def sweep_configs(cfg: StudyConfig, params: PlantParams | None = None) -> list[dict]:
    """The sweep's scenarios as dicts (delay x tracker x controller x reference x seed) on the
    plant ``params`` (default ``study_plant(cfg)``): every tracker of ``cfg.trackers`` on the
    PID and MPC random-reference points, the first one on the step and on the variants."""
    params = params or study_plant(cfg)
    out = []
    refs = [(*STEP_REFERENCE, STEP_CONTROLLERS)]
    fastest = max(cfg.max_rates_rad_s, default=None)
    refs += [(*_random_reference(w), VARIANTS if w == fastest else RANDOM_CONTROLLERS)
             for w in cfg.max_rates_rad_s]
    for d in cfg.delays_ms:
        for ref_name, ref, rate, controllers in refs:
            for ctrl in controllers:
                every = ref["kind"] == "random" and ctrl in RANDOM_CONTROLLERS
                for tracker in cfg.trackers if every else cfg.trackers[:1]:
                    for seed in range(cfg.n_seeds):
                        run_ref, ref_seed = _with_reference_seed(ref, cfg, seed)
                        s = Scenario(
                            name=f"{tracker}-{ctrl}-{ref_name}-{d:g}ms-s{seed}",
                            duration_s=cfg.duration_s,
                            seed=seed,
                            plant=params,
                            observer={"kind": "solver"},
                            controller=_controller_spec(ctrl, cfg),
                            reference=run_ref,
                            pipeline={"observer": {"kind": "constant", "value_s": d / 1e3}},
                            measurement={"sigma_px": cfg.sigma_px, "loss": _loss(cfg, tracker)},
                        )
                        c = s.model_dump(mode="json")
                        c["study"] = {"tracker": tracker, "controller": ctrl,
                                      "reference": ref_name, "delay_ms": d,
                                      "max_rate_rad_s": rate, "reference_seed": ref_seed}
                        out.append(c)
    return out


def study_run(config: dict) -> dict:
    """Sweep entry point, event loop: the scenario's summary (the ``study`` block is
    bookkeeping)."""
    return simulate(Scenario.model_validate(_scenario_part(config)), engine="event").summary


def study_runs(configs: list[dict]) -> list[dict | Exception]:
    """Batched sweep entry point: the summaries of ``study_run``, the runs advanced together."""
    return run_summaries([_scenario_part(c) for c in configs])


def _scenario_part(config: dict) -> dict:
    return {k: v for k, v in config.items() if k != "study"}


def tidy_sweep(df: pd.DataFrame) -> pd.DataFrame:
    """One row per run: the study's bookkeeping (controller, reference, delay, rate, seed, the
    random reference's seed ``reference_seed``, NaN for the step, and the tracker of the
    image-mode runs) and the run's summary metrics."""
    keep = {
        "config.study.tracker": "tracker",
        "config.study.controller": "controller",
        "config.study.reference": "reference",
        "config.study.delay_ms": "vision_delay_ms",
        "config.study.max_rate_rad_s": "max_rate_rad_s",
        "config.seed": "seed",
        "config.study.reference_seed": "reference_seed",
        "error": "error",
    }
    keep = {k: v for k, v in keep.items() if k in df.columns}
    out = df[list(keep)].rename(columns=keep)
    for c in df.columns:
        if c.startswith("result."):
            out[c.removeprefix("result.")] = df[c]
    order = [c for c in ("tracker", "controller", "reference", "vision_delay_ms") if c in out]
    return out.sort_values(order).reset_index(drop=True)


#: Columns of the sweep summarised over seeds (means with bootstrap intervals).
SWEEP_MEANS = ("rms_error_deg", "lost_frame_fraction", "overshoot_pct", "settling_time_s",
               "steady_state_error_deg")


def sweep_intervals(sweep: pd.DataFrame) -> pd.DataFrame:
    """Mean over seeds with 95 % intervals per controller, reference and delay (bootstrap for
    means, Wilson for the probability of loss of control and the fraction of runs that settle;
    ``settling_time_s`` is the mean over the runs that settle; the step metrics, the settled
    fraction among them, are NaN on the random references). Failed runs are left out."""
    ok = sweep[sweep.error == ""].assign(
        settled=lambda d: np.where(np.isfinite(d.step_size_deg),
                                   np.isfinite(d.settling_time_s), np.nan)
    )
    return seed_intervals(ok, ["tracker", "controller", "reference", "vision_delay_ms"],
                          SWEEP_MEANS,
                          ("loss_of_control", "settled"))


def loss_intervals(sweep: pd.DataFrame) -> pd.DataFrame:
    """Probability of loss of control per tracker, controller and delay over the random
    references' runs (every peak rate and seed pooled; the step, run with the first tracker
    only, is left out so that every tracker's figure pools the same references), with Wilson
    intervals."""
    ok = sweep[(sweep.error == "") & sweep.controller.isin(RANDOM_CONTROLLERS)
               & sweep.reference.str.startswith("random")]
    return seed_intervals(ok, ["tracker", "controller", "vision_delay_ms"], (),
                          ("loss_of_control",))


def predicted_boundary_ms(margins: pd.DataFrame) -> float:
    """First vision delay (ms) at which the sequential-observer loop is unstable: the
    headroom of the zero-delay row (the delay scanned through the pipeline)."""
    row = margins[(margins.observer == "sequential") & np.isclose(margins.vision_delay_ms, 0.0)]
    return float(1e3 * row.headroom_s.iloc[0]) if len(row) else float("nan")


# --- 2b. tracking loss from the trackers themselves (the image engine) ---------------------
#: The image-engine section's metrics, image runs and calibrated-model twins alike.
IMAGE_MEANS = ("rms_error_deg", "lost_frame_fraction")


def image_loop_scenarios(cfg: StudyConfig, params: PlantParams) -> list[tuple[dict, Scenario]]:
    """The image-engine section's runs (tracker x the seed's latencies, its own or both
    (``image_loop_delays``) x peak rate x reference seed, PID, the per-frame solver, analytic
    renderer): bookkeeping and scenario. A tracker without a seed latency of its own runs at
    both."""
    out = []
    for tracker in cfg.trackers:
        own = OWN_DELAY_MS.get(tracker)
        delays = (own,) if cfg.image_loop_delays == "own" and own is not None \
            else (GK_MS, DUAL_MS)
        for d in delays:
            for rate in cfg.image_loop_rates_rad_s:
                ref_name, ref, _ = _random_reference(rate)
                for seed in range(cfg.image_loop_n_seeds):
                    run_ref, ref_seed = _with_reference_seed(ref, cfg, seed)
                    s = Scenario(
                        name=f"image-{tracker}-{ref_name}-{d:.2f}ms-s{seed}",
                        duration_s=cfg.image_loop_duration_s, seed=seed, mode="image",
                        tracker=tracker, plant=params,
                        observer={"kind": "solver"}, controller=_controller_spec("pid", cfg),
                        reference=run_ref,
                        pipeline={"observer": {"kind": "constant", "value_s": d / 1e3}},
                    )
                    book = {"tracker": tracker, "controller": "pid", "reference": ref_name,
                            "vision_delay_ms": d, "max_rate_rad_s": rate, "seed": seed,
                            "reference_seed": ref_seed}
                    out.append((book, s))
    return out


def _twin(s: Scenario, tracker: str) -> Scenario:
    """The measurement-model run with ``tracker``'s calibrated loss on the same reference,
    delay, seed and duration as the image run ``s``."""
    body = s.model_dump(mode="json")
    del body["tracker"]
    body |= {"mode": "measurement", "name": s.name.replace("image-", "model-", 1),
             "measurement": {"loss": {"kind": "calibrated", "tracker": tracker}}}
    return Scenario.model_validate(body)


def image_loop(cfg: StudyConfig, params: PlantParams, out: Path) -> pd.DataFrame:
    """Run the image-engine section (``latency.image_engine``) and the calibrated models'
    twins on the same references; one row per tracker, delay and rate with both sides' 95 %
    intervals (bootstrap for means, Wilson for loss of control) and ``agree`` (the image
    runs' and the model's intervals overlap for the lost-frame fraction and for loss of
    control). Run tables: ``image_loop.parquet`` (``side`` image or model)."""
    jobs = image_loop_scenarios(cfg, params)
    if not jobs:
        return pd.DataFrame()
    books = [b for b, _ in jobs]
    images = run_images(build_loop, [s for _, s in jobs], workers=cfg.workers or 2,
                        progress=True)
    twins = simulate_many([_twin(s, b["tracker"]) for b, s in jobs], tables=False)
    runs = pd.DataFrame(
        [b | {"side": side} | r.summary for side, res in (("image", images), ("model", twins))
         for b, r in zip(books, res, strict=True)])
    runs.to_parquet(out / "image_loop.parquet")
    by = ["tracker", "vision_delay_ms", "max_rate_rad_s"]
    sides = {side: seed_intervals(g, by, IMAGE_MEANS, ("loss_of_control",)).set_index(by)
             for side, g in runs.groupby("side")}
    table = sides["image"].add_prefix("image_").join(sides["model"].add_prefix("model_"))
    table["agree"] = [
        _overlap(r, "image_lost_frame_fraction", "model_lost_frame_fraction")
        and _overlap(r, "image_p_loss_of_control", "model_p_loss_of_control")
        for _, r in table.iterrows()]
    table = table.reset_index()
    table.to_parquet(out / "image_loop_intervals.parquet")
    return table


def _overlap(row: pd.Series, a: str, b: str) -> bool:
    """The 95 % intervals of columns ``a`` and ``b`` of ``row`` overlap
    (``experiments.intervals.intervals_overlap``)."""
    return intervals_overlap(*(tuple(float(row[f"{c}{e}"]) for e in ("", "_lo", "_hi"))
                               for c in (a, b)))


def calibration_table(trackers: tuple[str, ...]) -> pd.DataFrame:
    """The held-out validation of each tracker's calibrated loss model, as written by
    ``pmspm calibrate-loss`` (one row per tracker, delay and peak rate)."""
    rows = []
    for t in trackers:
        data = load_loss_model(t).data
        for v in data.validation:
            row = {"tracker": t, "fit_frames": data.n_frames, "delay_ms": v["delay_ms"],
                   "rate_rad_s": v["rate_rad_s"], "image_runs": v["image_runs"],
                   "model_runs": v["model_runs"], "agree": v["agree"]}
            for k in ("image_lost_frame_fraction", "model_lost_frame_fraction",
                      "image_loss_of_control", "model_loss_of_control"):
                row[k], row[f"{k}_lo"], row[f"{k}_hi"] = v[k]
            rows.append(row)
    return pd.DataFrame(rows)


# --- 3. time series -------------------------------------------------------------------------
def time_series(
    cfg: StudyConfig, params: PlantParams, out: Path
) -> tuple[dict[str, pd.DataFrame], dict]:
    """A 5° tilt step at the seed's two latencies, PID and MPC, on the plant ``params``: the
    step logs (also written as Parquet) and the summaries."""
    series, summaries = {}, {}
    for d in (GK_MS, DUAL_MS):
        for ctrl in ("pid", "mpc"):
            s = Scenario(
                duration_s=2.0,
                plant=params,
                observer={"kind": "solver"},
                controller=_controller_spec(ctrl, cfg),
                reference={"kind": "tilt_step", "tilt_deg": 5.0, "t_step_s": 0.1},
                pipeline={"observer": {"kind": "constant", "value_s": d / 1e3}},
                measurement={"sigma_px": cfg.sigma_px},
            )
            r = simulate(s, engine=cfg.engine)
            key = f"{ctrl}_{d:.2f}ms"
            series[key] = r.steps
            summaries[key] = r.summary
            r.steps.to_parquet(out / f"timeseries_{key}.parquet")
    return series, summaries


# --- 4. measured facts and summary ----------------------------------------------------------
def measure_here(params: PlantParams, cfg: StudyConfig, out: Path) -> dict[str, float]:
    """Median per-frame latency (ms) of GK-TransT and the dual TransT measured on this machine
    (``latency.profile.measure_pair_tracker_latency``; profiles saved beside the report). A
    tracker whose network cannot be loaded is left out (the report says so)."""
    from observer.trackers import make_pair_tracker
    from observer.transt.weights import WeightsError

    measured = {}
    for name in ("gk_transt", "dual_transt"):
        try:
            tracker = make_pair_tracker(name, params)
        except (ImportError, WeightsError):
            continue
        prof = measure_pair_tracker_latency(params, tracker, n_frames=cfg.latency_frames)
        prof.save(out / f"latency_{name}.json")
        measured[name] = 1e3 * float(np.median(prof.samples_s))
    return measured


def _cpu_model() -> str:
    """The CPU's model name as the operating system reports it ("unknown" if it does not)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_facts(params: PlantParams, cfg: StudyConfig | None = None) -> dict[str, str | float]:
    """What the report may say about the run: read from the machine, the parameters and the
    motor and camera files of ``cfg``."""
    cfg = cfg or StudyConfig()
    return {
        "motor_file": str(cfg.motor_file) if cfg.motor_file else "",
        "camera_file": str(cfg.camera_file) if cfg.camera_file else "",
        "machine": platform.machine(),
        "processor": _cpu_model(),
        "cpus": float(os.cpu_count() or 0),
        "python": platform.python_version(),
        "frame_rate_hz": params.camera.frame_rate_hz,
        "frame_period_ms": 1e3 / params.camera.frame_rate_hz,
        "coulomb_Nm": params.rotor.coulomb_Nm,
    }


def _at(df: pd.DataFrame, mode: str, d_ms: float, col: str) -> float:
    row = df[(df.observer == mode) & (np.isclose(df.vision_delay_ms, d_ms))]
    return float(row[col].iloc[0]) if len(row) else float("nan")


def _ci(row: pd.Series, col: str, scale: float = 1.0, fmt: str = ".2f") -> str:
    """``mean (low–high)`` of an interval column; the mean alone without an interval."""
    m, lo, hi = (scale * float(row[c]) for c in (col, f"{col}_lo", f"{col}_hi"))
    if not np.isfinite(m):
        return "—"
    return f"{m:{fmt}} ({lo:{fmt}}–{hi:{fmt}})" if np.isfinite(lo) else f"{m:{fmt}}"


def _preview_lines(step: pd.DataFrame) -> list[str]:
    """What the MPC's reference preview changes on the step at GK-TransT's latency: the RMS
    error over the run, not the tail metrics (overshoot, settling, steady-state error), which
    the two variants can share."""
    at = step[np.isclose(step.vision_delay_ms, GK_MS)].set_index("controller")
    if not {"mpc", "mpc_nopreview"} <= set(at.index):
        return []
    with_p, without = at.loc["mpc"], at.loc["mpc_nopreview"]
    return [
        f"- **MPC reference preview.** On the 5° step at {GK_MS:.2f} ms the RMS error over "
        f"the run is {_ci(with_p, 'rms_error_deg', fmt='.3f')}° with preview and "
        f"{_ci(without, 'rms_error_deg', fmt='.3f')}° without: previewing, the MPC starts "
        "moving before the step. Its overshoot, settling time and steady-state error can "
        "nevertheless equal those without preview: once the step is past, both see the same "
        "constant reference and their trajectories meet within a few tenths of a second, "
        "long before the slow creep into the settling band (Coulomb friction) that sets "
        "those metrics."
    ]


def _loss_lines(loss: pd.DataFrame, intervals: pd.DataFrame, cfg: StudyConfig) -> list[str]:
    """Per controller: each tracker at its own seed latency (its own loss model), lost frames
    on the random references and the probability of loss of control."""
    lines: list[str] = []
    if loss.empty:
        return lines
    model = ("its calibrated loss model" if cfg.loss_model == "calibrated"
             else f"the hand-set {cfg.search_radius_px:g} px search window")
    rnd = intervals[intervals.reference.str.startswith("random")]
    for ctrl in RANDOM_CONTROLLERS:
        parts = []
        for tracker in cfg.trackers:
            d = OWN_DELAY_MS.get(tracker)
            if d is None:
                continue
            g = loss[(loss.controller == ctrl) & (loss.tracker == tracker)
                     & np.isclose(loss.vision_delay_ms, d)]
            lf = rnd[(rnd.controller == ctrl) & (rnd.tracker == tracker)
                     & np.isclose(rnd.vision_delay_ms, d)]
            if not len(g):
                continue
            lost = ", ".join(f"{r.reference.removeprefix('random_').replace('rad_s', ' rad/s')}"
                             f" {_ci(r, 'lost_frame_fraction', 100.0, '.1f')} %"
                             for _, r in lf.iterrows())
            parts.append(f"{TRACKER_NAMES.get(tracker, tracker)} at its {d:.2f} ms: "
                         f"P(loss of control) {_ci(g.iloc[0], 'p_loss_of_control')} "
                         f"({int(g.iloc[0].n_runs)} runs), lost frames {lost}")
        if parts:
            lines.append(f"- **{ctrl.upper()}: tracking loss and loss of control, each tracker "
                         f"at its own latency** (random references, each tracker's loss from "
                         f"{model}; loss of control: sustained tilt-stop contact, marker loss, "
                         f"an error beyond what the reference demands, or divergence): "
                         + "; ".join(parts) + ".")
    return lines


def _image_loop_lines(image: pd.DataFrame | None) -> list[str]:
    """The image-engine section in a line per tracker: lost frames from the trackers
    themselves at the seed's two latencies, and the agreement of the calibrated models."""
    title = "- **Tracking loss from the trackers themselves (image engine).** "
    if image is None:
        return [title + "Not run in this study (`StudyConfig.image_loop` is off)."]
    if not len(image):
        return [title + "Not run: no tracker to run."]
    parts = []
    for tracker, g in image.groupby("tracker", sort=False):
        at = "; ".join(
            f"{r.vision_delay_ms:.2f} ms, {r.max_rate_rad_s:g} rad/s: "
            f"{_ci(r, 'image_lost_frame_fraction', 100.0, '.1f')} % (model "
            f"{_ci(r, 'model_lost_frame_fraction', 100.0, '.1f')} %)"
            for _, r in g.iterrows())
        parts.append(f"{TRACKER_NAMES.get(tracker, tracker)}, lost frames in PID runs: {at}; "
                     f"the calibrated model agrees on {int(g.agree.sum())} of {len(g)} points")
    return [title + ". ".join(parts) + "."]


def summary_text(
    margins: pd.DataFrame, intervals: pd.DataFrame, loss: pd.DataFrame, ts: dict,
    measured: dict[str, float], facts: dict, cfg: StudyConfig,
    mpc_margins: pd.DataFrame | None = None, image: pd.DataFrame | None = None,
) -> list[str]:
    """Plain-language findings, every number taken from the tables or measured in this run."""
    fps, period = facts["frame_rate_hz"], facts["frame_period_ms"]
    pm_gk = _at(margins, "sequential", GK_MS, "phase_margin_deg")
    pm_dual = _at(margins, "sequential", DUAL_MS, "phase_margin_deg")
    pm_dual_p = _at(margins, "pipelined", DUAL_MS, "phase_margin_deg")
    head_gk = 1e3 * _at(margins, "sequential", GK_MS, "headroom_s")
    dm_gk = 1e3 * _at(margins, "sequential", GK_MS, "delay_margin_s")
    jm_dual = 1e3 * _at(margins, "sequential", DUAL_MS, "jitter_margin_s")
    dm_dual = 1e3 * _at(margins, "sequential", DUAL_MS, "delay_margin_s")
    boundary = predicted_boundary_ms(margins)
    lines = [
        f"- **Phase margin.** With the PID tuned for a {cfg.crossover_rad_s:g} rad/s crossover "
        f"at {fps:g} frames/s, GK-TransT's {GK_MS:.2f} ms leaves {pm_gk:.1f}° of phase margin; "
        f"the loop tolerates {head_gk:.1f} ms more vision delay before it is unstable "
        f"(scanned through the sequential pipeline; the constant-delay margin at the fixed "
        f"{period:.1f} ms update period would say {dm_gk:.1f} ms, but beyond one frame period "
        f"the observer drops frames). The dual TransT's {DUAL_MS:.2f} ms leaves {pm_dual:.1f}°: "
        f"it is slower than the {period:.1f} ms frame period, so a sequential observer also "
        f"drops frames and lowers the update rate; a pipelined observer would keep "
        f"{pm_dual_p:.1f}°. There the jitter margin of the PID as it runs is {jm_dual:.1f} ms "
        f"(constant-delay margin {dm_dual:.1f} ms). The sequential loop is predicted unstable "
        f"from {boundary:.1f} ms of vision delay.",
    ]
    if measured:
        names = {"gk_transt": ("GK-TransT", GK_MS), "dual_transt": ("dual TransT", DUAL_MS)}
        parts = [f"{names[k][0]} {v:.2f} ms (seed: {names[k][1]:.2f} ms)"
                 for k, v in measured.items()]
        lines.append(
            f"- **Latency measured here.** Median per frame on this machine "
            f"({facts['processor']}, {facts['cpus']:.0f} CPUs seen by Python): "
            + "; ".join(parts) + ". Marked on the plots beside the seed's figures."
        )
    else:
        lines.append("- **Latency measured here.** Not measured: the TransT network could not "
                     "be loaded.")
    if mpc_margins is not None:
        aware = mpc_margins[mpc_margins.delay_aware]

        def deg(mode: str, d: float) -> str:
            v = _at(aware, mode, d, "phase_margin_deg")
            if not np.isfinite(v):
                return "none (unstable)"
            n = int(_at(aware, mode, d, "n_crossovers"))
            w = _at(aware, mode, d, "crossover_rad_s")
            gm = _at(aware, mode, d, "gain_margin")
            head = 1e3 * _at(aware, mode, d, "headroom_s")
            cond = bool(_at(aware, mode, d, "conditionally_stable"))
            extra = f"; {n} gain crossovers, this one critical" if n > 1 else ""
            extra += "; conditionally stable" if cond else ""
            return (f"{v:.1f}° at {w:.1f} rad/s (gain margin {gm:.2f}, headroom {head:.1f} ms"
                    f"{extra})")

        lines.append(
            f"- **MPC margins (linearised law).** The delay-aware MPC keeps "
            f"{deg('sequential', GK_MS)} at {GK_MS:.2f} ms. At {DUAL_MS:.2f} ms a sequential "
            f"observer lowers its update rate and leaves {deg('sequential', DUAL_MS)}; a "
            f"pipelined one keeps {deg('pipelined', DUAL_MS)}."
        )
    lines += _loss_lines(loss, intervals, cfg)
    step = intervals[intervals.reference == "tilt_step_5deg"]
    for d in (GK_MS, DUAL_MS):
        at = step[np.isclose(step.vision_delay_ms, d)].set_index("controller")
        parts = []
        for ctrl in STEP_CONTROLLERS:
            if ctrl not in at.index:
                continue
            r = at.loc[ctrl]
            settled = float(r.p_settled)
            settle = (f"settles in {_ci(r, 'settling_time_s')} s" if settled == 1.0 else
                      "does not settle within the run" if settled == 0.0 else
                      f"settles in {100 * settled:.0f} % of the runs")
            over = _ci(r, "overshoot_pct", fmt=".1f")
            sse = _ci(r, "steady_state_error_deg", fmt=".3f")
            parts.append(f"{CONTROLLER_STYLE[ctrl][1]}: overshoot {over} %, {settle}, "
                         f"steady-state error {sse}°")
        if parts:
            lines.append(f"- **5° tilt step at {d:.2f} ms** (band ±{SETTLE_BAND_DEG:g}°, "
                         f"{cfg.duration_s:g} s runs). " + "; ".join(parts) + ".")
    lines += _preview_lines(step)
    lines += _image_loop_lines(image)
    pid_gk = step[(step.controller == "pid") & np.isclose(step.vision_delay_ms, GK_MS)]
    coulomb_mNm = 1e3 * facts["coulomb_Nm"]
    if len(pid_gk) and float(pid_gk.p_settled.iloc[0]) < 1.0:
        lines.append(
            f"- **Coulomb friction.** With the default {coulomb_mNm:g} mN·m the PID's "
            "integrator winds up while the rotor sticks and drives it slowly past the target: "
            "the step does not settle within the run. The remedy measured here is the PID's "
            f"friction compensation ({cfg.friction_compensation_Nm * 1e3:g} mN·m, "
            "`PIDConfig.friction_compensation_Nm`; row 'PID + friction compensation')."
        )
    return lines


def run_study(out_root: Path = Path("runs"), config: StudyConfig | None = None) -> Path:
    """Run the whole study and write the report folder; returns its path."""
    cfg = config or StudyConfig()
    params = study_plant(cfg)
    stamp = dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    out = Path(out_root) / f"{stamp}-study"
    out.mkdir(parents=True, exist_ok=False)

    measured = measure_here(params, cfg, out)
    facts = machine_facts(params, cfg)
    marks = {"GK-TransT (seed)": GK_MS, "dual TransT (seed)": DUAL_MS}
    labels = {"gk_transt": "GK-TransT here", "dual_transt": "dual TransT here"}
    marks |= {labels[k]: v for k, v in measured.items()}

    margins = margins_table(params, cfg)
    margins.to_parquet(out / "margins.parquet")
    plot_margins(margins, marks, out / "margins_vs_delay.png")
    mpc_margins = mpc_margins_table(params, cfg)
    mpc_margins.to_parquet(out / "mpc_margins.parquet")
    plot_pm_pid_vs_mpc(margins, mpc_margins, marks, out / "pm_pid_vs_mpc.png")

    batched = cfg.engine != "event"
    raw = run_sweep(
        f"experiments.study:{'study_runs' if batched else 'study_run'}",
        sweep_configs(cfg, params),
        out / "sweep",
        scheduler=cfg.scheduler,
        workers=cfg.workers,
        batch_size=STUDY_BATCH if batched else None,
    )
    sweep = tidy_sweep(raw)
    sweep.to_parquet(out / "sweep.parquet")
    intervals = sweep_intervals(sweep)
    intervals.to_parquet(out / "sweep_intervals.parquet")
    loss = loss_intervals(sweep)
    loss.to_parquet(out / "loss_of_control.parquet")
    mpc_aware = mpc_margins[mpc_margins.delay_aware]
    boundaries = {"pid": predicted_boundary_ms(margins), "mpc": predicted_boundary_ms(mpc_aware)}
    plot_sweep(intervals, sweep[sweep.error != ""], marks, out / "sweep_error_loss.png",
               boundaries)
    plot_steps(intervals, marks, out / "step_vs_delay.png")
    plot_boundary_overlay(loss, boundaries, marks, out / "boundary_vs_loss_of_control.png")

    image = image_loop(cfg, params, out) if cfg.image_loop else None
    series, ts = time_series(cfg, params, out)
    plot_time_series(series, (GK_MS, DUAL_MS), out / "timeseries_16_vs_31ms.png")

    findings = summary_text(margins, intervals, loss, ts, measured, facts, cfg, mpc_margins,
                            image)
    (out / "study_config.json").write_text(json.dumps(cfg.model_dump(mode="json"), indent=1))
    calibration = calibration_table(cfg.trackers) if cfg.loss_model == "calibrated" else None
    write_report(out, cfg, findings, margins, intervals, loss, ts, measured, facts, mpc_margins,
                 image, calibration)
    return out
