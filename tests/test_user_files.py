"""A user's motor and camera YAML: the examples describe the seed's motor, scenarios accept the
files, and a bad value is reported with its field and allowed range."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from experiments.cli import app
from experiments.scenario import Scenario
from experiments.user_files import load_setup
from plant.params import PlantParams

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def test_example_files_describe_the_seed_motor_and_camera():
    setup = load_setup(EXAMPLES / "motor.yaml", EXAMPLES / "camera.yaml")
    assert setup.params == PlantParams()
    # seed 000 §3.2.2: markers at opposite corners of a 20 mm square, L = 28.28 mm apart, on the
    # bottom pole (z = -R = -65 mm), red at -x
    half = 0.01 * np.sqrt(2.0)
    assert np.allclose(setup.markers_m, [[-half, 0.0, -0.065], [half, 0.0, -0.065]], atol=1e-9)
    assert setup.camera.image_size == (612, 512)


def test_scenario_takes_the_motor_and_camera_files(tmp_path):
    motor = yaml.safe_load((EXAMPLES / "motor.yaml").read_text())
    motor["rotor"]["mass_kg"] = 2.0
    motor["rotor"]["com_offset_m"] = [0.0, 0.0, -0.002]
    (tmp_path / "motor.yaml").write_text(yaml.safe_dump(motor))
    s = Scenario.model_validate({"motor_file": str(tmp_path / "motor.yaml"),
                                 "camera_file": str(EXAMPLES / "camera.yaml")})
    assert s.plant.rotor.mass_kg == 2.0
    assert s.plant.rotor.com_offset_m == (0.0, 0.0, -0.002)
    assert s.plant.camera == PlantParams().camera


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"rotor": {"mass_kg": -1.0}}, ["rotor.mass_kg", "greater than 0"]),
        ({"rotor": {"tilt_stop_deg": 75.0}}, ["rotor.tilt_stop_deg", "less than 60"]),
        ({"motor": {"i_max_A": 0.0}}, ["motor.i_max_A", "greater than 0"]),
        ({"markers": [{"colour": "red", "offset_m": [0.0, 0.0, -0.5], "radius_mm": 4.0},
                      {"colour": "yellow", "offset_m": [0.01, 0.0, -0.065], "radius_mm": 4.0}]},
         ["markers.0.offset_m", "[0.0325, 0.0975] m"]),
    ],
)
def test_bad_motor_values_name_the_field_and_range(tmp_path, change, words):
    (tmp_path / "motor.yaml").write_text(yaml.safe_dump(change))
    with pytest.raises(ValueError) as err:
        load_setup(tmp_path / "motor.yaml")
    for w in words:
        assert w in str(err.value), str(err.value)


def test_scenario_with_a_bad_motor_file_exits_2(tmp_path):
    (tmp_path / "motor.yaml").write_text(yaml.safe_dump({"rotor": {"radius_m": 0.0}}))
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({"motor_file": str(tmp_path / "motor.yaml")}))
    res = CliRunner().invoke(app, ["simulate", str(tmp_path / "s.yaml"), "--out",
                                   str(tmp_path / "runs")])
    assert res.exit_code == 2 and "rotor.radius_m" in res.output, res.output


def test_scenario_refuses_a_marker_layout_it_cannot_render(tmp_path):
    motor = yaml.safe_load((EXAMPLES / "motor.yaml").read_text())
    motor["markers"][1]["offset_m"] = [0.02, 0.0, -0.065]
    (tmp_path / "motor.yaml").write_text(yaml.safe_dump(motor))
    assert load_setup(tmp_path / "motor.yaml").markers_m[1, 0] == 0.02  # fine for track
    with pytest.raises(ValueError, match="markers"):
        Scenario.model_validate({"motor_file": str(tmp_path / "motor.yaml")})


def test_a_camera_file_sets_the_frame_timeline_too(tmp_path):
    # One timing source: the camera file's frame rate and exposure reach the frame pipeline.
    camera = yaml.safe_load((EXAMPLES / "camera.yaml").read_text())
    camera["camera"].update(frame_rate_hz=50.0, exposure_s=1.5e-3)
    path = tmp_path / "camera.yaml"
    path.write_text(yaml.safe_dump(camera))
    s = Scenario.model_validate({"camera_file": str(path)})
    assert (s.plant.camera.frame_rate_hz, s.pipeline.frame_rate_hz) == (50.0, 50.0)
    assert (s.plant.camera.exposure_s, s.pipeline.exposure_s) == (1.5e-3, 1.5e-3)
