"""The timed closed loop: both modes, events, safe fallbacks, and MuJoCo's native delay."""

import numpy as np
import pytest

from controller.base import Controller, Reference, RefSample
from latency.frontends import ImageFrontEnd, MeasurementConfig, MeasurementFrontEnd
from latency.loop import ClosedLoop
from latency.loop_config import LoopConfig
from latency.models import Constant, seed_profile
from latency.pipeline import FrameScheduler, PipelineConfig
from observer.cor_model import CorModel
from observer.cor_solver import CorSolver
from observer.pixel_observer import FilterObserver, SolverObserver
from plant import attitude as A
from plant.camera import marker_pixels
from plant.dynamics import MujocoPlant
from plant.params import PlantParams
from plant.render_analytic import AnalyticRenderer
from plant.rigid_body import STOP_TIMECONST_S

P = PlantParams()
J = P.rotor.inertia_com_kgm2[0]


class TiltStep(Reference):
    """A pure tilt of ``tilt_deg`` toward azimuth ``yaw_deg`` from ``t0`` (s)."""

    def __init__(self, tilt_deg=5.0, yaw_deg=30.0, t0=0.1):
        g = np.deg2rad(yaw_deg)
        self.q1 = A.from_zyz(-g, np.deg2rad(tilt_deg), g)
        self.t0 = t0

    def sample(self, t):
        return RefSample(self.q1 if t >= self.t0 else np.array([1.0, 0, 0, 0]))


class PD(Controller):
    """Test double: body-frame PD on the rotation-vector error, gain sign selectable; zero
    torque on an invalid estimate."""

    def __init__(self, wc=20.0, zeta=0.8, sign=1.0):
        self.kp, self.kd, self.sign = J * wc**2, 2 * zeta * J * wc, sign

    def reset(self):
        pass

    def command(self, est, reference, t):
        if not est.valid:
            return np.zeros(3)
        q_ref = reference.sample(t).q
        e = A.to_rotvec(A.multiply(A.conjugate(est.q), q_ref))
        w = np.nan_to_num(est.omega)
        return A.to_matrix(est.q) @ (self.sign * (self.kp * e - self.kd * w))


def measurement_loop(duration=1.5, profile="gk_transt", meas=None, controller=None, **kw):
    rng = np.random.default_rng(0)
    cfg = LoopConfig(
        duration_s=duration, pipeline=PipelineConfig(observer=seed_profile(profile)), **kw
    )
    front = MeasurementFrontEnd(P, meas or MeasurementConfig(), rng)
    return ClosedLoop(P, controller or PD(), TiltStep(), front, FilterObserver(P), cfg)


def test_measurement_model_loop_settles_a_tilt_step():
    r = measurement_loop().run()
    s = r.summary
    assert s["diverged"] == 0.0
    assert r.steps["error_deg"].iloc[-300:].max() < 0.1  # the last 0.3 s on target
    assert s["settling_time_s"] < 0.8
    assert s["lost_frame_fraction"] == 0.0
    assert s["mean_latency_s"] == pytest.approx(1e-3 + 16.33e-3)
    # one row per 1 ms physics step, truth and reference recorded
    assert len(r.steps) == 1501
    assert np.allclose(np.linalg.norm(r.steps[["qw", "qx", "qy", "qz"]], axis=1), 1.0)


def test_slow_observer_drops_frames_and_the_table_says_so():
    r = measurement_loop(profile="dual_transt").run()
    assert r.summary["dropped_frame_fraction"] == pytest.approx(0.5, abs=0.02)
    assert (r.events.kind == "frame_dropped").sum() == r.frames.dropped.sum()


def test_dropouts_are_tracking_losses_and_the_loop_survives():
    r = measurement_loop(meas=MeasurementConfig(dropout_prob=0.3)).run()
    assert r.summary["lost_frame_fraction"] == pytest.approx(0.3, abs=0.12)
    kinds = set(r.events.kind)
    assert {"tracking_loss", "reacquisition"} <= kinds
    assert r.summary["diverged"] == 0.0


def test_no_measurements_at_all_gives_the_safe_command():
    r = measurement_loop(duration=1.0, meas=MeasurementConfig(dropout_prob=1.0)).run()
    assert "invalid_estimate" in set(r.events.kind)
    assert np.abs(r.steps[[f"torque_delivered_{c}_Nm" for c in "xyz"]].to_numpy()).max() == 0.0
    assert r.summary["lost_frame_fraction"] == 1.0


def test_destabilising_controller_is_flagged_and_the_run_covers_its_duration():
    r = measurement_loop(duration=3.0, controller=PD(sign=-1.0)).run()
    assert r.summary["diverged"] == 1.0 and r.summary["loss_of_control"] == 1.0
    assert list(r.events.kind).count("divergence") == 1
    assert r.summary["simulated_s"] == pytest.approx(3.0)  # metrics over the same duration


def test_saturation_and_tilt_stop_events():
    # A stiff PD on a 20° request: the allocation saturates and the rotor meets the 15° stop.
    class Big(TiltStep):
        def __init__(self):
            super().__init__(tilt_deg=20.0)

    front = MeasurementFrontEnd(P, MeasurementConfig(), np.random.default_rng(0))
    cfg = LoopConfig(duration_s=1.0)
    r = ClosedLoop(P, PD(wc=30.0), Big(), front, FilterObserver(P), cfg).run()
    kinds = set(r.events.kind)
    assert "saturation" in kinds and "tilt_stop_contact" in kinds
    # The stop is a critically damped spring-damper (time constant tau): an impact at tilt
    # rate w overshoots 15° by about w tau / e (plus the push's static T / k); allow w tau.
    tilt = np.radians(r.steps["tilt_deg"].to_numpy())
    k = int(np.argmax(tilt >= np.radians(15.0)))
    w_impact = (tilt[k] - tilt[k - 1]) / P.physics_dt_s
    assert tilt.max() - np.radians(15.0) < w_impact * STOP_TIMECONST_S


def test_run_steps_the_physics_compiled_and_equals_the_step_by_step_path(monkeypatch):
    """``ClosedLoop.run`` serves the physics through the compiled kernel (``KernelAdvance``)
    and writes its state back into the plant; a stiff PD on a 20° request (saturated currents,
    the tilt stop) with the coils' lag gives the steps table of the step-by-step path
    (``_advance_segment``) to 1e-12."""
    from latency import loop as loop_module
    from latency import segments
    from plant.params import MotorParams

    class Big(TiltStep):
        def __init__(self):
            super().__init__(tilt_deg=20.0)

    params = P.model_copy(update={"motor": MotorParams(coil_time_constant_s=0.0015)})
    calls = []

    class Spy(segments.KernelAdvance):
        def __call__(self, req):
            calls.append(req.t_target_s)
            return super().__call__(req)

    class StepByStep:
        def __init__(self, plant, n_steps):
            self.plant, self.n_steps = plant, n_steps

        def __call__(self, req):
            return segments._advance_segment(self.plant, req, params.physics_dt_s,
                                             self.n_steps, False)

    def steps(advance):
        monkeypatch.setattr(loop_module, "KernelAdvance", advance)
        front = MeasurementFrontEnd(params, MeasurementConfig(), np.random.default_rng(0))
        loop = ClosedLoop(params, PD(wc=30.0), Big(), front, FilterObserver(params),
                          LoopConfig(duration_s=0.6))
        r = loop.run()
        return r.steps.select_dtypes("number").to_numpy(float), set(r.events.kind)

    fast, kinds = steps(Spy)
    assert len(calls) > 30
    slow, kinds_slow = steps(StepByStep)
    assert {"saturation", "tilt_stop_contact"} <= kinds == kinds_slow
    assert fast.shape == slow.shape
    assert np.nanmax(np.abs(fast - slow)) <= 1e-12


def test_config_errors_are_clear():
    with pytest.raises(ValueError, match="duration_s"):
        LoopConfig(duration_s=0.01, pipeline=PipelineConfig(observer=seed_profile("csrt")))
    with pytest.raises(ValueError, match="value_s"):
        LoopConfig(duration_s=1.0, pipeline=PipelineConfig(observer=Constant(value_s=-0.01)))
    with pytest.raises(ValueError, match="frame_rate_hz"):
        LoopConfig(duration_s=1.0, pipeline=PipelineConfig(frame_rate_hz=0))


def test_results_save_as_parquet(tmp_path):
    r = measurement_loop(duration=0.3).run()
    out = r.save(tmp_path / "run")
    assert {p.name for p in out.iterdir()} == {
        "steps.parquet",
        "frames.parquet",
        "events.parquet",
        "summary.json",
    }


def test_delay_pipeline_matches_mujoco_native_sensor_delay():
    # A constant delay through our pipeline (exposure/2 + readout + processing) against MuJoCo's
    # own delayed ballquat sensor with the same total delay. 40 frames/s and 2 ms exposure keep
    # every event on the 1 ms physics grid, where MuJoCo's delay buffer is exact.
    cfg = PipelineConfig(frame_rate_hz=40.0, exposure_s=2e-3, observer=Constant(value_s=16e-3))
    total = 0.5 * cfg.exposure_s + cfg.observer.value_s
    plant = MujocoPlant(P, omega0=[0.4, -0.3, 3.0], sensor_delay_s=total)
    frames = FrameScheduler(cfg, np.random.default_rng(0)).schedule(0.5)
    h = P.physics_dt_s
    truth, compared = {0: plant.q}, 0
    release_at = {round(f.t_release / h): round(f.t_exposure / h) for f in frames}
    for k in range(1, 560):
        plant.step(np.zeros(16), h)
        truth[k] = plant.q
        # After the step to time k h MuJoCo's sensors describe time (k - 1) h.
        if k - 1 in release_at:
            ours = truth[release_at[k - 1]]  # the measurement our pipeline releases now
            assert A.geodesic_angle(ours, plant.delayed_q()) < 1e-12
            compared += 1
    assert compared == len(frames)


def test_solver_observer_in_the_loop_reproduces_exact_measurements():
    # With noise-free pixels the per-frame least-squares solver returns the attitude at the
    # exposure time: released estimates equal the recorded truth at t_exposure.
    front = MeasurementFrontEnd(P, MeasurementConfig(sigma_px=0.0), np.random.default_rng(0))
    obs = SolverObserver(CorSolver(CorModel.nominal(P)))
    cfg = LoopConfig(duration_s=0.6, pipeline=PipelineConfig(frame_rate_hz=40.0))
    r = ClosedLoop(P, PD(), TiltStep(), front, obs, cfg).run()
    t_steps = r.steps.t_s.to_numpy()
    compared = 0
    for _, f in r.frames.iterrows():
        k = int(np.argmin(np.abs(t_steps - f.t_exposure_s)))
        assert abs(t_steps[k] - f.t_exposure_s) < 1e-9  # mid-exposure falls on a physics step
        truth = r.steps.loc[k, ["qw", "qx", "qy", "qz"]].to_numpy(float)
        est = f[["est_qw", "est_qx", "est_qy", "est_qz"]].to_numpy(float)
        assert A.geodesic_angle(truth, est) < 1e-7
        compared += 1
    assert compared == len(r.frames) == 24  # 0.6 s at 40 frames/s


def test_image_in_the_loop_with_kcf_and_gk_closes_the_loop():
    renderer = AnalyticRenderer(P, seed=0)
    front = ImageFrontEnd(P, renderer)
    cfg = LoopConfig(duration_s=1.2)
    r = ClosedLoop(P, PD(), TiltStep(tilt_deg=3.0), front, FilterObserver(P), cfg).run()
    assert r.summary["diverged"] == 0.0
    assert r.summary["lost_frame_fraction"] == 0.0
    assert r.frames.centre_error_px.max() < 3.0  # sensor px, against rendered ground truth
    assert r.steps["error_deg"].iloc[-200:].max() < 0.2
    # the markers were measured, so the pixel columns are real numbers
    assert np.isfinite(r.frames[["meas_red_u_px", "meas_yellow_v_px"]].to_numpy()).all()
    assert np.allclose(
        r.frames[["true_red_u_px", "true_red_v_px"]].iloc[0],
        marker_pixels(P, [1.0, 0, 0, 0])[0],
        atol=1e-6,
    )


def test_motion_loss_model_of_the_measurement_front_end():
    # Spin about the shaft at a constant rate: the markers move on a circle, d px per frame.
    w = 4.0  # rad/s
    frame = 1 / 36
    lever_px = (
        np.linalg.norm(marker_pixels(P, [1.0, 0, 0, 0])[0] - marker_pixels(P, [1, 0, 0, 0])[1]) / 2
    )
    d = lever_px * w * frame  # chord ~ arc per frame, sensor px
    qs = [A.axis_angle([0, 0, 1], w * k * frame) for k in range(30)]
    omega = np.array([0.0, 0.0, w])

    def lost_flags(**kw):
        fe = MeasurementFrontEnd(P, MeasurementConfig(sigma_px=0.0, **kw), np.random.default_rng(0))
        return [fe.capture(q, omega, k * frame).lost for k, q in enumerate(qs)]

    assert not any(lost_flags(search_radius_px=1.5 * d, predictive_search=False))
    flags = lost_flags(search_radius_px=0.5 * d, predictive_search=False, reacquire_after_frames=3)
    assert flags[:2] == [False, True]  # lost at the first move...
    assert flags[1:5] == [True, True, True, False]  # ...re-detected after 3 lost frames
    # A constant-velocity prediction follows the circle up to the curvature error (about
    # d^2 / lever = 4 px here; 11 px right after a re-detection, whose motion estimate spans the
    # lost frames): after the first move, which it cannot predict, and a re-detection 3 frames
    # later, a window half the per-frame motion keeps the markers.
    r = 0.5 * d
    flags = lost_flags(search_radius_px=r, predictive_search=True, reacquire_after_frames=3)
    assert flags[:5] == [False, True, True, True, False] and not any(flags[5:])
    # Blur: the markers travel w * exposure * lever during the exposure.
    travel = lever_px * w * P.camera.exposure_s
    assert all(lost_flags(blur_limit_px=0.9 * travel))
    assert not any(lost_flags(blur_limit_px=1.1 * travel))


def test_fixed_rate_controller_runs_on_its_own_clock():
    """``controller_rate_hz``: commands at k/rate + the controller latency, on the latest
    released estimate (a safe command before the first); the loop still follows the step."""
    from latency import Scenario, build_loop

    sc = Scenario.model_validate({
        "duration_s": 1.5, "controller_rate_hz": 100.0,
        "controller_latency": {"kind": "constant", "value_s": 0.002},
        "reference": {"kind": "tilt_step", "tilt_deg": 3.0, "t_step_s": 0.1},
    })
    loop = build_loop(sc)
    calls = []
    command = loop.controller.command
    loop.controller.command = lambda est, ref, t: (calls.append(t), command(est, ref, t))[1]
    r = loop.run()
    assert r.summary["diverged"] == 0.0
    # one call per tick; the ticks before the first estimate get the controller's safe command
    # (it holds its initial zero torque)
    first = r.frames.t_release_s.dropna().min()
    ticks = np.arange(0.0, 1.5, 0.01)
    np.testing.assert_allclose(calls, ticks[: len(calls)], atol=1e-9)
    assert len(calls) >= len(ticks) - 1
    T = r.steps[[f"torque_cmd_{c}_Nm" for c in "xyz"]].to_numpy()
    t = r.steps.t_s.to_numpy()
    assert np.all(T[t <= first + 0.002] == 0.0)
    changes = t[1:][np.any(np.abs(np.diff(T, axis=0)) > 0, axis=1)]
    # every change of the commanded torque falls on the 100 Hz clock plus the 2 ms latency; the
    # 1 ms log row at a command's time is written before the command applies, hence + 1 ms
    phase = np.round((changes - 0.003) * 100.0, 6) % 1.0
    assert np.all(np.isclose(phase, 0.0, atol=1e-6) | np.isclose(phase, 1.0, atol=1e-6))
    assert r.steps["error_deg"].iloc[-1] < 1.0
    assert {"max_spin_error_deg", "max_tilt_error_deg", "max_yaw_error_deg"} <= set(r.summary)


def test_closed_loop_releases_what_mujocos_native_delayed_sensor_reports():
    """The whole closed loop (PD closing on the estimates, noise-free pixels, per-frame solver,
    constant latency) against MuJoCo's own delayed ``ballquat`` sensor on the same plant: each
    released estimate equals the sensor's reading at the release time. 40 frames/s and a 2 ms
    exposure keep every event on the 1 ms physics grid, where MuJoCo's delay buffer is exact."""
    pipe = PipelineConfig(frame_rate_hz=40.0, exposure_s=2e-3, observer=Constant(value_s=16e-3))
    total = 0.5 * pipe.exposure_s + pipe.observer.value_s
    front = MeasurementFrontEnd(P, MeasurementConfig(sigma_px=0.0), np.random.default_rng(0))
    obs = SolverObserver(CorSolver(CorModel.nominal(P)))
    cfg = LoopConfig(duration_s=0.8, pipeline=pipe, mujoco_sensor_delay_s=total,
                     omega0_rad_s=(0.4, -0.3, 3.0))
    r = ClosedLoop(P, PD(), TiltStep(), front, obs, cfg).run()
    assert np.abs(r.steps[["torque_delivered_x_Nm", "torque_delivered_y_Nm"]].to_numpy()).max() > 0
    t_steps = r.steps.t_s.to_numpy()
    h = P.physics_dt_s
    compared = 0
    for _, f in r.frames.dropna(subset=["est_qw"]).iterrows():
        # the sensor row that describes the release time: one physics step later
        k = int(np.argmin(np.abs(t_steps - (f.t_release_s + h))))
        if abs(t_steps[k] - (f.t_release_s + h)) > 1e-9:
            continue
        native = r.steps.loc[k, ["mj_delayed_qw", "mj_delayed_qx", "mj_delayed_qy",
                                 "mj_delayed_qz"]].to_numpy(float)
        ours = f[["est_qw", "est_qx", "est_qy", "est_qz"]].to_numpy(float)
        assert A.geodesic_angle(ours, native) < 1e-7
        compared += 1
    assert compared >= 0.9 * len(r.frames)
