"""Tests of the paper reproduction (seed 000 §5): the steady-state extraction on
synthetic signals with hand-computed answers, the rotary table against SeedSteps and finite
differences, a shortened step test against ground truth, and the structure of the tables."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from controller.reference import SeedSteps
from experiments import reproduction as rp
from observer.cor_model import CorModel
from observer.crb import crb_camera
from plant import attitude
from plant.params import PlantParams

DEG = math.pi / 180.0


# ------------------------------------------------------------------------------------------------
# Steady-state windows and RMSE on synthetic data
# ------------------------------------------------------------------------------------------------
def test_settling_offset_is_excluded_and_rmse_matches_hand_computation() -> None:
    """Two 180-frame dwells. Dwell 0: the first 30 frames read +5° off, the rest +0.1° off.
    A 90-frame window holding m of the +5° frames has std 4.9° sqrt(p(1 − p)), p = m/90, which is
    below 0.3° only for m = 0, so the steady frames are exactly frames 30–179. Dwell 1 reads −0.2°
    off throughout. Frames between the dwells (id −1) are never used.
    RMSE = sqrt((150·0.1² + 180·0.2²)/330)."""
    ref = np.r_[np.full(180, 10.0), np.full(20, 15.0), np.full(180, 20.0)] * DEG
    dwell = np.r_[np.zeros(180, int), -np.ones(20, int), np.ones(180, int)]
    meas = ref.copy()
    meas[:30] += 5.0 * DEG
    meas[30:180] += 0.1 * DEG
    meas[180:200] += 3.0 * DEG  # the move: far off, but outside the dwells
    meas[200:] -= 0.2 * DEG
    ss = rp.steady_state_rmse(meas, ref, dwell)
    expected_mask = np.r_[np.zeros(30, bool), np.ones(150, bool), np.zeros(20, bool),
                          np.ones(180, bool)]
    np.testing.assert_array_equal(ss.mask, expected_mask)
    hand = math.sqrt((150 * 0.1**2 + 180 * 0.2**2) / 330) * DEG
    assert ss.rmse_rad == pytest.approx(hand, rel=1e-12)
    assert ss.rmse_deg == pytest.approx(math.degrees(hand), rel=1e-12)
    assert ss.n_frames == 330 and ss.n_dwells == 2 and ss.dwells_without_steady == ()


@pytest.mark.parametrize(("slope_deg", "steady"), [(0.0115, True), (0.0116, False)])
def test_std_is_the_population_std_below_the_threshold(slope_deg: float, steady: bool) -> None:
    """A ramp of a per frame has, over 90 frames, population std a·sqrt((90² − 1)/12) = 25.98 a
    (sample std, ddof = 1: a·sqrt(90·91/12) = 26.12 a). a = 0.0115° gives 0.2988° (< 0.3°:
    every window steady) but 0.3004° with ddof = 1; a = 0.0116° gives 0.3014° (none steady)."""
    assert 0.0115 * math.sqrt((90**2 - 1) / 12) < 0.3 < 0.0115 * math.sqrt(90 * 91 / 12)
    assert 0.0116 * math.sqrt((90**2 - 1) / 12) > 0.3
    x = slope_deg * np.arange(180) * DEG
    mask = rp.steady_state_mask(x, np.zeros(180, int))
    assert mask.all() if steady else not mask.any()


def test_windows_must_fit_in_one_dwell_and_skip_invalid_frames() -> None:
    """A NaN at frame 100 of a 180-frame dwell: windows [s, s + 90) avoiding it start at s ≤ 10,
    so frames 0–99 are steady and 100–179 are not. An 89-frame dwell has no window at all. The
    same id on two separate runs of frames counts as two dwells' worth of windows."""
    x = np.zeros(180)
    x[100] = np.nan
    m = rp.steady_state_mask(x, np.zeros(180, int))
    np.testing.assert_array_equal(m, np.arange(180) < 100)
    short = rp.steady_state_rmse(np.zeros(89), np.zeros(89), np.zeros(89, int))
    assert short.n_frames == 0 and math.isnan(short.rmse_rad)
    assert short.dwells_without_steady == (0,)
    # id 0, then a move (-1), then id 0 again, 60 frames each: no run reaches 90 frames.
    d = np.r_[np.zeros(60, int), -np.ones(5, int), np.zeros(60, int)]
    assert not rp.steady_state_mask(np.zeros(125), d).any()
    with pytest.raises(ValueError, match="differ"):
        rp.steady_state_mask(np.zeros(3), np.zeros(4, int))


def test_custom_window_and_threshold() -> None:
    """A 10-frame window with a 1° threshold: alternating ±1° has std 1° (not < 1°), ±0.9° has
    std 0.9° (steady)."""
    sign = np.where(np.arange(20) % 2, 1.0, -1.0)
    d = np.zeros(20, int)
    assert not rp.steady_state_mask(sign * DEG, d, 10, 1.0 * DEG).any()
    assert rp.steady_state_mask(0.9 * sign * DEG, d, 10, 1.0 * DEG).all()


# ------------------------------------------------------------------------------------------------
# The rotary table
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("axis", rp.AXES)
def test_table_dwells_hold_the_seed_steps_attitudes(axis: str) -> None:
    """Each dwell holds ``SeedSteps.attitude_of`` of its value; the dwell ids follow the
    timeline rest, (move, dwell) × n."""
    table = rp.make_table(axis, dwell_s=5.0, move_s=1.0, rest_s=2.0)
    steps = SeedSteps(axis=axis)
    vals = steps.values()
    assert table.duration_s == pytest.approx(2.0 + 6.0 * len(vals))
    for k, v in enumerate(vals):
        for t in (table.dwell_start_s(k), table.dwell_start_s(k) + 4.99):
            s = table.sample(t)
            assert attitude.geodesic_angle(s.q, steps.attitude_of(v)) < 1e-12
            assert np.allclose(s.omega, 0.0) and table.value(t)[0] == pytest.approx(v * DEG)
        assert table.dwell_id([table.dwell_start_s(k) + 2.0])[0] == k
        assert table.dwell_id([table.dwell_start_s(k) - 0.5])[0] == -1  # moving
    assert table.dwell_id([1.0, table.duration_s + 0.1]).tolist() == [-1, -1]
    ts = table.frame_times(36.0)
    assert len(ts) == round(table.duration_s * 36) and np.sum(table.dwell_id(ts) == 0) == 180


@pytest.mark.parametrize("axis", rp.AXES)
def test_table_rates_match_finite_differences_of_the_attitude(axis: str) -> None:
    """During a move the body rate is 2 Im(q* ⊗ dq/dt) (central differences, independent of the
    Z-Y-Z chain rule), and the body acceleration the difference of the rates."""
    table = rp.make_table(axis)
    h = 1e-5
    for t in (table.dwell_start_s(1) - 0.7, table.dwell_start_s(2) - 0.25):
        s = table.sample(t)
        dq = (table.sample(t + h).q - table.sample(t - h).q) / (2 * h)
        w = 2.0 * attitude.multiply(attitude.conjugate(s.q), dq)[1:]
        np.testing.assert_allclose(s.omega, w, atol=1e-8)
        dw = (table.sample(t + h).omega - table.sample(t - h).omega) / (2 * h)
        np.testing.assert_allclose(s.alpha, dw, atol=1e-6)
        assert np.linalg.norm(s.omega) > 0.01
    if axis == "yaw":  # the rotary table turns about the stator Z axis (seed 000 §5.3)
        s = table.sample(table.dwell_start_s(1) - 0.5)
        w_stator = attitude.to_matrix(s.q) @ s.omega
        np.testing.assert_allclose(w_stator[:2], 0.0, atol=1e-12)


def test_table_rejects_bad_timing() -> None:
    with pytest.raises(ValueError, match="move_s"):
        rp.RotaryTable(SeedSteps(axis="spin"), move_s=-1.0)
    with pytest.raises(ValueError, match="rest_s"):
        rp.RotaryTable(SeedSteps(axis="spin"), rest_s=math.nan)
    with pytest.raises(ValueError, match="window_frames"):
        rp.ReproductionConfig(dwell_s=2.0)


# ------------------------------------------------------------------------------------------------
# Angles
# ------------------------------------------------------------------------------------------------
def test_measured_angles_on_the_seed_benches() -> None:
    """Spin at zero tilt → the turn about Z; tilt → β; yaw at 15° tilt on the table → γ;
    NaN rows stay NaN; unwrapping lands on the reference's 2π branch."""
    q_spin = attitude.from_zyz(0.3, 0.0, 0.0)
    q_tilt = attitude.from_zyz(0.0, 0.2, 0.0)
    q_yaw = attitude.from_zyz(0.0, 15 * DEG, 1.2)
    assert rp.measured_angle("spin", q_spin)[0] == pytest.approx(0.3)
    assert rp.measured_angle("tilt", q_tilt)[0] == pytest.approx(0.2)
    assert rp.measured_angle("yaw", q_yaw)[0] == pytest.approx(1.2)
    assert np.isnan(rp.measured_angle("yaw", np.full((2, 4), np.nan))).all()
    ref = np.array([0.0, 0.0, 0.1, 0.2])
    meas = np.array([2 * math.pi - 0.01, 0.005, 0.1, 0.2])  # noise across 0 = 2π
    np.testing.assert_allclose(rp.unwrap_to_reference(meas, ref), [-0.01, 0.005, 0.1, 0.2],
                               atol=1e-12)


def test_crb_of_the_spin_at_zero_tilt_is_the_about_boresight_bound() -> None:
    """At β = 0 the spin (turn about Z) error is the camera-frame z component of the error, so
    its bound is sqrt(crb_camera[2, 2]); the tilt's mean square is the cross-boresight trace."""
    p = PlantParams()
    model = CorModel.nominal(p)
    q = attitude.from_zyz(0.4, 0.0, 0.0)
    c = crb_camera(model, q, 0.5)
    assert rp.crb_angle_rms_rad("spin", [q], 0.5, p) == pytest.approx(math.sqrt(c[2, 2]),
                                                                      rel=1e-5)
    assert rp.crb_angle_rms_rad("tilt", [q], 0.5, p) == pytest.approx(
        math.sqrt(c[0, 0] + c[1, 1]), rel=1e-12)


# ------------------------------------------------------------------------------------------------
# A shortened step test against ground truth: rendered, tracked and solved end to end (9 s of
# frames, about 15 s of CPU), so in the slow lane
# ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def short_spin() -> rp.StepTestResult:
    """Spin 0 → 10°, 3 s dwells, 0.5 s move, 2 s rest (9 s, 324 frames), analytic renderer with
    2 DN read noise, KCF + GK assistance; MEMS with one noise seed."""
    cfg = rp.ReproductionConfig(renderer="analytic", tracker="kcf_gk", spin_values_deg=(0, 10),
                                dwell_s=3.0, move_s=0.5, rest_s=2.0, mems_seeds=(0,))
    return rp.run_step_test("spin", cfg)


@pytest.mark.slow
def test_short_step_test_rmse_against_ground_truth(short_spin: rp.StepTestResult) -> None:
    """Camera spin RMSE, recomputed from the true attitudes, within a bound from the measured
    marker errors.

    At zero tilt a turn about Z moves the two markers by ±(D/2) perpendicular to their
    separation D (sensor px), so a marker error e_r, e_y changes the turn by
    (e_y − e_r)·n⊥/D; hence |error| ≤ (|e_r| + |e_y|)/D per frame. The closed form takes exactly
    that azimuth; the least squares solves the linearised problem, whose turn about Z is the same
    expression (tilt absorbs the common-mode shift), so we allow 20 % for the linearisation.
    Absolute bound: the analytic renderer draws disc centroids within 0.03 px and the circle
    fit stays within 0.5 px at 2 DN noise, so the error stays below 2·0.5/D ≈ 0.084°."""
    r = short_spin
    cam = r.camera
    assert cam is not None and cam.tracker_name == "kcf_gk" and not cam.lost.any()
    assert cam.red_refined.mean() > 0.9  # the solvers see the sub-pixel circle fit
    e = cam.marker_px - cam.marker_true_px
    D = np.linalg.norm(cam.marker_true_px[:, 1] - cam.marker_true_px[:, 0], axis=1)
    per_frame_bound = (np.linalg.norm(e[:, 0], axis=1) + np.linalg.norm(e[:, 1], axis=1)) / D
    psi_true = rp.measured_angle("spin", r.q_true)
    for key, slack in (("camera_closed_form", 1.0 + 1e-9), ("camera_least_squares", 1.2)):
        tr = r.traces[key]
        m = tr.steady.mask
        assert tr.steady.n_frames == 2 * 108  # every 90-frame window of both 108-frame dwells
        err_truth = attitude.wrap_angle(rp.measured_angle("spin", cam.q[key]) - psi_true)
        rmse_truth = math.sqrt(np.mean(err_truth[m] ** 2))
        assert tr.steady.rmse_rad == pytest.approx(rmse_truth, rel=1e-9, abs=1e-12)
        assert rmse_truth <= slack * math.sqrt(np.mean(per_frame_bound[m] ** 2))
        assert np.all(np.abs(err_truth[m]) <= slack * per_frame_bound[m] + 1e-9)
    assert np.max(np.abs(e[r.dwell_id >= 0])) < 0.5
    assert r.traces["camera_least_squares"].steady.rmse_deg < 2 * 0.5 / D.min() / DEG


@pytest.mark.slow
def test_short_step_test_mems_within_its_drift_bound(short_spin: rp.StepTestResult) -> None:
    """MEMS spin with the seed's zeroing: after 2 s zeroing at 200 Hz the residual z-gyro bias
    has σ = 0.0038 °/s/√Hz·√200/√400 = 0.0027 °/s, plus angle random walk 0.0038·√7 = 0.010°
    over the ≤ 7 s after zeroing; 5σ of each: 5·0.0027·7 + 5·0.010 = 0.145° < 0.15°."""
    tr = short_spin.traces["mems_known_start"]
    assert tr.steady.n_frames > 0 and tr.steady.rmse_deg < 0.15
    assert tr.noise_seed == 0 and tr.rmse_spread_rad is None


@pytest.mark.slow
def test_results_table_structure(short_spin: rp.StepTestResult) -> None:
    """One row per scheme; per axis our RMSE, steady frames and the seed's RMSE (seed 000
    §5.1–5.3); axes that were not run are NaN; the Markdown labels the seed's numbers."""
    df = rp.results_table({"spin": short_spin})
    assert list(df["scheme"]) == [*rp.CAMERA_BACKENDS, *rp.MEMS_VARIANTS]
    for axis in rp.AXES:
        for col in ("rmse_deg", "steady_frames", "seed_rmse_deg", "rmse_min_deg",
                    "rmse_max_deg"):
            assert f"{axis}_{col}" in df.columns
    cam = df[df.seed_row == "camera"]
    mem = df[df.seed_row == "mems"]
    assert len(cam) == len(rp.CAMERA_BACKENDS) == 4 and len(mem) == 2
    assert (cam["spin_seed_rmse_deg"] == 0.2979).all()
    assert (cam["yaw_seed_rmse_deg"] == 0.8847).all()
    assert (mem["tilt_seed_rmse_deg"] == 0.2640).all()
    assert (mem["yaw_seed_rmse_deg"] == 15.0819).all()
    assert df["spin_rmse_deg"].notna().all() and df["tilt_rmse_deg"].isna().all()
    row = df.set_index("scheme").loc["camera_least_squares"]
    assert row["spin_rmse_deg"] == pytest.approx(
        short_spin.traces["camera_least_squares"].steady.rmse_deg)
    md = rp.markdown_step_table(df)
    lines = md.splitlines()
    assert len(lines) == 2 + len(df)
    assert "spin, seed 000" in lines[0] and "0.2979° (seed)" in md and "15.0819° (seed)" in md
    assert all(line.count("|") == 8 for line in lines)


def test_tracking_table_summary_flags_stand_ins(tmp_path) -> None:
    """The tracking summary averages the sequences per tracker and case, puts the seed's
    numbers beside, and flags stand-in rows."""
    rows = []
    for tracker, prec in (("kcf", (0.8, 0.6)), ("gk_standin", (1.0, 0.9))):
        for seq, d in (("a", 0.0), ("b", 0.1)):
            rows.append(dict(tracker=tracker, sequence=seq, case="clean",
                             main_precision_20px=prec[0] - d, aux_precision_20px=prec[1] - d,
                             latency_median_ms=5.0 + 10 * d, fps=100.0))
    csv = tmp_path / "m.csv"
    pd.DataFrame(rows).to_csv(csv, index=False)
    md = rp.tracking_table_markdown(str(csv)).splitlines()
    kcf = next(line for line in md if line.startswith("| kcf |"))
    assert "0.750 / 0.550" in kcf and "0.894 / 0.868" in kcf and "10.86" in kcf
    assert "stand-in" in next(line for line in md if line.startswith("| gk_standin"))


def test_locator_choice() -> None:
    """KCF + GK is always available; "auto" falls back to it (with the reason) when GK-TransT's
    weights do not load; an unknown name is an error."""
    p = PlantParams()
    loc, name, note = rp.make_locator("kcf_gk", p)
    assert name == "kcf_gk" and note == ""
    ok, why = rp.gk_transt_available()
    _, name, note = rp.make_locator("auto", p)
    assert name == ("gk_transt" if ok else "kcf_gk")
    assert ("SHA-256" in note) if ok else (why in note)
    with pytest.raises(ValueError, match="tracker"):
        rp.make_locator("nope", p)


def test_disc_centroid_offset_is_zero_facing_the_camera_and_grows_with_tilt() -> None:
    """Facing the camera (β = 0) a disc images as a circle centred on the image of its centre;
    tilted, the centroid shifts (perspective) roughly in proportion to sin β."""
    p = PlantParams()
    np.testing.assert_allclose(rp.disc_centroid_offset_px(attitude.from_zyz(0.3, 0, 0), p), 0.0,
                               atol=1e-9)
    d5 = np.linalg.norm(rp.disc_centroid_offset_px(attitude.from_zyz(0, 5 * DEG, 0), p), axis=1)
    d15 = np.linalg.norm(rp.disc_centroid_offset_px(attitude.from_zyz(0, 15 * DEG, 0), p),
                         axis=1)
    assert np.all(d5 > 0.01) and np.all(d15 / d5 == pytest.approx(
        math.sin(15 * DEG) / math.sin(5 * DEG), rel=0.1))
