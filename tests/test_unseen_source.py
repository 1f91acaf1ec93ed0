"""The evaluation-only image source (``plant.render_unseen``), its place in the tracking
benchmark, its separation from the training code, and the training's appearance jitter."""

import ast
import colorsys
from pathlib import Path

import cv2
import numpy as np
import pytest

from experiments import tracking_bench as tb
from observer.transt.training.augment import appearance_jitter
from plant import attitude
from plant.camera import sensor_to_image
from plant.render_unseen import SensorLook, UnseenLook, UnseenRenderer, draw_look

ROOT = Path(__file__).resolve().parents[1]


def _red_centroid(image: np.ndarray) -> np.ndarray:
    """Centroid (u, v), image px, of the largest blob of red pixels (red the largest channel,
    green and blue under half of it; demosaicing fringes elsewhere are small blobs)."""
    f = image.astype(float) / 255.0
    red = ((f[..., 0] > 0.15) & (f[..., 1] < 0.5 * f[..., 0])
           & (f[..., 2] < 0.5 * f[..., 0])).astype(np.uint8)
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(red)
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    assert stats[k, cv2.CC_STAT_AREA] > 200, "no red marker found"
    return centroids[k]


def test_training_code_never_names_the_unseen_source():
    """No module of observer/transt names ``render_unseen`` (that importing the training entry
    points does not load it through another module: tests/test_transt_training_apart.py)."""
    named = []
    for path in sorted((ROOT / "observer" / "transt").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import | ast.ImportFrom):
                names = [a.name for a in node.names] + [getattr(node, "module", None) or ""]
                named += [path.name for n in names if "render_unseen" in n]
    assert named == []


@pytest.mark.parametrize(("bayer", "demosaic"), [("RG", "bilinear"), ("BG", "vng"),
                                                 ("GR", "edge_aware"), ("GB", "bilinear")])
def test_sensor_keeps_the_markers_colours(bayer, demosaic):
    """Through every Bayer layout and demosaicing algorithm the red marker stays red and the
    yellow one yellow (a layout read with the wrong code swaps red and blue)."""
    look = UnseenLook(sensor=SensorLook(bayer=bayer, demosaic=demosaic, read_noise_dn=0.5))
    q = attitude.from_zyz(0.3, np.radians(5.0), 1.0)
    with UnseenRenderer(look=look, seed=1) as r:
        f = r.render(q)
    hues = []
    for m in range(2):
        u, v = np.rint(sensor_to_image(f.marker_px[m], f.binning)).astype(int)
        rgb = f.image[v - 2:v + 3, u - 2:u + 3].reshape(-1, 3).mean(axis=0) / 255.0
        hues.append(colorsys.rgb_to_hsv(*rgb)[0] * 360.0)
    red_off = min(hues[0], 360.0 - hues[0])
    assert red_off < 15.0 and 35.0 < hues[1] < 70.0, hues


def test_truth_follows_the_rolling_shutter():
    """With a 25 ms readout and a fast turn, the red marker is drawn where the rotor was when
    its row was read: the truth is within 1.5 image px of the drawn centroid, while the
    mid-frame attitude's projection is several px away."""
    look = UnseenLook(sensor=SensorLook(readout_s=0.025, read_noise_dn=0.5))
    q = attitude.from_zyz(0.0, np.radians(8.0), 0.4)
    omega = np.array([8.0, 0.0, 0.0])  # rad/s about x: the markers sweep along the image
    with UnseenRenderer(look=look, seed=2) as r:
        f = r.render(q, exposure_s=1e-4, omega=omega)
        still = r.render(q, exposure_s=1e-4)
    drawn = _red_centroid(f.image)
    truth = sensor_to_image(f.marker_px[0], f.binning)
    mid = sensor_to_image(still.marker_px[0], still.binning)
    assert np.hypot(*(drawn - truth)) < 1.5
    assert np.hypot(*(drawn - mid)) > 4.0
    assert np.hypot(*(_red_centroid(still.image) - mid)) < 1.0


def test_looks_are_drawn_from_the_seed_and_differ():
    a, b = draw_look(np.random.default_rng(5)), draw_look(np.random.default_rng(5))
    c = draw_look(np.random.default_rng(6))
    assert a == b and a != c


def test_benchmark_has_network_alone_rows_on_the_unseen_source(tmp_path):
    """GK-TransT and the network alone with and without the hold (here with the stand-in) run a
    second time on the same cases rendered by the unseen source: their own rows, figures, a
    target line on the clean case and the dual TransT's precision against GK-TransT's there;
    the other trackers do not."""
    rep = tb.run_tracking_benchmark(
        tmp_path, seeds=1, frames=3, cases=["clean"],
        trackers=["gk_transt", "dual_transt", "dual_transt_hold", "kcf"], stand_in=True)
    assert set(rep.summary.tracker) == {"gk_standin", "dual_standin", "dual_standin_hold", "kcf",
                                        "gk_standin_unseen", "dual_standin_unseen",
                                        "dual_standin_hold_unseen"}
    for row in ("dual_standin_unseen", "dual_standin_hold_unseen"):
        assert sum(c.startswith(f"{row} clean ") and "against gk_standin_unseen's" in c
                   for c in rep.checks) == 2
    assert "dual_standin_unseen_clean_main_err_median_px" in rep.figures
    assert "dual_standin_unseen_clean_main_precision_20px" in rep.figures
    assert any(c.startswith("dual_standin_unseen (network alone, unseen renderer) clean main")
               for c in rep.checks)
    assert "network alone, unseen renderer" in rep.notes
    assert "dual_standin_unseen" not in set(rep.table1.algorithm)
    off = tb.run_tracking_benchmark(tmp_path, seeds=1, frames=3, cases=["clean"],
                                    trackers=["dual_transt"], stand_in=True, unseen=False)
    assert set(off.summary.tracker) == {"dual_standin"}


def test_appearance_jitter_keeps_the_target_where_it_is():
    """A grey crop pair with a red disc at the labelled box: after 30 new looks the disc
    (the red within 1.5 radii of it; distractors may be drawn further out) is still centred
    within 1 px of where it was in most looks (the jitter changes the look, not the geometry),
    and the crops did change."""
    side_t, side_s = 64, 128
    yy, xx = np.mgrid[0:side_s, 0:side_s]
    centre = np.array([70.3, 52.6])
    disc = (xx + 0.5 - centre[0]) ** 2 + (yy + 0.5 - centre[1]) ** 2 <= 12.0**2
    search = np.full((side_s, side_s, 3), 120, np.uint8)
    search[disc] = (210, 25, 20)
    yt, xt = np.mgrid[0:side_t, 0:side_t]
    template = np.full((side_t, side_t, 3), 120, np.uint8)
    template[(xt + 0.5 - 32) ** 2 + (yt + 0.5 - 32) ** 2 <= 14.0**2] = (210, 25, 20)
    box = np.array([centre[0] / side_s, centre[1] / side_s, 24 / side_s, 24 / side_s], np.float32)
    rng = np.random.default_rng(0)
    changed, n = 0, 30
    errors = []
    for _ in range(n):
        t2, s2 = appearance_jitter(template, search, box, rng)
        assert t2.shape == template.shape and s2.shape == search.shape and s2.dtype == np.uint8
        f = s2.astype(float)
        redness = np.clip(f[..., 0] - 0.5 * (f[..., 1] + f[..., 2]), 0, None)
        redness[np.hypot(xx + 0.5 - centre[0], yy + 0.5 - centre[1]) > 18.0] = 0.0  # the disc
        redness[redness < 0.5 * redness.max()] = 0.0
        c = np.array([(redness * (xx + 0.5)).sum(), (redness * (yy + 0.5)).sum()]) / redness.sum()
        errors.append(float(np.hypot(*(c - centre))))
        changed += int(np.abs(f - search).mean() > 2.0)
    # a glossy highlight on the disc (15 % of looks) moves its red centroid, not the disc
    assert len(errors) == n and np.median(errors) < 0.5, errors
    assert np.mean(np.asarray(errors) < 1.0) >= 0.8, errors
    assert changed > n // 2


def test_tinted_surroundings_take_a_hue_and_leave_the_target_alone():
    """A grey search crop with a red disc: the tint (forced by a generator whose first draw is
    below 0.4) gives the grey outside the disc a colour (its channels differ by > 10 %) of a
    mean gain of 1, and leaves every pixel inside the grown target ellipse as it was."""
    from observer.transt.training.augment import _ellipse_mask, _tint_surroundings

    side = 128
    box = np.array([0.5, 0.5, 0.2, 0.2], np.float32)
    crop = np.full((side, side, 3), 120.0, np.float32)
    keep = _ellipse_mask(side, box, 1.2).astype(bool)
    crop[keep] = (210.0, 25.0, 20.0)
    tinted = 0
    for seed in range(40):
        rng = np.random.default_rng(seed)
        if rng.uniform() >= 0.4:
            continue
        crops = [crop.copy()]
        _tint_surroundings(crops, [box], np.random.default_rng(seed))
        out = crops[0]
        np.testing.assert_array_equal(out[keep], crop[keep])
        grey = out[~keep][0]
        assert grey.max() / grey.min() > 1.1
        assert abs(grey.mean() - 120.0) < 1e-3
        tinted += 1
    assert tinted >= 8


def test_unseen_gap_checks_compare_each_marker_with_gk_transt():
    """A precision 0.05 below GK-TransT's on the unseen source is met, 0.06 below is not, per
    marker and case; rows missing on either side give no line."""
    import pandas as pd

    from experiments.network_alone import unseen_gap_checks
    from experiments.tracking_runs import summary_table

    rows = [{"tracker": t, "case": c, "main_precision_20px": p[0], "aux_precision_20px": p[1],
             "main_err_median_px": 1.0, "aux_err_median_px": 1.0}
            for t, c, p in (("gk_transt_unseen", "clean", (1.0, 1.0)),
                            ("gk_transt_unseen", "occlusion", (1.0, 0.96)),
                            ("dual_transt_unseen", "clean", (0.95, 0.94)),
                            ("dual_transt_unseen", "occlusion", (0.80, 0.92)),
                            ("dual_transt_hold_unseen", "clean", (1.0, 1.0)))]
    lines = unseen_gap_checks(summary_table(pd.DataFrame(rows)), "gk_transt", "_transt")
    verdicts = [(ln.split()[0], ln.split()[1], ln.split()[2], ln.endswith(": met"))
                for ln in lines]
    assert verdicts == [
        ("dual_transt_unseen", "clean", "main", True),
        ("dual_transt_unseen", "clean", "aux", False),
        ("dual_transt_unseen", "occlusion", "main", False),
        ("dual_transt_unseen", "occlusion", "aux", True),
        ("dual_transt_hold_unseen", "clean", "main", True),
        ("dual_transt_hold_unseen", "clean", "aux", True),
    ]


def test_the_unseen_source_runs_only_with_a_network_alone(tmp_path):
    """GK-TransT without the network alone is not run on the unseen source (it is there only to
    be compared with it); with the hold variant alone, both are."""
    rep = tb.run_tracking_benchmark(tmp_path, seeds=1, frames=3, cases=["clean"],
                                    trackers=["gk_transt", "kcf"], stand_in=True)
    assert set(rep.summary.tracker) == {"gk_standin", "kcf"}
    rep = tb.run_tracking_benchmark(tmp_path, seeds=1, frames=3, cases=["clean"],
                                    trackers=["gk_transt", "dual_transt_hold"], stand_in=True)
    assert set(rep.summary.tracker) == {"gk_standin", "dual_standin_hold", "gk_standin_unseen",
                                        "dual_standin_hold_unseen"}
