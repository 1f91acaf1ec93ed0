"""A user's motor and camera YAML: the examples describe the seed's motor, scenarios accept the
files, and a bad value is reported with its field and allowed range."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from experiments.cli import app
from latency import Scenario
from plant.params import PlantParams
from plant.user_files import load_setup

pytestmark = pytest.mark.engine  # runs the compiled engines

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


def _pinhole_pixels(q_wxyz, markers_rotor_m, fx, fy, cx, cy, distance_m):
    """Independent pinhole projection, full-sensor px: scipy's rotation of the rotor-frame
    marker centres about the centre of rotation, then u = fx x/z + cx, v = fy y/z + cy in a
    camera ``distance_m`` below the CoR looking up (+Z), x along u."""
    from scipy.spatial.transform import Rotation

    w, x, y, z = q_wxyz
    p = Rotation.from_quat([x, y, z, w]).apply(markers_rotor_m) + [0.0, 0.0, distance_m]
    return np.column_stack([fx * p[:, 0] / p[:, 2] + cx, fy * p[:, 1] / p[:, 2] + cy])


@pytest.fixture(scope="module")
def off_centre_camera(tmp_path_factory):
    """The example camera with a calibration block: principal point 80 px right of and 60 px
    above the sensor centre, fx != fy."""
    cam = yaml.safe_load((EXAMPLES / "camera.yaml").read_text())
    cam["calibration"] = {"fx_px": 7330.0, "fy_px": 7180.0, "cx_px": 1303.5, "cy_px": 963.5}
    path = tmp_path_factory.mktemp("cam") / "camera.yaml"
    path.write_text(yaml.safe_dump(cam))
    return path, cam["calibration"]


def test_a_calibrated_principal_point_moves_the_markers_as_a_pinhole_says(off_centre_camera):
    from latency import build_loop
    from observer.cor_model import CorModel
    from observer.cor_solver import CorSolver
    from plant import attitude
    from plant.camera import marker_pixels, sensor_to_image
    from plant.render_analytic import AnalyticRenderer, AnalyticRenderOptions
    from plant.render_mujoco import MujocoRenderer
    from tests.test_renderers import centroids

    path, cal = off_centre_camera
    s = Scenario.model_validate({"camera_file": str(path), "motor_file":
                                 str(EXAMPLES / "motor.yaml")})
    markers = load_setup(EXAMPLES / "motor.yaml").markers_m
    distance = s.plant.rotor.radius_m + s.plant.camera.h_c_m
    q = attitude.from_zyz(0.4, np.deg2rad(9.0), -0.7)
    truth = _pinhole_pixels(q, markers, cal["fx_px"], cal["fy_px"], cal["cx_px"], cal["cy_px"],
                            distance)
    nominal = _pinhole_pixels(q, markers, 7246.376811594203, 7246.376811594203, 1223.5, 1023.5,
                              distance)
    assert np.abs(truth - nominal).max() > 50.0  # the calibration moves the markers far
    # the measurement model's truth, the solver's model and the renderer's image
    assert np.allclose(marker_pixels(s.plant, q), truth, rtol=0.0, atol=1e-6)
    assert build_loop(s).front_end.params.camera.intrinsics_px == (
        cal["fx_px"], cal["fy_px"], cal["cx_px"], cal["cy_px"])
    solved = CorSolver(CorModel.nominal(s.plant)).solve(truth, q_prev=q)
    assert solved.valid and attitude.geodesic_angle(solved.q, q) < 1e-6
    opts = AnalyticRenderOptions(noise_sigma_dn=0.0)
    b = s.plant.camera.binning
    for renderer in (AnalyticRenderer(s.plant, options=opts), MujocoRenderer(s.plant)):
        image = renderer.render(q).image
        assert np.abs(centroids(image) - sensor_to_image(truth, b)).max() < 0.3  # image px


def test_the_study_analyses_and_sweeps_the_users_motor_and_camera(tmp_path):
    from experiments.study import machine_facts, pid_axis_margins
    from experiments.study_config import StudyConfig, study_plant
    from experiments.study_sweep import sweep_configs

    motor = yaml.safe_load((EXAMPLES / "motor.yaml").read_text())
    motor["rotor"]["inertia_com_kgm2"] = [4.4e-3, 4.4e-3, 5.0e-3]
    camera = yaml.safe_load((EXAMPLES / "camera.yaml").read_text())
    camera["camera"]["frame_rate_hz"] = 50.0
    (tmp_path / "motor.yaml").write_text(yaml.safe_dump(motor))
    (tmp_path / "camera.yaml").write_text(yaml.safe_dump(camera))
    cfg = StudyConfig(delays_ms=(10.0,), max_rates_rad_s=(1.0,), n_seeds=1,
                      motor_file=tmp_path / "motor.yaml", camera_file=tmp_path / "camera.yaml")
    assert study_plant(StudyConfig()) == PlantParams()
    p = study_plant(cfg)
    assert p.rotor.inertia_com_kgm2 == (4.4e-3, 4.4e-3, 5.0e-3)
    # the analysis: a pipelined observer updates on every frame of the 50 Hz camera
    timing, _ = pid_axis_margins(p, cfg.crossover_rad_s, 0.010, "pipelined")
    assert timing.update_period_s == pytest.approx(1.0 / 50.0)
    # the sweep: every run on that plant, its frame timeline from that camera
    for c in sweep_configs(cfg):
        s = Scenario.model_validate({k: v for k, v in c.items() if k != "study"})
        assert s.plant == p and s.pipeline.frame_rate_hz == 50.0
    facts = machine_facts(p, cfg)
    assert (facts["motor_file"], facts["camera_file"], facts["frame_rate_hz"]) == (
        str(tmp_path / "motor.yaml"), str(tmp_path / "camera.yaml"), 50.0)


def test_study_with_a_bad_motor_file_exits_2_before_running(tmp_path):
    (tmp_path / "motor.yaml").write_text(yaml.safe_dump({"rotor": {"mass_kg": -1.0}}))
    res = CliRunner().invoke(app, ["study", "--motor-file", str(tmp_path / "motor.yaml"),
                                   "--out", str(tmp_path / "runs")])
    assert res.exit_code == 2 and "rotor.mass_kg" in res.output, res.output
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())
