"""``pmspm calibrate-mount``: frames rendered with a rolled camera whose optical centre is off the
rotation axis; the estimate recovers both, and the calibrated camera file removes the constant
attitude offset that the nominal camera shows."""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from experiments.cli import app
from experiments.mount import MIN_ARC_DEG, run_calibrate_mount
from experiments.sources import UserInputError, open_source
from experiments.track import run_track
from experiments.track_accuracy import attitude_errors_deg
from observer.trackers import make_pair_tracker
from plant import attitude as A
from plant.camera import Camera, marker_pixels
from plant.params import PlantParams
from plant.render_analytic import AnalyticRenderer
from plant.user_files import UserSetup, load_setup

P = PlantParams()
ROLL_DEG = 3.0
OFFSET_MM = (2.0, -1.5)
MOUNTED = P.model_copy(update={"camera": P.camera.model_copy(
    update={"mount_roll_deg": ROLL_DEG, "mount_offset_mm": OFFSET_MM})})
#: Resting attitudes (spin, tilt, yaw in deg), 4 frames each, joined by 6 moving frames.
POSES = [(0.0, 0.0, 0.0), (0.0, 6.0, 0.0), (0.0, 6.0, 90.0), (40.0, 4.0, 200.0)]
REST, MOVE = 4, 6
RUNNER = CliRunner()


def _write(frames, folder):
    folder.mkdir(parents=True)
    for k, img in enumerate(frames):
        cv2.imwrite(str(folder / f"{k:04d}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))


@pytest.fixture(scope="module")
def resting(tmp_path_factory):
    """The rotor resting at POSES, seen by the mounted camera, as a PNG folder and the known
    attitudes CSV."""
    renderer = AnalyticRenderer(MOUNTED, seed=1)
    qs = [A.from_zyz(*np.deg2rad(p)) for p in POSES]
    frames, rows, truth = [], [], []
    for i, q in enumerate(qs):
        if i:
            for s in np.linspace(0.0, 1.0, MOVE + 2)[1:-1]:  # slerp from the previous pose
                d = A.multiply(A.conjugate(qs[i - 1]), q)
                step = A.multiply(qs[i - 1], A.from_rotvec(s * A.to_rotvec(d)))
                frames.append(renderer.render(step).image)
                truth.append(step)
        rows.append((len(frames), len(frames) + REST - 1, *POSES[i]))
        for _ in range(REST):
            frames.append(renderer.render(q).image)
            truth.append(q)
    d = tmp_path_factory.mktemp("mount")
    _write(frames, d / "png")
    pd.DataFrame(rows, columns=["first_frame", "last_frame", "spin_deg", "tilt_deg",
                                "yaw_deg"]).to_csv(d / "known.csv", index=False)
    return {"dir": d, "truth": truth, "rows": rows}


def _track(folder, out, setup):
    return run_track(open_source(str(folder)), make_pair_tracker("kcf_gk", setup.params), out,
                     "auto", setup=setup, write_video=False)


def test_known_attitudes_recover_roll_and_offset_and_remove_the_attitude_offset(resting,
                                                                              tmp_path):
    d = resting["dir"]
    est = run_calibrate_mount(open_source(str(d / "png")), make_pair_tracker("kcf_gk", P),
                              tmp_path / "mount", "auto", UserSetup(), d / "known.csv")
    # within 3 sigma of the fit and within 0.05° / 0.05 mm of the truth
    assert abs(est.roll_deg - ROLL_DEG) < max(3 * est.roll_std_deg, 1e-3)
    assert abs(est.roll_deg - ROLL_DEG) < 0.05 and est.roll_std_deg < 0.05
    assert np.all(np.abs(est.offset_mm - OFFSET_MM) < np.maximum(3 * est.offset_std_mm, 1e-3))
    assert np.all(np.abs(est.offset_mm - OFFSET_MM) < 0.05)
    # the resting frames with both markers measured (a frame right after a move may not be)
    assert REST * len(POSES) - 4 <= est.frames_used <= REST * len(POSES)
    # the nominal camera shows the roll as a constant attitude offset (≈ ROLL_DEG); the
    # calibrated camera file removes it
    resting_frames = np.concatenate([np.arange(a, b + 1) for a, b, *_ in resting["rows"]])
    nominal = _track(d / "png", tmp_path / "nominal", UserSetup())
    err0 = attitude_errors_deg(nominal.table, resting["truth"])[resting_frames]
    # (NaN: frames whose markers were not both measured, left out of the attitude errors)
    assert np.isfinite(err0).sum() >= REST * len(POSES) - 4
    assert np.nanmin(err0) > 0.8 * ROLL_DEG, err0
    calibrated = _track(d / "png", tmp_path / "calibrated",
                        load_setup(None, tmp_path / "mount" / "camera.yaml"))
    err1 = attitude_errors_deg(calibrated.table, resting["truth"])[resting_frames]
    assert np.isfinite(err1).sum() >= REST * len(POSES) - 4
    assert np.nanmax(err1) < 0.05, err1
    assert "roll 3.0" in (tmp_path / "mount" / "mount_report.md").read_text()


def _spin_frames(arc_deg: float, n: int):
    renderer = AnalyticRenderer(MOUNTED, seed=2)
    return [renderer.render(A.from_zyz(np.deg2rad(a), 0.0, 0.0)).image
            for a in np.linspace(0.0, arc_deg, n)]


def test_a_spin_at_zero_tilt_recovers_the_offset_not_the_roll(tmp_path):
    _write(_spin_frames(180.0, 41), tmp_path / "spin")
    est = run_calibrate_mount(open_source(str(tmp_path / "spin")),
                              make_pair_tracker("kcf_gk", P), tmp_path / "out", "auto",
                              UserSetup())
    assert np.all(np.abs(est.offset_mm - OFFSET_MM) < 0.05), est.offset_mm
    assert np.all(est.offset_std_mm < 0.05)
    assert not est.roll_identified and est.roll_deg == 0.0
    assert any("roll not identified" in n for n in est.notes)


def test_too_little_motion_says_what_motion_is_needed(resting, tmp_path):
    _write(_spin_frames(30.0, 8), tmp_path / "short")
    with pytest.raises(UserInputError, match=f"at least {MIN_ARC_DEG:g} deg"):
        run_calibrate_mount(open_source(str(tmp_path / "short")),
                            make_pair_tracker("kcf_gk", P), tmp_path / "o1", "auto", UserSetup())
    one_pose = resting["dir"] / "one_pose.csv"
    pd.DataFrame([resting["rows"][0]], columns=["first_frame", "last_frame", "spin_deg",
                                                "tilt_deg", "yaw_deg"]).to_csv(one_pose,
                                                                               index=False)
    res = RUNNER.invoke(app, ["calibrate-mount", str(resting["dir"] / "png"), "--known",
                              str(one_pose), "--out", str(tmp_path / "o2")])
    assert res.exit_code == 2 and "2 or more known attitudes" in res.output, res.output


def test_the_mounted_camera_model():
    """The roll turns the image about the axis's image point, the offset shifts it: the red
    marker at rest is where the rotated, shifted nominal projection puts it (hand geometry)."""
    q = A.from_zyz(0.5, np.deg2rad(5.0), 1.0)
    cam = Camera.from_plant(MOUNTED)
    # the mounted camera sees the nominal camera's view of the rotor turned by -roll about Z
    # and moved by -offset in the camera-aligned frame
    turned = A.multiply(A.axis_angle([0, 0, 1], -np.deg2rad(ROLL_DEG)), q)
    shifted = P.model_copy(update={"camera": P.camera.model_copy(
        update={"mount_offset_mm": OFFSET_MM})})
    assert np.allclose(marker_pixels(MOUNTED, q), marker_pixels(shifted, turned), atol=1e-9)
    f = cam.matrix(1)[0, 0]
    depth = P.camera.h_c_m  # the markers at rest lie at h_c below the optical centre
    shift = marker_pixels(shifted, A.from_zyz(0, 0, 0)) - marker_pixels(P, A.from_zyz(0, 0, 0))
    assert np.allclose(shift, -f * np.array(OFFSET_MM) / 1000.0 / depth, atol=1e-6)
    assert np.allclose(A.multiply(cam.mount_quaternion, turned), q)
