"""Write a study's report: ``report.md`` and the same as ``report.html`` (python-markdown), with
the plots beside them and the key numbers as tables taken from the Parquet files."""

from __future__ import annotations

import platform
from datetime import datetime
from pathlib import Path

import markdown
import numpy as np
import pandas as pd

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
    out = rows[["vision_delay_ms", "observer", "update_period_s", "stable", "phase_margin_deg"]]
    out = out.assign(
        delay_margin_ms=1e3 * rows.delay_margin_s, jitter_margin_ms=1e3 * rows.jitter_margin_s
    )
    return out.reset_index(drop=True)


def key_sweep(sweep: pd.DataFrame) -> pd.DataFrame:
    """RMS error and lost-frame fraction by controller, reference and delay (seed means)."""
    cols = ["rms_error_deg", "lost_frame_fraction", "dropped_frame_fraction", "diverged"]
    g = sweep.groupby(["controller", "reference", "vision_delay_ms"], as_index=False)[cols].mean()
    return g


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
        "left out of this analysis (for both controllers). Where a stable loop shows a negative "
        "phase margin it has several gain crossovers and is only conditionally stable (the "
        "encirclements cancel); its delay margin is then the number to read.",
        "",
        "![PID vs MPC](pm_pid_vs_mpc.png)",
        "",
        md_table(key_margins(rows.drop(columns="delay_aware").assign(jitter_margin_s=np.nan))),
        "",
        "Full table: `mpc_margins.parquet` (also without the delay compensation).",
        "",
    ]


def write_report(
    out: Path, cfg, findings, margins, sweep, ts: dict, measured_ms: float, mpc_margins=None
) -> None:
    """Write ``report.md`` and ``report.html`` into ``out``."""
    md = [
        "# What vision delay does to the PMSpM attitude loop",
        "",
        f"Generated {datetime.now().isoformat(timespec='seconds')} on "
        f"{platform.machine()} ({platform.python_version()}) by `pmspm study`.",
        "",
        "## Summary",
        "",
        *findings,
        "",
        "## 1. Margins against vision delay (analysis)",
        "",
        "Per-axis loop 1/(J s² + b s) with the PID exactly as it runs (discrete, at the observer's "
        "update period), exact delay, stability from the closed-loop eigenvalues "
        "(`latency.margins.sampled_margins`); jitter margin from the hybrid model (Kao & Lincoln). "
        "Delay = observer latency; the loop adds half the exposure.",
        "",
        "![margins](margins_vs_delay.png)",
        "",
        md_table(key_margins(margins)),
        "",
        "Full table: `margins.parquet`.",
        "",
        *_mpc_section(mpc_margins),
        "## 2. Closed-loop sweep (measurement-model loop)",
        "",
        f"Sequential observer at 36 frames/s, pixel noise {cfg.sigma_px} px, tracker search window "
        f"{cfg.search_radius_px:g} px with a constant-velocity prediction; "
        f"{cfg.duration_s:g} s per run; per-frame least-squares attitude; the MPC predicts across "
        "the delay itself, the PID does not.",
        "",
        "![sweep](sweep_error_loss.png)",
        "",
        "![steps](step_vs_delay.png)",
        "",
        md_table(key_sweep(sweep)),
        "",
        "Full table: `sweep.parquet` (one row per run; every run's own file is in `sweep/runs/`).",
        "",
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
                    }
                    for k, v in ts.items()
                ]
            )
        ),
        "",
        f"Latency measured here: KCF + GK assistance, {measured_ms:.2f} ms median "
        "(`latency_kcf_gk.json`, reusable as an empirical latency profile).",
        "",
    ]
    text = "\n".join(md)
    (out / "report.md").write_text(text)
    html = markdown.markdown(text, extensions=["tables"])
    page = HTML_HEAD.format(title="PMSpM study") + html + "</body></html>"
    (out / "report.html").write_text(page)
