"""The headline study's simulated runs (``experiments.study``): the closed-loop sweep in the
measurement-model loop (controllers, references, trackers' loss models and delays; tidied into
tables with 95 % intervals over seeds) and the image-engine section, whose tracking loss comes
from the trackers themselves, beside its calibrated-model twins."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from controller.mpc_config import MPCConfig
from controller.pid import PIDConfig
from controller.registry import MPCSpec, PIDSpec
from experiments.intervals import intervals_overlap, seed_intervals
from experiments.study_config import DUAL_MS, GK_MS, OWN_DELAY_MS, StudyConfig, study_plant
from latency import Scenario, build_loop, simulate, simulate_many
from latency.image_engine import run_images
from latency.loop_config import LoopResult
from latency.loss_model import load_loss_model
from latency.simulation import run_summaries
from plant.params import PlantParams


# --- 2. closed-loop sweep -------------------------------------------------------------------
def controller_spec(name: str, cfg: StudyConfig) -> PIDSpec | MPCSpec:
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
                            controller=controller_spec(ctrl, cfg),
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
                        observer={"kind": "solver"}, controller=controller_spec("pid", cfg),
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
    intervals (bootstrap for means, the exact binomial one of the pooled frames for image runs
    that lost none, ``frame_fraction_ci``; Wilson for loss of control) and ``agree`` (the image
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
        [b | {"side": "image"} | r.summary | _frame_counts(r) for b, r in zip(books, images,
                                                                           strict=True)]
        + [b | {"side": "model"} | r.summary for b, r in zip(books, twins, strict=True)])
    runs.to_parquet(out / "image_loop.parquet")
    by = ["tracker", "vision_delay_ms", "max_rate_rad_s"]
    counts = {"lost_frame_fraction": ("lost_frames", "processed_frames")}
    sides = {side: seed_intervals(g, by, IMAGE_MEANS, ("loss_of_control",), counts)
             .set_index(by) for side, g in runs.groupby("side")}
    table = sides["image"].add_prefix("image_").join(sides["model"].add_prefix("model_"))
    table["agree"] = [
        _overlap(r, "image_lost_frame_fraction", "model_lost_frame_fraction")
        and _overlap(r, "image_p_loss_of_control", "model_p_loss_of_control")
        for _, r in table.iterrows()]
    table = table.reset_index()
    table.to_parquet(out / "image_loop_intervals.parquet")
    return table


def _frame_counts(res: LoopResult) -> dict[str, int]:
    """An image run's lost and processed (not dropped) frames: the counts behind its
    lost-frame fraction, for the interval of runs that lost none
    (``experiments.intervals.frame_fraction_ci``)."""
    kept = ~res.frames["dropped"].astype(bool)
    return {"lost_frames": int(res.frames.loc[kept, "lost"].astype(bool).sum()),
            "processed_frames": int(kept.sum())}


def _overlap(row: pd.Series, a: str, b: str) -> bool:
    """The 95 % intervals of columns ``a`` and ``b`` of ``row`` overlap
    (``experiments.intervals.intervals_overlap``)."""
    return intervals_overlap(*(tuple(float(row[f"{c}{e}"]) for e in ("", "_lo", "_hi"))
                               for c in (a, b)))


def calibration_conditions(trackers: tuple[str, ...]) -> pd.DataFrame:
    """Each tracker's lost-frame fraction in its calibration's fit runs per camera (frame rate,
    exposure) and per scene appearance, as written by ``pmspm calibrate-loss``: what its loss
    model averages over (one row per tracker and condition)."""
    rows = []
    for t in trackers:
        for c in load_loss_model(t).data.lost_by_condition:
            what = (f"{c['frame_rate_hz']:g} Hz, {c['exposure_ms']:g} ms exposure"
                    if "appearance" not in c else f"scene: {c['appearance']}")
            rows.append({"tracker": t, "condition": what, "frames": c["frames"],
                         "lost_frame_fraction": c["lost_frame_fraction"]})
    return pd.DataFrame(rows, columns=["tracker", "condition", "frames", "lost_frame_fraction"])


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


