"""The frame observer, update(frame, t_exposure) -> Estimate, on rendered frames."""

import numpy as np
import pytest

from observer.cor_model import CorModel
from observer.cor_solver import CorSolver
from observer.frame_observer import FrameObserver
from observer.gk.hsv_gate import box_sensor_to_image
from observer.opencv_trackers import OpenCVTracker
from observer.pixel_observer import FilterObserver, SolverObserver
from observer.trackers import make_pair_tracker
from observer.trackers.gk_transt import GKTransTPairTracker
from plant import attitude as A
from plant.params import PlantParams
from plant.render_analytic import AnalyticRenderer

P = PlantParams()


def cone(t):
    """A slow cone: 8° tilt whose azimuth turns at 1 rad/s, no turn about the shaft."""
    g = 1.0 * t
    return A.from_zyz(-g, np.deg2rad(8.0), g)


def run(backend, n=40):
    renderer = AnalyticRenderer(P, seed=3)
    obs = FrameObserver(make_pair_tracker("kcf_gk", P), backend)
    obs.reset(cone(0.0), 0.0)
    errors, ests = [], []
    dt = 1.0 / P.camera.frame_rate_hz
    for k in range(n):
        t = k * dt
        frame = renderer.render(cone(t), t_exposure=t)
        if k == 0:
            obs.start(frame.image, frame.binning, frame.boxes_px)
        est = obs.update(frame, t)
        ests.append(est)
        errors.append(A.geodesic_angle(est.q, cone(est.state_time)))
    return np.array(errors), ests


def test_solver_observer_on_rendered_frames():
    errors, ests = run(SolverObserver(CorSolver(CorModel.nominal(P))))
    assert all(e.valid and not e.lost for e in ests)
    assert np.degrees(errors.max()) < 0.15
    assert all(e.compute_time_s > 0 and e.latency_s >= e.compute_time_s for e in ests)


def test_filter_observer_on_rendered_frames_estimates_the_rate():
    # The cone is imposed kinematically (a rotary table): no torque is recorded, so the filter's
    # model is given no friction, which would otherwise brake its predicted rate.
    free = P.model_copy(
        update={"rotor": P.rotor.model_copy(update={"viscous_Nms_per_rad": 0.0, "coulomb_Nm": 0.0})}
    )
    errors, ests = run(FilterObserver(free, compensate_delay=False), n=60)
    assert np.degrees(errors[10:].max()) < 0.15
    # Body rate of R = Rz(g) Ry(b) Rz(-g): omega_stator = g' (z - shaft), |omega| = 2 sin(b/2) g'.
    for e in ests[30:]:
        R = A.to_matrix(cone(e.state_time))
        w_true = R.T @ (np.array([0.0, 0.0, 1.0]) - R[:, 2])
        assert np.linalg.norm(e.omega - w_true) < 0.1 * np.linalg.norm(w_true)


def test_locator_predicts_through_blank_frames_and_reacquires():
    renderer = AnalyticRenderer(P, seed=4)
    loc = make_pair_tracker("kcf_gk", P)
    frame = renderer.render(cone(0.0))
    loc.start(frame.image, frame.boxes_px, frame.binning)
    dt = 1.0 / P.camera.frame_rate_hz
    for k in range(1, 4):
        loc.step(renderer.render(cone(k * dt)).image)
    for _ in range(4, 8):  # the markers vanish: the Kalman prediction stands in
        res = loc.step(np.zeros_like(frame.image))
        assert not res.red_measured and np.all(np.isfinite(res.red_px))
        assert loc.last_gk.red_source == "prediction"
    for k in range(8, 12):
        f = renderer.render(cone(k * dt))
        res = loc.step(f.image)
    assert not res.lost and res.red_measured and loc.last_gk.red_source == "measurement"
    assert np.linalg.norm(res.marker_px - f.marker_px, axis=1).max() < 3.0


# --- bad frames (a flagged estimate with a reason, never a crash mid-loop) ---------------------

def _bad_frames(image):
    """Name -> (bad image, words its reason must contain)."""
    nan_float = np.full(image.shape, np.nan)
    return {
        "empty": (np.zeros((0, 0, 3), np.uint8), "empty"),
        "float": (image.astype(np.float64) / 255.0, "uint8"),
        "nan_float": (nan_float, "float64"),
        "grey_2d": (image[..., 0].copy(), "(H, W, 3)"),
        "four_channels": (np.dstack([image, image[..., :1]]), "(H, W, 3)"),
        "wrong_size": (np.ascontiguousarray(image[:100, :120]), "does not match the sensor"),
        "not_an_array": (None, "not a numpy array"),
    }


class _Frame:
    def __init__(self, image, binning):
        self.image, self.binning = image, binning


def _started_observer(backend, seed=5):
    renderer = AnalyticRenderer(P, seed=seed)
    obs = FrameObserver(make_pair_tracker("kcf_gk", P), backend)
    obs.reset(cone(0.0), 0.0)
    first = renderer.render(cone(0.0), t_exposure=0.0)
    obs.start(first.image, first.binning, first.boxes_px)
    assert obs.update(first, 0.0).valid
    return obs, renderer, first


def test_bad_frames_give_an_invalid_estimate_with_a_reason():
    dt = 1.0 / P.camera.frame_rate_hz
    for make_backend in (lambda: SolverObserver(CorSolver(CorModel.nominal(P))),
                         lambda: FilterObserver(P, compensate_delay=False)):
        obs, renderer, first = _started_observer(make_backend())
        for k, (name, (img, words)) in enumerate(_bad_frames(first.image).items(), start=1):
            est = obs.update(_Frame(img, first.binning), k * dt)  # must not raise
            assert not est.valid, name
            assert est.lost, name
            assert est.reason.startswith("bad frame: "), (name, est.reason)
            assert words in est.reason, (name, est.reason)


def test_observer_recovers_after_bad_frames():
    """Three bad frames, then good ones: the track resumes and the attitude is right again."""
    obs, renderer, first = _started_observer(SolverObserver(CorSolver(CorModel.nominal(P))))
    dt = 1.0 / P.camera.frame_rate_hz
    bad = list(_bad_frames(first.image).values())
    k = 1
    for k in range(1, 4):
        assert not obs.update(_Frame(bad[k][0], first.binning), k * dt).valid
    for k in range(4, 10):
        t = k * dt
        est = obs.update(renderer.render(cone(t), t_exposure=t), t)
    assert est.valid and not est.lost and est.reason == ""
    assert np.degrees(A.geodesic_angle(est.q, cone(est.state_time))) < 0.15


def test_locator_flags_a_bad_frame_without_showing_it_to_the_tracker():
    renderer = AnalyticRenderer(P, seed=6)
    calls = []

    class Spy(OpenCVTracker):
        def track(self, frame, search_centre_image_px=None):
            calls.append(frame.shape)
            return super().track(frame, search_centre_image_px)

    loc = GKTransTPairTracker(Spy("kcf"), P, guide_search=False, restart_on_prediction=True)
    f = renderer.render(cone(0.0))
    loc.start(f.image, f.boxes_px, f.binning)
    loc.step(f.image)
    res = loc.step(f.image.astype(np.float32))
    assert calls == [f.image.shape]
    assert res.lost and "float32" in res.bad_frame and res.reason.startswith("bad frame: ")
    assert res.reason.count("float32") == 1  # said once, not repeated by the GK stage


def test_opencv_tracker_rejects_bad_frames_with_a_reason():
    renderer = AnalyticRenderer(P, seed=7)
    f = renderer.render(cone(0.0))
    box = box_sensor_to_image(f.boxes_px[0], f.binning)
    for kind in ("kcf", "csrt"):
        tr = OpenCVTracker(kind)
        res = tr.track(f.image)
        b, s = res.box_image_px, res.score
        assert np.all(np.isnan(b)) and s == 0.0 and "not initialised" in res.reason
        with pytest.raises(ValueError, match="uint8"):
            tr.initialize(f.image.astype(float), box)
        tr.initialize(f.image, box)
        for name, (img, words) in _bad_frames(f.image).items():
            res = tr.track(img)  # must not raise (it raised cv2.error before)
            b, s = res.box_image_px, res.score
            assert np.all(np.isnan(b)) and s == 0.0, (kind, name)
            # The tracker knows only its init frame, not the sensor.
            words = "differs from the init frame" if name == "wrong_size" else words
            assert words in res.reason, (kind, name, res.reason)
        res = tr.track(f.image)  # a good frame still tracks after the bad ones
        b, s = res.box_image_px, res.score
        assert s == 1.0 and res.valid and res.reason == ""
        c = (b[:2] + 0.5 * b[2:] + 0.5) * f.binning - 0.5
        assert np.linalg.norm(c - f.marker_px[0]) < 3.0
