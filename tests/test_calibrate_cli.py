"""``pmspm calibrate``: rendered chessboard views in, the rendering camera's intrinsics out."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from experiments.cli import app
from plant.calibration import random_board_poses, render_checkerboard
from plant.camera import Camera
from plant.camera_file import CameraFile
from plant.params import PlantParams

RUNNER = CliRunner()
N_VIEWS = 20


@pytest.fixture(scope="module")
def board_views(tmp_path_factory):
    """20 rendered views of the 12 x 9, 5 mm board by the default camera at 4x binning, PNG."""
    p = PlantParams()
    folder = tmp_path_factory.mktemp("board")
    rng = np.random.default_rng(1)
    for k, (rvec, tvec) in enumerate(random_board_poses(p, N_VIEWS, rng, 4)):
        cv2.imwrite(str(folder / f"{k:03d}.png"), render_checkerboard(p, rvec, tvec, 4))
    return folder


def test_calibrate_recovers_the_rendering_intrinsics_within_1_percent(board_views, tmp_path):
    res = RUNNER.invoke(app, ["calibrate", str(board_views), "--pattern", "12x9", "--square-mm",
                              "5", "--binning", "4", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    cam = CameraFile.from_yaml(tmp_path / "camera.yaml")
    cal = cam.calibration
    assert cal is not None and cal.n_views == N_VIEWS
    K = Camera.from_plant(PlantParams()).matrix(1)  # the truth, full-sensor px
    got = np.array([cal.fx_px, cal.fy_px, cal.cx_px, cal.cy_px])
    truth = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
    assert np.all(np.abs(got / truth - 1.0) < 0.01), got / truth - 1.0
    # the reported one-sigma uncertainties cover the actual error
    assert np.all(np.abs(got - truth) < 4.0 * np.array(cal.std_px))
    assert (cam.camera.sensor_width_px, cam.camera.sensor_height_px) == (2448, 2048)
    assert abs(cam.camera.focal_length_m / 0.025 - 1.0) < 0.01
    for name in ("report.md", "coverage.png", "residuals.png"):
        assert (tmp_path / name).exists()
    assert "RMS reprojection error" in res.output


def test_calibrate_without_boards_exits_2(tmp_path):
    for k in range(3):
        cv2.imwrite(str(tmp_path / f"{k}.png"), np.full((64, 80), 128, np.uint8))
    res = RUNNER.invoke(app, ["calibrate", str(tmp_path), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2 and "chessboard was found in 0 of 3" in res.output, res.output
