"""The GK assistance (seed 000 §3.2; seed 004 §4) against ground truth and independent maths.

One file of about 700 lines: the five GK stages and their composition share the rendered
sequences built once per module by its fixtures.

Frames come from ``plant.render_analytic.AnalyticRenderer`` (default camera, 4× binned, read
noise 2 DN); its ground truth ``Frame.marker_px`` / ``Frame.boxes_px`` is in full-sensor pixels.
The "tracker" in front of ``GKAssist`` is the ground-truth box of the red marker: the assistance
must work with any source of boxes, and this one keeps the tests about the assistance itself.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import scipy.linalg

from observer.gk.assist import GKAssist, GKConfig
from observer.gk.aux_locator import AuxLocator, AuxLocatorConfig
from observer.gk.hsv_gate import (
    HSVGate,
    HSVGateConfig,
    HSVRange,
    box_image_to_sensor,
    box_sensor_to_image,
    check_frame,
)
from observer.gk.pixel_kalman import F_CV, H_CV, PixelKalman, PixelKalmanConfig
from observer.gk.scale import PixelScaleEMA, ScaleEMAConfig, scale_from_camera
from observer.gk.subpixel import (
    fit_circle_algebraic,
    fit_circle_geometric,
    refine_marker_centre,
)
from observer.gk.subpixel_kernels import median_rgb
from plant import attitude
from plant.camera import (
    Camera,
    image_to_sensor,
    marker_pixels,
    rotor_to_stator,
    sensor_to_image,
)
from plant.params import PlantParams
from plant.render_analytic import AnalyticRenderer, AnalyticRenderOptions
from plant.scene import disc_outlines_rotor

TILT_MAX_DEG = 15.0  # seed 000 §2.4
OCCLUSION_MARGIN_SENSOR_PX = 20.0  # seed 000 §4.3.1
PRECISION_THRESHOLD_PX = 20.0  # seed 000 §4.2, sensor px


# --- helpers ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def params() -> PlantParams:
    return PlantParams()


@pytest.fixture(scope="module")
def renderer(params: PlantParams) -> AnalyticRenderer:
    return AnalyticRenderer(params, seed=11)


def pure_tilt(beta_deg: float, azimuth_rad: float, spin_rad: float = 0.0) -> np.ndarray:
    """Tilt by beta toward ``azimuth`` plus a turn ``spin`` about the shaft (docs/plant.md)."""
    return attitude.from_zyz(spin_rad - azimuth_rad, math.radians(beta_deg), azimuth_rad)


def occlude(image: np.ndarray, boxes_sensor_px: np.ndarray, binning: int) -> np.ndarray:
    """Black rectangle over the union of the boxes (x, y, w, h; sensor px) plus the seed's
    20 px margin (seed 000 §4.3.1), painted on a copy of the RGB frame."""
    b = np.atleast_2d(boxes_sensor_px)
    lo = b[:, :2].min(axis=0) - OCCLUSION_MARGIN_SENSOR_PX
    hi = (b[:, :2] + b[:, 2:]).max(axis=0) + OCCLUSION_MARGIN_SENSOR_PX
    lo_i, hi_i = sensor_to_image(lo, binning), sensor_to_image(hi, binning)
    out = image.copy()
    c0, r0 = np.floor(lo_i).astype(int)
    c1, r1 = np.ceil(hi_i).astype(int) + 1
    out[max(r0, 0):r1, max(c0, 0):c1] = 0
    return out


def enlarged(box: np.ndarray, margin: float = 0.3) -> np.ndarray:
    return np.r_[box[:2] - margin * box[2:], box[2:] * (1 + 2 * margin)]


def ellipse_centre_px(params: PlantParams, q: np.ndarray, marker: int) -> np.ndarray:
    """Centre (sensor px) of the exact image ellipse of a marker disc: a general conic fitted
    (SVD null vector) to 720 exactly projected outline points. Independent of the code under
    test; its offset from ``Frame.marker_px`` is the perspective bias of any circle/ellipse
    centre (see ``observer.gk.subpixel``)."""
    outline = disc_outlines_rotor(params, 720)[marker]
    uv = Camera.from_plant(params).project(rotor_to_stator(q, outline), 1)
    m = uv.mean(axis=0)
    x, y = (uv - m).T
    A = np.column_stack([x * x, x * y, y * y, x, y, np.ones_like(x)])
    a, b, c, d, e, _ = np.linalg.svd(A)[2][-1]
    return np.linalg.solve([[2 * a, b], [b, 2 * c]], [-d, -e]) + m


# --- pixel Kalman filter (seed 000 §3.2.1) -------------------------------------------------------
def test_kalman_model_is_the_seeds() -> None:
    kf = PixelKalman()
    assert np.array_equal(kf.kf.F, [[1, 0, 1, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]])
    assert np.array_equal(kf.kf.H, [[1, 0, 0, 0], [0, 1, 0, 0]])
    assert np.array_equal(kf.kf.Q, 0.01 * np.eye(4))
    assert np.array_equal(kf.kf.R, 0.1 * np.eye(2))


@pytest.mark.parametrize(
    ("Q", "R"),
    [
        (0.01 * np.eye(4), 0.1 * np.eye(2)),  # seed 000 §3.2.1
        (np.diag([0.0, 0.0, 0.02, 0.005]), np.array([[0.5, 0.1], [0.1, 0.3]])),
    ],
)
def test_kalman_converges_to_the_riccati_solution(Q: np.ndarray, R: np.ndarray) -> None:
    """After many frames the prior covariance and gain equal the steady state of the discrete
    algebraic Riccati equation P = F P Fᵀ − F P Hᵀ (H P Hᵀ + R)⁻¹ H P Fᵀ + Q (scipy)."""
    P_dare = scipy.linalg.solve_discrete_are(F_CV.T, H_CV.T, Q, R)
    K_dare = P_dare @ H_CV.T @ np.linalg.inv(H_CV @ P_dare @ H_CV.T + R)
    kf = PixelKalman(PixelKalmanConfig(Q=Q, R=R))
    rng = np.random.default_rng(0)
    kf.update(rng.normal(size=2))
    for _ in range(400):
        kf.predict()
        P_prior = kf.kf.P.copy()
        kf.update(rng.normal(size=2))
    np.testing.assert_allclose(P_prior, P_dare, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(kf.kf.K, K_dare, rtol=1e-8, atol=1e-12)


def test_kalman_error_statistics_match_its_covariance() -> None:
    """Monte Carlo on the filter's own model (X_k = F X + w, w ~ N(0, Q); z = H X + v,
    v ~ N(0, R)): the empirical covariance of the posterior error equals the steady-state
    posterior covariance (I − K H) P of the Riccati solution. 20,000 frames; the errors are
    correlated over a few frames, so the variance estimates carry about 3 % standard error;
    the tolerance is 12 %, four of those."""
    Q, R = 0.01 * np.eye(4), 0.1 * np.eye(2)
    P_dare = scipy.linalg.solve_discrete_are(F_CV.T, H_CV.T, Q, R)
    K = P_dare @ H_CV.T @ np.linalg.inv(H_CV @ P_dare @ H_CV.T + R)
    P_post = (np.eye(4) - K @ H_CV) @ P_dare
    rng = np.random.default_rng(1)
    n = 20000
    w = rng.multivariate_normal(np.zeros(4), Q, size=n)
    v = rng.multivariate_normal(np.zeros(2), R, size=n)
    X = np.array([100.0, 200.0, 1.5, -0.5])
    kf = PixelKalman()
    kf.update(H_CV @ X + v[0])
    err = np.empty((n, 4))
    for k in range(1, n):
        X = F_CV @ X + w[k]
        kf.predict()
        kf.update(H_CV @ X + v[k])
        err[k] = kf.x - X
    e = err[500:]
    # unbiased: the mean error's standard error is about sqrt(P)/45 (≈ 2,000 independent frames)
    assert np.all(np.abs(e.mean(axis=0)) < 0.1 * np.sqrt(np.diag(P_post)))
    emp = np.cov(e.T)
    np.testing.assert_allclose(np.diag(emp), np.diag(P_post), rtol=0.12)


def test_kalman_coasting_grows_covariance_in_closed_form() -> None:
    """n frames without observations: X = Fⁿ X₀ and P = Fⁿ P₀ Fⁿᵀ + Σ_{i<n} Fⁱ Q Fⁱᵀ."""
    kf = PixelKalman()
    for k in range(30):
        kf.predict()
        kf.update([10.0 + 2.0 * k, 50.0 - 1.0 * k])
    X0, P0 = kf.x.copy(), kf.kf.P.copy()
    Q = 0.01 * np.eye(4)
    n = 11
    for _ in range(n):
        kf.predict()
        kf.coast()
    Fn = np.linalg.matrix_power(F_CV, n)
    P_expected = Fn @ P0 @ Fn.T + sum(
        np.linalg.matrix_power(F_CV, i) @ Q @ np.linalg.matrix_power(F_CV, i).T for i in range(n)
    )
    np.testing.assert_allclose(kf.x, Fn @ X0, rtol=1e-12)
    np.testing.assert_allclose(kf.kf.P, P_expected, rtol=1e-10)
    # a straight track at constant speed is predicted without lag (type-2 tracking)
    np.testing.assert_allclose(kf.position, [10.0 + 2.0 * (29 + n), 50.0 - (29 + n)], atol=1e-6)


def test_kalman_rejects_bad_observations_without_raising() -> None:
    kf = PixelKalman()
    assert not kf.update([np.nan, 1.0])
    assert not kf.initialised
    assert kf.update([1.0, 2.0])
    kf.predict()
    assert not kf.update([np.inf, 0.0])
    np.testing.assert_allclose(kf.position, [1.0, 2.0])


@pytest.mark.parametrize(
    ("field", "kwargs"),
    [
        ("Q", {"Q": -0.01 * np.eye(4)}),
        ("Q", {"Q": np.diag([1.0, 1.0, 1.0, -1e-3])}),
        ("Q", {"Q": np.eye(3)}),
        ("Q", {"Q": np.eye(4) + np.triu(np.ones((4, 4)), 1)}),  # not symmetric
        ("R", {"R": np.zeros((2, 2))}),
        ("R", {"R": [[1.0, np.nan], [np.nan, 1.0]]}),
        ("velocity_var0", {"velocity_var0": -1.0}),
    ],
)
def test_kalman_config_errors_name_the_field(field: str, kwargs: dict) -> None:
    with pytest.raises(ValueError, match=field):
        PixelKalmanConfig(**kwargs)


# --- HSV gate (seed 000 §3.2.1) ------------------------------------------------------------------
def test_gate_ratios_on_rendered_markers(renderer: AnalyticRenderer) -> None:
    """In its own bounding box a marker's image (a near-circular ellipse) covers π/4 of the box.
    The counted ratio is 0 to +0.045 above that: the partly covered rim pixels whose S and V stay
    above 50 count as whole, and the box is cut to whole pixels (measured over 120 boxes:
    0.784–0.822). The other colour covers nothing."""
    gate = HSVGate()
    rng = np.random.default_rng(2)
    for _ in range(5):
        q = attitude.from_zyz(rng.uniform(0, 2 * np.pi), math.radians(rng.uniform(0, 15)),
                              rng.uniform(0, 2 * np.pi))
        f = renderer.render(q)
        for m, (own, other) in enumerate((("red", "yellow"), ("yellow", "red"))):
            box = box_sensor_to_image(f.boxes_px[m], f.binning)
            r_own = gate.ratio(f.image, box, own)
            assert r_own.confident and math.pi / 4 - 0.01 < r_own.ratio < math.pi / 4 + 0.045
            r_other = gate.ratio(f.image, box, other)
            assert not r_other.confident and r_other.ratio == 0.0 and r_other.reason


def test_gate_expects_rgb(renderer: AnalyticRenderer) -> None:
    """The frames are RGB; a BGR frame (red and blue swapped) shows no red."""
    f = renderer.render(pure_tilt(5.0, 0.5))
    box = box_sensor_to_image(f.boxes_px[0], f.binning)
    assert HSVGate().ratio(f.image, box, "red").confident
    bgr = cv2.cvtColor(f.image, cv2.COLOR_RGB2BGR)
    assert HSVGate().ratio(bgr, box, "red").ratio < 0.05


def test_gate_rejects_occluded_red(renderer: AnalyticRenderer) -> None:
    f = renderer.render(pure_tilt(5.0, 0.5))
    img = occlude(f.image, f.boxes_px, f.binning)
    res = HSVGate().ratio(img, box_sensor_to_image(f.boxes_px[0], f.binning), "red")
    assert res.ratio == 0.0 and not res.confident and "0.05" in res.reason


def test_box_conversions_round_trip() -> None:
    box = np.array([1000.3, 400.7, 190.0, 187.5])
    for b in (1, 2, 4, 8):
        np.testing.assert_allclose(box_image_to_sensor(box_sensor_to_image(box, b), b), box)
    # a box's centre maps like a point (plant.camera.sensor_to_image)
    img = box_sensor_to_image(box, 4)
    np.testing.assert_allclose(img[:2] + img[2:] / 2, sensor_to_image(box[:2] + box[2:] / 2, 4))


@pytest.mark.parametrize(
    ("field", "kwargs"),
    [
        ("hue", {"hue": ((0, 190),)}),
        ("hue", {"hue": ((20, 10),)}),
        ("hue", {"hue": ()}),
        ("sat", {"hue": ((0, 10),), "sat": (50, 300)}),
        ("val", {"hue": ((0, 10),), "val": (200, 100)}),
    ],
)
def test_hsv_range_errors_name_the_field(field: str, kwargs: dict) -> None:
    with pytest.raises(ValueError, match=field):
        HSVRange(**kwargs)


def test_gate_threshold_validated() -> None:
    with pytest.raises(ValueError, match="min_ratio"):
        HSVGateConfig(min_ratio=-0.1)


# --- sub-pixel centres (seed 004 §4) ------------------------------------------------------------
def test_circle_fits_recover_a_known_circle() -> None:
    """Noise-free points on a 100° arc: both fits are exact. With noise on a short arc Kåsa's
    algebraic fit is biased toward small circles; the geometric fit (seed 004 eq. 27) is not."""
    c_true, R_true = np.array([30.2, -11.7]), 24.3
    t = np.linspace(0.2, 0.2 + np.deg2rad(100), 60)
    pts = c_true + R_true * np.column_stack([np.cos(t), np.sin(t)])
    c_a, R_a = fit_circle_algebraic(pts)
    np.testing.assert_allclose(c_a, c_true, atol=1e-9)
    assert abs(R_a - R_true) < 1e-9
    c_g, R_g, res = fit_circle_geometric(pts, c_true + [1.0, -2.0], R_true + 3.0)
    np.testing.assert_allclose(c_g, c_true, atol=1e-9)
    assert abs(R_g - R_true) < 1e-9 and np.abs(res).max() < 1e-9
    rng = np.random.default_rng(3)
    bias_a, bias_g = [], []
    for _ in range(1000):
        noisy = pts + rng.normal(scale=0.3, size=pts.shape)
        c_a, R_a = fit_circle_algebraic(noisy)
        _, R_g, _ = fit_circle_geometric(noisy, c_a, R_a)
        bias_a.append(R_a - R_true)
        bias_g.append(R_g - R_true)
    assert np.mean(bias_a) < -0.1  # Kåsa shrinks the circle on a short arc
    # the geometric radius is unbiased to first order (a second-order σ²/2R = 0.002 px remains):
    # its mean error lies within 4 standard errors of zero
    assert abs(np.mean(bias_g)) < 4 * np.std(bias_g) / np.sqrt(len(bias_g)) + 0.002


def test_subpixel_centres_match_ground_truth(params: PlantParams,
                                             renderer: AnalyticRenderer) -> None:
    """Circle-fit centres of both markers at 24 random workspace attitudes (tilt 0–15°).

    Error budget, sensor px: the perspective bias of any ellipse-centre estimate (the image
    ellipse's centre is not the projected disc centre, ``ellipse_centre_px``) reaches 0.32 px at
    15° tilt; the renderer's anti-aliased discs have centroids within 0.03 image px = 0.12
    sensor px of the truth (plant/render_analytic.py) and the 2 DN read noise adds about 0.05 px.
    Measured over 300 fits: |error − bias| median 0.056, max 0.163; |error| max 0.435. The
    bounds: |error − bias| < 0.25, median < 0.1, |error| < 0.5 sensor px (0.125 image px).
    """
    rng = np.random.default_rng(4)
    err, err_minus_bias, bias_level = [], [], []
    for _ in range(24):
        q = attitude.from_zyz(rng.uniform(0, 2 * np.pi), math.radians(rng.uniform(0, 15)),
                              rng.uniform(0, 2 * np.pi))
        f = renderer.render(q)
        for m, colour in enumerate(("red", "yellow")):
            res = refine_marker_centre(
                f.image, colour, box_sensor_to_image(enlarged(f.boxes_px[m]), f.binning)
            )
            assert res.valid, res.reason
            c = res.centre_sensor_px(f.binning)
            bias = ellipse_centre_px(params, q, m) - f.marker_px[m]
            err.append(np.hypot(*(c - f.marker_px[m])))
            err_minus_bias.append(np.hypot(*(c - f.marker_px[m] - bias)))
            if attitude.tilt(q) < math.radians(1.0):
                bias_level.append(np.hypot(*bias))
            # the fitted radius is the disc's: 4 mm at ~0.3 m, 24.15 image px at binning 4
            assert abs(res.radius_image_px - 24.15) < 1.2
    assert max(err) < 0.5
    assert max(err_minus_bias) < 0.25 and np.median(err_minus_bias) < 0.1
    assert all(b < 0.03 for b in bias_level)  # no perspective bias with the plate level


def test_circle_fits_of_degenerate_points_say_so_without_raising() -> None:
    """Collinear points have no algebraic circle (NaN), and points that all coincide make the
    geometric fit's normal equations singular: it stops where it started."""
    line = np.column_stack([np.linspace(0.0, 10.0, 20), np.linspace(5.0, 25.0, 20)])
    c_a, R_a = fit_circle_algebraic(line)
    assert np.all(np.isnan(c_a)) and np.isnan(R_a)
    assert np.isnan(fit_circle_algebraic(line[:2])[1])  # fewer than three points
    c_g, R_g, res = fit_circle_geometric(np.full((6, 2), 3.0), [1.0, 2.0], 4.0)
    np.testing.assert_array_equal(c_g, [1.0, 2.0])
    assert R_g == 4.0 and res.shape == (6,)


def test_perspective_bias_of_the_circle_centre_grows_with_tilt(params: PlantParams) -> None:
    """The bias stated in observer/gk/subpixel.py: 0 level, about f·(ρ/Z)²·tan θ at tilt."""
    f_px = params.camera.focal_length_m / params.camera.pixel_size_m
    rho, Z = params.vfc.marker_diameter_mm / 2000.0, params.camera.h_c_m
    for beta in (0.0, 5.0, 10.0, 15.0):
        q = pure_tilt(beta, 0.3)
        bias = np.hypot(*(ellipse_centre_px(params, q, 0) - marker_pixels(params, q)[0]))
        approx = f_px * (rho / Z) ** 2 * math.tan(math.radians(beta))
        assert abs(bias - approx) < 0.2 * approx + 1e-3


def test_subpixel_survives_partial_occlusion(renderer: AnalyticRenderer) -> None:
    """A black bar over 20 % of the red disc: the burr test drops the bar's straight edge and the
    arc fit stays within 1 sensor px, where the centroid of the visible part is ~15 px off."""
    f = renderer.render(pure_tilt(8.0, 1.0, 0.3))
    box = box_sensor_to_image(f.boxes_px[0], f.binning)
    img = f.image.copy()
    x_cut = int(box[0] + 0.8 * box[2])
    img[:, x_cut:int(box[0] + box[2]) + 3] = 0
    res = refine_marker_centre(img, "red", box_sensor_to_image(enlarged(f.boxes_px[0]), 4))
    assert res.valid and res.n_burrs > 0
    assert np.hypot(*(res.centre_sensor_px(4) - f.marker_px[0])) < 1.0
    v, u = np.nonzero(img[..., 0] > 150)  # the visible red pixels
    centroid_sensor = image_to_sensor([u.mean(), v.mean()], f.binning)
    assert np.hypot(*(centroid_sensor - f.marker_px[0])) > 10.0


@pytest.mark.parametrize(
    ("image", "roi", "reason"),
    [
        (np.zeros((0, 0, 3), np.uint8), (0, 0, 10, 10), "empty"),
        (np.zeros((50, 50), np.uint8), (0, 0, 10, 10), "shape"),
        (np.zeros((50, 50, 3), np.float32), (0, 0, 10, 10), "uint8"),
        (np.zeros((50, 50, 3), np.uint8), (np.nan, 0, 10, 10), "roi"),
        (np.zeros((50, 50, 3), np.uint8), (100, 100, 10, 10), "outside"),
        (np.zeros((50, 50, 3), np.uint8), (0, 0, 50, 50), "no marker"),
    ],
)
def test_subpixel_bad_input_is_flagged(image: np.ndarray, roi: tuple, reason: str) -> None:
    res = refine_marker_centre(image, "red", roi)
    assert not res.valid and reason in res.reason and np.all(np.isnan(res.centre_image_px))


# --- auxiliary point (seed 000 §3.2.2) ------------------------------------------------------------
def run_gk(gk: GKAssist, renderer: AnalyticRenderer, qs: list, modify=None) -> list:
    """Feed rendered frames with the ground-truth red box; ``modify(k, frame) -> image``."""
    out = []
    for k, q in enumerate(qs):
        f = renderer.render(q, k / 36.0)
        img = f.image if modify is None else modify(k, f)
        res = gk.step(img, f.binning, box_sensor_px=f.boxes_px[0],
                      tilt_prev_rad=attitude.tilt(qs[max(k - 1, 0)]))
        out.append((f, res))
    return out


def test_aux_fallback_follows_the_last_relative_vector(renderer: AnalyticRenderer) -> None:
    """Yellow occluded (black box + 20 px) for frames 20–29 of a slow spin (0.05 rad/s, 3°
    tilt): the locator falls back to P_red + V_rel of frame 19, so its error is the change of the
    true red→yellow vector since frame 19 (computed from ground truth), within the sub-pixel
    noise of the three measured points, and it stays inside the seed's 20 px threshold."""
    qs = [pure_tilt(3.0, 0.7, 0.05 * k / 36.0) for k in range(30)]
    occluded = range(20, 30)

    def modify(k, f):
        return occlude(f.image, f.boxes_px[1], f.binning) if k in occluded else f.image

    out = run_gk(GKAssist(), renderer, qs, modify)
    v_gt = [f.marker_px[1] - f.marker_px[0] for f, _ in out]
    for k, (f, res) in enumerate(out):
        assert res.red_source == "measurement"
        err = res.yellow_px - f.marker_px[1]
        if k in occluded:
            assert res.yellow_source == "fallback" and "yellow" in res.reason
            last_good = out[occluded[0] - 1][1]
            V_rel = last_good.yellow_px - last_good.red_px
            np.testing.assert_allclose(res.yellow_px, res.red_px + V_rel, rtol=0, atol=1e-9)
            chord = v_gt[19] - v_gt[k]
            assert np.hypot(*(err - chord)) < 0.6
            assert np.hypot(*err) < PRECISION_THRESHOLD_PX
        else:
            assert res.yellow_source == "measurement"
            assert np.hypot(*err) < 0.5
    # the fallback error grows with the rotation: ~0.95 px per frame at this rate
    assert np.hypot(*(out[29][1].yellow_px - out[29][0].marker_px[1])) > 5.0


def yellow_distractor_pixels(f, near_yellow_image_px: float = 40.0) -> np.ndarray:
    """Image pixels (n, 2) of yellow colour away from the yellow marker (the distractor)."""
    hsv = cv2.cvtColor(f.image, cv2.COLOR_RGB2HSV)
    v, u = np.nonzero(cv2.inRange(hsv, (15, 50, 50), (40, 255, 255)))
    yel = sensor_to_image(f.marker_px[1], f.binning)
    far = np.hypot(u - yel[0], v - yel[1]) > near_yellow_image_px
    return np.column_stack([u[far], v[far]])


def test_distractor_outside_the_search_radius_is_ignored(params: PlantParams) -> None:
    r = AnalyticRenderer(params, options=AnalyticRenderOptions(colour_distractor="yellow"),
                         seed=1)
    q = pure_tilt(5.0, 1.0, 0.3)
    f = r.render(q)
    S = scale_from_camera(params.camera)
    loc = AuxLocator(params.vfc.L_m, params.vfc.marker_diameter_mm / 1000.0)
    # precondition, checked on the image: a sizeable yellow sticker, entirely outside the radius
    pix = yellow_distractor_pixels(f)
    red_img = sensor_to_image(f.marker_px[0], f.binning)
    assert len(pix) > 300
    assert np.hypot(*(pix - red_img).T).min() > loc.search_radius_px(S) / f.binning + 5
    res = loc.locate(f.image, f.binning, f.marker_px[0], S, attitude.tilt(q))
    assert res.source == "measurement" and res.n_candidates == 1
    assert np.hypot(*(res.yellow_sensor_px - f.marker_px[1])) < 0.5
    # with the marker hidden the sticker is still not taken: the fallback is used instead
    img = occlude(f.image, f.boxes_px[1], f.binning)
    res2 = loc.locate(img, f.binning, f.marker_px[0], S, attitude.tilt(q))
    assert res2.source == "fallback" and res2.n_candidates == 0
    np.testing.assert_allclose(res2.yellow_sensor_px, res.yellow_sensor_px, atol=1e-9)


def test_visible_marker_wins_over_a_distractor_inside_the_radius(params: PlantParams) -> None:
    """A yellow sticker inside the search radius at a distance that passes E < 0.3: with the
    marker visible the locator sees both candidates and takes the marker (nearest to
    P_red + V_rel once V_rel is known, smallest E before). The full search (no predicted
    window, which would not look at the sticker once V_rel is known)."""
    r = AnalyticRenderer(params, options=AnalyticRenderOptions(colour_distractor="yellow"),
                         seed=11)
    S = scale_from_camera(params.camera)
    loc = AuxLocator(params.vfc.L_m, params.vfc.marker_diameter_mm / 1000.0,
                     AuxLocatorConfig(window_marker_radii=0.0))
    for k in range(3):
        q = pure_tilt(5.0, 1.0, 0.3 + 0.01 * k)
        f = r.render(q)
        pix = yellow_distractor_pixels(f)
        d_sticker = np.hypot(*(image_to_sensor(pix.mean(axis=0), f.binning) - f.marker_px[0]))
        assert abs(d_sticker / (params.vfc.L_m * S) - 1.0) < 0.3  # it would pass the check
        res = loc.locate(f.image, f.binning, f.marker_px[0], S, attitude.tilt(q))
        assert res.source == "measurement" and res.n_candidates == 2
        assert np.hypot(*(res.yellow_sensor_px - f.marker_px[1])) < 0.5
        assert loc.V_rel is not None


def test_candidate_at_the_wrong_distance_fails_the_check(params: PlantParams,
                                                         renderer: AnalyticRenderer) -> None:
    """A yellow blob inside the search radius at half the marker distance: E = 0.5 > 0.3."""
    q = pure_tilt(4.0, 2.0, 1.0)
    f = renderer.render(q)
    S = scale_from_camera(params.camera)
    loc = AuxLocator(params.vfc.L_m, params.vfc.marker_diameter_mm / 1000.0)
    first = loc.locate(f.image, f.binning, f.marker_px[0], S, attitude.tilt(q))
    assert first.source == "measurement"
    img = occlude(f.image, f.boxes_px[1], f.binning)
    fake = sensor_to_image(0.5 * (f.marker_px[0] + f.marker_px[1]), f.binning)
    cv2.circle(img, tuple(int(v) for v in np.round(fake)), 24, (240, 200, 20), -1, cv2.LINE_AA)
    res = loc.locate(img, f.binning, f.marker_px[0], S, attitude.tilt(q))
    assert res.n_candidates == 1 and res.source == "fallback"
    assert abs(res.E - 0.5) < 0.02 and "distance check" in res.reason


def test_without_history_the_locator_reports_none(params: PlantParams,
                                                   renderer: AnalyticRenderer) -> None:
    f = renderer.render(pure_tilt(2.0, 0.0))
    loc = AuxLocator(params.vfc.L_m, params.vfc.marker_diameter_mm / 1000.0)
    img = occlude(f.image, f.boxes_px[1], f.binning)
    res = loc.locate(img, f.binning, f.marker_px[0], scale_from_camera(params.camera))
    assert res.source == "none" and np.all(np.isnan(res.yellow_sensor_px)) and res.reason
    res = loc.locate(f.image, f.binning, [np.nan, 3.0], scale_from_camera(params.camera))
    assert res.source == "none"


@pytest.mark.parametrize(("field", "args"), [("L_m", (0.0, 0.008)), ("L_m", (-1.0, 0.008)),
                                             ("marker_diameter_m", (0.028, math.nan))])
def test_aux_locator_config_errors(field: str, args: tuple) -> None:
    with pytest.raises(ValueError, match=field):
        AuxLocator(*args)
    with pytest.raises(ValueError, match="E_max"):
        AuxLocatorConfig(E_max=1.5)


# --- pixel-scale EMA (seed 000 §3.2.3) ----------------------------------------------------------
def test_initial_scale_is_the_projected_marker_distance(params: PlantParams) -> None:
    """S_0 = f/(p·h_c) equals the ground-truth pixel distance of the markers at rest over L."""
    gt = marker_pixels(params, np.array([1.0, 0.0, 0.0, 0.0]))
    S_gt = np.hypot(*(gt[1] - gt[0])) / params.vfc.L_m
    assert abs(scale_from_camera(params.camera) / S_gt - 1.0) < 1e-9


def test_scale_ema_converges_when_level_and_locks_when_tilted(params: PlantParams,
                                                              renderer: AnalyticRenderer) -> None:
    """Started 15 % low, the EMA reaches the true scale (ground-truth D/L) at β = 1° within
    0.1 % after 80 frames (0.9⁸⁰ · 15 % = 0.003 %; the rest is measurement noise); at β = 5° it
    stays locked exactly, as it does when β is unknown."""
    S_true0 = scale_from_camera(params.camera)
    gk = GKAssist(params, GKConfig(S0_px_per_m=0.85 * S_true0))
    qs = [pure_tilt(1.0, 0.02 * k, 0.5 + 0.03 * k) for k in range(80)]
    out = run_gk(gk, renderer, qs)
    assert all(res.scale_updated for _, res in out[1:])
    S_true = np.mean([np.hypot(*(f.marker_px[1] - f.marker_px[0])) / params.vfc.L_m
                      for f, _ in out[-10:]])
    assert abs(gk.scale.S / S_true - 1.0) < 1e-3
    S_locked = gk.scale.S
    out = run_gk(gk, renderer, [pure_tilt(5.0, 0.1 * k) for k in range(10)])
    assert all(not res.scale_updated for _, res in out[1:]) and gk.scale.S == S_locked
    f = renderer.render(pure_tilt(1.0, 0.0))
    res = gk.step(f.image, f.binning, box_sensor_px=f.boxes_px[0], tilt_prev_rad=None)
    assert res.yellow_source == "measurement" and not res.scale_updated
    assert gk.scale.S == S_locked


def test_scale_ema_step_is_the_seeds_formula() -> None:
    ema = PixelScaleEMA(0.02828, 20000.0)
    assert ema.update(700.0, math.radians(1.0))[0]
    assert ema.S == pytest.approx(0.9 * 20000.0 + 0.1 * 700.0 / 0.02828, rel=1e-12)
    updated, why = ema.update(700.0, math.radians(2.0))
    assert not updated and "locked" in why
    assert not ema.update(math.nan, 0.0)[0]


@pytest.mark.parametrize(("field", "args"), [("L_m", (0.0, 1.0)), ("S0_px_per_m", (0.03, -5.0))])
def test_scale_config_errors(field: str, args: tuple) -> None:
    with pytest.raises(ValueError, match=field):
        PixelScaleEMA(*args)
    with pytest.raises(ValueError, match="alpha"):
        ScaleEMAConfig(alpha=0.0)


# --- the composed workflow (seed 000 §3.2.3) -----------------------------------------------------
def test_occlusion_prediction_stands_in(renderer: AnalyticRenderer) -> None:
    """Both markers under a black box (+20 px) for 11 frames (seed 000 §4.3.1) during a tilt
    ramp: the gate rejects the tracker's box, the Kalman prior stands in (exactly the search
    centre announced before the frame), its error stays within 3σ of the filter's own covariance
    and inside the seed's 20 px threshold, yellow follows by P_red + V_rel, and measurements
    resume after the occlusion."""
    qs = [pure_tilt(3.0 + 0.1 * k, 0.6, 0.2) for k in range(60)]
    occluded = range(30, 41)
    gk = GKAssist()
    for k, q in enumerate(qs):
        f = renderer.render(q, k / 36.0)
        img = occlude(f.image, f.boxes_px, f.binning) if k in occluded else f.image
        announced = gk.search_centre_sensor_px()
        res = gk.step(img, f.binning, box_sensor_px=f.boxes_px[0],
                      tilt_prev_rad=attitude.tilt(qs[max(k - 1, 0)]))
        err_red = np.hypot(*(res.red_px - f.marker_px[0]))
        err_yellow = np.hypot(*(res.yellow_px - f.marker_px[1]))
        assert not res.lost
        if k in occluded:
            assert res.confidence == 0.0 and not res.confident and "0.05" in res.reason
            assert res.red_source == "prediction" and res.yellow_source == "fallback"
            np.testing.assert_array_equal(res.red_px, announced)
            sigma = math.sqrt(np.linalg.eigvalsh(res.red_cov_px2).max())
            assert err_red < 3 * sigma and err_red < PRECISION_THRESHOLD_PX
            assert err_yellow < PRECISION_THRESHOLD_PX
        else:
            assert res.confident and res.confidence > 0.7
            assert res.red_source == "measurement" and res.red_refined
            assert res.yellow_source == "measurement" and res.valid and res.reason == ""
            assert err_red < 0.5 and err_yellow < 0.5


def test_long_occlusion_is_lost_then_recovers(renderer: AnalyticRenderer) -> None:
    cfg = GKConfig(max_coast_frames=5)
    gk = GKAssist(config=cfg)
    q = pure_tilt(4.0, 1.0)
    for k in range(14):
        f = renderer.render(q)
        img = occlude(f.image, f.boxes_px, f.binning) if 3 <= k < 10 else f.image
        res = gk.step(img, f.binning, box_sensor_px=f.boxes_px[0])
        if k < 3 or k >= 10:
            assert not res.lost and res.red_source == "measurement"
        elif k - 3 + 1 > 5:
            assert res.lost and "5" in res.reason and not res.valid
        else:
            assert not res.lost and res.red_source == "prediction"


def test_centre_only_tracker_and_filtered_output(renderer: AnalyticRenderer) -> None:
    """A tracker that gives only a centre (with a 3 px error) works; ``filtered`` output is the
    Kalman posterior."""
    gk = GKAssist(config=GKConfig(red_output="filtered"))
    q = pure_tilt(6.0, 2.5)
    for _ in range(5):
        f = renderer.render(q)
        res = gk.step(f.image, f.binning, centre_sensor_px=f.marker_px[0] + [3.0, -2.0])
        assert res.confident and res.red_refined and res.yellow_source == "measurement"
        np.testing.assert_allclose(res.red_px, gk.kalman.position)
        assert np.hypot(*(res.red_px - f.marker_px[0])) < 0.5


def test_bad_input_is_flagged_never_raised(renderer: AnalyticRenderer) -> None:
    gk = GKAssist()
    f = renderer.render(pure_tilt(5.0, 0.4))
    res = gk.step(f.image, f.binning, box_sensor_px=[np.nan] * 4)
    assert res.red_source == "none" and res.lost and "not finite" in res.reason
    for _ in range(3):
        res = gk.step(f.image, f.binning, box_sensor_px=f.boxes_px[0])
    assert res.valid
    bad_calls = [
        ((f.image, f.binning), {"box_sensor_px": [np.nan, 1.0, 2.0, 3.0]}, "not finite"),
        ((f.image, f.binning), {"box_sensor_px": [1.0, 2.0]}, "(x, y, w, h)"),
        ((f.image, f.binning), {"box_sensor_px": [10.0, 10.0, 0.0, 5.0]}, "w, h"),
        ((f.image, f.binning), {"centre_sensor_px": [np.inf, 2.0]}, "not finite"),
        ((f.image, f.binning), {}, "no tracker output"),
        ((np.zeros((0, 0, 3), np.uint8), 4), {"box_sensor_px": f.boxes_px[0]}, "empty"),
        ((f.image[..., 0], 4), {"box_sensor_px": f.boxes_px[0]}, "shape"),
        ((f.image[:100], 4), {"box_sensor_px": f.boxes_px[0]}, "does not match"),
        ((f.image.astype(float), 4), {"box_sensor_px": f.boxes_px[0]}, "uint8"),
        ((None, 4), {"box_sensor_px": f.boxes_px[0]}, "numpy array"),
        ((f.image, 7), {"box_sensor_px": f.boxes_px[0]}, "binning"),
    ]
    for args, kwargs, reason in bad_calls:
        res = gk.step(*args, **kwargs)
        assert reason in res.reason, (reason, res.reason)
        assert not res.confident and res.red_source == "prediction"
        assert res.yellow_source in ("fallback", "measurement")
        assert np.all(np.isfinite(res.red_px)) and np.all(np.isfinite(res.yellow_px))
    res = gk.step(f.image, f.binning, box_sensor_px=f.boxes_px[0])
    assert res.red_source == "measurement" and not res.lost


def test_tracker_score_threshold(renderer: AnalyticRenderer) -> None:
    gk = GKAssist(config=GKConfig(min_score=0.5))
    f = renderer.render(pure_tilt(5.0, 0.4))
    assert gk.step(f.image, 4, box_sensor_px=f.boxes_px[0], score=0.9).confident
    res = gk.step(f.image, 4, box_sensor_px=f.boxes_px[0], score=0.2)
    assert not res.confident and res.red_source == "prediction" and "score" in res.reason
    with pytest.raises(ValueError, match="Q"):
        GKConfig(kalman={"Q": -np.eye(4)})


# The blurred sequence (31 frames of 6 sub-renders each, about 15 s) is in the slow lane.
@pytest.mark.parametrize("case", ["occlusion", pytest.param("blur", marks=pytest.mark.slow)])
def test_predicted_window_gives_the_full_search_result(
    case: str, params: PlantParams, monkeypatch
) -> None:
    """The auxiliary locator's predicted window (a speed-up) returns exactly what the full search
    returns, frame by frame, through an occlusion or a blur and with a yellow distractor sticker
    on the rotor; and the window is really used on most frames."""
    from experiments.sequences import render_sequence, validation_suite

    spec = validation_suite(1, (case,), 170)[0]
    seq = render_sequence(spec)
    renderer = AnalyticRenderer(params, options=AnalyticRenderOptions(colour_distractor="yellow"),
                                seed=3)
    qs = [attitude.from_zyz(0.1 * k, math.radians(3 + 0.05 * k), 0.02 * k) for k in range(60)]
    extra = [renderer.render(q, 0.0) for q in qs]
    frames = [im for im in seq.images] + [f.image for f in extra]
    boxes = list(seq.boxes_px[:, 0]) + [f.boxes_px[0] for f in extra]
    used = []
    real = AuxLocator._candidates

    def spy(self, *args, whole_only=False, **kw):
        out = real(self, *args, whole_only=whole_only, **kw)
        if whole_only:
            used.append(out is not None)
        return out

    monkeypatch.setattr(AuxLocator, "_candidates", spy)
    cfg = GKConfig()
    full = GKAssist(params, cfg.model_copy(update={"aux": cfg.aux.model_copy(
        update={"window_marker_radii": 0.0})}))
    fast = GKAssist(params, cfg)
    for k, (im, box) in enumerate(zip(frames, boxes, strict=True)):
        if k in (0, len(seq.images)):
            full.reset(), fast.reset()
        a = full.step(im, seq.binning, box_sensor_px=box, score=0.9)
        b = fast.step(im, seq.binning, box_sensor_px=box, score=0.9)
        np.testing.assert_array_equal(a.yellow_px, b.yellow_px)
        assert a.yellow_source == b.yellow_source
    assert np.mean(used) > 0.5


def test_median_rgb_is_the_lower_median_of_the_masked_pixels():
    """The lower median (rank ceil(n/2) of n, 1-based) of each channel over the masked
    pixels, against a full sort, on random crops and masks (odd and even counts, ties)."""
    rng = np.random.default_rng(3)
    n_checked = 0
    for trial in range(60):
        img = rng.integers(0, 256 if trial % 2 else 4, (20, 30, 3)).astype(np.uint8)
        mask = (rng.random((20, 30)) < rng.uniform(0.01, 1.0)).astype(np.uint8)
        px = img[mask > 0]
        if len(px) == 0:
            continue
        want = np.sort(px, axis=0)[(len(px) + 1) // 2 - 1]
        got = median_rgb(img, mask)
        assert got.dtype == np.float32 and got.tolist() == want.tolist(), trial
        n_checked += 1
    assert n_checked >= 50


def test_check_frame_refuses_only_featureless_frames():
    """A frame is featureless when all its values lie within 2 DN: black, white, grey with
    ±1 DN of noise. One bright pixel anywhere (here in the first and the last row, away from
    the middle row) or a dark band makes it usable."""
    rng = np.random.default_rng(2)
    grey = (128 + rng.integers(-1, 2, (60, 80, 3))).astype(np.uint8)
    refused = [np.zeros((60, 80, 3), np.uint8), np.full((60, 80, 3), 255, np.uint8), grey]
    assert all("uniform" in check_frame(f) for f in refused)
    usable = []
    for row, col in ((0, 5), (59, 79)):
        f = np.zeros((60, 80, 3), np.uint8)
        f[row, col, 1] = 3
        usable.append(f)
    band = np.full((60, 80, 3), 200, np.uint8)
    band[10:12] = 20
    usable.append(band)
    assert [check_frame(f) for f in usable] == ["", "", ""]
