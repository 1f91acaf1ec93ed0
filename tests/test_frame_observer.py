"""The DESIGN observer, update(frame, t_exposure) -> Estimate, on rendered frames."""

import numpy as np

from observer.cor_model import CorModel
from observer.cor_solver import CorSolver
from observer.frame_observer import FrameObserver, MarkerLocator
from observer.pixel_observer import FilterObserver, SolverObserver
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
    obs = FrameObserver(MarkerLocator(P), backend)
    obs.reset(cone(0.0), 0.0)
    errors, ests = [], []
    dt = 1.0 / P.camera.frame_rate_hz
    for k in range(n):
        t = k * dt
        frame = renderer.render(cone(t), t_exposure=t)
        if k == 0:
            obs.start(frame.image, frame.binning, frame.boxes_px[0])
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
    loc = MarkerLocator(P)
    frame = renderer.render(cone(0.0))
    loc.start(frame.image, frame.binning, frame.boxes_px[0])
    dt = 1.0 / P.camera.frame_rate_hz
    for k in range(1, 4):
        loc.locate(renderer.render(cone(k * dt)).image, frame.binning)
    for _ in range(4, 8):  # the markers vanish: the Kalman prediction stands in, tracker restarts
        blank = np.zeros_like(frame.image)
        res = loc.locate(blank, frame.binning)
        assert res.gk.red_source == "prediction"
    for k in range(8, 12):
        f = renderer.render(cone(k * dt))
        res = loc.locate(f.image, f.binning)
    assert not res.lost and res.gk.red_source == "measurement"
    assert np.linalg.norm(res.marker_px - f.marker_px, axis=1).max() < 3.0
