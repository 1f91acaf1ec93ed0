"""``pmspm track``: rendered frames written to a lossy MP4 and a PNG folder are tracked back to
the rendered attitudes; a CVAT file starts and scores a run; a live source drops, not queues,
the frames that arrive while the tracker is busy; bad input exits with status 2."""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from experiments.cli import app
from experiments.cvat import export_cvat_xml
from experiments.sources import Source, open_source
from experiments.track import run_track
from experiments.track_accuracy import attitude_errors_deg
from latency.models import Empirical
from latency.profile import cone_attitude
from observer.gk.hsv_gate import box_sensor_to_image
from observer.trackers import make_pair_tracker
from observer.tracking import PairResult
from plant.params import PlantParams
from plant.render_analytic import AnalyticRenderer

RUNNER = CliRunner()
N_FRAMES = 20
#: Attitude accuracy required of a run on the rendered cone (8° tilt) with kcf_gk: measured on
#: this sequence, the lossless PNG frames (the clean frames) give at most 0.020°, the mp4v
#: video 0.023°; the bound leaves twice that for codec and platform differences.
MAX_ATTITUDE_ERROR_DEG = 0.05


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """20 rendered frames of a slow cone as an mp4v video, a PNG folder and a CVAT XML."""
    p = PlantParams()
    renderer = AnalyticRenderer(p, seed=0)
    frames = []
    for k in range(N_FRAMES):
        t = k / p.camera.frame_rate_hz
        q, omega = cone_attitude(t)
        frames.append(renderer.render(q, t_exposure=t, omega=omega))
    d = tmp_path_factory.mktemp("recording")
    h, w = frames[0].image.shape[:2]
    writer = cv2.VideoWriter(str(d / "rec.mp4"), cv2.VideoWriter_fourcc(*"mp4v"),
                             p.camera.frame_rate_hz, (w, h))
    (d / "png").mkdir()
    for k, f in enumerate(frames):
        bgr = cv2.cvtColor(f.image, cv2.COLOR_RGB2BGR)
        writer.write(bgr)
        cv2.imwrite(str(d / "png" / f"{k:04d}.png"), bgr)
    writer.release()
    boxes = {lab: np.array([box_sensor_to_image(f.boxes_px[m], f.binning) for f in frames])
             for m, lab in enumerate(("red", "yellow"))}
    export_cvat_xml(d / "rec.xml", boxes, w, h)
    first = np.stack([boxes["red"][0], boxes["yellow"][0]])
    return {"dir": d, "frames": frames, "boxes": first, "q": [f.q for f in frames],
            "size": (w, h)}


def _track(source: str, out, **kw):
    return run_track(open_source(source), make_pair_tracker("kcf_gk", PlantParams()), out, **kw)


def test_lossy_video_gives_the_rendered_attitudes(recording, tmp_path):
    outcome = _track(str(recording["dir"] / "rec.mp4"), tmp_path, boxes_image_px=recording["boxes"])
    err = attitude_errors_deg(outcome.table, recording["q"])
    assert len(err) == N_FRAMES and np.all(np.isfinite(err))
    assert err.max() < MAX_ATTITUDE_ERROR_DEG
    table = pd.read_parquet(tmp_path / "frames.parquet")
    assert np.allclose(table["capture_time_s"], np.arange(N_FRAMES) / 36.0)
    assert (table[["tracker_time_s", "solver_time_s"]] >= 0).all().all()
    profile = Empirical.load(tmp_path / "latency_profile.json")
    assert len(profile.samples_s) == N_FRAMES
    video = cv2.VideoCapture(str(tmp_path / "annotated.mp4"))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == N_FRAMES
    assert "attitude.png" in (tmp_path / "report.md").read_text()


def test_png_folder_gives_the_same_attitudes_as_the_video(recording, tmp_path):
    png = _track(str(recording["dir"] / "png"), tmp_path / "png",
                 boxes_image_px=recording["boxes"])
    mp4 = _track(str(recording["dir"] / "rec.mp4"), tmp_path / "mp4",
                 boxes_image_px=recording["boxes"])
    err = attitude_errors_deg(png.table, recording["q"])
    assert np.all(np.isfinite(err)) and err.max() < MAX_ATTITUDE_ERROR_DEG
    q_png = png.table[["q_w", "q_x", "q_y", "q_z"]].to_numpy()
    between = attitude_errors_deg(mp4.table, q_png)
    assert between.max() < MAX_ATTITUDE_ERROR_DEG


def test_cvat_file_starts_and_scores_the_run(recording, tmp_path):
    outcome = _track(str(recording["dir"] / "png"), tmp_path,
                     ground_truth=recording["dir"] / "rec.xml")
    assert outcome.metrics["red precision@20px"] == 1.0
    assert outcome.metrics["yellow precision@20px"] == 1.0
    # box centres (the annotation) and disc-centre projections differ by a fraction of a px
    assert outcome.metrics["red mean centre error px"] < 4.0
    err = attitude_errors_deg(outcome.table, recording["q"])
    assert err.max() < MAX_ATTITUDE_ERROR_DEG


class _SimClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


class _FakeCamera:
    """A camera delivering frame k at k/fps on a simulated clock; ``read`` waits (advances the
    clock) for a frame not yet delivered, as a real camera blocks."""

    def __init__(self, image, fps: float, n: int, clock: _SimClock) -> None:
        self.image, self.period, self.n, self.clock = image, 1.0 / fps, n, clock
        self.next = 0
        self.decoded: list[int] = []

    def _take(self) -> bool:
        if self.next >= self.n:
            return False
        assert self.next * self.period <= self.clock.now + self.period, "asked ahead of time"
        self.clock.now = max(self.clock.now, self.next * self.period)
        self.next += 1
        return True

    def grab(self) -> bool:
        return self._take()

    def read(self):
        k = self.next
        if not self._take():
            return False, None
        self.decoded.append(k)
        return True, self.image

    def release(self) -> None:
        pass

    def isOpened(self) -> bool:  # noqa: N802 - OpenCV's name
        return True

    def get(self, prop_id: int) -> float:
        return 0.0


class _SlowTracker:
    """A pair tracker that takes ``busy_s`` of simulated time per frame."""

    name = "slow"
    tilt_hint_rad = None
    started = True

    def __init__(self, clock: _SimClock, busy_s: float, start_s: float = 0.0) -> None:
        self.clock, self.busy_s, self.start_s = clock, busy_s, start_s

    def start(self, image, boxes_sensor_px, binning=None) -> None:
        self.clock.now += self.start_s

    def step(self, image) -> PairResult:
        self.clock.now += self.busy_s
        return PairResult.failed("simulated", self.busy_s)

    def reset(self) -> None:
        pass


def test_live_camera_drops_frames_the_tracker_is_too_slow_for(recording, tmp_path):
    clock = _SimClock()
    fps = 64.0  # binary-exact period and busy time keep the schedule free of round-off
    bgr = cv2.cvtColor(recording["frames"][0].image, cv2.COLOR_RGB2BGR)
    camera = _FakeCamera(bgr, fps, 40, clock)
    source = Source(camera, "live", fps, None, "fake camera")
    outcome = run_track(source, _SlowTracker(clock, 2.5 / fps), tmp_path,
                        boxes_image_px=recording["boxes"], clock=clock, write_video=False)
    # The tracker becomes free at 2.5 n frame periods; the newest frame then is floor(2.5 n).
    expected = [int(np.floor(2.5 * n)) for n in range(16)]  # 0, 2, 5, 7, ..., 37
    assert outcome.table["frame_index"].tolist() == expected
    assert camera.decoded == expected  # only the processed frames were decoded: no queue
    assert outcome.dropped == 40 - len(expected)
    assert np.allclose(outcome.table["capture_time_s"], np.array(expected) / fps)


def test_live_camera_drops_the_frames_that_arrived_while_the_tracker_started(recording,
                                                                              tmp_path):
    clock = _SimClock()
    fps = 64.0
    bgr = cv2.cvtColor(recording["frames"][0].image, cv2.COLOR_RGB2BGR)
    camera = _FakeCamera(bgr, fps, 12, clock)
    tracker = _SlowTracker(clock, 0.5 / fps, start_s=3.25 / fps)
    outcome = run_track(Source(camera, "live", fps, None, "fake camera"), tracker, tmp_path,
                        boxes_image_px=recording["boxes"], clock=clock, write_video=False)
    # Frame 0 is processed from 3.25 to 3.75 periods; frames 1 and 2 are stale by then, frame 3
    # is the newest; from then on the tracker keeps up and waits for each frame.
    assert outcome.table["frame_index"].tolist() == [0, *range(3, 12)]
    assert outcome.dropped == 2 and camera.decoded == [0, *range(3, 12)]


def _cli(args):
    return RUNNER.invoke(app, ["track", *args, "--tracker", "kcf_gk"])


def _boxes_arg(boxes) -> str:
    return ";".join(",".join(f"{v:.2f}" for v in b) for b in boxes)


def test_bad_input_exits_2_with_a_clear_message(recording, tmp_path):
    d = recording["dir"]
    good = ["--boxes", _boxes_arg(recording["boxes"]), "--out", str(tmp_path / "o")]
    (tmp_path / "broken.mp4").write_bytes(b"not a video at all" * 10)
    (tmp_path / "empty.mp4").write_bytes(b"")
    for path in ("broken.mp4", "empty.mp4"):
        res = _cli([str(tmp_path / path), *good])
        assert res.exit_code == 2 and "unreadable" in res.output, res.output
    w, h = recording["size"]
    outside = recording["boxes"].copy()
    outside[1, 0] = w + 5.0
    res = _cli([str(d / "rec.mp4"), "--boxes", _boxes_arg(outside), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "outside" in res.output, res.output
    red = recording["boxes"][0]
    export_cvat_xml(tmp_path / "other_size.xml", {"red": [red], "yellow": [red]}, 640, 480)
    export_cvat_xml(tmp_path / "other_count.xml",
                    {"red": [red] * 5, "yellow": [red] * 5}, w, h)
    for xml in ("other_size.xml", "other_count.xml"):
        res = _cli([str(d / "rec.mp4"), "--cvat", str(tmp_path / xml), "--out",
                    str(tmp_path / "o")])
        assert res.exit_code == 2 and "another video" in res.output, res.output
    (tmp_path / "cam.yaml").write_text(yaml.safe_dump({"camera": {"binning": 2}}))
    res = _cli([str(d / "rec.mp4"), *good, "--camera", str(tmp_path / "cam.yaml")])
    assert res.exit_code == 2 and "image size" in res.output, res.output
    assert "1224 x 1024" in res.output and f"{w} x {h}" in res.output, res.output
    res = _cli([str(d / "rec.mp4"), *good, "--observer", "kalman"])
    assert res.exit_code == 2 and "--observer must be one of" in res.output, res.output


class _InterruptedCamera(_FakeCamera):
    """Ctrl-C arrives while the run waits for frame ``stop_at``."""

    def __init__(self, *args, stop_at: int) -> None:
        super().__init__(*args)
        self.stop_at = stop_at

    def read(self):
        if self.next == self.stop_at:
            raise KeyboardInterrupt
        return super().read()


def test_ctrl_c_ends_the_run_and_keeps_what_was_processed(recording, tmp_path):
    clock = _SimClock()
    bgr = cv2.cvtColor(recording["frames"][0].image, cv2.COLOR_RGB2BGR)
    camera = _InterruptedCamera(bgr, 64.0, 40, clock, stop_at=6)
    source = Source(camera, "live", 64.0, None, "fake camera")
    outcome = run_track(source, _SlowTracker(clock, 0.5 / 64.0), tmp_path,
                        boxes_image_px=recording["boxes"], clock=clock)
    assert outcome.interrupted
    assert pd.read_parquet(tmp_path / "frames.parquet")["frame_index"].tolist() == [0, 1, 2, 3,
                                                                                   4, 5]
    assert "Ctrl-C" in (tmp_path / "report.md").read_text()


def test_cli_prints_precision_with_ground_truth(recording, tmp_path):
    res = _cli([str(recording["dir"] / "rec.mp4"), "--cvat", str(recording["dir"] / "rec.xml"),
                "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "red precision@20px: 1.000" in res.output
    assert "yellow precision@20px: 1.000" in res.output
    assert (tmp_path / "frames.parquet").exists()


def test_calibrated_camera_and_motor_file_give_the_rendered_attitudes(recording, tmp_path):
    from pathlib import Path

    from experiments.calibrate import calibrate_frames
    from plant.calibration import random_board_poses, render_checkerboard
    from plant.user_files import load_setup

    p = PlantParams()
    views = [(f"{k}", render_checkerboard(p, r, t, 4))
             for k, (r, t) in enumerate(random_board_poses(p, 15, np.random.default_rng(2), 4))]
    calibrate_frames(views, (12, 9), 5.0, p.camera).camera.save(tmp_path / "camera.yaml")
    examples = Path(__file__).resolve().parents[1] / "examples"
    setup = load_setup(examples / "motor.yaml", tmp_path / "camera.yaml")
    cal = setup.camera.calibration
    assert cal is not None
    outcome = run_track(open_source(str(recording["dir"] / "png")),
                        make_pair_tracker("kcf_gk", setup.params), tmp_path / "run",
                        recording["boxes"], setup=setup)
    err = attitude_errors_deg(outcome.table, recording["q"])
    # A principal point off by d px turns the markers' rays by d/f rad, i.e. moves them by
    # d h_c / f m at their depth h_c, which reads as a tilt of d h_c / (f R) rad about the CoR
    # (markers at R from it). Bound: 3 sigma of the calibration's reported cx, cy uncertainty
    # on top of the tracking error on clean frames.
    d_px = 3.0 * float(np.hypot(cal.std_px[2], cal.std_px[3]))
    bound_deg = np.rad2deg(d_px * p.camera.h_c_m / (cal.fx_px * p.rotor.radius_m))
    assert np.all(np.isfinite(err))
    assert err.max() < MAX_ATTITUDE_ERROR_DEG + bound_deg, (err.max(), bound_deg)


def test_auto_boxes_find_the_markers_by_colour(recording, tmp_path):
    from experiments.sources import UserInputError
    from experiments.track import auto_boxes

    frame = recording["frames"][0]
    bgr = cv2.cvtColor(frame.image, cv2.COLOR_RGB2BGR)
    found = auto_boxes(bgr)
    truth = recording["boxes"]  # the rendered discs' bounds, image px
    centres = [b[:, :2] + 0.5 * b[:, 2:] for b in (found, truth)]
    assert np.all(np.abs(centres[0] - centres[1]) < 1.0)
    assert np.all(np.abs(found[:, 2:] - truth[:, 2:]) < 2.0)
    res = _cli([str(recording["dir"] / "png"), "--boxes", "auto", "--max-frames", "3",
                "--out", str(tmp_path)])
    assert res.exit_code == 0 and "first-frame boxes" in res.output, res.output
    no_yellow = bgr.copy()
    hsv = cv2.cvtColor(no_yellow, cv2.COLOR_BGR2HSV)
    no_yellow[(hsv[..., 0] >= 15) & (hsv[..., 0] <= 40) & (hsv[..., 1] >= 50)] = 0
    with pytest.raises(UserInputError, match="no yellow marker"):
        auto_boxes(no_yellow)


def test_aekf_back_end_gives_the_rendered_attitudes(recording, tmp_path):
    """``--observer aekf`` on the clean frames, as accurate as the least-squares path (the
    same bound; measured here: AEKF 0.020° at most, solver 0.020°)."""
    aekf = _track(str(recording["dir"] / "png"), tmp_path / "aekf",
                  boxes_image_px=recording["boxes"], observer="aekf")
    err = attitude_errors_deg(aekf.table, recording["q"])
    assert len(err) == N_FRAMES and np.all(np.isfinite(err))
    assert aekf.table["attitude_valid"].all()
    assert err.max() < MAX_ATTITUDE_ERROR_DEG
    assert "attitude: aekf" in (tmp_path / "aekf" / "report.md").read_text()
    res = _cli([str(recording["dir"] / "png"), "--boxes", _boxes_arg(recording["boxes"]),
                "--tracker", "kcf_gk", "--observer", "aekf", "--max-frames", "4", "--out",
                str(tmp_path / "cli")])
    assert res.exit_code == 0 and "attitude (aekf) valid on 4 of 4 frames" in res.output, \
        res.output


def test_aekf_back_end_refuses_a_marker_layout_it_does_not_model(recording, tmp_path):
    from pathlib import Path

    from experiments.sources import UserInputError
    from plant.user_files import load_setup

    motor = yaml.safe_load((Path(__file__).resolve().parents[1] / "examples" / "motor.yaml")
                           .read_text())
    motor["markers"][1]["offset_m"] = [0.02, 0.0, -0.065]
    (tmp_path / "motor.yaml").write_text(yaml.safe_dump(motor))
    setup = load_setup(tmp_path / "motor.yaml")
    with pytest.raises(UserInputError, match="--observer solver"):
        run_track(open_source(str(recording["dir"] / "png")),
                  make_pair_tracker("kcf_gk", setup.params), tmp_path / "run",
                  recording["boxes"], setup=setup, observer="aekf", write_video=False)


# --- the frame rate ------------------------------------------------------------------------------
def _camera_file(tmp_path, rate):
    path = tmp_path / f"cam_{rate}.yaml"
    path.write_text(yaml.safe_dump({"camera": {"frame_rate_hz": rate}}))
    return path


def test_a_folder_is_timed_at_the_camera_files_rate_and_the_report_says_so(recording, tmp_path):
    cam = _camera_file(tmp_path, 50.0)
    res = _cli([str(recording["dir"] / "png"), "--boxes", _boxes_arg(recording["boxes"]),
                "--camera", str(cam), "--max-frames", "4", "--out", str(tmp_path / "run")])
    assert res.exit_code == 0, res.output
    table = pd.read_parquet(tmp_path / "run" / "frames.parquet")
    assert np.allclose(table["capture_time_s"], np.arange(4) / 50.0)
    report = (tmp_path / "run" / "report.md").read_text()
    assert f"50 frames/s (from frame_rate_hz of {cam})" in report
    # --fps overrides the camera file
    res = _cli([str(recording["dir"] / "png"), "--boxes", _boxes_arg(recording["boxes"]),
                "--camera", str(cam), "--fps", "25", "--max-frames", "4", "--out",
                str(tmp_path / "fps")])
    assert res.exit_code == 0, res.output
    table = pd.read_parquet(tmp_path / "fps" / "frames.parquet")
    assert np.allclose(table["capture_time_s"], np.arange(4) / 25.0)
    assert "25 frames/s (from --fps)" in (tmp_path / "fps" / "report.md").read_text()


def test_a_videos_own_rate_is_checked_against_the_camera_file(recording, tmp_path):
    """The video was written at 36 frames/s; a camera file saying 50 Hz gives a warning naming
    both, and the video's rate is used."""
    res = _cli([str(recording["dir"] / "rec.mp4"), "--boxes", _boxes_arg(recording["boxes"]),
                "--camera", str(_camera_file(tmp_path, 50.0)), "--max-frames", "3", "--out",
                str(tmp_path / "run")])
    assert res.exit_code == 0, res.output
    assert "warning: the video's own frame rate is 36 Hz" in res.output, res.output
    assert "is 50 Hz" in res.output
    table = pd.read_parquet(tmp_path / "run" / "frames.parquet")
    assert np.allclose(table["capture_time_s"], np.arange(3) / 36.0)
    report = (tmp_path / "run" / "report.md").read_text()
    assert "36 frames/s (from the video's own rate)" in report and "Warning" in report
    same = _cli([str(recording["dir"] / "rec.mp4"), "--boxes", _boxes_arg(recording["boxes"]),
                 "--camera", str(_camera_file(tmp_path, 36.0)), "--max-frames", "2", "--out",
                 str(tmp_path / "same")])
    assert same.exit_code == 0 and "warning" not in same.output, same.output


@pytest.mark.parametrize("rate", ["0", "-5", "nan", "inf"])
def test_a_frame_rate_that_is_not_positive_and_finite_is_refused(recording, tmp_path, rate):
    good = ["--boxes", _boxes_arg(recording["boxes"]), "--out", str(tmp_path / "o")]
    res = _cli([str(recording["dir"] / "png"), *good, "--fps", rate])
    assert res.exit_code == 2 and "--fps must be a finite frame rate > 0 Hz" in res.output, \
        res.output
    res = _cli([str(recording["dir"] / "png"), *good, "--camera",
                str(_camera_file(tmp_path, float(rate)))])
    assert res.exit_code == 2 and "frame_rate_hz" in res.output, res.output
