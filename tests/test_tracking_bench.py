"""The tracking benchmark: metrics on hand-made inputs, the sequences (seed 000 §4.3 cases) against
independent computations, the CVAT round trip, and the pipeline with a tracker of known error."""

from __future__ import annotations

import math
import shutil
import textwrap

import cv2
import numpy as np
import pytest

from experiments import cvat
from experiments import tracking_bench as tb
from experiments.sequences import (
    BLUR_FRAMES,
    K_DOWNSAMPLE,
    M_AVERAGE,
    OCCLUSION_MARGIN_SENSOR_PX,
    SequenceSpec,
    attitudes,
    development_seeds,
    manual_motion,
    occluder_pixels,
    render_sequence,
    trajectory_index,
    validation_seeds,
)
from experiments.tracking_metrics import (
    IOU_THRESHOLDS,
    box_iou,
    centre_errors,
    latency_stats,
    precision_at,
    precision_curve,
    reacquisition_frames,
    success_auc,
    success_curve,
)
from experiments.tracking_plots import plot_error_curves, plot_precision_curves
from experiments.tracking_runs import (
    evaluate,
    latency_ratio,
    run_benchmark,
    run_trackers,
    summary_table,
    table1,
)
from observer.trackers import MarkerPairTracker, PairResult, box_around
from plant.camera import marker_pixels, sensor_to_image
from plant.params import PlantParams

SEED = development_seeds(3)[2]


# --- metrics on hand-made inputs ----------------------------------------------------------------
def test_centre_errors_and_precision_curve():
    pred = np.array([[0, 0], [3, 4], [10, 0], [0, 20], [30, 0], [np.nan, 0]], float)
    true = np.zeros((6, 2))
    e = centre_errors(pred, true)
    assert np.allclose(e[:5], [0, 5, 10, 20, 30]) and np.isinf(e[5])
    assert np.allclose(precision_curve(e, [0, 9.99, 10, 20, 50]), [1 / 6, 2 / 6, 3 / 6, 4 / 6,
                                                                    5 / 6])
    assert precision_at(e) == pytest.approx(4 / 6)  # error <= 20 px counts (seed 000 §4.2)
    # frames without truth are not scored
    true2 = true.copy()
    true2[0] = np.nan
    e2 = centre_errors(pred, true2)
    assert np.isnan(e2[0]) and precision_at(e2) == pytest.approx(3 / 5)


def test_box_iou_by_hand():
    a = np.array([[0, 0, 10, 10], [0, 0, 10, 10], [0, 0, 10, 10], [0, 0, 10, 10],
                  [np.nan, 0, 1, 1]], float)
    b = np.array([[5, 5, 10, 10], [0, 0, 10, 10], [20, 20, 5, 5], [0, 0, 20, 5],
                  [0, 0, 1, 1]], float)
    assert np.allclose(box_iou(a, b), [25 / 175, 1.0, 0.0, 50 / 150, 0.0])


def test_success_curve_and_auc_by_hand():
    ious = np.array([1.0, 0.5, 0.0, 0.72])
    curve = success_curve(ious)
    expect = [sum(v > t for v in ious) / 4 for t in np.linspace(0, 1, 21)]
    assert np.allclose(curve, expect)
    assert success_auc(ious) == pytest.approx(np.mean(expect))
    assert len(IOU_THRESHOLDS) == 21
    # a perfect tracker: IoU 1 everywhere exceeds every threshold below 1 -> 20/21
    assert success_auc(np.ones(7)) == pytest.approx(20 / 21)


def test_latency_stats_and_ratio():
    st = latency_stats([0.01, 0.02, 0.03, np.nan])
    assert st["latency_median_ms"] == pytest.approx(20.0)
    assert st["latency_mean_ms"] == pytest.approx(20.0)
    assert st["fps"] == pytest.approx(50.0)
    import pandas as pd

    t = pd.DataFrame({"algorithm": ["gk_transt", "dual_transt"], "latency_median_ms": [16.33,
                                                                                      31.23]})
    assert latency_ratio(t) == pytest.approx(0.523, abs=1e-3)
    assert math.isnan(latency_ratio(t, "kcf"))


def test_reacquisition_frames_by_hand():
    e = np.array([1, 1, 50, 50, 50, 30, 5, 6, 50, 3, 3, 3, 3, 3, 3], float)
    m = np.array([1, 1, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1], bool)
    # occlusion frames 2-4: first visible frame 5; frame 6 is within but 8 leaves (hold 5);
    # frame 9 holds -> 4 frames after
    assert reacquisition_frames(e, m, 5) == 4.0
    assert reacquisition_frames(e, m, 5, hold=2) == 1.0
    m2 = m.copy()
    m2[9:] = False  # never measured again
    assert math.isinf(reacquisition_frames(e, m2, 5))


# --- sequences ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def blur_seq():
    return render_sequence(SequenceSpec(seed=SEED, case="blur", n_frames=165))


def test_seed_ranges_are_disjoint():
    v, d = validation_seeds(1000), development_seeds(1000)
    assert not set(v) & set(d)
    assert min(v + d) >= 6_000_000  # training scripts stay below (docstring of sequences)


def test_motion_stays_in_the_workspace():
    ang = manual_motion(np.random.default_rng(3), 600, 36.0, SequenceSpec(seed=0).motion)
    assert np.all(ang[:, 1] >= 0) and np.all(ang[:, 1] <= math.radians(15.0) + 1e-12)
    assert np.all(np.isfinite(ang))
    speed = np.degrees(np.abs(np.diff(ang, axis=0))).max(axis=0) * 36.0
    assert np.all(speed < 400.0)  # deg/s: a hand, not a motor


def test_sequences_are_deterministic_and_match_the_projection(blur_seq):
    spec = SequenceSpec(seed=SEED, case="clean", n_frames=12)
    a, b = render_sequence(spec), render_sequence(spec)
    assert np.array_equal(a.images, b.images) and np.array_equal(a.marker_px, b.marker_px)
    # ground truth = the camera projection of the marker centres at the trajectory attitude
    rng = np.random.default_rng([spec.seed, 0x7A3C])
    n_traj = 12 + (K_DOWNSAMPLE - 1) * (len(BLUR_FRAMES) - 1)
    qs = attitudes(manual_motion(rng, n_traj, spec.fps, spec.motion))
    p = PlantParams()
    for k in (0, 7, 11):
        assert np.allclose(a.marker_px[k], marker_pixels(p, qs[k]), atol=1e-6)
    # the clean frames of the blur case before frame 130 are the same motion
    assert np.allclose(blur_seq.marker_px[:12], render_sequence(
        SequenceSpec(seed=SEED, case="clean", n_frames=12)).marker_px)


def test_blur_case_time_warp_and_average(blur_seq):
    """Frames 130-160: trajectory advanced K = 5 per frame, truth = mean of M = 6 positions."""
    assert [trajectory_index(k, "blur") for k in (129, 130, 131, 160, 161)] == \
        [129, 130, 135, 280, 281]
    assert np.array_equal(np.flatnonzero(blur_seq.blurred), np.arange(130, 161))
    rng = np.random.default_rng([SEED, 0x7A3C])
    n_traj = 165 + (K_DOWNSAMPLE - 1) * (len(BLUR_FRAMES) - 1)
    qs = attitudes(manual_motion(rng, n_traj, 36.0, SequenceSpec(seed=SEED).motion))
    p = PlantParams()
    for k in (130, 145, 160):
        tau = trajectory_index(k, "blur")
        mean = np.mean([marker_pixels(p, qs[j]) for j in range(tau - M_AVERAGE + 1, tau + 1)],
                       axis=0)
        assert np.allclose(blur_seq.marker_px[k], mean, atol=1e-6)
    assert np.allclose(blur_seq.marker_px[162], marker_pixels(p, qs[162 + 120]), atol=1e-6)


def test_occlusion_case_blacks_out_both_markers_with_margin():
    seq = render_sequence(SequenceSpec(seed=SEED, case="occlusion", n_frames=113))
    b = seq.binning
    assert np.array_equal(np.flatnonzero(seq.occluded), np.arange(100, 111))
    for k in (100, 105, 110):
        img = seq.images[k]
        for m in range(2):  # every pixel of each marker's box, 20 px margin included, is black
            lo = seq.boxes_px[k, m, :2] - OCCLUSION_MARGIN_SENSOR_PX
            hi = seq.boxes_px[k, m, :2] + seq.boxes_px[k, m, 2:] + OCCLUSION_MARGIN_SENSOR_PX
            c0, r0 = np.ceil(sensor_to_image(lo, b)).astype(int)
            c1, r1 = np.floor(sensor_to_image(hi, b)).astype(int)
            assert np.all(img[r0:r1 + 1, c0:c1 + 1] == 0)
    # frames outside 100-110 are not black over the markers
    for k in (99, 111, 112):
        u, v = np.rint(sensor_to_image(seq.marker_px[k, 0], b)).astype(int)
        assert seq.images[k][v, u].max() > 50
    rows, cols = occluder_pixels(np.array([[10.0, 10.0, 4.0, 4.0]]), 4, 100, 100, 0.0)
    assert (rows, cols) == (slice(2, 4), slice(2, 4))


# --- the pipeline with a tracker of known error -------------------------------------------------
class OffsetTracker(MarkerPairTracker):
    """Reports the truth shifted by fixed offsets (red 10 px, yellow 30 px along u)."""

    name = "offset"

    def __init__(self, truth: np.ndarray, boxes: np.ndarray) -> None:
        super().__init__()
        self.truth, self.boxes, self.k = truth, boxes, 0

    def _start(self, image, boxes_sensor_px):
        self.k = 0

    def _step(self, image):
        self.k += 1
        r = self.truth[self.k, 0] + [10.0, 0.0]
        y = self.truth[self.k, 1] + [30.0, 0.0]
        return PairResult(r, y, False, "", 0.0, red_box_px=box_around(r, self.boxes[self.k, 0, 2:]),
                          yellow_box_px=box_around(y, self.boxes[self.k, 1, 2:]))


def test_benchmark_pipeline_with_known_errors(tmp_path):
    seq = render_sequence(SequenceSpec(seed=SEED, case="clean", n_frames=20))
    metrics, runs, seqs = run_benchmark(
        {"offset": lambda: OffsetTracker(seq.marker_px, seq.boxes_px)}, [seq])
    row = metrics.iloc[0]
    assert row["main_precision_20px"] == 1.0 and row["aux_precision_20px"] == 0.0
    assert row["main_err_median_px"] == pytest.approx(10.0)
    assert row["aux_err_median_px"] == pytest.approx(30.0)
    # IoU of a box shifted by d along u: (w - d) h / ((w + d) h)
    w = seq.boxes_px[1:, 0, 2]
    iou = (w - 10) / (w + 10)
    assert row["main_success_auc"] == pytest.approx(success_auc(iou))
    t1 = table1(runs)
    assert t1.loc[0, "algorithm"] == "offset" and t1.loc[0, "frames"] == 19
    s = summary_table(metrics)
    assert s.loc[0, "main_precision_20px"] == 1.0
    p1, p2 = tmp_path / "p.png", tmp_path / "e.png"
    plot_precision_curves(runs, seqs, "clean").savefig(p1)
    plot_error_curves(runs, seq).savefig(p2)
    assert cv2.imread(str(p1)) is not None and cv2.imread(str(p2)) is not None
    assert evaluate(runs[0], seq)["frames"] == 19


class FlaggedTracker(OffsetTracker):
    """Reports the truth, except on odd frames the yellow marker 30 px off and flagged as not
    measured (a prediction)."""

    name = "flagged"

    def _step(self, image):
        self.k += 1
        r, y = self.truth[self.k]
        odd = self.k % 2 == 1
        y = y + [30.0, 0.0] if odd else y
        return PairResult(r, y, False, "", 0.0, yellow_measured=not odd,
                          red_box_px=box_around(r, self.boxes[self.k, 0, 2:]),
                          yellow_box_px=box_around(y, self.boxes[self.k, 1, 2:]))


def test_measured_precision_leaves_out_predicted_frames_and_the_frames_table_says_so():
    seq = render_sequence(SequenceSpec(seed=SEED, case="clean", n_frames=11))
    metrics, runs, _ = run_benchmark(
        {"flagged": lambda: FlaggedTracker(seq.marker_px, seq.boxes_px)}, [seq])
    row = metrics.iloc[0]
    assert row["aux_precision_20px"] == pytest.approx(0.5)  # the seed's: every frame counts
    assert row["aux_precision_20px_measured"] == 1.0
    assert row["aux_predicted_frames"] == 5 and row["main_predicted_frames"] == 0
    table = runs[0].frames_table(seq)
    assert len(table) == 11 and table["yellow_measured"].tolist() == [k % 2 == 0
                                                                     for k in range(11)]
    assert table["red_measured"].all()
    assert table["attitude_source"].tolist() == ["both measured" if k % 2 == 0
                                                 else "one predicted" for k in range(11)]
    assert table["yellow_error_px"][1::2].to_numpy() == pytest.approx(30.0)


def test_interleaved_runs_equal_separate_runs():
    """Taking turns frame by frame changes nothing but the timing: same tracks as one by one."""
    from observer.trackers import make_pair_tracker

    seq = render_sequence(SequenceSpec(seed=SEED, case="clean", n_frames=15))
    names = ("kcf_numpy", "k2cf", "kcf")
    a = run_trackers([make_pair_tracker(n) for n in names], seq, interleave=True)
    b = run_trackers([make_pair_tracker(n) for n in names], seq, interleave=False)
    for ra, rb in zip(a, b, strict=True):
        assert ra.tracker == rb.tracker
        assert np.array_equal(ra.marker_px, rb.marker_px, equal_nan=True)
        assert np.array_equal(ra.measured, rb.measured)


# --- CVAT ---------------------------------------------------------------------------------------
def test_cvat_round_trip(tmp_path):
    seq = render_sequence(SequenceSpec(seed=SEED, case="occlusion", n_frames=112))
    xml = cvat.export_sequence(seq, tmp_path / "ann.xml")
    tr = cvat.read_cvat_xml(xml)
    assert tr.n_frames == seq.n_frames
    assert (tr.width, tr.height) == (seq.images.shape[2], seq.images.shape[1])
    from observer.gk.hsv_gate import box_image_to_sensor

    for m, lab in enumerate(cvat.LABELS):
        back = np.array([box_image_to_sensor(b, seq.binning) for b in tr.boxes_px[lab]])
        assert np.allclose(back, seq.boxes_px[:, m], atol=0.01 * seq.binning)
        assert np.array_equal(tr.occluded[lab], seq.occluded)


def test_cvat_pixel_convention_and_interpolation(tmp_path):
    """CVAT corner coordinates -> our pixel-centre boxes; boxes between keyframes interpolate;
    an ``outside`` box hides the object until the next listed box."""
    xml = tmp_path / "hand.xml"
    xml.write_text(textwrap.dedent("""\
        <?xml version="1.0" encoding="utf-8"?>
        <annotations>
          <version>1.1</version>
          <meta><task><size>14</size><mode>interpolation</mode><start_frame>0</start_frame>
            <original_size><width>612</width><height>512</height></original_size>
          </task></meta>
          <track id="0" label="red" source="manual">
            <box frame="0" outside="0" occluded="0" keyframe="1" xtl="10.5" ytl="20.5"
                 xbr="30.5" ybr="40.5" z_order="0"/>
            <box frame="10" outside="0" occluded="1" keyframe="1" xtl="20.5" ytl="20.5"
                 xbr="40.5" ybr="40.5" z_order="0"/>
            <box frame="12" outside="1" occluded="0" keyframe="1" xtl="20.5" ytl="20.5"
                 xbr="40.5" ybr="40.5" z_order="0"/>
          </track>
          <track id="1" label="yellow" source="manual">
            <box frame="2" outside="0" occluded="0" keyframe="1" xtl="100" ytl="100"
                 xbr="110" ybr="110" z_order="0"/>
          </track>
          <track id="2" label="blue" source="manual"/>
        </annotations>
        """))
    tr = cvat.read_cvat_xml(xml)
    red = tr.boxes_px["red"]
    assert np.allclose(red[0], [10.0, 20.0, 20.0, 20.0])
    assert np.allclose(red[5], [15.0, 20.0, 20.0, 20.0])  # halfway between the keyframes
    assert np.allclose(red[11], [20.0, 20.0, 20.0, 20.0])
    assert np.all(np.isnan(red[12:]))
    assert tr.occluded["red"][10] and not tr.occluded["red"][9]
    yel = tr.boxes_px["yellow"]
    assert np.all(np.isnan(yel[:2])) and np.allclose(yel[2], [99.5, 99.5, 10, 10])
    assert np.all(np.isnan(yel[3:]))  # a track ends at its last listed box
    assert tr.extra_labels == ["blue"]


def test_cvat_bad_files(tmp_path):
    (tmp_path / "a.xml").write_text("<annotations><version>1.1</version>"
                                    "<image id='0' name='x.png'/></annotations>")
    with pytest.raises(ValueError, match="for images"):
        cvat.read_cvat_xml(tmp_path / "a.xml")
    (tmp_path / "b.xml").write_text("<annotations><version>1.1</version>"
                                    "<track id='0' label='red'/></annotations>")
    with pytest.raises(ValueError, match="yellow"):
        cvat.read_cvat_xml(tmp_path / "b.xml")
    (tmp_path / "c.xml").write_text("not xml")
    with pytest.raises(ValueError):
        cvat.read_cvat_xml(tmp_path / "c.xml")


CVAT_HEAD = """<?xml version="1.0" encoding="utf-8"?>
<annotations>
  <version>1.1</version>
  <meta><task><size>{size}</size><start_frame>{start}</start_frame></task></meta>
  <track id="0" label="red" source="manual">
    <box frame="{start}" outside="0" occluded="0" xtl="10.5" ytl="20.5" xbr="30.5" ybr="40.5"/>
  </track>
  <track id="1" label="yellow" source="manual">
"""


@pytest.mark.parametrize(
    ("box", "size", "start", "words"),
    [
        ('frame="1000000000" xtl="1" ytl="1" xbr="9" ybr="9"', 14, 0,
         "frame 1000000000 is beyond the task's size of 14 frames"),
        ('frame="3" xtl="1" ytl="1" xbr="9"', 14, 5, "frame 3 is before start_frame 5"),
        ('frame="6" xtl="1" ytl="1" xbr="9"', 14, 5, "coordinate ybr=None is missing"),
        ('frame="6" xtl="1" ytl="nan" xbr="9" ybr="9"', 14, 5, "ytl='nan'"),
        ('frame="2" xtl="20" ytl="1" xbr="9" ybr="9"', 14, 0, "width -11 and height 8"),
        ('frame="2" xtl="1" ytl="1" xbr="1" ybr="9"', 14, 0, "must be positive"),
        ('frame="two" xtl="1" ytl="1" xbr="9" ybr="9"', 14, 0, "frame='two' is not an integer"),
        ('xtl="1" ytl="1" xbr="9" ybr="9"', 14, 0, "frame=None is not an integer"),
    ],
)
def test_cvat_bad_boxes_are_errors_naming_the_line_and_element(tmp_path, box, size, start,
                                                                words):
    """Each bad box raises ``CvatError`` (a ValueError) with the file, the line of the box (the
    9th of this file) and the problem; none is dropped or kept silently, and a huge frame
    number is refused before anything of that size is allocated."""
    xml = tmp_path / "bad.xml"
    xml.write_text(CVAT_HEAD.format(size=size, start=start) + f"    <box {box}/>\n"
                   "  </track>\n</annotations>\n")
    assert xml.read_text().splitlines()[8].strip().startswith("<box")
    with pytest.raises(cvat.CvatError) as err:
        cvat.read_cvat_xml(xml)
    msg = str(err.value)
    assert isinstance(err.value, ValueError)
    assert msg.startswith(f"{xml}, line 9: <box frame=") and "track '1' (yellow)" in msg, msg
    assert words in msg, msg


def test_cvat_frame_count_bounds_the_frames(tmp_path):
    """Frame numbers are checked against the frames given, the declared size or stop_frame,
    else a fixed cap; an outside box may be empty."""
    ok = '<box frame="12" outside="1" xtl="0.5" ytl="0.5" xbr="0.5" ybr="0.5"/>'
    xml = tmp_path / "a.xml"
    xml.write_text(CVAT_HEAD.format(size=14, start=0) + f"    {ok}\n  </track>\n</annotations>")
    assert cvat.read_cvat_xml(xml).n_frames == 14
    with pytest.raises(cvat.CvatError, match="beyond the 10 frames given"):
        cvat.read_cvat_xml(xml, n_frames=10)
    undeclared = CVAT_HEAD.replace("<size>{size}</size>", "").format(start=0)
    big = f'<box frame="{cvat.MAX_UNDECLARED_FRAMES}" xtl="1" ytl="1" xbr="9" ybr="9"/>'
    xml.write_text(undeclared + f"    {big}\n  </track>\n</annotations>")
    with pytest.raises(cvat.CvatError, match="declares no size or stop_frame"):
        cvat.read_cvat_xml(xml)
    xml.write_text(undeclared.replace("<start_frame>", "<stop_frame>99</stop_frame><start_frame>")
                   + f"    {big}\n  </track>\n</annotations>")
    with pytest.raises(cvat.CvatError, match="stop_frame 99"):
        cvat.read_cvat_xml(xml)
    with pytest.raises(cvat.CvatError, match="cannot read"):
        cvat.read_cvat_xml(tmp_path / "missing.xml")


def test_benchmark_on_a_cvat_folder(tmp_path):
    """A 'recording': frames written as PNG files plus their CVAT XML, run through the
    benchmark; ground truth survives the trip and KCF tracks every frame."""
    seq = render_sequence(SequenceSpec(seed=SEED, case="clean", n_frames=16))
    frames = tmp_path / "frames"
    frames.mkdir()
    for k, img in enumerate(seq.images):
        cv2.imwrite(str(frames / f"frame_{k:06d}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    xml = cvat.export_sequence(seq, tmp_path / "annotations.xml")
    loaded = cvat.load_cvat_sequence(frames, xml)
    assert np.array_equal(loaded.images, seq.images)
    assert np.allclose(loaded.boxes_px, seq.boxes_px, atol=0.05)
    box_centres = seq.boxes_px[:, :, :2] + 0.5 * seq.boxes_px[:, :, 2:]
    assert np.allclose(loaded.marker_px, box_centres, atol=0.05)
    metrics, t1 = cvat.benchmark_cvat_folder(frames, xml, trackers=("kcf", "k2cf"),
                                             out_dir=tmp_path / "out")
    assert list(metrics.tracker) == ["kcf", "k2cf"]
    assert np.all(metrics.main_precision_20px == 1.0) and np.all(metrics.aux_precision_20px == 1.0)
    assert (tmp_path / "out" / f"{loaded.name}_precision.png").exists()
    with pytest.raises(ValueError, match="binned"):
        cvat.load_cvat_sequence(frames, xml, PlantParams(camera={"sensor_width_px": 2000}))


def test_broken_transt_weights_fail_bench_trackers_naming_the_rows(tmp_path, monkeypatch):
    """Weights whose .sha256 is empty: ``bench-trackers --trackers gk_transt,kcf`` exits with
    status 2 and says which rows need the network and why, before any output is written (it
    exited 0 and left the GK-TransT rows out); the library call leaves them out and says so."""
    from typer.testing import CliRunner

    from experiments.cli import app
    from observer.transt.tracker import TransTTracker
    from observer.transt.weights import SMALL_WEIGHTS

    broken = tmp_path / "transt_small.pt"
    shutil.copy(SMALL_WEIGHTS, broken)
    (tmp_path / "transt_small.pt.sha256").write_text("")
    small = TransTTracker.small.__func__
    monkeypatch.setattr(TransTTracker, "small",
                        classmethod(lambda cls, weights=broken, **kw: small(cls, weights, **kw)))
    factories, note = tb.tracker_factories(["gk_transt", "kcf"])
    assert list(factories) == ["kcf"]
    assert "gk_transt skipped" in note and "is empty" in note
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["bench-trackers", "--seeds", "1", "--cases", "clean",
                                      "--frames", "3", "--trackers", "gk_transt,kcf",
                                      "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output and not out.exists()
    for words in ("gk_transt need the shipped TransT network", "is empty", "--stand-in"):
        assert words in result.output, result.output


def test_benchmark_variants_build_what_they_name():
    """``gk_transt_fullcrop`` is GK-TransT without the smaller search crop, beside the default
    that has it; the refine variants set the circle fit; an unknown name lists the known."""
    factories, note = tb.tracker_factories(
        ["gk_transt", "gk_transt_fullcrop", "gk_transt_norefine", "dual_transt_refine"])
    assert note == ""
    assert factories["gk_transt"]().steady_search_size == 96
    assert factories["gk_transt_norefine"]().steady_search_size == 96
    full = factories["gk_transt_fullcrop"]()
    assert full.steady_search_size is None and full.refine
    assert not factories["gk_transt_norefine"]().refine
    assert factories["dual_transt_refine"]().refine
    with pytest.raises(ValueError, match="gk_transt_fullcrop"):
        tb.tracker_factories(["gk_transt_cropped"])
