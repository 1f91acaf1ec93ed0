"""The loss-of-control verdict (``latency.metrics.loss_of_control``) against the exact margins.

For the PID (10 rad/s crossover) and the delay-aware MPC, each in the study's closed loop
(measurement model, sequential observer, per-frame least squares, 0.5 px noise, 240 px tracker
window; ``experiments.study``), the analysis gives the first unstable vision delay (the
boundary, scanned through the pipeline: ``pid_headroom_s``, ``mpc_headroom_s``). Two delays per
controller:

* **stable**: the boundary minus 20 ms (rounded down to 0.01 ms, checked to have at least 20 ms
  of headroom). A run flagged there is a false alarm.
* **unstable**: the boundary plus 20 ms (rounded up; checked unstable by the analysis). A run
  not flagged there is a missed detection.

Each run follows its own smooth random reference (``RandomSmooth``, reference seed = run seed)
with a peak rate of 1 rad/s, the slowest of the study's, which a loop with 20 ms of headroom
follows with errors of a degree or two; faster references are run on smaller sets for
information (``--rates``, ``--rates-runs``): there a stable PID may leave its linear range
and lose control physically (tilt stop, markers), which the linear analysis cannot see.
Every run lasts
``--duration`` s and is judged on its first L seconds for each length L of ``--lengths`` (the
verdict of the first L s of a run is that of a run of L s: the loop is causal and every draw
comes in time order; the verdict's window is the last half of the L s). Figures: the flagged
fraction per controller, delay class, rate and length, with its 95 % Wilson interval, and the
criteria that fired.

The runs go through ``experiments.sweep.run_sweep`` (one file per run under
``results/verdict_sweep/``): an interrupted benchmark resumes where it stopped.

Run: python benchmarks/bench_verdict.py            (200 runs per case at 1 rad/s, 50 at 3 and 6)
     python benchmarks/bench_verdict.py --quick    (a few runs: checks that it works)
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import pandas as pd
from _report import record

from experiments.intervals import wilson_ci
from experiments.study import mpc_headroom_s, pid_headroom_s
from experiments.study_config import StudyConfig, study_plant
from experiments.study_sweep import controller_spec
from experiments.sweep import run_id, run_sweep
from experiments.sweep import table as sweep_table
from latency import Scenario, simulate_many
from latency.loop_config import LoopResult
from latency.metrics import summarize

HERE = Path(__file__).resolve().parent
#: The distance from the boundary the verdict is held to, ms (both sides).
DISTANCE_MS = 20.0
CONTROLLERS = ("pid", "mpc")
VERDICT_KEYS = ("loss_of_control", "loc_tilt_stop", "loc_marker_loss", "loc_excess_error",
                "loc_divergence")


def delays_ms(cfg: StudyConfig) -> dict[str, dict[str, float]]:
    """Per controller: the analysis' boundary and the stable and unstable test delays, ms."""
    params = study_plant(cfg)
    out = {}
    for ctrl in CONTROLLERS:
        def headroom_s(d_s: float, ctrl: str = ctrl) -> float:
            if ctrl == "pid":
                return pid_headroom_s(params, cfg.crossover_rad_s, d_s, "sequential")
            return mpc_headroom_s(params, d_s, "sequential")

        boundary = 1e3 * headroom_s(0.0)
        stable = math.floor(100.0 * (boundary - DISTANCE_MS)) / 100.0
        unstable = math.ceil(100.0 * (boundary + DISTANCE_MS)) / 100.0
        head = 1e3 * headroom_s(stable / 1e3)
        if not head >= DISTANCE_MS:
            raise RuntimeError(f"{ctrl}: {stable} ms has {head} ms of headroom, not "
                               f">= {DISTANCE_MS} ms")
        if np.isfinite(headroom_s(unstable / 1e3)):
            raise RuntimeError(f"{ctrl}: the analysis says {unstable} ms is stable")
        out[ctrl] = {"boundary": boundary, "stable": stable, "unstable": unstable}
    return out


def configs(cfg: StudyConfig, delays: dict, n_runs: int, rate_rad_s: float,
            duration_s: float, lengths_s: tuple[float, ...]) -> list[dict]:
    """The runs (scenario dicts with a ``verdict`` block of bookkeeping), seed by seed (each
    seed's four cases together, so that an interrupted benchmark has them all)."""
    params = study_plant(cfg)
    out = []
    for seed in range(n_runs):
        for ctrl in CONTROLLERS:
            for kind in ("stable", "unstable"):
                d = delays[ctrl][kind]
                s = Scenario(
                    name=f"verdict-{ctrl}-{kind}-{rate_rad_s:g}-s{seed}", duration_s=duration_s,
                    seed=seed, plant=params, observer={"kind": "solver"},
                    controller=controller_spec(ctrl, cfg),
                    reference={"kind": "random",
                               "args": {"max_rate_rad_s": rate_rad_s, "seed": seed}},
                    pipeline={"observer": {"kind": "constant", "value_s": d / 1e3}},
                    measurement={"sigma_px": cfg.sigma_px,
                                 "search_radius_px": cfg.search_radius_px},
                )
                c = s.model_dump(mode="json")
                c["verdict"] = {"controller": ctrl, "kind": kind, "delay_ms": d,
                                "rate_rad_s": rate_rad_s, "lengths_s": list(lengths_s)}
                out.append(c)
    return out


def verdict_at(result: LoopResult, length_s: float) -> dict[str, float]:
    """The verdict of the run's first ``length_s`` s (its tables cut there; diverged if the
    loop noted the divergence by then)."""
    steps = result.steps[result.steps.t_s <= length_s + 1e-9]
    frames = result.frames[result.frames.t_exposure_s <= length_s]
    ev = result.events
    diverged = bool(((ev.kind == "divergence") & (ev.t_s <= length_s)).any())
    s = summarize(steps, frames, ev.iloc[:0], length_s, "diverged" if diverged else "",
                  step_metrics=False)
    return {k: s[k] for k in (*VERDICT_KEYS, "late_rms_error_deg", "late_error_bound_deg")}


def verdict_runs(batch: list[dict]) -> list[dict | Exception]:
    """Sweep entry point: run the scenarios together (with their tables) and return, per run,
    the verdict at each length of its ``verdict.lengths_s`` (keys ``<name>_<L>s``)."""
    scenarios = [Scenario.model_validate({k: v for k, v in c.items() if k != "verdict"})
                 for c in batch]
    out: list[dict | Exception] = []
    for c, r in zip(batch, simulate_many(scenarios, engine="batched"), strict=True):
        row = {}
        for length in c["verdict"]["lengths_s"]:
            row |= {f"{k}_{length:g}s": v for k, v in verdict_at(r, length).items()}
        out.append(row)
    return out


def figures_of(table: pd.DataFrame, delays: dict, lengths_s: tuple[float, ...]) -> dict:
    """Flat figures: the boundaries and test delays, then per controller, delay class, rate
    and length the flagged fraction with its Wilson interval and the criteria's fractions."""
    fig: dict[str, float] = {}
    for ctrl, d in delays.items():
        for k, v in d.items():
            fig[f"{ctrl}_{k}_delay_ms" if k != "boundary" else f"{ctrl}_boundary_ms"] = v
    ok = table[table.error == ""]
    fig["failed_runs"] = float(len(table) - len(ok))
    for (ctrl, kind, rate), g in ok.groupby(["config.verdict.controller", "config.verdict.kind",
                                             "config.verdict.rate_rad_s"]):
        tag = f"{ctrl}_{kind}_{rate:g}rad_s".replace(".", "p")
        fig[f"{tag}_runs"] = float(len(g))
        for length in lengths_s:
            flags = g[f"result.loss_of_control_{length:g}s"].to_numpy(float) > 0.5
            p, lo, hi = wilson_ci(int(flags.sum()), len(flags))
            lt = f"{tag}_{length:g}s"
            fig[f"{lt}_flagged"] = p
            fig[f"{lt}_flagged_lo"], fig[f"{lt}_flagged_hi"] = lo, hi
            for crit in VERDICT_KEYS[1:]:
                fig[f"{lt}_{crit}"] = float(np.mean(g[f"result.{crit}_{length:g}s"] > 0.5))
            ratio = (g[f"result.late_rms_error_deg_{length:g}s"]
                     / g[f"result.late_error_bound_deg_{length:g}s"])
            fig[f"{lt}_max_error_over_bound" if kind == "stable"
                else f"{lt}_min_error_over_bound"] = float(
                ratio.max() if kind == "stable" else ratio.min())
    return fig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=200, help="Runs per condition at 1 rad/s.")
    ap.add_argument("--rates-runs", type=int, default=50,
                    help="Runs per condition at each faster rate of --rates (0: none).")
    ap.add_argument("--rates", type=float, nargs="*", default=[3.0, 6.0],
                    help="Faster peak rates, rad/s, run on --rates-runs runs each.")
    ap.add_argument("--duration", type=float, default=12.0, help="Run length, s.")
    ap.add_argument("--lengths", type=float, nargs="+", default=[3.0, 4.0, 6.0, 8.0, 10.0, 12.0],
                    help="Lengths judged, s (each at most --duration).")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--quick", action="store_true", help="3 runs per condition, 4 s.")
    ap.add_argument("--no-run", action="store_true",
                    help="Record the figures of the runs finished so far (the _runs keys say "
                    "how many per case); run nothing.")
    a = ap.parse_args()
    if a.quick:
        a.runs, a.rates_runs, a.duration, a.lengths = 3, 0, 4.0, [3.0, 4.0]
    lengths = tuple(a.lengths)
    if max(lengths) > a.duration:
        raise SystemExit(f"--lengths {lengths} go beyond --duration {a.duration}")
    cfg = StudyConfig()
    delays = delays_ms(cfg)
    runs = configs(cfg, delays, a.runs, 1.0, a.duration, lengths)
    if a.rates_runs:
        for rate in a.rates:
            runs += configs(cfg, delays, a.rates_runs, rate, a.duration, lengths)
    out = HERE / "results" / ("verdict_quick_sweep" if a.quick else "verdict_sweep")
    if a.no_run:
        table = sweep_table(out, [run_id(c) for c in runs])
    else:
        table = run_sweep("bench_verdict:verdict_runs", runs, out, workers=a.workers,
                          batch_size=25)
    fig = figures_of(table, delays, lengths)
    fig["run_length_s"] = a.duration
    if a.quick:
        print({k: v for k, v in fig.items() if "flagged" in k and "_lo" not in k})
        return
    record(
        "bench_verdict",
        "Loss-of-control verdict against the exact margins (false alarms 20 ms inside, "
        "detection 20 ms beyond the boundary)",
        fig,
        notes="Rates, not timings. <ctrl>_<stable|unstable>_<rate>_<L>s_flagged: fraction of "
        "runs the verdict flags judged on their first L s (95 % Wilson interval in _lo/_hi); "
        "on 'stable' it is the false-alarm rate, on 'unstable' the detection rate. Targets: "
        "false alarms <= 1 %, detection >= 99 %. Test delays: the analysis' boundary "
        "(sequential observer) -/+ 20 ms. Each run on its own random reference "
        "(RandomSmooth, seed = run seed).",
    )


if __name__ == "__main__":
    main()
