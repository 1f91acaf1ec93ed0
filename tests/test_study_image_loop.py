"""The study per tracker: the sweep's calibrated loss models and the image-engine section
beside them, with the calibrated models' held-out agreement."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import latency.loss_model as lm
from experiments.report import _calibration_section, _image_loop_section
from experiments.study_config import DUAL_MS, GK_MS, StudyConfig
from experiments.study_summary import _image_loop_lines
from experiments.study_sweep import (
    _overlap,
    _twin,
    calibration_conditions,
    calibration_table,
    image_loop,
    image_loop_scenarios,
    sweep_configs,
)
from latency import Scenario
from plant.params import PlantParams

pytestmark = pytest.mark.engine  # runs the compiled engines


@pytest.fixture()
def models(tmp_path, monkeypatch):
    """Calibrations of both trackers in a private folder: a tracker that never loses a frame
    (GK-TransT) and one that loses one in five whatever the motion (dual TransT)."""
    folder = tmp_path / "models"
    monkeypatch.setattr(lm, "MODELS_DIR", folder)
    lm._load.cache_clear()
    p = 0.2
    for tracker, hazard in (("gk_transt", -30.0), ("dual_transt", float(np.log(p / (1 - p))))):
        lm.write_loss_model(lm.LossModelFile(
            format_version=lm.FORMAT_VERSION, tracker=tracker,
            weights_sha256=lm.current_weights_sha256(tracker), hazard=(hazard, 0.0, 0.0),
            persistence=(hazard, 0.0, 0.0, 0.0), noise_sigma_px=0.2, n_frames=10, n_runs=1,
            design={}, created_utc="2026-01-01T00:00:00+00:00",
            lost_by_condition=[
                {"frame_rate_hz": 36.0, "exposure_ms": 2.0, "frames": 900,
                 "lost_frame_fraction": 0.25 * p if tracker == "dual_transt" else 0.0},
                {"appearance": "dim", "frames": 400,
                 "lost_frame_fraction": p if tracker == "dual_transt" else 0.0}],
            validation=[{"delay_ms": 16.33, "rate_rad_s": 2.0, "image_runs": 4, "model_runs": 16,
                         "image_lost_frame_fraction": [0.1, 0.05, 0.15],
                         "model_lost_frame_fraction": [0.12, 0.1, 0.14],
                         "image_loss_of_control": [0.0, 0.0, 0.49],
                         "model_loss_of_control": [0.0, 0.0, 0.19], "agree": True}]))
    yield folder
    lm._load.cache_clear()


def test_sweep_has_each_tracker_with_its_own_calibrated_loss(models):
    cfg = StudyConfig(n_seeds=3, delays_ms=(GK_MS, DUAL_MS), max_rates_rad_s=(1.0, 3.0))
    configs = sweep_configs(cfg, PlantParams())
    random_pid = [c for c in configs if c["study"]["controller"] in ("pid", "mpc")
                  and c["study"]["reference"].startswith("random")]
    # every tracker on each PID / MPC random point: 2 delays x 2 rates x 2 controllers x
    # 2 trackers x 3 seeds, the tracker's own model in each
    assert len(random_pid) == 2 * 2 * 2 * 2 * 3
    for c in random_pid:
        assert c["measurement"]["loss"] == {"kind": "calibrated",
                                            "tracker": c["study"]["tracker"], "noise": "calibrated",
                                            "scene": "nominal"}
    # the step and the variants with the first tracker only
    others = [c for c in configs if c not in random_pid]
    assert others and {c["study"]["tracker"] for c in others} == {"gk_transt"}


def test_search_window_mode_is_the_same_for_every_tracker(models):
    cfg = StudyConfig(n_seeds=1, delays_ms=(GK_MS,), max_rates_rad_s=(3.0,),
                      loss_model="search_window", search_radius_px=123.0)
    losses = {str(c["measurement"]["loss"]) for c in sweep_configs(cfg, PlantParams())}
    assert len(losses) == 1 and "123.0" in losses.pop()


def test_image_loop_runs_each_tracker_at_its_own_latency_by_default(models):
    jobs = image_loop_scenarios(StudyConfig(image_loop_n_seeds=2), PlantParams())
    delays = {(b["tracker"], round(b["vision_delay_ms"], 2)) for b, _ in jobs}
    assert delays == {("gk_transt", round(GK_MS, 2)), ("dual_transt", round(DUAL_MS, 2))}
    assert len(jobs) == 2 * 3 * 2


def test_image_loop_runs_each_tracker_at_both_seed_latencies(models):
    cfg = StudyConfig(image_loop_n_seeds=3, image_loop_rates_rad_s=(1.0, 6.0),
                      image_loop_delays="both")
    jobs = image_loop_scenarios(cfg, PlantParams())
    assert len(jobs) == 2 * 2 * 2 * 3
    seeds_per_point: dict[tuple, set] = {}
    for book, s in jobs:
        assert s.mode == "image" and s.tracker == book["tracker"]
        assert s.pipeline.observer.mean_s * 1e3 == pytest.approx(book["vision_delay_ms"])
        assert s.reference.args["seed"] == book["reference_seed"]
        key = (book["tracker"], book["vision_delay_ms"], book["max_rate_rad_s"])
        seeds_per_point.setdefault(key, set()).add(book["reference_seed"])
        twin = _twin(s, book["tracker"])
        assert twin.mode == "measurement" and twin.reference == s.reference
        assert twin.seed == s.seed and twin.duration_s == s.duration_s
        assert twin.pipeline == s.pipeline
        assert twin.measurement.loss.tracker == book["tracker"]
    assert {round(k[1], 2) for k in seeds_per_point} == {round(GK_MS, 2), round(DUAL_MS, 2)}
    # references vary within a point: as many reference seeds as runs
    assert all(len(v) == 3 for v in seeds_per_point.values())


def test_overlap_of_intervals():
    row = pd.Series({"a": 0.1, "a_lo": 0.05, "a_hi": 0.2, "b": 0.3, "b_lo": 0.21, "b_hi": 0.4,
                     "c": 0.0, "c_lo": np.nan, "c_hi": np.nan})
    assert not _overlap(row, "a", "b")
    assert _overlap(pd.concat([row.drop("b_lo"), pd.Series({"b_lo": 0.2})]), "a", "b")
    assert not _overlap(row, "c", "a")  # an interval without ends is its value, 0 < 0.05


def test_calibration_table_reads_the_files(models):
    t = calibration_table(("gk_transt", "dual_transt"))
    assert len(t) == 2 and t.agree.all()
    assert t.image_lost_frame_fraction_lo.tolist() == [0.05, 0.05]
    text = "\n".join(_calibration_section(t))
    assert "held-out" in text and "dual_transt" in text
    c = calibration_conditions(("gk_transt", "dual_transt"))
    assert len(c) == 4 and set(c.condition) == {"36 Hz, 2 ms exposure", "scene: dim"}
    lines = "\n".join(_calibration_section(t, c)).splitlines()
    # one row per condition, the trackers in columns, in percent: dual TransT's 5 % and 20 %
    assert "| condition | dual_transt | gk_transt |" in lines
    assert "| 36 Hz, 2 ms exposure | 5.000 | 0.000 |" in lines
    assert "| scene: dim | 20.000 | 0.000 |" in lines


@pytest.mark.slow
def test_image_loop_side_by_side_with_the_models(models, tmp_path):
    cfg = StudyConfig(image_loop_n_seeds=2, image_loop_rates_rad_s=(3.0,),
                      image_loop_duration_s=0.8, workers=1)
    table = image_loop(cfg, PlantParams(), tmp_path)
    assert set(table.tracker) == {"gk_transt", "dual_transt"} and len(table) == 2
    assert (table.image_n_runs == 2).all() and (table.model_n_runs == 2).all()
    runs = pd.read_parquet(tmp_path / "image_loop.parquet")
    assert set(runs.side) == {"image", "model"}
    image = runs[runs.side == "image"]
    # the counts behind the lost-frame fractions (0.8 s at 36 frames/s; the dual TransT at
    # 31.23 ms processes every second frame)
    assert (image.processed_frames >= 14).all()
    np.testing.assert_allclose(image.lost_frames / image.processed_frames,
                               image.lost_frame_fraction)
    model = runs[runs.side == "model"].groupby("tracker").lost_frame_fraction.mean()
    # the stand-in models: GK-TransT never loses a frame; the dual TransT about one in five
    assert model["gk_transt"] == 0.0 and 0.05 < model["dual_transt"] < 0.4
    text = "\n".join(_image_loop_section(table, cfg))
    assert "up to" in text and "gk_transt" in text
    assert "agrees on" in _image_loop_lines(table)[0]


def test_scenario_names_for_the_study_trackers():
    for tracker in ("gk_transt", "dual_transt"):
        assert Scenario.model_validate({"mode": "image", "tracker": tracker}).tracker == tracker


def test_report_quotes_the_network_alone_on_the_unseen_source_for_these_weights(tmp_path):
    """The report quotes the committed accuracy file's figures only when it was measured on
    weights with the SHA-256 of the weights in use; otherwise it says so and how to rerun."""
    import json
    import shutil

    from experiments.report import network_alone_unseen_lines
    from observer.transt.weights import SMALL_WEIGHTS, verify

    w = tmp_path / "w.pt"
    shutil.copy(SMALL_WEIGHTS, w)
    shutil.copy(SMALL_WEIGHTS.with_name(SMALL_WEIGHTS.name + ".sha256"), tmp_path / "w.pt.sha256")
    acc = tmp_path / "unseen_accuracy.json"
    figures = {"clean_main_precision_20px": 0.612, "clean_aux_precision_20px": 0.7,
               "clean_main_err_median_px": 18.1, "clean_aux_err_median_px": 9.25}
    record = {"weights_sha256": verify(w), "figures": figures, "cases": ["clean"], "seeds": 1,
              "frames": 300, "date": "2026-12-06T04:00:00"}
    acc.write_text(json.dumps(record))
    text = " ".join(network_alone_unseen_lines(acc, w))
    for words in ("precision@20px 0.612 / 0.700", "median error 18.1 / 9.2 sensor px",
                  "plant.render_unseen", verify(w)[:12]):
        assert words in text, text
    acc.write_text(json.dumps(record | {"weights_sha256": "f" * 64}))
    text = " ".join(network_alone_unseen_lines(acc, w))
    assert "measured on other weights" in text and "0.612" not in text
    assert "bench_transt_unseen.py" in text
    acc.unlink()
    assert "not measured for these weights" in " ".join(network_alone_unseen_lines(acc, w))
