"""The tracker -> attitude boundary rule: the frame observer, the image front end of the loop and
``pmspm track`` are fed the same pair-tracker outputs (some markers predicted, a few px off) and
give the same attitudes, resting only on the measured markers."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import pandas as pd

from experiments.sources import Source
from experiments.track import predicted_stretches, run_track
from experiments.track_accuracy import attitude_accuracy
from latency.frontends import ImageFrontEnd
from latency.profile import cone_attitude
from observer.cor_model import CorModel
from observer.cor_solver import CorSolver
from observer.frame_observer import FrameObserver
from observer.pixel_observer import SolverObserver
from observer.trackers import box_around
from observer.tracking import PairResult, attitude_input, attitude_source
from plant import attitude as A
from plant.camera import marker_pixels
from plant.params import PlantParams
from tests.fake_clock import StepClock

P = PlantParams()
FPS = P.camera.frame_rate_hz
N = 20
#: frame -> (red measured, yellow measured); an unmeasured marker is reported 5 px off (a
#: drifting Kalman prediction), close enough for the solver's residual bound (5 px RMS) to accept
#: it, so that fusing it would move the attitude.
SCRIPT = {5: (False, True), 6: (False, True), 7: (False, True), 11: (False, False),
          12: (False, False), 15: (True, False)}
OFF_PX = np.array([4.0, -3.0])


def truth_q(k: int):
    return cone_attitude(k / FPS)[0]


def scripted_result(k: int) -> PairResult:
    """The pair tracker's output for frame k (the truth, or a flagged guess per SCRIPT)."""
    red_m, yellow_m = SCRIPT.get(k, (True, True))
    px = marker_pixels(P, truth_q(k))
    red = px[0] if red_m else px[0] + OFF_PX
    yellow = px[1] if yellow_m else px[1] - OFF_PX
    size = np.array([40.0, 40.0])
    return PairResult(red, yellow, False, "" if red_m and yellow_m else "predicted", 0.0,
                      red_measured=red_m, yellow_measured=yellow_m,
                      red_box_px=box_around(red, size), yellow_box_px=box_around(yellow, size))


def frame_image(k: int) -> np.ndarray:
    """A frame of the camera's size whose first pixel carries its index (the fake tracker
    reads it back, whatever drives it)."""
    b = P.camera.binning
    w, h = P.camera.sensor_width_px // b, P.camera.sensor_height_px // b
    img = np.full((h, w, 3), 40, np.uint8)
    img[0, 0] = k
    return img


class ScriptedTracker:
    """A ``PairTracker`` replaying ``scripted_result`` for the frame it is shown."""

    name = "scripted"

    def __init__(self) -> None:
        self.tilt_hint_rad = None
        self.residual_hint_px = None
        self.clock = StepClock(1e-3)
        self._started = False

    def start(self, image, boxes_sensor_px, binning=None) -> None:
        self._started = True

    def step(self, image) -> PairResult:
        return scripted_result(int(image[0, 0, 0]))

    @property
    def started(self) -> bool:
        return self._started

    def reset(self) -> None:
        self._started = False


@dataclass
class _Frame:
    image: np.ndarray
    boxes_px: np.ndarray
    marker_px: np.ndarray
    binning: int = P.camera.binning


class ScriptedRenderer:
    """Renders frame k = round(t fps) as ``frame_image(k)``."""

    def render(self, q, t_exposure=0.0, omega=None):
        k = round(t_exposure * FPS)
        px = marker_pixels(P, truth_q(k))
        boxes = np.array([box_around(c, (40.0, 40.0)) for c in px])
        return _Frame(frame_image(k), boxes, px)


class _FrameList:
    """The frames 0..N-1 (BGR) as a ``experiments.sources.Capture``."""

    def __init__(self) -> None:
        self.k = 0

    def read(self):
        if self.k >= N:
            return False, None
        img = cv2.cvtColor(frame_image(self.k), cv2.COLOR_RGB2BGR)
        self.k += 1
        return True, img

    def grab(self) -> bool:
        self.k += 1
        return self.k <= N

    def release(self) -> None:
        self.k = N

    def isOpened(self) -> bool:  # noqa: N802 - OpenCV's name
        return self.k < N

    def get(self, prop_id: int) -> float:
        return 0.0


def _solver_backend() -> SolverObserver:
    return SolverObserver(CorSolver(CorModel.nominal(P)))


def test_attitude_source_names_what_the_attitude_rests_on():
    assert attitude_source(True, True) == "both measured"
    assert attitude_source(True, False) == attitude_source(False, True) == "one predicted"
    assert attitude_source(False, False) == "both predicted"
    given = attitude_input(scripted_result(5))
    assert np.all(np.isnan(given.marker_px[0])) and np.all(np.isfinite(given.marker_px[1]))
    assert not given.lost and given.source == "one predicted"
    assert attitude_input(scripted_result(11)).lost


def test_observer_front_end_and_track_give_the_same_attitudes(tmp_path):
    # 1. the frame observer
    obs = FrameObserver(ScriptedTracker(), _solver_backend())
    obs.reset(truth_q(0), 0.0)
    obs.start(frame_image(0), P.camera.binning, np.zeros((2, 4)))
    q_obs = np.array([obs.update(_Frame(frame_image(k), None, None), k / FPS).q
                      for k in range(N)])
    # 2. the image front end, its capture fused as the loop fuses it
    front = ImageFrontEnd(P, ScriptedRenderer(), ScriptedTracker())
    back = _solver_backend()
    back.reset(truth_q(0), 0.0)
    q_loop, sources = [], []
    for k in range(N):
        cap = front.capture(truth_q(k), np.zeros(3), k / FPS)
        back.process(cap.measurement, k / FPS, cap.lost, cap.reason, cap.compute_time_s)
        q_loop.append(back.release(k / FPS).q)
        sources.append(attitude_source(*cap.measured))
    q_loop = np.array(q_loop)
    # 3. pmspm track (the least-squares back end)
    source = Source(_FrameList(), "folder", FPS, N, "scripted")
    out = run_track(source, ScriptedTracker(), tmp_path, boxes_image_px=[[100, 100, 10, 10],
                    [200, 100, 10, 10]], write_video=False)
    t = out.table
    q_track = t[["q_w", "q_x", "q_y", "q_z"]].to_numpy()

    both = np.array([SCRIPT.get(k, (True, True)) == (True, True) for k in range(N)])
    assert both.sum() == N - len(SCRIPT)
    assert t["attitude_source"].tolist() == [attitude_source(*SCRIPT.get(k, (True, True)))
                                             for k in range(N)]
    assert sources[1:] == t["attitude_source"].tolist()[1:]  # frame 0: the loop's annotation
    assert (t["red_measured"] == [SCRIPT.get(k, (True, True))[0] for k in range(N)]).all()
    # Frames with both markers measured: all three give the true attitude.
    for q in (q_obs, q_loop, q_track):
        err = np.degrees([A.geodesic_angle(q[k], truth_q(k)) for k in np.flatnonzero(both)])
        assert err.max() < 1e-4, err.max()
    # Frames with a predicted marker: no attitude from the least-squares solve in track, and
    # the frame observer and the loop's back end hold the last measured frame's attitude.
    assert not t["attitude_valid"][~both].any() and np.isnan(q_track[~both]).all()
    held = [k - 1 - next(j for j in range(k) if both[k - 1 - j]) for k in np.flatnonzero(~both)]
    for q in (q_obs, q_loop):
        err = np.degrees([A.geodesic_angle(q[k], truth_q(h))
                          for k, h in zip(np.flatnonzero(~both), held, strict=True)])
        assert err.max() < 1e-4, err.max()
    assert np.allclose(q_obs[1:], q_loop[1:], atol=1e-9)


def test_accuracy_summary_leaves_out_predicted_frames_and_says_how_many(tmp_path):
    source = Source(_FrameList(), "folder", FPS, N, "scripted")
    out = run_track(source, ScriptedTracker(), tmp_path, boxes_image_px=[[100, 100, 10, 10],
                    [200, 100, 10, 10]], write_video=False, observer="aekf")
    q_true = [truth_q(k) for k in range(N)]
    acc = attitude_accuracy(out.table, q_true)
    assert acc["predicted_frames_left_out"] == len(SCRIPT)
    assert acc["frames_scored"] == N - len(SCRIPT)
    everything = attitude_accuracy(out.table, q_true, include_predicted=True)
    assert everything["predicted_frames_left_out"] == 0
    assert everything["frames_scored"] == N
    assert "attitude rests on: both measured 14, one predicted 4, both predicted 2 frames" \
        in (tmp_path / "report.md").read_text()


def test_predicted_stretches_are_the_runs_of_predicted_frames():
    table = pd.DataFrame({"capture_time_s": np.arange(N) / FPS,
                          "attitude_source": [attitude_source(*SCRIPT.get(k, (True, True)))
                                              for k in range(N)]})
    half = 0.5 / FPS
    got = [(round((a + half) * FPS), round((b - half) * FPS), s)
           for a, b, s in predicted_stretches(table)]
    assert got == [(5, 7, "one predicted"), (11, 12, "both predicted"), (15, 15, "one predicted")]
