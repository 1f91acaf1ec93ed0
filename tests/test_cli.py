"""The command line: the headline study's report, scenario validation, sweeps, margins."""

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from experiments.cli import _expand, app

pytestmark = pytest.mark.engine  # runs the compiled engines

RUNNER = CliRunner()
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def quick_study(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    result = RUNNER.invoke(app, ["study", "--quick", "--out", str(out), "--workers", "1"])
    assert result.exit_code == 0, result.output
    (folder,) = out.iterdir()
    return folder


def test_study_writes_report_plots_and_tables(quick_study):
    names = {p.name for p in quick_study.iterdir()}
    assert {"report.md", "report.html", "margins.parquet", "sweep.parquet"} <= names
    for png in ("margins_vs_delay.png", "sweep_error_loss.png", "timeseries_16_vs_31ms.png"):
        assert (quick_study / png).stat().st_size > 20_000
    html = (quick_study / "report.html").read_text()
    for img in re.findall(r'<img alt="[^"]*" src="([^"]+)"', html):
        assert (quick_study / img).exists()
    # the image engine's section is in the default study, beside each tracker's model
    assert "Tracking loss from the trackers themselves" in (quick_study / "report.md").read_text()
    runs = pd.read_parquet(quick_study / "image_loop.parquet")
    assert set(runs.tracker) == {"gk_transt", "dual_transt"} and set(runs.side) == {"image",
                                                                                     "model"}
    assert set(pd.read_parquet(quick_study / "sweep.parquet").tracker) == {"gk_transt",
                                                                            "dual_transt"}


def test_report_numbers_match_the_parquet_tables(quick_study):
    html = (quick_study / "report.html").read_text()
    margins = pd.read_parquet(quick_study / "margins.parquet")
    row = margins[(margins.observer == "sequential") & np.isclose(margins.vision_delay_ms, 31.23)]
    pm = float(row.phase_margin_deg.iloc[0])
    cells = re.findall(r"<td>31\.230</td>\s*<td>sequential</td>\s*<td>[^<]*</td>\s*<td>True</td>"
                       r"\s*<td>([-0-9.]+)</td>", html)
    assert cells and float(cells[0]) == pytest.approx(pm, abs=1e-3)
    sweep = pd.read_parquet(quick_study / "sweep.parquet")
    assert (sweep.error == "").all()
    # each seed of a random-reference point follows its own reference; no step metrics there
    rnd = sweep[sweep.reference.str.startswith("random")]
    per_point = rnd.groupby(["controller", "reference", "vision_delay_ms"])
    assert (per_point.reference_seed.nunique() == per_point.seed.nunique()).all()
    assert rnd.overshoot_pct.isna().all() and rnd.settling_time_s.isna().all()
    assert sweep[sweep.reference == "tilt_step_5deg"].step_size_deg.notna().all()
    mpc = sweep[(sweep.controller == "mpc") & (sweep.reference == "tilt_step_5deg")
                & np.isclose(sweep.vision_delay_ms, 16.33)]
    assert f"{float(mpc.rms_error_deg.mean()):.3f}" in html
    # the summary's numbers are the tables' (and the measured profiles')
    md = (quick_study / "report.md").read_text()
    summary = md.split("## 1.")[0]
    gk = margins[(margins.observer == "sequential") & np.isclose(margins.vision_delay_ms, 16.33)]
    assert f"tolerates {1e3 * float(gk.headroom_s.iloc[0]):.1f} ms more" in summary
    jm = 1e3 * float(row.jitter_margin_s.iloc[0])
    assert f"jitter margin of the PID as it runs is {jm:.1f}" in summary
    assert f"leaves {pm:.1f}°" in summary
    for name, label in (("gk_transt", "GK-TransT"), ("dual_transt", "dual TransT")):
        samples = json.loads((quick_study / f"latency_{name}.json").read_text())["samples_s"]
        assert f"{label} {1e3 * np.median(samples):.2f} ms (seed" in summary
    loss = pd.read_parquet(quick_study / "loss_of_control.parquet")
    pid_loss = loss[(loss.controller == "pid") & (loss.tracker == "dual_transt")
                    & np.isclose(loss.vision_delay_ms, 31.23)].iloc[0]
    # independent: the fraction of the sweep's PID runs of the dual TransT at 31.23 ms that
    # lost control
    runs = sweep[(sweep.controller == "pid") & (sweep.tracker == "dual_transt")
                 & np.isclose(sweep.vision_delay_ms, 31.23)]
    assert pid_loss.p_loss_of_control == pytest.approx(runs.loss_of_control.mean())
    ci = (f"{pid_loss.p_loss_of_control:.2f} ({pid_loss.p_loss_of_control_lo:.2f}–"
          f"{pid_loss.p_loss_of_control_hi:.2f})" if np.isfinite(pid_loss.p_loss_of_control_lo)
          else f"{pid_loss.p_loss_of_control:.2f}")
    assert f"dual TransT at its 31.23 ms: P(loss of control) {ci}" in summary
    steps = pd.read_parquet(quick_study / "sweep_intervals.parquet")
    st = steps[(steps.controller == "mpc") & (steps.reference == "tilt_step_5deg")
               & np.isclose(steps.vision_delay_ms, 31.23)].iloc[0]
    runs = sweep[(sweep.controller == "mpc") & (sweep.reference == "tilt_step_5deg")
                 & np.isclose(sweep.vision_delay_ms, 31.23)]
    assert st.overshoot_pct == pytest.approx(runs.overshoot_pct.mean())
    assert (f"MPC: overshoot {st.overshoot_pct:.1f} ({st.overshoot_pct_lo:.1f}–"
            f"{st.overshoot_pct_hi:.1f}) %") in summary.split("31.23 ms** (")[1]


def test_jitter_margin_never_exceeds_the_delay_margin_on_the_study_grid(quick_study):
    margins = pd.read_parquet(quick_study / "margins.parquet")
    stable = margins[margins.stable]
    # the quick study's grid: 0-60 ms by 5 ms and the seed's two latencies, both observers;
    # all but the sequential observer's 60 ms are stable
    assert len(stable) >= 25 and stable.jitter_margin_s.notna().all()
    assert (stable.jitter_margin_s <= stable.delay_margin_s).all()


def test_study_table_and_summary_match_an_independent_derivation(quick_study):
    """margins.parquet's phase margin, critical crossover and headroom at 16.33 and 31.23 ms,
    sequential and pipelined, to 1e-3 of tests/independent_margins.py (which does not call the
    project's margin code), and the report's summary prints the derived figures."""
    from plant.params import PlantParams
    from tests.independent_margins import derive

    margins = pd.read_parquet(quick_study / "margins.parquet")
    derived = {}
    for mode in ("sequential", "pipelined"):
        for d_ms in (16.33, 31.23):
            want = derived[(mode, d_ms)] = derive(PlantParams(), 10.0, d_ms / 1e3, mode)
            at = (margins.observer == mode) & np.isclose(margins.vision_delay_ms, d_ms)
            (row,) = (r for _, r in margins[at].iterrows())
            assert row.phase_margin_deg == pytest.approx(want.phase_margin_deg, rel=1e-3)
            assert row.crossover_rad_s == pytest.approx(want.crossover_rad_s, rel=1e-3)
            assert row.headroom_s == pytest.approx(want.headroom_s, rel=1e-3)
    assert len(derived) == 4
    summary = (quick_study / "report.md").read_text().split("## 1.")[0]
    gk, dual = derived[("sequential", 16.33)], derived[("sequential", 31.23)]
    assert f"16.33 ms leaves {gk.phase_margin_deg:.1f}°" in summary
    assert f"tolerates {1e3 * gk.headroom_s:.1f} ms more" in summary
    assert f"31.23 ms leaves {dual.phase_margin_deg:.1f}°" in summary
    assert f"would keep {derived[('pipelined', 31.23)].phase_margin_deg:.1f}°" in summary


def test_cli_study_and_notebook_give_the_same_margins(quick_study, tmp_path):
    """The same scenario (PID, 10 rad/s crossover, 31.23 ms, sequential observer) in the CLI's
    output, the study's table and the call the notebook makes; the command writes its plots."""
    from experiments.study import pid_axis_margins
    from plant.params import PlantParams

    result = RUNNER.invoke(app, ["margins", "--delay-ms", "31.23", "--observer", "sequential",
                                 "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "case: sequential observer" in result.output and "55.56 ms" in result.output
    assert "stable" in result.output
    (folder,) = tmp_path.iterdir()
    assert (folder / "bode.png").exists() and (folder / "nyquist.png").exists()
    cli_pm = float(re.search(r"PM ([-0-9.]+) deg", result.output).group(1))
    cli_dm = float(re.search(r"delay margin ([0-9.]+) ms", result.output).group(1))
    cli_jm = float(re.search(r"jitter margin ([0-9.]+) ms", result.output).group(1))
    margins = pd.read_parquet(quick_study / "margins.parquet")
    row = margins[(margins.observer == "sequential")
                  & np.isclose(margins.vision_delay_ms, 31.23)].iloc[0]
    _, nb = pid_axis_margins(PlantParams(), 10.0, 31.23e-3, "sequential")
    for value, study, notebook in ((cli_pm, row.phase_margin_deg, nb.phase_margin_deg),
                                   (cli_dm, 1e3 * row.delay_margin_s, 1e3 * nb.delay_margin_s),
                                   (cli_jm, 1e3 * row.jitter_margin_s, 1e3 * nb.jitter_margin_s)):
        assert value == pytest.approx(study, abs=1e-2) and notebook == pytest.approx(study)
    source = (ROOT / "experiments" / "notebooks" / "bode_phase_margin.ipynb").read_text()
    assert "pid_axis_margins(params, CROSSOVER_RAD_S, latency, OBSERVER" in source
    assert "OBSERVER = 'sequential'" in source


def test_simulate_rejects_a_bad_field_by_name(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("duration_s: -2\npipeline: {frame_rate_hz: 0}\n")
    result = RUNNER.invoke(app, ["simulate", str(bad)])
    assert result.exit_code == 2
    assert "duration_s" in result.output and "frame_rate_hz" in result.output
    assert "Traceback" not in result.output


def test_simulate_runs_a_scenario_file_and_never_overwrites_a_result(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text("name: t\nduration_s: 0.5\nobserver: {kind: solver}\n")
    out = tmp_path / "out"
    folders = []
    for _ in range(2):  # the same scenario twice, within the same second
        result = RUNNER.invoke(app, ["simulate", str(f), "--out", str(out)])
        assert result.exit_code == 0, result.output
        assert "rms_error_deg" in result.output
        folders.append(sorted(out.iterdir()))
    first, second = folders
    assert len(first) == 1 and len(second) == 2 and first[0] in second
    for folder in second:
        assert re.fullmatch(r"\d{8}-\d{6}-simulate-t(-2)?", folder.name)
        assert (folder / "steps.parquet").exists() and (folder / "summary.json").exists()


def test_sweep_grid_expansion():
    configs = _expand({"a": {"b": 1}}, {"a.b": [1, 2], "c": ["x", "y", "z"]})
    assert len(configs) == 6
    assert {(c["a"]["b"], c["c"]) for c in configs} == {(i, s) for i in (1, 2) for s in "xyz"}


def test_every_command_has_an_example_in_its_help():
    commands = ("study", "simulate", "margins", "sweep", "measure-latency", "tune-kalman",
                "bench-trackers", "track", "calibrate", "calibrate-mount", "calibrate-loss",
                "codesign", "parts")
    for cmd in commands:
        result = RUNNER.invoke(app, [cmd, "--help"])
        assert result.exit_code == 0 and "Example" in result.output, cmd
    assert set(commands) == {c.name or c.callback.__name__ for c in app.registered_commands}


def test_sweep_help_shows_the_brackets_of_its_example():
    # Rich markup swallowed "[pid, mpc]" as a style tag.
    result = RUNNER.invoke(app, ["sweep", "--help"], env={"COLUMNS": "120"})
    assert result.exit_code == 0
    assert "controller.kind: [pid, mpc]" in result.output
    assert "[0.01633, 0.03123]" in result.output and "\\[" not in result.output


def test_bench_trackers_writes_metrics_plots_and_a_table(tmp_path):
    out = tmp_path / "bench"
    args = ["bench-trackers", "--seeds", "1", "--cases", "clean", "--frames", "20",
            "--trackers", "gk_transt,kcf_numpy", "--stand-in", "--out", str(out)]
    result = RUNNER.invoke(app, args)
    assert result.exit_code == 0, result.output
    metrics = pd.read_csv(out / "tracking_metrics.csv")
    assert list(metrics.tracker) == ["gk_standin", "kcf_numpy"]
    assert (metrics.case == "clean").all() and (metrics.frames == 19).all()
    assert metrics.main_precision_20px.between(0, 1).all()
    for png in ("tracking_precision_clean.png", "tracking_errors_clean.png"):
        assert (out / png).stat().st_size > 10_000
    report = (out / "report.md").read_text()
    assert "| algorithm |" in report and "gk_standin" in report and "--stand-in" in report
    assert "results: " in result.output
    # The seed's disturbance cases need their frames; a wrong option exits 2 naming it.
    result = RUNNER.invoke(app, ["bench-trackers", "--cases", "blur", "--frames", "100",
                                 "--stand-in", "--out", str(tmp_path / "x")])
    assert result.exit_code == 2 and "frames must be >= 161" in result.output
    result = RUNNER.invoke(app, ["bench-trackers", "--trackers", "sift", "--stand-in",
                                 "--out", str(tmp_path / "y")])
    assert result.exit_code == 2 and "unknown trackers ['sift']" in result.output
    assert "Traceback" not in result.output


def test_bench_trackers_default_folder_is_new_and_timestamped(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    args = ["bench-trackers", "--seeds", "1", "--cases", "clean", "--frames", "3",
            "--trackers", "kcf_numpy"]
    assert RUNNER.invoke(app, args).exit_code == 0
    (folder,) = (tmp_path / "runs").iterdir()
    assert re.fullmatch(r"\d{8}-\d{6}-bench-trackers", folder.name)
    assert (folder / "tracking_metrics.csv").exists()


def test_measure_latency_times_every_tracker(tmp_path):
    result = RUNNER.invoke(app, ["measure-latency", "--tracker", "all", "--frames", "2",
                                 "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    (folder,) = tmp_path.glob("*-measure-latency-all")
    for name, label in (("kcf", "kcf+GK"), ("csrt", "csrt+GK"), ("gk_transt", "GK-TransT"),
                        ("dual_transt", "dual TransT"), ("orb", "ORB-AEKF")):
        assert f"{label}: median" in result.output
        assert (folder / f"latency_{name}.json").exists()
