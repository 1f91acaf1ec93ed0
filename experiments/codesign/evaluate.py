"""The Monte-Carlo evaluation of designs: seeds × references on the batched engine, cached run by
run, with 95 % intervals (``experiments.intervals``).

Each run is a measurement-model scenario (``experiments.codesign.space.scenario_dict``) run
through the sweep runner's files (``experiments.sweep``: one Parquet row per run, named by the
hash of its config), so a rerun, or another design with the same runs, recomputes nothing.
Several designs' runs go to the batched engine together. A run that raises counts as a loss of
control (its error is kept in the row).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from experiments import sweep
from experiments.codesign.space import Design, scenario_dict
from experiments.codesign.spec import CodesignSpec
from experiments.intervals import bootstrap_mean_ci, wilson_ci
from latency.simulation import run_summaries

#: The sweep runner's entry point for a batch of runs (the batched engine).
BATCH_TARGET = "experiments.codesign.evaluate:run_batch"
#: The run metrics kept (``latency.loop.summarize``).
METRICS = ("rms_error_deg", "rms_torque_Nm", "lost_frame_fraction", "loss_of_control")
#: Most runs per call of the batched engine (our choice, as the tuning's).
BATCH_SIZE = 256


def run_batch(configs: list[dict]) -> list[dict | Exception]:
    """Sweep entry point: the metrics of each config's ``scenario``, the runs advanced together
    by the batched engine; an invalid scenario gives its exception in its place."""
    results = run_summaries([c["scenario"] for c in configs])
    return [r if isinstance(r, Exception) else {k: float(r[k]) for k in METRICS}
            for r in results]


def design_key(design: Design) -> str:
    """A stable id of a design (the hash of its settings)."""
    return sweep.run_id(design.model_dump(mode="json"))


def design_configs(spec: CodesignSpec, design: Design) -> list[dict]:
    """The sweep configs of a design's Monte Carlo: one per seed × reference."""
    key = design_key(design)
    return [{"scenario": scenario_dict(spec, design, s, i),
             "tag": {"design": key, "seed": int(s), "reference": i}}
            for s in spec.seeds for i in range(len(spec.references))]


def run_configs(
    configs: Sequence[dict],
    out_dir: Path,
    scheduler: str | None = None,
    workers: int = 1,
    progress: bool = False,
) -> pd.DataFrame:
    """Run the configs not yet done into ``out_dir/runs`` and return their rows: in this
    process (``workers == 1`` without a scheduler) or through ``sweep.run_sweep`` (a process
    pool or Dask)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    if scheduler is None and workers == 1:
        todo = sweep.pending(configs, out_dir)
        for k in tqdm(range(0, len(todo), BATCH_SIZE), desc="runs", unit="batch",
                      disable=not progress, leave=False):
            sweep.execute_batch(BATCH_TARGET, todo[k:k + BATCH_SIZE], str(out_dir))
    else:
        sweep.run_sweep(BATCH_TARGET, list(configs), out_dir, scheduler=scheduler,
                        workers=workers, progress=progress, batch_size=BATCH_SIZE)
    return sweep.table(out_dir, [sweep.run_id(c) for c in configs])


def summarise(runs: pd.DataFrame) -> dict[str, float]:
    """Means over a design's runs with 95 % intervals: ``rms_error_deg`` (and ``_lo``/``_hi``,
    bootstrap), ``rms_torque_Nm``, ``lost_frame_fraction``, ``p_loss_of_control`` (Wilson),
    ``n_runs``, ``n_failed``. A failed run counts as a loss of control and is left out of the
    means."""
    failed = runs["error"].astype(str) != ""
    ok = runs[~failed]
    out: dict[str, float] = {"n_runs": float(len(runs)), "n_failed": float(failed.sum())}
    for c in ("rms_error_deg", "rms_torque_Nm", "lost_frame_fraction"):
        col = f"result.{c}"
        values = ok[col].to_numpy(float) if col in ok else np.array([])
        out[c], out[f"{c}_lo"], out[f"{c}_hi"] = bootstrap_mean_ci(values)
    flags = ok["result.loss_of_control"].to_numpy(float) if len(ok) else np.array([])
    k = int(np.sum(flags > 0.5)) + int(failed.sum())
    out["p_loss_of_control"], out["p_loss_of_control_lo"], out["p_loss_of_control_hi"] = (
        wilson_ci(k, len(runs)))
    return out


def monte_carlo(
    spec: CodesignSpec,
    designs: Sequence[Design],
    out_dir: Path,
    scheduler: str | None = None,
    workers: int = 1,
    progress: bool = False,
) -> list[dict[str, float]]:
    """``summarise`` of each design's runs, all designs' runs advanced together."""
    per_design = [design_configs(spec, d) for d in designs]
    table = run_configs([c for cs in per_design for c in cs], out_dir, scheduler, workers,
                        progress)
    by_id = table.set_index("run_id")
    return [summarise(by_id.loc[[sweep.run_id(c) for c in cs]]) for cs in per_design]


def mc_excess(spec: CodesignSpec, mc: dict[str, float]) -> tuple[float, float]:
    """How far the loss-of-control probability and the lost-frame fraction exceed their limits
    (<= 0: met), on the means or, with ``constraints.bound: upper``, on the upper ends of their
    95 % intervals (the mean where there is no interval); a missing figure counts as 1."""
    c = spec.constraints

    def value(key: str) -> float:
        v = mc.get(f"{key}_hi", math.nan) if c.bound == "upper" else math.nan
        v = mc.get(key, math.nan) if not math.isfinite(v) else v
        return v if math.isfinite(v) else 1.0

    return (value("p_loss_of_control") - c.max_loss_of_control,
            value("lost_frame_fraction") - c.max_lost_frames)


def mc_feasible(spec: CodesignSpec, mc: dict[str, float]) -> bool:
    """The Monte-Carlo constraints of ``spec`` hold (``mc_excess``)."""
    return all(x <= 0.0 for x in mc_excess(spec, mc))
