"""Wall time of the headline study (under 10 minutes on two cores) and its key figures.

Runs ``experiments.study.run_study`` with the embedded default into a temporary folder, as
``make study`` does after the install, and records the wall time and the headline margins.

Run: python benchmarks/bench_study.py
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from _report import record

from experiments.study import run_study
from experiments.study_config import DUAL_MS, GK_MS


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        out = run_study(Path(tmp))
        wall = time.perf_counter() - t0
        m = pd.read_parquet(out / "margins.parquet")
        mpc = pd.read_parquet(out / "mpc_margins.parquet")
    figures: dict[str, float] = {"study_wall_time_s": wall}
    for d in (GK_MS, DUAL_MS):
        tag = f"{d:.2f}ms".replace(".", "p")
        row = m[(m.observer == "sequential") & np.isclose(m.vision_delay_ms, d)].iloc[0]
        figures[f"pid_sequential_{tag}_phase_margin_deg"] = float(row.phase_margin_deg)
        row = mpc[(mpc.observer == "sequential") & mpc.delay_aware
                  & np.isclose(mpc.vision_delay_ms, d)].iloc[0]
        figures[f"mpc_sequential_{tag}_phase_margin_deg"] = float(row.phase_margin_deg)
    record(
        "bench_study",
        "Headline study (pmspm study): wall time",
        figures,
        notes="The embedded default StudyConfig, in-process (the install of `make study` not "
        "included). Target: under 10 minutes on two cores.",
    )


if __name__ == "__main__":
    main()
