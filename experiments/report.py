"""Write a study's report: ``report.md`` and the same as ``report.html`` (python-markdown), with
the plots beside them and the key numbers as tables taken from the Parquet files."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import markdown
import numpy as np
import pandas as pd

from experiments.intervals import widest_wilson_width
from latency import metrics
from latency.models import SEED_LATENCY_S

HTML_HEAD = """<!doctype html><html><head><meta charset="utf-8"><title>{title}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.45}}
table{{border-collapse:collapse}}td,th{{border:1px solid #bbb;padding:3px 8px;text-align:right}}
img{{max-width:100%}}code{{background:#f3f3f3}}</style></head><body>
"""


def _fmt(x) -> str:
    if isinstance(x, float | np.floating):
        return "—" if not np.isfinite(x) else f"{x:.3f}"
    return str(x)


def md_table(df: pd.DataFrame) -> str:
    """A DataFrame as a Markdown table (numbers with 3 decimals, NaN as a dash)."""
    head = "| " + " | ".join(df.columns) + " |"
    rule = "|" + "---|" * len(df.columns)
    rows = ["| " + " | ".join(_fmt(v) for v in r) + " |" for r in df.itertuples(index=False)]
    return "\n".join([head, rule, *rows])


def key_margins(margins: pd.DataFrame) -> pd.DataFrame:
    """The margin rows at the seed's two latencies, both observer semantics."""
    marks = [SEED_LATENCY_S["gk_transt"] * 1e3, SEED_LATENCY_S["dual_transt"] * 1e3]
    rows = margins[np.isclose(margins.vision_delay_ms.to_numpy()[:, None], marks).any(axis=1)]
    out = rows[["vision_delay_ms", "observer", "update_period_s", "stable", "phase_margin_deg",
                "crossover_rad_s", "n_crossovers", "gain_margin", "conditionally_stable"]]
    out = out.assign(
        delay_margin_ms=1e3 * rows.delay_margin_s, headroom_ms=1e3 * rows.headroom_s,
        jitter_margin_ms=1e3 * rows.jitter_margin_s,
    )
    return out.reset_index(drop=True)


def key_sweep(intervals: pd.DataFrame) -> pd.DataFrame:
    """Means over seeds with 95 % intervals by controller, reference and delay."""
    cols = ["tracker", "controller", "reference", "vision_delay_ms", "n_runs"]
    for c in ("rms_error_deg", "lost_frame_fraction"):
        cols += [c, f"{c}_lo", f"{c}_hi"]
    cols += ["p_loss_of_control", "p_loss_of_control_lo", "p_loss_of_control_hi"]
    return intervals[cols]


def key_steps(intervals: pd.DataFrame) -> pd.DataFrame:
    """Step metrics with 95 % intervals at the seed's two latencies, every controller."""
    marks = [SEED_LATENCY_S["gk_transt"] * 1e3, SEED_LATENCY_S["dual_transt"] * 1e3]
    st = intervals[(intervals.reference == "tilt_step_5deg")
                   & np.isclose(intervals.vision_delay_ms.to_numpy()[:, None], marks).any(axis=1)]
    cols = ["controller", "vision_delay_ms", "n_runs"]
    for c in ("overshoot_pct", "settling_time_s", "steady_state_error_deg"):
        cols += [c, f"{c}_lo", f"{c}_hi"]
    cols += ["p_settled"]
    return st[cols].reset_index(drop=True)


def _mpc_section(mpc_margins) -> list[str]:
    """The MPC's margins (its linearised law), or nothing when they were not computed."""
    if mpc_margins is None:
        return []
    rows = mpc_margins[mpc_margins.delay_aware]
    return [
        "### PID against MPC",
        "",
        "The MPC's margins come from its linearised feedback law (`latency.mpc_law`): the gain "
        "of the real solver at rest by central differences, the backward-difference rate and the "
        "delay compensation with the commands already sent, analysed like the PID's exact "
        "discrete law; the delay includes the MPC's measured compute time. Coulomb friction is "
        "left out of this analysis (for both controllers). A loop may cross |L| = 1 more than "
        "once: the phase margin reported is the critical crossover's, where L comes closest "
        "to -1 (`n_crossovers` counts them); 'conditionally stable' is said only where a lower "
        "gain margin exists (the loop would go unstable if its gain shrank).",
        "",
        "![PID vs MPC](pm_pid_vs_mpc.png)",
        "",
        md_table(key_margins(rows.drop(columns="delay_aware").assign(jitter_margin_s=np.nan))),
        "",
        "Full table: `mpc_margins.parquet` (also without the delay compensation).",
        "",
    ]


def _ends(df: pd.DataFrame, col: str, scale: float = 1.0) -> pd.Series:
    """``mean [low, high]`` of an interval column per row (the mean alone without ends)."""
    def one(r: pd.Series) -> str:
        m, lo, hi = (scale * float(r[c]) for c in (col, f"{col}_lo", f"{col}_hi"))
        return f"{m:.3g} [{lo:.3g}, {hi:.3g}]" if np.isfinite(lo) else f"{m:.3g}"
    return df.apply(one, axis=1)


def network_alone_unseen_lines(
    accuracy_file: Path | None = None, weights: Path | None = None
) -> list[str]:
    """What the committed results file ``accuracy_file`` (default
    ``observer.transt.weights.UNSEEN_ACCURACY``) says of the network alone on the unseen image
    source, for the weights ``weights`` (default the shipped ones): the figures if the file was
    measured on weights with the same SHA-256, else why there are none. Read, never
    recomputed."""
    import json

    from observer.transt.weights import SMALL_WEIGHTS, UNSEEN_ACCURACY, WeightsError, verify

    acc_path = Path(accuracy_file or UNSEEN_ACCURACY)
    w = Path(weights or SMALL_WEIGHTS)
    rerun = "`python benchmarks/bench_transt_unseen.py`"
    head = "**The network alone on frames from elsewhere** (the dual TransT's side): "
    try:
        digest = verify(w)
    except WeightsError as exc:
        return [head + f"not known: the weights do not load ({str(exc).splitlines()[0]}).", ""]
    if not acc_path.is_file():
        return [head + f"not measured for these weights (no `{acc_path.name}`); run {rerun}.", ""]
    acc = json.loads(acc_path.read_text())
    if acc.get("weights_sha256") != digest:
        return [head + f"`{acc_path.name}` was measured on other weights (SHA-256 "
                f"{str(acc.get('weights_sha256'))[:12]}…, these are {digest[:12]}…); rerun "
                f"{rerun}.", ""]
    fig = acc["figures"]
    cases = "; ".join(
        f"{case}: precision@20px {fig[f'{case}_main_precision_20px']:.3f} / "
        f"{fig[f'{case}_aux_precision_20px']:.3f}, median error "
        f"{fig[f'{case}_main_err_median_px']:.1f} / {fig[f'{case}_aux_err_median_px']:.1f} "
        "sensor px" for case in acc["cases"])
    return [head + "the weights used here (SHA-256 " + digest[:12] + "…), tracking without GK "
            "(box centres) the validation sequences rendered by an image source never used for "
            "training (`plant.render_unseen`: MuJoCo in drawn looks through a sensor model), "
            f"{acc['seeds']} seed(s) of {acc['frames']} frames, main / auxiliary marker — "
            f"{cases} (from `{acc_path.name}`, {acc.get('date', 'undated')}). The dual TransT's "
            "tracking loss below is that of this network; where it is far from its accuracy on "
            "the project's own renders, the comparison measures the training set as well as "
            "the delay.", ""]


def _image_loop_section(image_loop: pd.DataFrame | None, cfg) -> list[str]:
    """Tracking loss from the trackers themselves (the image engine) beside the calibrated
    models on the same references, with the network's accuracy on the unseen image source
    (``network_alone_unseen_lines``)."""
    head = ["### Tracking loss from the trackers themselves (image engine)", "",
            *network_alone_unseen_lines()]
    if image_loop is None:
        return head + ["Not run in this study (`StudyConfig.image_loop` is off).", ""]
    if not len(image_loop):
        return head + ["Not run: no tracker to run.", ""]
    n = int(cfg.image_loop_n_seeds)
    t = image_loop[["tracker", "vision_delay_ms", "max_rate_rad_s"]].copy()
    t["image_runs"] = image_loop["image_n_runs"].astype(int)
    t["lost frames image (%)"] = _ends(image_loop, "image_lost_frame_fraction", 100.0)
    t["lost frames model (%)"] = _ends(image_loop, "model_lost_frame_fraction", 100.0)
    t["P(loss of control) image"] = _ends(image_loop, "image_p_loss_of_control")
    t["P(loss of control) model"] = _ends(image_loop, "model_p_loss_of_control")
    t["agree"] = image_loop["agree"]
    return head + [
        "The loop closed on rendered frames (analytic renderer) tracked by each tracker itself, "
        "PID, the per-frame solver, at the seed's latencies (constant; "
        + ("each tracker at its own" if cfg.image_loop_delays == "own" else
           "every tracker at both") + f"), {n} reference "
        f"seed(s) per point of {cfg.image_loop_duration_s:g} s, run by the batched image engine "
        "(`latency.image_engine`: each run computes what the event loop computes for it; the "
        "latency it charges is the constant above, not the batched wall time). Beside it, the "
        "tracker's calibrated loss model in the measurement-model loop on the same references, "
        "delays, seeds and durations. 95 % intervals over the runs (bootstrap for lost frames; "
        "for image runs that lost no frame the exact binomial interval of their pooled frames, "
        "not a bootstrap's [0, 0]; Wilson for loss of control; "
        f"with {n} runs a Wilson interval is up to {widest_wilson_width(n):.2f} wide). "
        "`agree`: both intervals overlap for the lost-frame fraction and for loss of control. "
        + verdict_sentence(cfg.image_loop_duration_s),
        "",
        md_table(t),
        "",
        "Full tables: `image_loop.parquet` (one row per run, `side` image or model), "
        "`image_loop_intervals.parquet`.",
        "",
    ]


def _calibration_section(calibration: pd.DataFrame | None,
                         conditions: pd.DataFrame | None = None) -> list[str]:
    """The calibrated loss models' held-out validation and their fit's lost frames per camera
    and scene (from their files)."""
    if calibration is None or not len(calibration):
        return []
    by_condition = []
    if conditions is not None and len(conditions):
        c = conditions.pivot(index="condition", columns="tracker", values="lost_frame_fraction")
        c = (100.0 * c).round(1)
        by_condition = [
            "Lost frames (%) in each tracker's fit runs, per camera and per scene appearance "
            "(every delay and peak rate of the design pooled). The model describes the camera "
            "through the prediction's miss and the blur, the scene through an offset on its "
            "intercepts; the study's runs use the nominal scene:",
            "",
            md_table(c.reset_index()),
            "",
        ]
    t = calibration[["tracker", "fit_frames", "delay_ms", "rate_rad_s", "image_runs",
                     "model_runs"]].copy()
    t["lost frames image (%)"] = _ends(calibration, "image_lost_frame_fraction", 100.0)
    t["lost frames model (%)"] = _ends(calibration, "model_lost_frame_fraction", 100.0)
    t["P(loss of control) image"] = _ends(calibration, "image_loss_of_control")
    t["P(loss of control) model"] = _ends(calibration, "model_loss_of_control")
    t["agree"] = calibration["agree"]
    return [
        "### The calibrated loss models: held-out agreement",
        "",
        "Each tracker's loss model was fitted by `pmspm calibrate-loss` on its own image runs "
        "(`fit_frames` frames; `latency.loss_model`) and checked on peak rates and reference "
        "seeds the fit did not use: the image runs against the model's runs on the same "
        "references, 95 % intervals.",
        "",
        md_table(t),
        "",
        *by_condition,
    ]


#: The verdict's validation against the exact margins (``benchmarks/bench_verdict.py``, run
#: here on 2026-12-06): per controller and run length (s), the fraction of runs flagged 20 ms
#: of vision delay inside the analysis' boundary (false alarms) and 20 ms beyond it
#: (detections), over ``runs`` runs each, every run on its own random reference of peak rate
#: ``rate_rad_s`` (docs/closed_loop.md).
VERDICT_VALIDATION: dict = {
    "runs": 200,
    "rate_rad_s": 1.0,
    "false_alarm": {("pid", 3.0): 0.0, ("pid", 4.0): 0.0, ("pid", 6.0): 0.0,
                    ("pid", 8.0): 0.0, ("pid", 10.0): 0.0, ("pid", 12.0): 0.0,
                    ("mpc", 3.0): 0.0, ("mpc", 4.0): 0.0, ("mpc", 6.0): 0.0,
                    ("mpc", 8.0): 0.0, ("mpc", 10.0): 0.0, ("mpc", 12.0): 0.0},
    "detection": {("pid", 3.0): 0.54, ("pid", 4.0): 0.685, ("pid", 6.0): 0.86,
                  ("pid", 8.0): 0.945, ("pid", 10.0): 0.985, ("pid", 12.0): 1.0,
                  ("mpc", 3.0): 0.95, ("mpc", 4.0): 0.99, ("mpc", 6.0): 1.0,
                  ("mpc", 8.0): 1.0, ("mpc", 10.0): 1.0, ("mpc", 12.0): 1.0},
}


def verdict_sentence(duration_s: float) -> str:
    """What the verdict's validation (``VERDICT_VALIDATION``) says about runs of
    ``duration_s``: the rates at the longest validated length not beyond it, and a warning
    when that length misses detections."""
    v = VERDICT_VALIDATION
    lengths = sorted({length for _, length in v["detection"]})
    fit = [length for length in lengths if length <= duration_s + 1e-9]
    if not fit:
        return (f"The verdict was validated on runs of {lengths[0]:g} s or more; on "
                f"{duration_s:g} s runs its rates are not known.")
    at = fit[-1]

    def pct(kind: str, ctrl: str) -> str:
        return f"{100 * v[kind][(ctrl, at)]:.1f} %"

    text = (f"Validated against the exact margins (`benchmarks/bench_verdict.py`, {v['runs']} "
            f"runs per case, each on its own random reference of peak rate "
            f"{v['rate_rad_s']:g} rad/s), judged on {at:g} s runs: 20 ms inside the analysis' "
            f"boundary it flags {pct('false_alarm', 'pid')} of the PID's runs and "
            f"{pct('false_alarm', 'mpc')} of the MPC's (false alarms), 20 ms beyond it "
            f"{pct('detection', 'pid')} and {pct('detection', 'mpc')} (detections).")
    needed = [length for length in lengths
              if all(v["detection"][(c, length)] >= 0.99 for c in ("pid", "mpc"))]
    if needed and at < needed[0]:
        text += (f" These runs are too short to detect a slowly growing instability "
                 f"reliably: {needed[0]:g} s runs reach 99 % detection.")
    return text


def _reference_sentence(cfg) -> str:
    """What a point's seeds vary: the random reference with the noise, or the noise only."""
    if getattr(cfg, "reference_mode", "per_seed") == "fixed":
        return ("Fixed-reference mode: every run follows the same random reference (one per "
                "peak rate), so the intervals are over pixel noise and latency draws only, not "
                "over references.")
    return ("Each run's random reference is drawn from its own seed (`reference_seed` in "
            "`sweep.parquet`), so the intervals on the random references are over references, "
            "pixel noise and latency draws together.")


def write_report(
    out: Path, cfg, findings, margins, intervals, loss, ts: dict, measured: dict[str, float],
    facts: dict, mpc_margins=None, image_loop: pd.DataFrame | None = None,
    calibration: pd.DataFrame | None = None, conditions: pd.DataFrame | None = None,
) -> None:
    """Write ``report.md`` and ``report.html`` into ``out``. Facts about the machine and the
    camera come from ``facts`` (read in this run), latencies from ``measured``; the image-mode
    section from ``image_loop`` (None: not run), the calibrated loss models' held-out
    agreement from ``calibration`` and their fit's lost frames per condition from
    ``conditions``."""
    md = [
        *_header_lines(facts),
        "## Summary",
        "",
        *findings,
        "",
        *_margins_section(margins),
        *_mpc_section(mpc_margins),
        *_sweep_section(cfg, facts, intervals),
        *_image_loop_section(image_loop, cfg),
        *_calibration_section(calibration, conditions),
        *_time_series_section(ts, measured),
    ]
    text = "\n".join(md)
    (out / "report.md").write_text(text)
    html = markdown.markdown(text, extensions=["tables"])
    page = HTML_HEAD.format(title="PMSpM study") + html + "</body></html>"
    (out / "report.html").write_text(page)


def _header_lines(facts: dict) -> list[str]:
    """The report's title and where it was made: date, machine, Python, motor and camera."""
    return [
        "# What vision delay does to the PMSpM attitude loop",
        "",
        f"Generated {datetime.now().isoformat(timespec='seconds')} on "
        f"{facts['machine']} ({facts['processor']}, {facts['cpus']:.0f} CPUs seen by Python, "
        f"Python {facts['python']}) by `pmspm study`.",
        "",
        "Motor: " + (f"`{facts['motor_file']}`" if facts.get("motor_file") else
                     "the seed's (default `PlantParams`)")
        + "; camera: " + (f"`{facts['camera_file']}`" if facts.get("camera_file") else
                          "the default camera") + ".",
        "",
    ]


def _margins_section(margins: pd.DataFrame) -> list[str]:
    """Section 1: the PID's margins against vision delay, as analysed."""
    return [
        "## 1. Margins against vision delay (analysis)",
        "",
        "Per-axis loop 1/(J s² + b s) with the PID exactly as it runs (discrete, at the observer's "
        "update period), exact delay, stability from the closed-loop eigenvalues "
        "(`latency.margins.as_run_margins`); jitter margin (Kao & Lincoln) from the same "
        "discrete C(z). Delay = observer latency; the loop adds half the exposure. The delay "
        "margin is the extra constant delay at the row's fixed update period; the headroom is "
        "the extra vision delay before instability found by scanning the delay through the "
        "pipeline (a sequential observer's update period grows once the delay exceeds a frame "
        "period).",
        "",
        "![margins](margins_vs_delay.png)",
        "",
        md_table(key_margins(margins)),
        "",
        "Full table: `margins.parquet`.",
        "",
    ]


def _sweep_section(cfg, facts: dict, intervals: pd.DataFrame) -> list[str]:
    """Section 2: the closed-loop sweep, how its runs were made and judged, its figures and
    its tables of step and sweep metrics with their intervals over seeds."""
    n_seeds = int(getattr(cfg, "n_seeds", 1))
    return [
        "## 2. Closed-loop sweep (measurement-model loop)",
        "",
        f"Sequential observer at {facts['frame_rate_hz']:g} frames/s, "
        + (f"each tracker's tracking loss and centre noise from its calibrated model "
           f"(`tracker` column: {', '.join(cfg.trackers)}; every tracker on the PID and MPC "
           "random-reference points at every delay, the first on the step and the variants)"
           if cfg.loss_model == "calibrated" else
           f"pixel noise {cfg.sigma_px} px, the hand-set tracker search window "
           f"{cfg.search_radius_px:g} px with a constant-velocity prediction for every tracker")
        + f"; {cfg.duration_s:g} s per run, every run over the whole "
        f"duration; {n_seeds} seed(s) per point. "
        + _reference_sentence(cfg)
        + " Bands and table columns `_lo`/`_hi` are 95 % "
        "intervals over seeds: bootstrap of the mean for RMS error and lost frames, Wilson for "
        "the probability of loss of control"
        + (" (with a single seed there is no interval)" if n_seeds < 2 else "")
        + f". Loss of control: the rotor rests on the tilt stop for {metrics.LOC_TILT_STOP_S:g} s, "
        f"the markers are lost for {metrics.LOC_MARKER_LOSS_S:g} s or on "
        f"{100 * metrics.LOC_LOST_FRACTION:.0f} % of the frames, the RMS error over the run's "
        f"last {100 * metrics.LOC_LATE_FRACTION:.0f} % exceeds what the reference demands there "
        f"({metrics.LOC_ERROR_FLOOR_DEG:g}° plus {metrics.LOC_LAG_S:g} s of its mean angular "
        "speed), or the error exceeds the divergence limit. "
        + verdict_sentence(cfg.duration_s)
        + " Step metrics are those of the step reference only (the random references have "
        "none). The step is "
        "measured against the commanded 5° (overshoot in % of it; settling into the absolute "
        f"band ±{metrics.SETTLE_BAND_DEG:g}°; steady-state error: the mean over the final "
        f"{metrics.STEADY_STATE_WINDOW_S:g} s). The MPC previews the reference and "
        "the PID feeds it forward; their variants without preview / feedforward are shown "
        "on the step for a fair comparison.",
        "",
        "![boundary](boundary_vs_loss_of_control.png)",
        "",
        "![sweep](sweep_error_loss.png)",
        "",
        "![steps](step_vs_delay.png)",
        "",
        md_table(key_steps(intervals)),
        "",
        md_table(key_sweep(intervals)),
        "",
        "Full tables: `sweep.parquet` (one row per run; every run's own file is in "
        "`sweep/runs/`), `sweep_intervals.parquet`, `loss_of_control.parquet`.",
        "",
    ]


def _time_series_section(ts: dict, measured: dict[str, float]) -> list[str]:
    """Section 3: the 16.33 ms against 31.23 ms time series and the latencies measured here
    (ms, median)."""
    lat = "; ".join(f"{k} {v:.2f} ms median (`latency_{k}.json`)" for k, v in measured.items())
    return [
        "## 3. Time series: 16.33 ms against 31.23 ms",
        "",
        "![time series](timeseries_16_vs_31ms.png)",
        "",
        md_table(
            pd.DataFrame(
                [
                    {
                        "run": k,
                        "rms_error_deg": v["rms_error_deg"],
                        "overshoot_pct": v["overshoot_pct"],
                        "settling_time_s": v["settling_time_s"],
                        "steady_state_error_deg": v["steady_state_error_deg"],
                    }
                    for k, v in ts.items()
                ]
            )
        ),
        "",
        f"Latency measured here: {lat or 'not measured (the TransT network could not be loaded)'}"
        " (reusable as empirical latency profiles).",
        "",
    ]
