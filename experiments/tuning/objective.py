"""The closed-loop objective of the pixel Kalman tuning: one run's cost, a setting's mean cost
over seeds and references (``experiments.tuning``)."""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Literal

import pandas as pd
from pydantic import BaseModel, ConfigDict, Field, ValidationError
from tqdm import tqdm

from experiments import sweep
from latency import Engine, Scenario, simulate, simulate_many
from latency.loop_config import LoopResult
from latency.models import SEED_LATENCY_S

#: Seed 000 §3.2.1: Q = 0.01·I4 (sensor px², (px/frame)²), R = 0.1·I2 (sensor px²).
SEED_Q_SCALE = 0.01
SEED_R_SCALE = 0.1
#: Half-width of the default (q, r) grid in decades (our choice): the grid spans 10^-2 .. 10^2
#: times the seed's q and r.
GRID_DECADES = 2.0
#: Seed 000 Table 1: GK-TransT and dual TransT latency on an RTX 4060 laptop, s.
DEFAULT_DELAYS_S = (SEED_LATENCY_S["gk_transt"], SEED_LATENCY_S["dual_transt"])
#: The sweep runner's entry point for one run of the objective (event loop).
RUN_TARGET = "experiments.tuning.objective:run_cost"
#: The sweep runner's entry point for many runs of the objective (batched engine).
BATCH_TARGET = "experiments.tuning.objective:run_costs"
#: Most runs per batch of the batched engine (spread evenly over the workers first).
BATCH_SIZE = 256


# --------------------------------------------------------------------------------------------
# The objective
# --------------------------------------------------------------------------------------------


class CostWeights(BaseModel):
    """Weights of the closed-loop cost ``J = e_rms + λ T²_ms + μ n_lost + D diverged`` (deg)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    effort_weight_deg_per_N2m2: float = Field(
        1000.0,
        ge=0.0,
        description="λ, deg per (N·m)² of mean-square torque. Our choice: 0.0316 N·m RMS "
        "(12 % of the 0.264 N·m limit) costs as much as 1° RMS error.",
    )
    lost_frame_penalty_deg: float = Field(
        0.1, ge=0.0, description="μ, deg per lost processed frame. Our choice."
    )
    divergence_penalty_deg: float = Field(
        60.0,
        ge=0.0,
        description="D, deg added to a run that diverged. Our choice: the loop's "
        "divergence threshold (LoopConfig.divergence_deg).",
    )


def _default_references() -> tuple[dict, ...]:
    return (
        {"kind": "tilt_step", "tilt_deg": 5.0},
        {"kind": "random", "args": {"max_rate_rad_s": 1.0}},
    )


class TuningObjective(BaseModel):
    """The closed-loop cost of a pixel-Kalman setting (q, r) at one vision delay.

    ``references`` are scenario reference specs (``controller.registry.ReferenceSpec`` as
    dicts); a ``"random"`` one without a ``seed`` in its ``args`` takes the run's seed, so each
    run seed also draws a new trajectory. ``scenario`` holds further overrides of the scenario
    (e.g. ``{"plant": ...}`` or other ``pipeline`` fields); it may not set the observer, the
    duration, the seed or the reference (``ValueError``), and this object's ``delay_s``,
    ``pipeline_mode``, ``sigma_px`` and ``measurement`` override the pipeline latency and mode
    and the measurement fields given there. ``filter_loop_margins`` needs the PID controller.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    delay_s: float = Field(
        SEED_LATENCY_S["gk_transt"],
        ge=0.0,
        description="Observer (vision) latency, s. Seed 000 Table 1: 16.33 ms GK-TransT, "
        "31.23 ms dual TransT.",
    )
    pipeline_mode: Literal["sequential", "pipelined"] = Field(
        "sequential", description="The seed's host loop: one observer thread, frames dropped."
    )
    sigma_px: float = Field(
        1.5, ge=0.0, description="Per-coordinate measurement noise, sensor px (our choice)."
    )
    measurement: dict = Field(
        default_factory=lambda: {"loss": {"kind": "search_window", "search_radius_px": 240.0,
                                          "blur_limit_px": 48.0}},
        description="Further MeasurementConfig fields. Our choice: a KCF-like search window "
        "of 240 sensor px (2.5 marker diameters) and a blur limit of half a marker diameter.",
    )
    duration_s: float = Field(3.0, gt=0.0, description="Length of each run, s (our choice).")
    seeds: tuple[int, ...] = Field((0, 1), min_length=1, description="Run seeds.")
    references: tuple[dict, ...] = Field(default_factory=_default_references, min_length=1)
    weights: CostWeights = CostWeights()
    scenario: dict = Field(default_factory=dict, description="Further Scenario overrides.")

    def scenario_dict(self, q: float, r: float, seed: int, reference: dict) -> dict:
        """The scenario of one run as a JSON-able dict (validated by ``Scenario``)."""
        owned = {"observer", "duration_s", "seed", "reference"}
        clash = owned & set(self.scenario)
        if clash:
            raise ValueError(f"TuningObjective.scenario may not set {sorted(clash)}")
        ref = json.loads(json.dumps(reference))
        if ref.get("kind") == "random":
            ref.setdefault("args", {}).setdefault("seed", int(seed))
        d = json.loads(json.dumps(self.scenario))
        pipe = d.setdefault("pipeline", {})
        pipe["observer"] = {"kind": "constant", "value_s": float(self.delay_s)}
        pipe["mode"] = self.pipeline_mode
        meas = d.setdefault("measurement", {})
        meas.update(json.loads(json.dumps(self.measurement)))
        meas["sigma_px"] = float(self.sigma_px)
        d.update(
            {
                "name": f"kalman-q{q:.3g}-r{r:.3g}-{self.delay_s * 1e3:.2f}ms",
                "duration_s": float(self.duration_s),
                "seed": int(seed),
                "observer": {
                    "kind": "pixel_kalman",
                    "pixel_q_scale": float(q),
                    "pixel_r_scale": float(r),
                },
                "reference": ref,
            }
        )
        Scenario.model_validate(d)  # fail here, not inside a worker
        return d

    def configs(self, q: float, r: float, seeds: Iterable[int] | None = None) -> list[dict]:
        """The sweep configs (one per seed × reference) whose mean cost is the cost of (q, r).

        Each is ``{"scenario": ..., "weights": ..., "tag": ...}``; ``tag`` (delay, q, r, seed,
        reference kind) is for grouping the table and is ignored by ``run_cost``."""
        out = []
        for seed in self.seeds if seeds is None else tuple(seeds):
            for i, ref in enumerate(self.references):
                out.append(
                    {
                        "scenario": self.scenario_dict(q, r, seed, ref),
                        "weights": self.weights.model_dump(),
                        "tag": {
                            "delay_s": float(self.delay_s),
                            "q": float(q),
                            "r": float(r),
                            "seed": int(seed),
                            "reference": f"{i}:{ref.get('kind', '?')}",
                        },
                    }
                )
        return out


def cost_terms(
    rms_error_deg: float,
    mean_square_torque_N2m2: float,
    n_lost_frames: int,
    diverged: bool,
    weights: CostWeights,
) -> dict[str, float]:
    """The closed-loop cost of one run and its terms, all in deg (module docstring)."""
    effort = weights.effort_weight_deg_per_N2m2 * mean_square_torque_N2m2
    lost = weights.lost_frame_penalty_deg * n_lost_frames
    div = weights.divergence_penalty_deg * float(bool(diverged))
    return {
        "cost": float(rms_error_deg + effort + lost + div),
        "cost_error_deg": float(rms_error_deg),
        "cost_effort_deg": float(effort),
        "cost_lost_deg": float(lost),
        "cost_divergence_deg": float(div),
    }


def run_cost(config: dict) -> dict:
    """Sweep entry point: run the scenario of ``config`` and return its cost and metrics.

    ``config`` is one element of ``TuningObjective.configs``. Returns ``cost`` (deg), its terms,
    ``rms_error_deg``, ``mean_square_torque_N2m2``, ``control_effort_N2m2s``, ``n_lost_frames``,
    ``n_processed_frames``, ``lost_frame_fraction`` and ``diverged``."""
    return _cost(simulate(Scenario.model_validate(config["scenario"]), engine="event"), config)


def run_costs(configs: list[dict]) -> list[dict | Exception]:
    """Batched sweep entry point: ``run_cost`` of each config, the runs advanced together by
    the batched engine (measurement-model scenarios). A config whose scenario does not
    validate gets its exception in its place; the others still run."""
    out: list[dict | Exception] = []
    scenarios = []
    for c in configs:
        try:
            scenarios.append(Scenario.model_validate(c["scenario"]))
            out.append({})
        except (ValidationError, KeyError) as exc:
            out.append(exc)
    results = iter(simulate_many(scenarios))
    return [
        o if isinstance(o, Exception) else _cost(next(results), c)
        for o, c in zip(out, configs, strict=True)
    ]


def _cost(result: LoopResult, config: dict) -> dict:
    """The cost and metrics of ``run_cost`` from a run's result."""
    weights = CostWeights.model_validate(config.get("weights", {}))
    s = result.summary
    frames = result.frames
    if len(frames) and "lost" in frames:
        processed = frames[~frames["dropped"].astype(bool)]
        n_lost = int(processed["lost"].fillna(False).astype(bool).sum())
        n_proc = int(len(processed))
    else:
        n_lost, n_proc = 0, 0
    ms_torque = float(s["rms_torque_Nm"]) ** 2
    out = {
        "rms_error_deg": float(s["rms_error_deg"]),
        "mean_square_torque_N2m2": ms_torque,
        "control_effort_N2m2s": float(s["control_effort_N2m2s"]),
        "n_lost_frames": n_lost,
        "n_processed_frames": n_proc,
        "lost_frame_fraction": float(s.get("lost_frame_fraction", 0.0)),
        "diverged": float(s["diverged"]),
    }
    out.update(cost_terms(out["rms_error_deg"], ms_torque, n_lost, bool(s["diverged"]), weights))
    return out


def _ratio(q: float, r: float) -> float:
    """``q/r`` rounded to 12 significant digits, so equal ratios from different (q, r) compare
    and group as equal."""
    return float(f"{q / r:.12g}")


_RESULT_COLUMNS = (
    "cost",
    "cost_error_deg",
    "cost_effort_deg",
    "cost_lost_deg",
    "cost_divergence_deg",
    "rms_error_deg",
    "mean_square_torque_N2m2",
    "n_lost_frames",
    "diverged",
)


def aggregate(runs: pd.DataFrame) -> pd.DataFrame:
    """Mean cost and metrics per (delay, q, r) from a sweep table of ``run_cost`` rows.

    A point with a failed run (error recorded by the sweep) gets ``cost = nan`` and
    ``n_failed > 0``. ``cost_sem`` is the standard error of the mean over its runs (deg)."""
    keys = ["config.tag.delay_s", "config.tag.q", "config.tag.r"]
    rows = []
    for (d, q, r), g in runs.groupby(keys, sort=True):
        ok = g[g["error"] == ""]
        row = {"delay_s": d, "q": q, "r": r, "q_over_r": _ratio(q, r), "n_runs": len(g)}
        row["n_failed"] = int(len(g) - len(ok))
        for c in _RESULT_COLUMNS:
            col = f"result.{c}"
            row[c] = float(ok[col].mean()) if len(ok) and col in ok else float("nan")
        if row["n_failed"]:
            row["cost"] = float("nan")
        n = len(ok)
        row["cost_sem"] = (
            float(ok["result.cost"].std(ddof=1) / math.sqrt(n)) if n > 1 else float("nan")
        )
        rows.append(row)
    return pd.DataFrame(rows)


def _rows_of(configs: Sequence[dict], out_dir: Path) -> pd.DataFrame:
    """The finished rows of these configs (read by run id, not the whole folder)."""
    files = [out_dir / "runs" / f"{sweep.run_id(c)}.parquet" for c in configs]
    return pd.concat([pd.read_parquet(f) for f in files], ignore_index=True)


def _run_configs(
    configs: Sequence[dict],
    out_dir: Path,
    scheduler: str | None,
    workers: int | None,
    progress: bool,
    engine: Engine = "batched",
) -> None:
    """Run the configs not yet done into ``out_dir/runs``: through ``sweep.run_sweep`` (a
    process pool or Dask), or, for ``workers == 1`` without a scheduler, in this process with
    the sweep's own ``execute`` / ``execute_batch`` (the same files and run ids, without
    starting a worker; ``progress`` then shows a bar over the batches or runs). ``engine``:
    the batched engine (``run_costs``, ``BATCH_SIZE`` runs at a time) or the event loop
    (``run_cost``)."""
    batched = engine != "event"
    if scheduler is None and workers == 1:
        out_dir.mkdir(parents=True, exist_ok=True)
        todo = sweep.pending(configs, out_dir)
        if batched:
            for k in tqdm(range(0, len(todo), BATCH_SIZE), desc=f"batches ({out_dir.name})",
                          unit="batch", disable=not progress):
                sweep.execute_batch(BATCH_TARGET, todo[k : k + BATCH_SIZE], str(out_dir))
        else:
            for c in tqdm(todo, desc=f"runs ({out_dir.name})", unit="run", disable=not progress):
                sweep.execute(RUN_TARGET, c, str(out_dir))
        return
    sweep.run_sweep(
        BATCH_TARGET if batched else RUN_TARGET, list(configs), out_dir, scheduler=scheduler,
        workers=workers, progress=progress, batch_size=BATCH_SIZE if batched else None,
    )


def evaluate(
    objective: TuningObjective,
    q: float,
    r: float,
    cache_dir: str | Path | None = None,
    seeds: Iterable[int] | None = None,
    engine: Engine = "batched",
) -> dict[str, float]:
    """Mean cost (deg) and metrics of (q, r) over the objective's seeds × references, run in
    this process by ``engine`` (the batched engine or the event loop). With ``cache_dir`` the
    runs are read from / written to ``cache_dir/runs`` as the sweep runner does (same run ids),
    so finished runs are never recomputed."""
    configs = objective.configs(q, r, seeds)
    if cache_dir is None:
        rows = []
        for c, res in zip(configs, _results(configs, engine), strict=True):
            row = {f"config.tag.{k}": v for k, v in c["tag"].items()}
            if isinstance(res, Exception):
                row["error"] = f"{type(res).__name__}: {res}"
            else:
                row.update({f"result.{k}": v for k, v in res.items()}, error="")
            rows.append(row)
        runs = pd.DataFrame(rows)
    else:
        out = Path(cache_dir)
        _run_configs(configs, out, None, 1, False, engine)
        runs = _rows_of(configs, out)
    return aggregate(runs).iloc[0].to_dict()


def _results(configs: Sequence[dict], engine: Engine) -> list[dict | Exception]:
    """``run_cost`` of each config, or the exception it raised (a failed run is a failed
    point, not a failed evaluation): all together on the batched engine, or one by one on the
    event loop."""
    if engine != "event":
        return run_costs(list(configs))
    results: list[dict | Exception] = []
    for c in configs:
        try:
            results.append(run_cost(c))
        except Exception as exc:  # noqa: BLE001 (a failed run is a failed point)
            results.append(exc)
    return results
