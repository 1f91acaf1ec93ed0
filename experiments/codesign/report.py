"""The co-design report: the designs table, the Pareto front with intervals, the recommended
design beside the seed's, and the image-in-the-loop check of the recommended design.

* **Non-dominated designs**: the feasible designs (every constraint met) that no other feasible
  design beats on all three objectives.
* **Recommended design**: the non-dominated design with the smallest mean RMS error (the first
  objective; effort and compute break ties through the front).
* **Seed's design** (``experiments.codesign.space.seed_design``): analysed and run through the
  same Monte Carlo, whatever its analysis says, so that the gains are like for like.
* **Image-in-the-loop check**: the recommended design re-run on the event loop with rendered
  frames and its tracker's real implementation (``TrackerModel.image_tracker``), a few seeds;
  the report states whether its mean error, lost-frame fraction and loss-of-control fraction
  lie inside the Monte-Carlo 95 % intervals. The frames are those of the design's camera
  mode: its timing, and only its region of interest (following the prediction when the
  design's does), so the region's losses are checked on rendered frames too.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from experiments.codesign.evaluate import summarise
from experiments.codesign.search import evaluate_designs
from experiments.codesign.space import Design, scenario_dict, seed_design, space_summary, tracker_of
from experiments.codesign.spec import CodesignSpec
from experiments.report import md_table
from latency import Scenario, simulate_many

#: Columns of the designs table, from a record (``search.evaluate_designs``).
_MC_COLUMNS = ("rms_error_deg", "rms_torque_Nm", "lost_frame_fraction", "p_loss_of_control")


def designs_table(records: list[dict]) -> pd.DataFrame:
    """One row per design: trial, label, pruned, feasible, the analysis, the Monte-Carlo means
    with their intervals and the compute per frame; ``non_dominated`` marks the front."""
    rows = []
    for r in records:
        d = Design.model_validate(r["design"])
        a = r["analysis"]
        row = {"trial": r.get("trial", -1), "design": d.label(), "pruned": r["pruned"],
               "feasible": bool(r["feasible"]), "stable": a["stable"],
               "phase_margin_deg": a["phase_margin_deg"], "headroom_ms": 1e3 * a["headroom_s"],
               "growth_rate_per_s": a.get("growth_rate_per_s", np.nan),
               "loop_delay_ms": 1e3 * a["delay_s"],
               "update_period_ms": 1e3 * a["update_period_s"]}
        mc = r["mc"] or {}
        for c in _MC_COLUMNS:
            for suffix in ("", "_lo", "_hi"):
                row[c + suffix] = mc.get(c + suffix, np.nan)
        row["compute_ms"] = 1e3 * r["objectives"][2] if r["objectives"] else np.nan
        rows.append(row)
    df = pd.DataFrame(rows)
    df["non_dominated"] = non_dominated(df)
    return df


def non_dominated(df: pd.DataFrame) -> np.ndarray:
    """Mask of the feasible rows that no other feasible row dominates on (error, effort,
    compute): no worse on all three and better on one."""
    cols = ["rms_error_deg", "rms_torque_Nm", "compute_ms"]
    feasible = df["feasible"].to_numpy(bool) if len(df) else np.zeros(0, bool)
    x = df[cols].to_numpy(float) if len(df) else np.zeros((0, 3))
    out = np.zeros(len(df), bool)
    for i in np.flatnonzero(feasible):
        others = x[feasible]
        dominated = np.any(np.all(others <= x[i], axis=1) & np.any(others < x[i], axis=1))
        out[i] = not dominated
    return out


def recommended(df: pd.DataFrame) -> pd.Series | None:
    """The non-dominated row with the smallest mean RMS error (None without one)."""
    front = df[df["non_dominated"]]
    return None if front.empty else front.loc[front["rms_error_deg"].idxmin()]


def plot_front(df: pd.DataFrame, seed: pd.Series) -> Figure:
    """Mean RMS error against effort and against compute per frame, 95 % intervals on the
    error; feasible designs coloured by compute, infeasible grey, the front outlined, the seed's
    design a red star."""
    fig = Figure(figsize=(11, 4.5))
    axes = fig.subplots(1, 2)
    ran = df[~df["pruned"]]
    for ax, xcol, xlabel in ((axes[0], "rms_torque_Nm", "control effort: RMS torque (N·m)"),
                             (axes[1], "compute_ms", "compute per frame (ms)")):
        for part, style in ((ran[~ran["feasible"]], {"color": "0.7", "label": "infeasible"}),
                            (ran[ran["feasible"] & ~ran["non_dominated"]],
                             {"color": "tab:blue", "label": "feasible"}),
                            (ran[ran["non_dominated"]],
                             {"color": "tab:green", "label": "non-dominated"})):
            if part.empty:
                continue
            err = np.vstack([part.rms_error_deg - part.rms_error_deg_lo,
                             part.rms_error_deg_hi - part.rms_error_deg])
            ax.errorbar(part[xcol], part.rms_error_deg, yerr=np.nan_to_num(err), fmt="o",
                        ms=5, capsize=2, alpha=0.8, **style)
        s_err = np.array([[seed.rms_error_deg - seed.rms_error_deg_lo],
                          [seed.rms_error_deg_hi - seed.rms_error_deg]])
        ax.errorbar([seed[xcol]], [seed.rms_error_deg], yerr=np.nan_to_num(s_err), fmt="*",
                    color="tab:red", ms=14, capsize=3, label="seed's design")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("mean RMS attitude error (deg)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("Co-design: Monte-Carlo error with 95 % intervals (pruned designs not shown)")
    fig.tight_layout()
    return fig


def image_scenarios(spec: CodesignSpec, design: Design) -> list[Scenario]:
    """The image-in-the-loop runs of ``design``: its Monte-Carlo scenarios for
    ``spec.image_check.seeds`` in image mode, rendered frames, the tracker's scenario tracker
    (``TrackerModel.image_tracker``; ``ValueError`` when it has none), the design's camera
    mode (frame timing, and the region of interest read out and followed as in the Monte
    Carlo, ``latency.frontends.ImageFrontEnd``)."""
    ic = spec.image_check
    tracker = tracker_of(spec, design).image_tracker
    if tracker is None:
        raise ValueError(f"tracker {design.tracker!r} has no image-in-the-loop implementation")
    scenarios = []
    for seed in ic.seeds:
        for i in range(len(spec.references)):
            d = scenario_dict(spec, design, seed, i)
            d.update(mode="image", renderer=ic.renderer, tracker=tracker,
                     duration_s=min(ic.duration_s, spec.duration_s))
            scenarios.append(Scenario.model_validate(d))
    return scenarios


def image_check(spec: CodesignSpec, design: Design, mc: dict) -> dict:
    """Re-run ``design`` on rendered frames with its tracker's real implementation (event
    loop) for ``spec.image_check.seeds`` and compare with the Monte-Carlo intervals ``mc``.

    Returns the image runs' ``summarise`` figures, ``tracker``, and per metric whether it lies
    inside the interval (``inside_error``, ``inside_lost_frames``, ``inside_loss_of_control``),
    or ``skipped`` with the reason."""
    tracker = tracker_of(spec, design).image_tracker
    if tracker is None:
        return {"skipped": f"tracker {design.tracker!r} has no image-in-the-loop implementation"}
    rows = []
    for res in simulate_many(image_scenarios(spec, design), engine="event"):
        s = res.summary
        rows.append({"error": "", **{f"result.{k}": float(s[k]) for k in (
            "rms_error_deg", "rms_torque_Nm", "lost_frame_fraction", "loss_of_control")}})
    got = summarise(pd.DataFrame(rows))

    def inside(key: str, lo: str, hi: str) -> bool:
        lo_v, hi_v = mc.get(lo, np.nan), mc.get(hi, np.nan)
        v = got[key]
        if not np.isfinite(lo_v) or not np.isfinite(hi_v):
            return bool(np.isclose(v, mc.get(key, np.nan)))
        return bool(lo_v - 1e-12 <= v <= hi_v + 1e-12)

    return {**got, "tracker": tracker,
            "inside_error": inside("rms_error_deg", "rms_error_deg_lo", "rms_error_deg_hi"),
            "inside_lost_frames": inside("lost_frame_fraction", "lost_frame_fraction_lo",
                                         "lost_frame_fraction_hi"),
            "inside_loss_of_control": inside("p_loss_of_control", "p_loss_of_control_lo",
                                             "p_loss_of_control_hi")}


def _fmt(row: pd.Series | dict, col: str, scale: float = 1.0, fmt: str = ".3g") -> str:
    v, lo, hi = (row.get(col + s, np.nan) for s in ("", "_lo", "_hi"))
    if not np.isfinite(v):
        return "n/a"
    if np.isfinite(lo) and np.isfinite(hi):
        return f"{scale * v:{fmt}} [{scale * lo:{fmt}}, {scale * hi:{fmt}}]"
    return f"{scale * v:{fmt}}"


def comparison(rec: pd.Series, seed: pd.Series) -> pd.DataFrame:
    """The recommended design beside the seed's: each metric and the gain."""
    items = [("mean RMS error (deg)", "rms_error_deg", 1.0),
             ("RMS torque (mN·m)", "rms_torque_Nm", 1e3),
             ("compute per frame (ms)", "compute_ms", 1.0),
             ("critical phase margin (deg)", "phase_margin_deg", 1.0),
             ("delay headroom (ms)", "headroom_ms", 1.0),
             ("P(loss of control)", "p_loss_of_control", 1.0),
             ("lost frames", "lost_frame_fraction", 1.0),
             ("loop delay (ms)", "loop_delay_ms", 1.0),
             ("update period (ms)", "update_period_ms", 1.0)]
    rows = []
    for name, col, k in items:
        r, s = float(rec[col]), float(seed[col])
        rows.append({"metric": name, "recommended": _fmt(rec, col, k),
                     "seed's design": _fmt(seed, col, k),
                     "change": f"{k * (r - s):+.3g}" if np.isfinite(r - s) else "n/a"})
    return pd.DataFrame(rows)


def write_report(
    spec: CodesignSpec,
    records: list[dict],
    out_dir: Path,
    run_image_check: bool | None = None,
) -> dict:
    """Write ``designs.csv``, ``pareto.png``, ``report.md`` and ``result.json`` into
    ``out_dir``; returns the result (recommended design, seed's design, comparison, image
    check)."""
    seed_rec = evaluate_designs(spec, [seed_design()], out_dir, prune=False)[0]
    df = designs_table(records)
    seed_row = designs_table([seed_rec]).iloc[0]
    df.to_csv(out_dir / "designs.csv", index=False)
    fig = plot_front(df, seed_row)
    fig.savefig(out_dir / "pareto.png", dpi=120)
    rec = recommended(df)
    result: dict = {"n_designs": len(df), "n_pruned": int(df["pruned"].sum()),
                    "n_feasible": int(df["feasible"].sum()),
                    "n_non_dominated": int(df["non_dominated"].sum()),
                    "seed": seed_row.to_dict(), "recommended": None, "image_check": None}
    lines = [f"# Co-design report: {spec.name}", "",
             f"{len(df)} designs evaluated ({result['n_pruned']} pruned by the analysis, "
             f"{result['n_feasible']} feasible, {result['n_non_dominated']} non-dominated); "
             f"{len(spec.seeds)} seeds × {len(spec.references)} references of "
             f"{spec.duration_s:g} s per design.", "", "## Design space", ""]
    lines += [f"- {s}" for s in space_summary(spec)]
    c = spec.constraints
    lines += ["", "## Constraints", "",
              f"critical phase margin ≥ {c.min_phase_margin_deg:g}°, delay headroom ≥ "
              f"{c.min_delay_headroom_ms:g} ms (analysis); P(loss of control) ≤ "
              f"{c.max_loss_of_control:g}, lost frames ≤ {c.max_lost_frames:g} (Monte Carlo "
              "means; 95 % intervals in brackets).", "", "![Pareto front](pareto.png)", ""]
    if rec is None:
        lines += ["**No feasible design**: relax the constraints or widen the space.", ""]
    else:
        best = Design.model_validate(records[int(np.flatnonzero(df.trial == rec.trial)[0])]
                                     ["design"])
        result["recommended"] = {"design": best.model_dump(mode="json"), **rec.to_dict()}
        cmp = comparison(rec, seed_row)
        result["comparison"] = cmp.to_dict(orient="records")
        lines += ["## Recommended design beside the seed's", "",
                  f"- recommended: {best.label()}",
                  f"- seed's: {seed_design().label()}", "", md_table(cmp), ""]
        do_check = spec.image_check.enabled if run_image_check is None else run_image_check
        if do_check:
            mc = {k: rec[k] for k in rec.index}
            check = image_check(spec, best, mc)
            result["image_check"] = check
            lines += ["## Image-in-the-loop check", "", _check_text(spec, check), ""]
    front = df[df["non_dominated"]].sort_values("rms_error_deg")
    front = front.assign(rms_torque_mNm=1e3 * front["rms_torque_Nm"])
    cols = ["trial", "design", "rms_error_deg", "rms_torque_mNm", "compute_ms",
            "phase_margin_deg", "headroom_ms", "p_loss_of_control", "lost_frame_fraction"]
    lines += ["## Non-dominated designs", "", md_table(front[cols]) if len(front) else "none",
              ""]
    (out_dir / "report.md").write_text("\n".join(lines))
    (out_dir / "result.json").write_text(json.dumps(result, indent=1, default=_json) + "\n")
    return result


def _json(x):
    """JSON for numpy scalars (and text for anything else ``json`` cannot write)."""
    return x.item() if isinstance(x, np.generic) else str(x)


def _check_text(spec: CodesignSpec, check: dict) -> str:
    if "skipped" in check:
        return f"Not run: {check['skipped']}."
    yes = {True: "inside", False: "outside"}
    return (
        f"The recommended design re-run with rendered frames ({spec.image_check.renderer}) and "
        f"the real tracker ({check['tracker']}), seeds {spec.image_check.seeds}, "
        f"{int(check['n_runs'])} runs: mean RMS error {_fmt(check, 'rms_error_deg')} deg "
        f"({yes[check['inside_error']]} the Monte-Carlo interval), lost frames "
        f"{_fmt(check, 'lost_frame_fraction')} ({yes[check['inside_lost_frames']]}), loss of "
        f"control {_fmt(check, 'p_loss_of_control')} "
        f"({yes[check['inside_loss_of_control']]}). The frames are the design's camera "
        "mode's, its region of interest only."
    )
