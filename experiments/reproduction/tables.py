"""Tables and figures of the reproduction: the step-test table, the seed-like figures and the
tracking table summarised from the tracking benchmark (``experiments.reproduction``)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

from experiments.reproduction.results import StepTestResult
from experiments.reproduction.table import AXES, SEED_RMSE_DEG


# ------------------------------------------------------------------------------------------------
# Tables and plots
# ------------------------------------------------------------------------------------------------
def results_table(results: dict[str, StepTestResult]):  # noqa: ANN201 - pandas.DataFrame
    """The step-test table: one row per scheme, for each axis our RMSE (deg), the number of
    steady-state frames and the seed's RMSE (deg; seed 000 §5.1–5.3, labelled as the seed's).

    Columns: ``scheme``, ``label``, then per axis ``{axis}_rmse_deg``, ``{axis}_steady_frames``,
    ``{axis}_seed_rmse_deg``, and for seed-spread rows ``{axis}_rmse_min_deg`` /
    ``{axis}_rmse_max_deg``.
    """
    import pandas as pd

    keys: list[str] = []
    for r in results.values():
        keys += [k for k in r.traces if k not in keys]
    rows = []
    for key in keys:
        row: dict[str, object] = {"scheme": key}
        for axis in AXES:
            r = results.get(axis)
            tr = r.traces.get(key) if r is not None else None
            if tr is not None:
                row.setdefault("label", tr.label)
                row["seed_row"] = tr.seed_row
            row[f"{axis}_rmse_deg"] = tr.steady.rmse_deg if tr else math.nan
            row[f"{axis}_steady_frames"] = tr.steady.n_frames if tr else 0
            spread = tr.rmse_spread_rad if tr else None
            row[f"{axis}_rmse_min_deg"] = math.degrees(spread[0]) if spread else math.nan
            row[f"{axis}_rmse_max_deg"] = math.degrees(spread[1]) if spread else math.nan
        rows.append(row)
    df = pd.DataFrame(rows)
    for axis in AXES:
        df[f"{axis}_seed_rmse_deg"] = [SEED_RMSE_DEG[s][axis] for s in df["seed_row"]]
    return df


def markdown_step_table(df) -> str:  # noqa: ANN001 - pandas.DataFrame from results_table
    """The step-test table in Markdown: ours beside the seed's for each axis."""
    head = ["scheme"]
    for axis in AXES:
        head += [f"{axis} RMSE, ours", f"{axis}, seed 000"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, r in df.iterrows():
        cells = [str(r["label"])]
        for axis in AXES:
            v = r[f"{axis}_rmse_deg"]
            s = "n/a" if not np.isfinite(v) else f"{v:.4f}°"
            lo, hi = r[f"{axis}_rmse_min_deg"], r[f"{axis}_rmse_max_deg"]
            if np.isfinite(lo):
                s += f" ({lo:.4f}–{hi:.4f}°)"
            cells += [s, f"{r[f'{axis}_seed_rmse_deg']:.4f}° (seed)"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot_step_test(result: StepTestResult, keys: Sequence[str] | None = None) -> Figure:
    """A figure like seed 000 Figures 17–19: (a) the angle trajectory of the table and each
    scheme, (b) each scheme's error over its steady-state frames (``keys``: the traces shown,
    default all)."""
    keys = list(keys or result.traces)
    fig = Figure(figsize=(9, 6.5))
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    t = result.t_s
    ax1.plot(t, np.degrees(result.reference_rad), "k-", lw=2.2, label="rotary table (truth)")
    styles = ["-", "--", ":", "-.", "-", "--"]
    for i, k in enumerate(keys):
        tr = result.traces[k]
        ax1.plot(t, np.degrees(tr.angle_rad), styles[i % len(styles)], lw=1.0, label=tr.label)
        e = np.where(tr.steady.mask, np.degrees(tr.angle_rad - result.reference_rad), np.nan)
        ax2.plot(t, e, styles[i % len(styles)], lw=1.0,
                 label=f"{tr.label}: RMSE {tr.steady.rmse_deg:.4f}°")
    name = {"spin": "Spin", "tilt": "Tilt", "yaw": "Yaw"}[result.axis]
    ax1.set_ylabel(f"{name} angle (°)")
    ax1.set_title(f"(a) {name} angle trajectory")
    ax1.legend(fontsize=7, loc="best")
    ax1.grid(alpha=0.3)
    ax2.set_ylabel("error (°)")
    ax2.set_xlabel("time (s)")
    ax2.set_title("(b) Steady-state measurement error (frames in steady windows only)")
    ax2.legend(fontsize=7, loc="best")
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    return fig


# ------------------------------------------------------------------------------------------------
# The tracking table (benchmarks/bench_tracking.py measures it; we only summarise its output)
# ------------------------------------------------------------------------------------------------
#: Seed 000 §4.2–4.3: precision at 20 px (main, aux) per case (latency and FPS: Table 1,
#: ``experiments.tracking_runs.SEED_TABLE1``).
SEED_TRACKING: dict[str, dict[str, tuple[float, float]]] = {
    "gk_transt": {"clean": (0.909, 0.944), "occlusion": (0.891, 0.944), "blur": (0.897, 0.926)},
    "dual_transt": {"clean": (0.909, 0.917)},
    "kcf": {"clean": (0.894, 0.868), "occlusion": (0.295, 0.295), "blur": (0.428, 0.431)},
    "csrt": {"clean": (0.947, 0.971)},
}


def tracking_table_markdown(csv_path: str) -> str:
    """Summary of ``benchmarks/results/tracking_metrics.csv`` (written by
    benchmarks/bench_tracking.py): mean precision at 20 px (main, aux), median latency and FPS
    per tracker and case, with the seed's numbers beside (seed 000 §4, Table 1)."""
    import pandas as pd

    from experiments.tracking_runs import SEED_TABLE1

    m = pd.read_csv(csv_path)
    g = m.groupby(["tracker", "case"], sort=False).agg(
        sequences=("sequence", "nunique"),
        main=("main_precision_20px", "mean"),
        aux=("aux_precision_20px", "mean"),
        lat=("latency_median_ms", "median"),
        fps=("fps", "median"),
    ).reset_index()
    head = ["tracker", "case", "sequences", "precision@20px main / aux, ours",
            "seed 000", "latency median (ms), ours / seed", "FPS, ours / seed"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, r in g.iterrows():
        base = str(r.tracker).removesuffix("_norefine")
        seed = SEED_TRACKING.get(base, {})
        sp = seed.get(str(r.case))
        sp_s = f"{sp[0]:.3f} / {sp[1]:.3f}" if sp else "—"
        sf, sl = SEED_TABLE1.get(base, (None, None))
        name = str(r.tracker)
        if "standin" in name:
            name += " (numpy-KCF stand-in for the network: not TransT numbers)"
        lines.append(
            f"| {name} | {r.case} | {r.sequences} | {r.main:.3f} / {r.aux:.3f} | {sp_s} | "
            f"{r.lat:.2f} / {sl if sl is not None else '—'} | "
            f"{r.fps:.1f} / {sf if sf is not None else '—'} |"
        )
    return "\n".join(lines)
