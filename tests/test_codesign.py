"""Co-design: the camera-mode model, the region-of-interest loss model, the search against the
seed's design, pruning by analysis against Monte Carlo, and resuming the SQLite study."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from controller.reference import pure_tilt
from experiments.codesign.analysis import analyse
from experiments.codesign.evaluate import mc_feasible, monte_carlo
from experiments.codesign.report import designs_table, recommended, write_report
from experiments.codesign.search import (
    evaluate_designs,
    open_study,
    run_search,
    storage_url,
    trial_records,
)
from experiments.codesign.space import Design, seed_design
from experiments.codesign.spec import CodesignSpec
from latency.frontends import MeasurementConfig, MeasurementFrontEnd
from plant.camera import marker_pixels
from plant.camera_mode import CameraMode, RegionOfInterest, SensorTiming
from plant.params import PlantParams

pytestmark = pytest.mark.engine  # runs the compiled engines

# --------------------------------------------------------------------------------------------
# The camera mode
# --------------------------------------------------------------------------------------------


def test_full_sensor_runs_at_the_seed_rate_and_fewer_rows_read_faster():
    s = SensorTiming()
    full = CameraMode()
    assert full.rate_hz == pytest.approx(36.0, rel=2e-3)  # seed 000 §5
    # Rows set the sensor readout, (rows + blanking) line times; columns and binning only
    # the bytes on the link, which stay below it here.
    half = CameraMode(rows=1024)
    assert half.readout_s == pytest.approx((1024 + s.blank_rows) * s.line_time_s)
    assert CameraMode(rows=1024, cols=1024, binning=2).readout_s == pytest.approx(half.readout_s)
    assert half.rate_hz == pytest.approx(1.0 / half.readout_s)
    # A long exposure, not the readout, limits a small region.
    small = CameraMode(rows=64, exposure_s=4e-3)
    assert small.rate_hz == pytest.approx(1.0 / (4e-3 + s.min_gap_s))
    # A link-bound mode: 2448 x 2048 bytes at 100 MB/s take 50 ms, longer than the readout.
    slow_link = CameraMode(sensor=SensorTiming(link_bytes_per_s=100e6))
    assert slow_link.readout_s == pytest.approx(2448 * 2048 / 100e6)


def test_shorter_exposure_is_noisier_by_the_square_root():
    s = SensorTiming(quantisation_px=0.0)
    ref = CameraMode(exposure_s=s.noise_ref_exposure_s, sensor=s)
    quarter = CameraMode(exposure_s=s.noise_ref_exposure_s / 4, sensor=s)
    assert ref.sigma_px == pytest.approx(s.noise_ref_px)
    assert quarter.sigma_px == pytest.approx(2.0 * s.noise_ref_px)


def test_a_rate_the_mode_cannot_reach_is_refused():
    with pytest.raises(ValueError, match="exceeds the fastest rate"):
        CameraMode(frame_rate_hz=40.0)


# --------------------------------------------------------------------------------------------
# The region of interest in the measurement front end
# --------------------------------------------------------------------------------------------

P = PlantParams()
CENTRE = np.array([(P.camera.sensor_width_px - 1) / 2, (P.camera.sensor_height_px - 1) / 2])


def _front(roi: RegionOfInterest) -> MeasurementFrontEnd:
    return MeasurementFrontEnd(P, MeasurementConfig(sigma_px=0.0, roi=roi),
                               np.random.default_rng(0))


@pytest.mark.parametrize("tilt_deg", [0.0, 2.0, 4.0, 6.0, 8.0])
def test_a_fixed_region_loses_the_markers_exactly_when_they_leave_it(tilt_deg):
    roi = RegionOfInterest(rows=256, cols=1024)
    q = pure_tilt(np.radians(tilt_deg), np.pi / 2)  # towards stator +y: along v
    truth = marker_pixels(P, q)
    off = np.abs(truth - CENTRE)
    outside = bool(np.any(off[:, 0] > 512) or np.any(off[:, 1] > 128))
    cap = _front(roi).capture(q, np.zeros(3), 0.0)
    assert cap.lost == outside
    if outside:
        assert "region of interest" in cap.reason
    else:
        np.testing.assert_allclose(cap.marker_px, truth)


def _ramp(front: MeasurementFrontEnd, tilts_deg) -> list[bool]:
    return [front.capture(pure_tilt(np.radians(t), np.pi / 2), np.zeros(3), 0.0).lost
            for t in tilts_deg]


def test_a_following_region_keeps_steady_motion_and_loses_a_jump_that_outruns_it():
    rows = 256
    tilts = np.linspace(0.0, 10.0, 21)  # about 30 px per frame along v
    v = np.array([marker_pixels(P, pure_tilt(np.radians(t), np.pi / 2))[:, 1].mean()
                  for t in tilts])
    assert np.max(np.abs(np.diff(v))) < rows / 4 and np.ptp(v) > rows  # steady, long travel
    fixed = _ramp(_front(RegionOfInterest(rows=rows, cols=1024)), tilts)
    assert any(fixed)  # the fixed region loses them on the way
    follow = _front(RegionOfInterest(rows=rows, cols=1024, follow=True))
    assert not any(_ramp(follow, tilts))
    # A jump of more than half the region in one frame (back to rest): lost, and the region
    # stays put, so the markers stay lost while they are away from it, and are found again
    # when they return to it.
    last, step, jump = tilts[-1], tilts[1] - tilts[0], 0.0
    dv = (marker_pixels(P, pure_tilt(np.radians(jump), np.pi / 2))[:, 1].mean()
          - (v[-1] + (v[-1] - v[-2])))
    assert abs(dv) > rows / 2
    assert _ramp(follow, [jump, jump]) == [True, True]
    assert _ramp(follow, [last + step]) == [False]


# --------------------------------------------------------------------------------------------
# The region of interest on rendered frames (image mode)
# --------------------------------------------------------------------------------------------


class _Recorded:
    """A stand-in that passes calls through and keeps what went through: the renderer's
    frames, or the images the pair tracker was given."""

    def __init__(self, inner) -> None:
        self.inner, self.seen = inner, []

    def render(self, *args, **kwargs):
        frame = self.inner.render(*args, **kwargs)
        self.seen.append(frame)
        return frame

    def start(self, image, *args):
        self.seen.append(image)
        return self.inner.start(image, *args)

    def step(self, image):
        self.seen.append(image)
        return self.inner.step(image)

    def __getattr__(self, name):
        return getattr(self.inner, name)


def _image_front(roi: RegionOfInterest):
    from latency.frontends import ImageFrontEnd
    from observer.trackers import make_pair_tracker
    from plant.render_analytic import AnalyticRenderer

    renderer = _Recorded(AnalyticRenderer(P, seed=0))
    tracker = _Recorded(make_pair_tracker("kcf_gk", P))
    return ImageFrontEnd(P, renderer, tracker, roi=roi), renderer, tracker


def _lost_in_loop(cap) -> bool:
    """The loop's verdict on a frame: the front end's, or a centre more than the loop's
    loss threshold (20 px, seed 000 §4.2) from the truth."""
    from latency.loop_config import LoopConfig

    err = np.linalg.norm(cap.marker_px - cap.true_px, axis=1)
    threshold = LoopConfig.model_fields["loss_threshold_px"].default
    return bool(cap.lost or not np.all(err <= threshold))


def _boxes_inside(boxes: np.ndarray, centre: np.ndarray, roi: RegionOfInterest) -> np.ndarray:
    """Per marker: its projected disc (box x, y, w, h, sensor px) lies wholly in the region
    centred on ``centre``."""
    half = 0.5 * np.array([roi.cols, roi.rows])
    return np.all((boxes[:, :2] >= centre - half) & (boxes[:, :2] + boxes[:, 2:] <= centre + half),
                  axis=1)


def _boxes_outside(boxes: np.ndarray, centre: np.ndarray, roi: RegionOfInterest) -> np.ndarray:
    """Per marker: its projected disc lies wholly outside the region centred on ``centre``."""
    half = 0.5 * np.array([roi.cols, roi.rows])
    return np.any((boxes[:, :2] > centre + half) | (boxes[:, :2] + boxes[:, 2:] < centre - half),
                  axis=1)


def test_a_fixed_region_on_rendered_frames_is_all_the_tracker_sees_and_loses_markers_left_out():
    """A 320-row region at the sensor centre, markers moved along v by about 27 px per frame
    to 13° of tilt and back: the tracker's image is the rendered frame inside the region and
    blank outside it; a frame whose projected discs lie wholly inside the region is measured,
    one with a disc wholly outside it is lost."""
    from plant.camera import image_to_sensor

    roi = RegionOfInterest(rows=320, cols=1024)
    front, renderer, tracker = _image_front(roi)
    tilts = [*np.arange(0.0, 13.5, 1.0), 0.0]
    caps = [front.capture(pure_tilt(np.radians(t), np.pi / 2), np.zeros(3), 0.0) for t in tilts]
    inside = [_boxes_inside(f.boxes_px, CENTRE, roi).all() for f in renderer.seen]
    outside = [_boxes_outside(f.boxes_px, CENTRE, roi).any() for f in renderer.seen]
    assert sum(inside) >= 4 and sum(outside) >= 3  # both cases occur
    for cap, i, o in zip(caps, inside, outside, strict=True):
        if i:
            assert not _lost_in_loop(cap)
        if o:
            assert _lost_in_loop(cap)
    # The pixels the tracker saw: binned pixels whose centre is in the region, nothing else.
    frame, image = renderer.seen[5], tracker.seen[5]
    h, w = frame.image.shape[:2]
    u = image_to_sensor(np.arange(w), frame.binning)
    v = image_to_sensor(np.arange(h), frame.binning)
    read = ((np.abs(v - CENTRE[1]) <= roi.rows / 2)[:, None]
            & (np.abs(u - CENTRE[0]) <= roi.cols / 2)[None, :])
    assert 0 < read.sum() < read.size
    np.testing.assert_array_equal(image[read], frame.image[read])
    assert not image[~read].any()


def test_a_following_region_on_rendered_frames_keeps_a_steady_ramp_and_loses_a_jump():
    """The same ramp with the region following the prediction: every frame measured, though
    a region fixed at the centre would lose the markers; then a jump back to rest of more
    than half the region in one frame: the region, placed on the constant-velocity
    prediction of the true centres, holds neither disc, so the markers are lost, and the
    region stays put until the markers come back into it."""
    roi = RegionOfInterest(rows=320, cols=1024, follow=True)
    front, renderer, _ = _image_front(roi)
    ramp = np.arange(0.0, 10.5, 1.0)

    def capture(tilt: float):
        return front.capture(pure_tilt(np.radians(tilt), np.pi / 2), np.zeros(3), 0.0)

    assert not any(_lost_in_loop(capture(t)) for t in ramp)
    truth = np.array([f.marker_px for f in renderer.seen])
    assert any(_boxes_outside(f.boxes_px, CENTRE, roi).any() for f in renderer.seen)
    predicted = (2 * truth[-1] - truth[-2]).mean(axis=0)  # where the region goes next
    jump = capture(0.0)
    assert _boxes_outside(renderer.seen[-1].boxes_px, predicted, roi).all()
    assert _lost_in_loop(jump)
    np.testing.assert_allclose(front.last_roi_centre_px, predicted, atol=2.0)
    assert _lost_in_loop(capture(0.0))  # still away from the region, which stays put
    np.testing.assert_allclose(front.last_roi_centre_px, predicted, atol=2.0)
    back = capture(ramp[-1] + 1.0)  # into the region again
    assert _boxes_inside(renderer.seen[-1].boxes_px, front.last_roi_centre_px, roi).all()
    assert not _lost_in_loop(back)


# --------------------------------------------------------------------------------------------
# Search, pruning and resume on small specs
# --------------------------------------------------------------------------------------------


def _tiny(**extra) -> CodesignSpec:
    base = {"duration_s": 0.4, "seeds": [0], "references": [{"kind": "tilt_step", "tilt_deg": 2.0,
                                                              "t_step_s": 0.05}],
            "trackers": ["kcf_gk"], "camera": {"rows": [2048], "cols": [2448], "binning": [1],
                                               "exposure_s": 0.002},
            "observer": {"pipeline": ["sequential"], "kind": ["solver"]},
            "controller": {"crossover_rad_s": [4.0, 12.0], "zero_ratio": 3.0,
                           "integral_ratio": 10.0},
            "constraints": {"min_phase_margin_deg": 0.0, "min_delay_headroom_ms": 0.0},
            "search": {"n_trials": 2, "batch_size": 1}, "image_check": {"enabled": False}}
    base.update(extra)
    return CodesignSpec.model_validate(base)


def test_the_study_resumes_from_sqlite_and_reruns_an_interrupted_design(tmp_path):
    spec = _tiny()
    run_search(spec, tmp_path, progress=False)
    first = {t.number: t.params for t in open_study(spec, storage_url(spec, tmp_path)).trials}
    n_run_files = len(list((tmp_path / "runs").glob("*.parquet")))
    assert len(first) == 2 and n_run_files == 2
    # An interrupted run: a trial asked but never told.
    study = open_study(spec, storage_url(spec, tmp_path))
    orphan = study.ask()
    orphan_x = orphan.suggest_float("crossover_rad_s", 4.0, 12.0, log=True)
    more = spec.model_copy(update={"search": spec.search.model_copy(update={"n_trials": 3})})
    run_search(more, tmp_path, progress=False)
    trials = open_study(more, storage_url(more, tmp_path)).trials
    assert {t.number: t.params for t in trials[:2]} == first  # finished trials kept
    assert trials[orphan.number].state.name == "FAIL"
    done = [t for t in trials if t.state.name in ("COMPLETE", "PRUNED")]
    assert len(done) == 3
    assert done[-1].params == {"crossover_rad_s": orphan_x}  # the interrupted design, again


def _linear_growth_rate_per_s(spec: CodesignSpec, design: Design) -> float:
    """The growth rate of the design's linear sampled loop measured in the time domain: the
    closed loop's state iterated from an arbitrary start, the slope of log |x| against time
    over its last 400 updates (independent of the analysis' eigenvalues)."""
    import control as ct

    from controller.pid import PIDConfig, PIDController
    from latency.margins import attitude_plant, sampled_loop

    a = analyse(spec, design)  # its update period and loop delay only
    pid = PIDController(PIDConfig(crossover_rad_s=design.crossover_rad_s,
                                  zero_ratio=design.zero_ratio,
                                  integral_ratio=design.integral_ratio), spec.plant)
    C = pid.discrete_transfer_function(a.update_period_s, axis=1)
    plant = attitude_plant(float(pid.J[1]), spec.plant.rotor.viscous_Nms_per_rad)
    A = np.asarray(ct.feedback(sampled_loop(plant, C, delay_s=a.delay_s), 1).A)
    x, log_norm = np.ones(A.shape[0]), np.zeros(800)
    for k in range(800):
        x = A @ x
        log_norm[k] = np.log(np.linalg.norm(x))
        x /= np.linalg.norm(x)
    t = np.arange(800) * a.update_period_s
    return float(np.polyfit(t[400:], np.cumsum(log_norm)[400:], 1)[0])


@pytest.mark.parametrize("crossover", [8.0, 17.0, 24.0])
def test_the_growth_rate_is_the_linear_loops_measured_growth(crossover):
    spec = _tiny()
    d = Design(frame_rate_hz=36.0, tracker="kcf_gk", observer="solver", crossover_rad_s=crossover)
    a = analyse(spec, d)
    assert a.growth_rate_per_s == pytest.approx(_linear_growth_rate_per_s(spec, d), rel=1e-2)
    assert a.stable == (a.growth_rate_per_s < 0.0)


def test_only_designs_growing_beyond_the_band_skip_the_monte_carlo(tmp_path):
    """KCF on the whole sensor: at 12 rad/s stable with 14° of margin, at 17 rad/s unstable
    but growing at 0.56/s, at 24 rad/s growing at 4.2/s. All three fail the 30° requirement
    and are infeasible; only the last grows faster than the default band (2/s) and is pruned:
    the other two get their Monte Carlo."""
    spec = _tiny(constraints={})
    designs = [Design(frame_rate_hz=36.0, tracker="kcf_gk", observer="solver",
                      crossover_rad_s=x) for x in (12.0, 17.0, 24.0)]
    growth = [_linear_growth_rate_per_s(spec, d) for d in designs]
    limit = spec.search.prune_growth_rate_per_s
    assert growth[0] < 0.0 < growth[1] < limit < growth[2]
    records = evaluate_designs(spec, designs, tmp_path)
    assert [r["pruned"] for r in records] == [False, False, True]
    assert [r["mc"] is None for r in records] == [False, False, True]
    assert not any(r["feasible"] for r in records)  # the analysis constraints still apply
    never = _tiny(search={"prune_growth_rate_per_s": None})
    assert not any(analyse(never, d).prunable(never) for d in designs)


def test_the_sampler_sees_only_designs_meeting_the_analysis_but_all_unpruned_run(tmp_path):
    """KCF at 4 rad/s (48° of margin) and at 12 rad/s (14°, under the 30° requirement, stable):
    both run their Monte Carlo; optuna holds the first as complete and the second as pruned,
    so that the sampler's populations meet the requirements; the records keep both results."""
    spec = _tiny(constraints={})
    study = open_study(spec, storage_url(spec, tmp_path))
    for x in (4.0, 12.0):
        study.enqueue_trial({"crossover_rad_s": x})
    run_search(spec, tmp_path, progress=False)
    states = {t.params["crossover_rad_s"]: t.state.name
              for t in open_study(spec, storage_url(spec, tmp_path)).trials}
    assert states == {4.0: "COMPLETE", 12.0: "PRUNED"}
    records = {r["design"]["crossover_rad_s"]: r for r in trial_records(study)}
    for x in (4.0, 12.0):
        assert not records[x]["pruned"] and records[x]["mc"] is not None
        assert len(records[x]["objectives"]) == 3
    assert records[4.0]["feasible"] and not records[12.0]["feasible"]


def _crossover_where(spec: CodesignSpec, tracker: str, growth_per_s: float) -> float:
    """The PID crossover (rad/s, 4 to 40) at which the design's analysed growth rate reaches
    ``growth_per_s`` (bisection to 1e-3 rad/s; the growth rises with the crossover past the
    stability boundary)."""
    def g(x: float) -> float:
        d = Design(frame_rate_hz=36.0, tracker=tracker, observer="solver", crossover_rad_s=x)
        return analyse(spec, d).growth_rate_per_s

    lo, hi = 4.0, 40.0
    assert g(lo) < growth_per_s < g(hi)
    while hi - lo > 1e-3:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if g(mid) < growth_per_s else (lo, mid)
    return hi


@pytest.mark.slow
def test_pruning_by_analysis_never_removes_a_design_monte_carlo_accepts(tmp_path):
    """On the default plant (3 mN·m Coulomb friction), a grid of PID crossovers every 1 rad/s
    from 4 to 24 rad/s for KCF, GK-TransT and CSRT latencies (whole sensor, least squares),
    with each tracker's stability boundary and pruning boundary added just beyond them: every
    design the analysis prunes fails the Monte-Carlo constraints (3 s runs of a 5° step and a
    random reference, two seeds)."""
    trackers = ("kcf_gk", "gk_transt", "csrt_gk")
    spec = _tiny(duration_s=3.0, seeds=[0, 1], trackers=list(trackers), constraints={},
                 references=[{"kind": "tilt_step", "tilt_deg": 5.0},
                             {"kind": "random", "args": {"max_rate_rad_s": 1.0}}])
    limit = spec.search.prune_growth_rate_per_s
    grid = []
    for tr in trackers:
        edges = [_crossover_where(spec, tr, g) for g in (0.0, limit)]
        grid += [Design(frame_rate_hz=36.0, tracker=tr, observer="solver", crossover_rad_s=x)
                 for x in sorted({*np.arange(4.0, 24.5, 1.0), *edges})]
    analyses = [analyse(spec, d) for d in grid]
    pruned = [d for d, a in zip(grid, analyses, strict=True) if a.prunable(spec)]
    unstable_kept = [d for d, a in zip(grid, analyses, strict=True)
                     if not a.stable and not a.prunable(spec)]
    assert pruned and unstable_kept  # the grid straddles both boundaries
    assert all(not a.meets(spec) for a in analyses if not a.stable)
    for d, mc in zip(pruned, monte_carlo(spec, pruned, tmp_path), strict=True):
        assert not mc_feasible(spec, mc), (d.label(), mc)


@pytest.mark.slow
def test_the_search_beats_the_seeds_design_with_the_constraints_met(tmp_path):
    """The seed's loop (the whole sensor read out in 27.8 ms, 45 ms of delay) leaves 8° of
    phase margin at its 10 rad/s; a region of interest read in 7 ms and a pipelined tracker
    let a crossover at least as high keep 30°. The search must find such a design: feasible
    and with a smaller mean error than the seed's."""
    spec = CodesignSpec.model_validate({
        "duration_s": 1.0, "seeds": [0, 1],
        "references": [{"kind": "tilt_step", "tilt_deg": 3.0, "t_step_s": 0.05}],
        "trackers": ["gk_transt"],
        "camera": {"rows": [2048, 512], "cols": [2448, 1024], "follow": [True],
                   "binning": [1], "exposure_s": 0.002},
        "observer": {"pipeline": ["sequential", "pipelined"], "kind": ["pixel_kalman"],
                     "q_scale": 0.01, "r_scale": 0.1},
        "controller": {"crossover_rad_s": [10.0, 13.0], "zero_ratio": 3.0,
                       "integral_ratio": 10.0},
        "search": {"n_trials": 8, "batch_size": 4, "sampler": "tpe"},
        "image_check": {"enabled": False}})
    study = run_search(spec, tmp_path, progress=False)
    result = write_report(spec, trial_records(study), tmp_path)
    df = designs_table(trial_records(study))
    best = recommended(df)
    assert best is not None and best.feasible
    c = spec.constraints
    assert best.phase_margin_deg >= c.min_phase_margin_deg
    assert best.headroom_ms >= c.min_delay_headroom_ms
    assert best.p_loss_of_control <= c.max_loss_of_control
    assert best.lost_frame_fraction <= c.max_lost_frames
    seed = result["seed"]
    assert best.rms_error_deg < seed["rms_error_deg"]
    assert (tmp_path / "report.md").is_file() and (tmp_path / "pareto.png").is_file()
    assert math.isfinite(seed["phase_margin_deg"])


def test_the_seeds_design_is_the_seeds_settings():
    d = seed_design()
    spec = CodesignSpec()
    mode = d.camera_mode(spec)
    assert mode.rate_hz == 36.0 and mode.roi is None and mode.exposure_s == 2e-3
    assert (d.tracker, d.pipeline, d.observer, d.q_scale, d.r_scale) == (
        "gk_transt", "sequential", "pixel_kalman", 0.01, 0.1)
    assert (d.controller, d.crossover_rad_s) == ("pid", 10.0)


def test_non_dominated_keeps_the_feasible_designs_no_other_beats_on_all_objectives():
    import pandas as pd

    from experiments.codesign.report import non_dominated

    df = pd.DataFrame({
        "rms_error_deg": [1.0, 2.0, 1.5, 0.5, 1.0],
        "rms_torque_Nm": [0.01, 0.005, 0.02, 0.001, 0.01],
        "compute_ms": [16.0, 16.0, 16.0, 10.0, 11.0],
        "feasible": [True, True, True, False, True],
    })
    # Row 2 is beaten by row 0 on error and effort at equal compute; row 0 by row 4 on compute
    # alone; row 3 beats everything but is infeasible and so is not on the front.
    assert non_dominated(df).tolist() == [False, True, False, False, True]


def test_the_spec_takes_a_users_motor_and_camera_files_and_a_measured_profile(tmp_path):
    from latency.models import Empirical
    from plant.camera_file import CameraFile

    examples = Path(__file__).resolve().parents[1] / "examples"
    profile = tmp_path / "latency.json"
    Empirical.from_measurements([0.020, 0.024], source="a tracker measured here").save(profile)
    spec = CodesignSpec.model_validate({
        "motor_file": str(examples / "motor.yaml"), "camera_file": str(examples / "camera.yaml"),
        "trackers": ["mine"], "tracker_models": {"mine": {"latency_file": str(profile)}}})
    assert spec.plant.camera == CameraFile.from_yaml(examples / "camera.yaml").camera
    assert spec.tracker_models["mine"].latency_model().mean_s == pytest.approx(0.022)
    assert "gk_transt" in spec.tracker_models  # the seed's catalogue is kept


def test_monte_carlo_constraints_on_the_means_or_on_the_upper_ends():
    mc = {"p_loss_of_control": 0.0, "p_loss_of_control_hi": 0.32,
          "lost_frame_fraction": 0.004, "lost_frame_fraction_hi": 0.008}
    on_means = _tiny()
    assert mc_feasible(on_means, mc)
    upper = _tiny(constraints={"bound": "upper"})
    assert not mc_feasible(upper, mc)  # 0.32 > 0.001
    assert mc_feasible(upper, mc | {"p_loss_of_control_hi": 0.0005})
    assert not mc_feasible(on_means, mc | {"lost_frame_fraction": float("nan")})


# --------------------------------------------------------------------------------------------
# The tracker catalogue and the image-in-the-loop re-run
# --------------------------------------------------------------------------------------------


def test_noise_scales_are_clean_centre_errors_relative_to_gk_transt(tmp_path):
    import pandas as pd

    from experiments.codesign.catalogue import noise_scales

    rows = [  # tracker, case, main / aux median centre error (sensor px)
        ("gk_transt", "clean", 0.1, 0.3), ("gk_transt", "clean", 0.2, 0.2),
        ("dual_transt", "clean", 4.0, 4.0), ("dual_transt", "clean", 3.0, 5.0),
        ("dual_transt", "occlusion", 1e9, 1e9),  # a lost track: not an accuracy figure
        ("gk_transt", "blur", 9.0, 9.0),
    ]
    csv = tmp_path / "tracking_metrics.csv"
    pd.DataFrame(rows, columns=["tracker", "case", "main_err_median_px",
                                "aux_err_median_px"]).to_csv(csv, index=False)
    # GK-TransT's mean median error 0.2 px, dual TransT's 4 px: 20 times noisier.
    assert noise_scales(csv) == pytest.approx({"gk_transt": 1.0, "dual_transt": 20.0})


def test_a_measured_latency_is_one_over_the_benchmarks_fps(tmp_path):
    import json

    from experiments.codesign.catalogue import measured_latency_s

    path = tmp_path / "bench.json"
    path.write_text(json.dumps({"k2cf_fps": 500.0}))
    assert measured_latency_s("k2cf", path) == pytest.approx(2e-3)
    with pytest.raises(ValueError, match="kcf_fps"):
        measured_latency_s("kcf", path)


def test_re_detection_takes_the_lost_frame_plus_the_slower_markers_reacquisition(tmp_path):
    import json

    from experiments.codesign.catalogue import reacquire_after_frames

    path = tmp_path / "bench.json"
    path.write_text(json.dumps({
        "gk_occlusion_main_reacquire_frames": 1.0, "gk_occlusion_aux_reacquire_frames": 0.0,
        "k2_occlusion_main_reacquire_frames": 0.0, "k2_occlusion_aux_reacquire_frames": 0.0,
        "box_occlusion_main_reacquire_frames": float("inf"),
        "box_occlusion_aux_reacquire_frames": 0.5}))
    assert reacquire_after_frames("gk", path) == 2
    assert reacquire_after_frames("k2", path) == 1
    assert reacquire_after_frames("box", path) is None  # never re-acquired
    with pytest.raises(ValueError, match="kcf_occlusion"):
        reacquire_after_frames("kcf", path)


def test_a_tracker_that_never_re_detects_keeps_a_lost_marker_lost_for_the_run():
    from experiments.codesign.space import scenario_dict

    spec = _tiny(tracker_models={"lost": {"latency": {"kind": "constant", "value_s": 0.01},
                                          "reacquire_after_frames": None}})
    design = Design(frame_rate_hz=36.0, tracker="lost", observer="solver")
    frames_in_run = spec.duration_s * 36.0
    assert scenario_dict(spec, design, 0, 0)["measurement"]["loss"]["reacquire_after_frames"] > (
        frames_in_run)


def test_the_catalogue_reads_the_seeds_latencies_and_the_tracking_benchmark():
    import json

    from experiments.codesign.catalogue import BENCH_JSON, noise_scales, reacquire_after_frames

    models = CodesignSpec().tracker_models
    assert set(models) == {"gk_transt", "dual_transt", "kcf_gk", "csrt_gk", "k2cf"}
    latency_ms = {k: 1e3 * m.latency_model().mean_s for k, m in models.items()}
    # Seed 000 Table 1 where the seed timed the tracker.
    assert latency_ms["gk_transt"] == pytest.approx(16.33)
    assert latency_ms["dual_transt"] == pytest.approx(31.23)
    assert latency_ms["kcf_gk"] == pytest.approx(10.86)
    assert latency_ms["csrt_gk"] == pytest.approx(67.62)
    # K²CF: the benchmark's FPS is 1 / its mean latency.
    fps = json.loads(BENCH_JSON.read_text())["k2cf_fps"]
    assert latency_ms["k2cf"] == pytest.approx(1e3 / fps)
    # Accuracy: the GK sub-pixel centre is the reference; the others from their own rows.
    scales = noise_scales()
    for name in ("gk_transt", "kcf_gk", "csrt_gk"):
        assert models[name].noise_scale == 1.0
    assert models["dual_transt"].noise_scale == pytest.approx(scales["dual_transt"])
    assert models["k2cf"].noise_scale == pytest.approx(scales["k2cf"])
    # Box centres are several px off, K²CF's sub-pixel peak a fraction of a px
    # (docs/tracking.md): both noisier than the GK fit, the box centres by far.
    assert 1.0 < models["k2cf"].noise_scale < 5.0 < models["dual_transt"].noise_scale
    # Re-detection: the GK assistance's (GK-TransT's row) for the three GK trackers.
    for name, row in (("gk_transt", "gk_transt"), ("kcf_gk", "gk_transt"),
                      ("csrt_gk", "gk_transt"), ("dual_transt", "dual_transt"), ("k2cf", "k2cf")):
        assert models[name].reacquire_after_frames == reacquire_after_frames(row)


def test_the_image_check_runs_each_catalogue_tracker_that_scenarios_render():
    from experiments.codesign.report import image_check, image_scenarios


    # a user's tracker without an image implementation (image_tracker None) is skipped
    mine = {"latency": {"kind": "constant", "value_s": 0.01}, "image_tracker": None}
    spec = _tiny(image_check={"seeds": [0, 1]}, tracker_models={"mine": mine})
    expected = {"gk_transt": "gk_transt", "dual_transt": "dual_transt", "kcf_gk": "kcf_gk",
                "csrt_gk": "csrt_gk", "k2cf": "k2cf", "mine": None}
    assert set(spec.tracker_models) == set(expected)
    for name, scenario_tracker in expected.items():
        design = Design(frame_rate_hz=36.0, tracker=name, observer="solver")
        if scenario_tracker is None:
            with pytest.raises(ValueError, match="no image-in-the-loop"):
                image_scenarios(spec, design)
            assert "skipped" in image_check(spec, design, {})
            continue
        runs = image_scenarios(spec, design)
        assert len(runs) == 2  # seeds x references
        for s in runs:
            assert (s.mode, s.tracker, s.measurement.roi) == ("image", scenario_tracker, None)


def test_the_image_check_runs_the_designs_camera_mode_region_and_timing():
    """A 512 × 1024 region following the markers: the image runs read it (the loop's image
    front end gets it) at the mode's rate, (512 + 16 blank rows) line times per frame."""
    from experiments.codesign.report import image_scenarios
    from latency import Scenario, build_loop

    spec = _tiny(image_check={"seeds": [0]})
    design = Design(rows=512, cols=1024, follow=True, tracker="kcf_gk", observer="solver")
    (s,) = image_scenarios(spec, design)
    readout = (512 + 16) * 13.45e-6
    assert s.measurement.roi == RegionOfInterest(rows=512, cols=1024, follow=True)
    assert s.pipeline.readout_s == pytest.approx(readout)
    assert s.plant.camera.frame_rate_hz == pytest.approx(1.0 / readout)
    assert build_loop(s).front_end.roi == s.measurement.roi
    with pytest.raises(ValueError, match="ORB front end reads the whole sensor"):
        Scenario.model_validate({"mode": "image", "observer": {"kind": "orb_aekf"},
                                 "measurement": {"roi": {"rows": 512, "cols": 1024}}})


@pytest.mark.slow
def test_the_image_check_re_runs_a_dual_transt_design_on_rendered_frames():
    """Both TransT networks on the analytic renderer's frames (no GK assistance): on a 2° step
    the markers stay tracked (the tracking benchmark's dual TransT keeps precision 1.0 on
    clean frames) and the loop stays in control."""
    from experiments.codesign.report import image_check
    from observer.transt.weights import SMALL_WEIGHTS

    if not SMALL_WEIGHTS.exists():
        pytest.skip("the TransT weights are not shipped in this checkout")
    spec = _tiny(trackers=["dual_transt"], image_check={"seeds": [0], "duration_s": 0.4})
    design = Design(frame_rate_hz=36.0, tracker="dual_transt", observer="solver")
    check = image_check(spec, design, {})
    assert check["tracker"] == "dual_transt"
    assert (check["n_runs"], check["n_failed"]) == (1, 0)
    assert check["lost_frame_fraction"] == 0.0 and check["p_loss_of_control"] == 0.0
    assert math.isfinite(check["rms_error_deg"])
