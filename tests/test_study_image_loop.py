"""The study's image-mode section: the loop closed on rendered frames tracked by GK-TransT and
by the dual TransT, each at its own measured latency profile, with intervals; without
``--full`` the report says how to get it."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from experiments.report import _image_loop_section
from experiments.scenario import Scenario
from experiments.study import (
    IMAGE_TRACKERS,
    StudyConfig,
    _image_loop_lines,
    image_loop,
    image_loop_configs,
)
from latency.models import Empirical
from plant.params import PlantParams

#: Stand-ins for the profiles ``measure_here`` writes: fixed samples, so that the runs do not
#: depend on this machine's speed; 25 ms apart.
PROFILES = {"gk_transt": Empirical(samples_s=(0.019, 0.020, 0.021), source="test"),
            "dual_transt": Empirical(samples_s=(0.044, 0.045, 0.046), source="test")}


def test_image_loop_configs_close_the_loop_on_each_tracker_at_its_latency():
    cfg = StudyConfig(n_seeds=5, image_loop_n_seeds=3, max_rates_rad_s=(1.0, 4.0),
                      duration_s=1.0)
    configs = image_loop_configs(cfg, PlantParams(), PROFILES)
    # 2 trackers x (the step, the fastest random reference) x (PID, MPC) x 3 seeds (the image
    # section's own seed count, not the sweep's)
    assert len(configs) == 2 * 2 * 2 * 3
    assert {c["seed"] for c in configs} == {0, 1, 2}
    for c in configs:
        study = c["study"]
        s = Scenario.model_validate({k: v for k, v in c.items() if k != "study"})
        assert s.mode == "image" and s.tracker == IMAGE_TRACKERS[study["tracker"]]
        assert s.pipeline.observer == PROFILES[study["tracker"]]
        assert study["delay_ms"] == pytest.approx(
            1e3 * float(np.median(PROFILES[study["tracker"]].samples_s)))
        assert study["reference"] in ("tilt_step_5deg", "random_4rad_s")
    assert {c["study"]["tracker"] for c in configs} == {"gk_transt", "dual_transt"}


def test_without_full_the_report_says_how_to_get_the_section():
    for text in ("\n".join(_image_loop_section(None, 2)), _image_loop_lines(None)[0]):
        assert "pmspm study --full" in text and "dual TransT" in text


@pytest.mark.slow
def test_image_loop_runs_both_trackers_with_intervals(tmp_path):
    cfg = StudyConfig(image_loop_n_seeds=1, max_rates_rad_s=(), duration_s=0.6, workers=1)
    for name, profile in PROFILES.items():
        profile.save(tmp_path / f"latency_{name}.json")
    table = image_loop(cfg, PlantParams(), tmp_path)
    assert set(table.tracker) == {"gk_transt", "dual_transt"}
    assert set(table.controller) == {"pid", "mpc"} and (table.n_runs == 1).all()
    assert table.lost_frame_fraction.between(0.0, 1.0).all()
    assert np.isfinite(table.rms_error_deg).all()
    runs = pd.read_parquet(tmp_path / "image_loop.parquet")
    assert (runs.error == "").all()
    # each tracker ran at its own latency: the dual TransT's runs lag 25 ms more
    lag = runs.groupby("tracker").mean_latency_s.mean()
    assert lag["dual_transt"] - lag["gk_transt"] == pytest.approx(0.025, abs=2e-3)
    text = "\n".join(_image_loop_section(table, cfg.image_loop_n_seeds))
    assert "gk_transt" in text and "dual_transt" in text


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
