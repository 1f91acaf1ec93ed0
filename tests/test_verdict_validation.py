"""The loss-of-control verdict against the exact margins, on a smaller set than
``benchmarks/bench_verdict.py`` (200 runs per condition there): runs of 12 s on random
references of peak rate 1 rad/s at 20 ms inside the analysis' boundary (no run may be flagged)
and 20 ms beyond it (every run must be), for the PID and the MPC; and the onset the study's
plots mark beside the loss-of-control curves."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from experiments.study import mpc_headroom_s, pid_headroom_s
from experiments.study_config import StudyConfig, study_plant
from experiments.study_plots import plot_sweep
from experiments.study_sweep import controller_spec
from latency import Scenario, simulate_many

pytestmark = pytest.mark.engine  # runs the compiled engines

#: Runs per controller and side of the boundary, and their length (s): the length the
#: benchmark found needed (docs/closed_loop.md).
N_RUNS, LENGTH_S = 6, 12.0


def _runs(ctrl: str, delay_ms: float, cfg: StudyConfig) -> list[dict]:
    params = study_plant(cfg)
    scenarios = [
        Scenario(duration_s=LENGTH_S, seed=seed, plant=params, observer={"kind": "solver"},
                 controller=controller_spec(ctrl, cfg),
                 reference={"kind": "random", "args": {"max_rate_rad_s": 1.0, "seed": seed}},
                 pipeline={"observer": {"kind": "constant", "value_s": delay_ms / 1e3}},
                 measurement={"sigma_px": cfg.sigma_px,
                              "search_radius_px": cfg.search_radius_px})
        for seed in range(100, 100 + N_RUNS)]  # seeds apart from the benchmark's 0-199
    return [r.summary for r in simulate_many(scenarios, engine="batched", tables=False)]


@pytest.mark.slow
@pytest.mark.parametrize("ctrl", ["pid", "mpc"])
def test_the_verdict_agrees_with_the_analysis_20_ms_either_side_of_the_boundary(ctrl):
    cfg = StudyConfig()
    params = study_plant(cfg)

    def headroom_ms(d_ms: float) -> float:
        if ctrl == "pid":
            return 1e3 * pid_headroom_s(params, cfg.crossover_rad_s, d_ms / 1e3, "sequential")
        return 1e3 * mpc_headroom_s(params, d_ms / 1e3, "sequential")

    boundary = headroom_ms(0.0)
    stable = math.floor(100.0 * (boundary - 20.0)) / 100.0
    unstable = math.ceil(100.0 * (boundary + 20.0)) / 100.0
    assert headroom_ms(stable) >= 20.0 and np.isnan(headroom_ms(unstable))
    inside = [s["loss_of_control"] for s in _runs(ctrl, stable, cfg)]
    beyond = [s["loss_of_control"] for s in _runs(ctrl, unstable, cfg)]
    assert inside == [0.0] * N_RUNS  # no false alarm
    assert beyond == [1.0] * N_RUNS  # every unstable run detected


def test_the_sweep_plot_marks_each_controllers_onset_beside_its_loss_curves(tmp_path):
    rows = [{"controller": c, "reference": "random_1rad_s", "vision_delay_ms": d,
             "rms_error_deg": 1.0, "lost_frame_fraction": 0.0, "p_loss_of_control": p}
            for c in ("pid", "mpc") for d, p in ((20.0, 0.0), (40.0, 0.2), (60.0, 1.0))]
    onsets = {"pid": 55.6, "mpc": 43.0}
    fig = plot_sweep(pd.DataFrame(rows), pd.DataFrame(columns=["controller", "reference",
                                                                 "vision_delay_ms"]),
                     {}, tmp_path / "sweep.png", onsets)
    loss_axes = [a for a in fig.axes if a.get_ylabel() == "P(loss of control)"]
    assert len(loss_axes) == 2
    for ax, ctrl in zip(loss_axes, ("pid", "mpc"), strict=True):
        vertical = [tuple(line.get_xdata()) for line in ax.lines
                    if len(set(line.get_xdata())) == 1]
        assert (onsets[ctrl], onsets[ctrl]) in vertical
        other = onsets["mpc" if ctrl == "pid" else "pid"]
        assert (other, other) not in vertical  # each curve beside its own controller's onset


def test_the_report_states_the_validation_at_the_studys_run_length(monkeypatch):
    from experiments import report

    table = {"runs": 200, "rate_rad_s": 1.0,
             "false_alarm": {(c, L): 0.0 for c in ("pid", "mpc") for L in (4.0, 12.0)},
             "detection": {("pid", 4.0): 0.685, ("mpc", 4.0): 0.995,
                           ("pid", 12.0): 1.0, ("mpc", 12.0): 1.0}}
    monkeypatch.setattr(report, "VERDICT_VALIDATION", table)
    short = report.verdict_sentence(6.0)  # judged at the longest validated length below 6 s
    assert "judged on 4 s runs" in short and "68.5 %" in short and "99.5 %" in short
    assert "too short" in short and "12 s runs reach 99 % detection" in short
    long = report.verdict_sentence(12.0)
    assert "judged on 12 s runs" in long and "too short" not in long
    assert "not known" in report.verdict_sentence(2.0)
