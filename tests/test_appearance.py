"""Appearance options of the analytic renderer, the appearance families, the randomised TransT
crop pairs and the hard tracking cases, against independent truth (drawn geometry, colour
maths, the renderer's ground truth)."""

from __future__ import annotations

import colorsys

import cv2
import numpy as np
import pytest

from experiments.network_alone import network_checks
from experiments.sequences import (
    HARD_FRAMES,
    SequenceSpec,
    _draw_disturbance,
    development_seeds,
    disturb,
    render_sequence,
)
from experiments.tracking_bench import min_frames
from experiments.tracking_runs import summary_table
from observer.gk.hsv_gate import RED, colour_mask
from observer.transt.network import SMALL
from observer.transt.training.data import CropPairs, PairSpec, generate_cache
from plant import attitude
from plant.appearance import (
    HELD_OUT_LIGHTING,
    HELD_OUT_OCCLUDER,
    HELD_OUT_PATTERN,
    OCCLUDER_HSV,
    TRAIN_LIGHTINGS,
    TRAIN_OCCLUDERS,
    TRAIN_PATTERNS,
    occluder_rgb,
    random_options,
    random_params,
)
from plant.render_analytic import AnalyticRenderer, AnalyticRenderOptions, jpeg_roundtrip

Q = attitude.from_zyz(0.3, np.radians(6.0), 1.1)


def _render(**opts):
    return AnalyticRenderer(options=AnalyticRenderOptions(noise_sigma_dn=0.0, **opts),
                            seed=3).render(Q)


def test_white_balance_and_lighting_scale_the_frame():
    base = _render().image.astype(float)
    wb = _render(white_balance=(1.1, 1.0, 0.8)).image.astype(float)
    lit = base > 20
    for ch, g in enumerate((1.1, 1.0, 0.8)):
        ratio = wb[..., ch][lit[..., ch] & (base[..., ch] < 200)] / base[..., ch][
            lit[..., ch] & (base[..., ch] < 200)]
        assert abs(np.median(ratio) - g) < 0.01
    # a gradient to the right: the right half is brighter than the left, by about the amount
    grad = _render(light_gradient=0.4).image.astype(float).mean(axis=2)
    b = base.mean(axis=2)
    w = b.shape[1]
    col = np.arange(w)
    m = b > 20
    expect = 1.0 + 0.4 * (col - (w - 1) / 2) / (w / 2)
    ratio = np.where(m, grad / np.maximum(b, 1), np.nan)
    assert np.nanmedian(ratio[:, w - 60:]) == pytest.approx(np.median(expect[w - 60:]), abs=0.02)
    assert np.nanmedian(ratio[:, :60]) == pytest.approx(np.median(expect[:60]), abs=0.02)


def test_rotor_pattern_leaves_plate_and_markers_alone():
    a, b = _render(), _render(rotor_pattern="checker", rotor_pattern_contrast=0.5)
    boxes = a.boxes_px / a.binning
    for x, y, w, h in boxes:  # the marker discs and the plate around them are unchanged
        sl = (slice(int(y), int(y + h)), slice(int(x), int(x + w)))
        assert np.array_equal(a.image[sl], b.image[sl])
    assert np.abs(a.image.astype(int) - b.image.astype(int)).max() > 40  # the rotor changed
    np.testing.assert_allclose(a.marker_px, b.marker_px)


def test_marker_diameter_from_params_sets_drawing_and_truth():
    p = random_params(np.random.default_rng(5))
    d = p.vfc.marker_diameter_mm
    assert 6.5 <= d <= 9.5
    f8 = AnalyticRenderer(options=AnalyticRenderOptions(noise_sigma_dn=0.0)).render(Q)
    fd = AnalyticRenderer(p, options=AnalyticRenderOptions(noise_sigma_dn=0.0)).render(Q)
    np.testing.assert_allclose(fd.boxes_px[:, 2:] / f8.boxes_px[:, 2:], d / 8.0, rtol=0.01)
    area = np.count_nonzero(colour_mask(fd.image, RED)) * fd.binning**2
    r_px = fd.boxes_px[0, 2] / 2
    assert area == pytest.approx(np.pi * r_px * r_px, rel=0.08)


def test_jpeg_roundtrip_is_lossy_but_close():
    img = _render().image
    assert jpeg_roundtrip(img, None) is img
    out = jpeg_roundtrip(img, 40)
    assert out.shape == img.shape and out.dtype == np.uint8
    diff = np.abs(out.astype(int) - img.astype(int))
    assert 0 < diff.mean() < 4


def test_occluder_families_have_their_hsv():
    rng = np.random.default_rng(0)
    hues_checked = 0
    for fam, ((h0, h1), (s0, s1), (v0, v1)) in OCCLUDER_HSV.items():
        for _ in range(20):
            h, s, v = colorsys.rgb_to_hsv(*(c / 255 for c in occluder_rgb(rng, fam)))
            # 8-bit rounding: saturation is known to about 1 DN / (255 v), hue only when the
            # colour is not nearly grey
            tol = 0.01 + 1.0 / (255.0 * max(v, 1e-3))
            assert v0 - 0.01 <= v <= v1 + 0.01 and s0 - tol <= s <= s1 + tol, fam
            if s * v * 255.0 >= 20.0:
                hue = h * 360.0
                assert h0 - 2 <= hue <= h1 + 2 or h0 - 2 <= hue + 360 <= h1 + 2, fam
                hues_checked += 1
    assert hues_checked >= 10 * len(OCCLUDER_HSV)  # most draws are coloured enough to check


def test_held_out_families_are_never_trained_on():
    assert HELD_OUT_PATTERN not in TRAIN_PATTERNS and HELD_OUT_LIGHTING not in TRAIN_LIGHTINGS
    assert HELD_OUT_OCCLUDER not in TRAIN_OCCLUDERS
    rng = np.random.default_rng(1)
    for _ in range(30):
        o = random_options(rng, TRAIN_PATTERNS, TRAIN_LIGHTINGS)
        assert o.rotor_pattern != HELD_OUT_PATTERN and o.light_spot == 0.0


def test_randomised_crop_pairs_label_the_target(tmp_path):
    spec = PairSpec.for_config(SMALL, randomise=True).model_copy(
        update={"occlusion_prob": 0.0, "centre_jitter": 1.0})
    d = CropPairs(generate_cache(tmp_path / "c", 12, seed=5, spec=spec, progress=False))
    hits = 0
    for i in range(len(d)):
        s = np.asarray(d.search[i])
        mask = colour_mask(s, RED)
        n, _, stats, cents = cv2.connectedComponentsWithStats(mask)
        if n < 2:
            continue
        cx, cy, w, h = d.box[i] * s.shape[0]
        # the red blob nearest the labelled centre sits on it (a glare or blur may shift it)
        k = 1 + np.argmin(np.hypot(*(cents[1:] - [cx, cy]).T))
        hits += np.hypot(*(cents[k] - [cx, cy])) < 0.3 * w
    assert hits >= 0.8 * len(d)



def test_tracking_regime_searches_hold_the_target_near_the_crop_centre(tmp_path):
    """With TransT's jitter (factor 3) a search may put the target up to 1.5 box sizes off the
    centre, about 0.375 of a context-4 crop; the tracking-regime searches (factor 1) keep it
    within 0.125."""
    base = PairSpec.for_config(SMALL)
    wide = CropPairs(generate_cache(tmp_path / "w", 8, seed=5, spec=base, progress=False))
    near = CropPairs(generate_cache(
        tmp_path / "n", 8, seed=5, spec=base.model_copy(update={"tracking_fraction": 1.0}),
        progress=False))
    off_wide = np.abs(wide.box[:, :2] - 0.5).max(axis=1)
    off_near = np.abs(near.box[:, :2] - 0.5).max(axis=1)
    assert off_near.max() <= 0.125 * 1.05  # the crop side follows the jittered size
    assert (off_wide > 0.15).sum() >= 3


def test_hard_case_finger_hides_the_red_marker_then_leaves():
    img = np.full((512, 612, 3), 30, np.uint8)
    markers = np.array([[300.0, 250.0], [340.0, 250.0]])
    d = _draw_disturbance("occluder_skin", np.random.default_rng(2))
    covered = [disturb("occluder_skin", k, img.copy(), markers, 12.0, d)
               for k in (HARD_FRAMES.start - 1, HARD_FRAMES.start + 3, 120, HARD_FRAMES.stop)]
    assert covered[0] == 0.0 and covered[-1] == 0.0
    assert 0.0 <= covered[1] < 0.5 and covered[2] == 1.0
    # the yellow marker is not touched
    out = img.copy()
    disturb("occluder_skin", 120, out, markers, 12.0, d)
    assert np.array_equal(out[238:263, 328:353], img[238:263, 328:353])


def test_hard_and_heldout_cases_render_and_need_their_frames():
    seed = development_seeds(1)[0]
    seq = render_sequence(SequenceSpec(seed=seed, case="heldout_pattern", n_frames=3))
    assert seq.case == "heldout_pattern" and seq.n_frames == 3
    assert min_frames("heldout_lighting") == 2 and min_frames("fast") == HARD_FRAMES.stop + 5


def test_network_checks_report_met_and_not_met():
    import pandas as pd

    m = pd.DataFrame([{"tracker": "dual_transt", "case": "heldout_pattern",
                       "main_precision_20px": 1.0, "aux_precision_20px": 0.5,
                       "main_err_median_px": 3.0, "aux_err_median_px": 9.0}])
    lines = network_checks(summary_table(m), "dual_transt", ["heldout_pattern"])
    assert lines[0].endswith(": met") and lines[1].endswith("NOT met")
