"""The command line and the placeholder demo behind `make study`."""

import numpy as np
import pandas as pd
from typer.testing import CliRunner

from experiments.cli import app


def test_study_placeholder_writes_a_report(tmp_path):
    result = CliRunner().invoke(app, ["study", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "placeholder" in result.output
    (folder,) = tmp_path.iterdir()
    report = (folder / "report.md").read_text()
    assert "Placeholder" in report
    assert len(list(folder.glob("frame_analytic_*.png"))) == 4
    assert len(list(folder.glob("frame_mujoco_*.png"))) == 4
    assert (folder / "tilt_step.png").stat().st_size > 10_000
    df = pd.read_parquet(folder / "timeseries.parquet")
    # The PD law on the true state settles on the 10° tilt step.
    assert abs(df.tilt_deg.iloc[-1] - 10.0) < 0.05
    assert np.isfinite(df[["qw", "qx", "qy", "qz"]].to_numpy()).all()


def test_help_lists_the_commands():
    result = CliRunner().invoke(app, ["--help"])
    assert result.exit_code == 0
    assert "study" in result.output and "demo" in result.output
