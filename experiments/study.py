"""The headline study: what does vision delay do to the PMSpM attitude loop?

The parts are modules of their own: the settings in ``study_config``, the simulated runs (the
sweep and the image-engine section) in ``study_sweep``, the findings in ``study_summary``, the
plots in ``study_plots`` and the page in ``report``; this module holds the margins, the time
series and ``run_study``, which ties them together.

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
import json
import os
import platform
from collections.abc import Callable
from pathlib import Path

import control as ct
import numpy as np
import pandas as pd

from controller.mpc_config import MPCConfig
from controller.pid import PIDConfig, PIDController
from experiments.report import write_report
from experiments.study_config import DUAL_MS, GK_MS, STUDY_BATCH, StudyConfig, study_plant
from experiments.study_plots import (
    plot_boundary_overlay,
    plot_margins,
    plot_pm_pid_vs_mpc,
    plot_steps,
    plot_sweep,
    plot_time_series,
)
from experiments.study_summary import predicted_boundary_ms, summary_text
from experiments.study_sweep import (
    calibration_conditions,
    calibration_table,
    controller_spec,
    image_loop,
    loss_intervals,
    sweep_configs,
    sweep_intervals,
    tidy_sweep,
)
from experiments.sweep import run_sweep
from latency import Scenario, simulate
from latency.margins import (
    Margins,
    as_run_margins,
    attitude_plant,
    first_unstable_delay,
    sampled_margins,
    sampled_stable,
)
from latency.mpc_law import mpc_discrete_law, mpc_state_gain
from latency.pipeline import LoopTiming, PipelineConfig, PipelineMode
from latency.profile import measure_pair_tracker_latency
from latency.scenario import MPC_CALL_MEDIAN_S
from plant.machine import cpu_model
from plant.params import PlantParams

# --- 1. margins -----------------------------------------------------------------------------
OBSERVER_MODES: tuple[PipelineMode, ...] = ("sequential", "pipelined")


def _vision_delays_ms(step_ms: float = 1.0) -> list[float]:
    """The margin tables' vision delays, ms: 0-60 ms by ``step_ms`` (the last step shorter
    where 60 is not a multiple) and the seed's two latencies."""
    grid = np.arange(0.0, 60.0, step_ms).tolist() + [60.0]
    return grid + [GK_MS, DUAL_MS]


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
        delays = _vision_delays_ms(cfg.margin_step_ms)
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
            delays = _vision_delays_ms(cfg.margin_step_ms)
            head = _headroom_column([d / 1e3 for d in delays], loop.stable_at(mode, aware))
            for d_ms, h in zip(delays, head, strict=True):
                t = loop_timing_for(params, d_ms / 1e3, mode, loop.compute_s)
                mg = sampled_margins(loop.plant, loop.law(t, aware), delay_s=t.delay_s)
                rows.append(_margin_row(d_ms, t, mg)
                            | {"delay_aware": aware, "headroom_s": h, "jitter_margin_s": np.nan})
    return (pd.DataFrame(rows).sort_values(["observer", "delay_aware", "vision_delay_ms"])
            .reset_index(drop=True))




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
                controller=controller_spec(ctrl, cfg),
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


def machine_facts(params: PlantParams, cfg: StudyConfig | None = None) -> dict[str, str | float]:
    """What the report may say about the run: read from the machine, the parameters and the
    motor and camera files of ``cfg``."""
    cfg = cfg or StudyConfig()
    return {
        "motor_file": str(cfg.motor_file) if cfg.motor_file else "",
        "camera_file": str(cfg.camera_file) if cfg.camera_file else "",
        "machine": platform.machine(),
        "processor": cpu_model(),
        "cpus": float(os.cpu_count() or 0),
        "python": platform.python_version(),
        "frame_rate_hz": params.camera.frame_rate_hz,
        "frame_period_ms": 1e3 / params.camera.frame_rate_hz,
        "coulomb_Nm": params.rotor.coulomb_Nm,
    }




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
        f"experiments.study_sweep:{'study_runs' if batched else 'study_run'}",
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
    calibrated = cfg.loss_model == "calibrated"
    calibration = calibration_table(cfg.trackers) if calibrated else None
    conditions = calibration_conditions(cfg.trackers) if calibrated else None
    write_report(out, cfg, findings, margins, intervals, loss, ts, measured, facts, mpc_margins,
                 image, calibration, conditions)
    return out

