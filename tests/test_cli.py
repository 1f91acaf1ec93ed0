"""The command line: the headline study's report, scenario validation, sweeps, margins."""

import re

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from experiments.cli import _expand, app

RUNNER = CliRunner()


@pytest.fixture(scope="module")
def quick_study(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    result = RUNNER.invoke(app, ["study", "--quick", "--out", str(out), "--workers", "2"])
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
    mpc = sweep[(sweep.controller == "mpc") & (sweep.reference == "tilt_step_5deg")
                & np.isclose(sweep.vision_delay_ms, 16.33)]
    assert f"{float(mpc.rms_error_deg.mean()):.3f}" in html


def test_simulate_rejects_a_bad_field_by_name(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("duration_s: -2\npipeline: {frame_rate_hz: 0}\n")
    result = RUNNER.invoke(app, ["simulate", str(bad)])
    assert result.exit_code == 2
    assert "duration_s" in result.output and "frame_rate_hz" in result.output
    assert "Traceback" not in result.output


def test_simulate_runs_a_scenario_file(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text("name: t\nduration_s: 0.5\nobserver: {kind: solver}\n")
    result = RUNNER.invoke(app, ["simulate", str(f), "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "simulate-t" / "steps.parquet").exists()
    assert "rms_error_deg" in result.output


def test_sweep_grid_expansion():
    configs = _expand({"a": {"b": 1}}, {"a.b": [1, 2], "c": ["x", "y", "z"]})
    assert len(configs) == 6
    assert {(c["a"]["b"], c["c"]) for c in configs} == {(i, s) for i in (1, 2) for s in "xyz"}


def test_margins_command_writes_plots(tmp_path):
    result = RUNNER.invoke(app, ["margins", "--delay-ms", "31.23", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "stable" in result.output
    (folder,) = tmp_path.iterdir()
    assert (folder / "bode.png").exists() and (folder / "nyquist.png").exists()


def test_every_command_has_an_example_in_its_help():
    commands = ("study", "simulate", "margins", "sweep", "measure-latency", "tune-kalman",
                "bench-trackers", "track", "calibrate")
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
