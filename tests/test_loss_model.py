"""Calibrated tracking-loss models: the fit, the file rules and the front ends that use them."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

import latency.loss_model as lm
from latency import Scenario, build_loop, compiled, simulate_many
from latency.frontends import MeasurementConfig, MeasurementFrontEnd
from latency.loss_model import (
    FORMAT_VERSION,
    LossModelError,
    LossModelFile,
    fit_logistic,
    load_loss_model,
    sigmoid,
    write_loss_model,
)
from plant.params import PlantParams

pytestmark = pytest.mark.engine  # runs the compiled engines


def _file(tracker: str = "kcf_gk", hazard=(-3.0, 0.8, 0.3), persistence=(1.0, -0.2, 0.1, -0.4),
          **kw) -> LossModelFile:
    return LossModelFile(format_version=FORMAT_VERSION, tracker=tracker,
                         weights_sha256=lm.current_weights_sha256(tracker), hazard=hazard,
                         persistence=persistence, noise_sigma_px=0.3, n_frames=1, n_runs=1,
                         design={}, created_utc="2026-01-01T00:00:00+00:00", **kw)


@pytest.fixture()
def models(tmp_path, monkeypatch):
    """A private calibration folder in place of the package's."""
    monkeypatch.setattr(lm, "MODELS_DIR", tmp_path)
    lm._load.cache_clear()
    yield tmp_path
    lm._load.cache_clear()


def test_fit_recovers_a_known_logistic_model() -> None:
    rng = np.random.default_rng(0)
    X = rng.normal(size=(40_000, 2)) * [1.0, 2.0] + [3.0, -1.0]
    true = np.array([-1.5, 0.7, -0.4])
    y = rng.random(len(X)) < sigmoid(true[0] + X @ true[1:])
    est = fit_logistic(X, y, ridge=0.0)
    # the maximum-likelihood estimate's standard error here is about 0.02-0.04
    np.testing.assert_allclose(est, true, atol=0.1)


def test_fit_keeps_a_steep_hazard_steep() -> None:
    # a tracker that loses almost nothing at slow motion and quickly more beyond: a steep
    # hazard in log1p(offset), 50,000 frames of which about 160 are lost (like a calibration's)
    rng = np.random.default_rng(3)
    offset = rng.lognormal(np.log(4.0), 1.0, 50_000)
    blur = rng.lognormal(np.log(3.0), 0.7, 50_000)
    X = np.column_stack([np.log1p(offset), np.log1p(blur)])
    true = np.array([-22.0, 5.0, 0.4])
    y = rng.random(len(X)) < sigmoid(true[0] + X @ true[1:])
    est = fit_logistic(X, y)
    assert abs(est[1] - true[1]) < 0.6  # standard error about 0.25
    # at 5 px off and 3 px of blur the true hazard is 3.8e-6 per frame: no loss floor
    slow = np.array([np.log1p(5.0), np.log1p(3.0)])
    assert sigmoid(est[0] + slow @ est[1:]) < 2e-5


def test_fit_refuses_bad_shapes() -> None:
    with pytest.raises(ValueError, match="X must be"):
        fit_logistic(np.zeros((0, 2)), np.zeros(0))


def test_front_end_loses_frames_at_the_markov_chain_rate(models) -> None:
    # slopes zero: hazard p and persistence r per frame whatever the motion, so the stationary
    # lost fraction is p / (p + 1 - r) (two-state Markov chain)
    p, r = 0.05, 0.6
    write_loss_model(_file(hazard=(float(np.log(p / (1 - p))), 0.0, 0.0),
                           persistence=(float(np.log(r / (1 - r))), 0.0, 0.0, 0.0)))
    params = PlantParams()
    cfg = MeasurementConfig(loss={"kind": "calibrated", "tracker": "kcf_gk"})
    fe = MeasurementFrontEnd(params, cfg, np.random.default_rng(1))
    q, w = np.array([1.0, 0, 0, 0]), np.zeros(3)
    lost = np.array([fe.capture(q, w, 0.0).lost for _ in range(20_000)])
    expected = p / (p + 1 - r)
    assert abs(lost.mean() - expected) < 0.01
    # runs of losses are geometric with mean 1 / (1 - r)
    ends = np.flatnonzero(np.diff(lost.astype(int)) == -1)
    starts = np.flatnonzero(np.diff(lost.astype(int)) == 1)
    lengths = ends[ends > starts[0]][: len(starts)] - starts[: len(ends[ends > starts[0]])]
    assert abs(lengths.mean() - 1 / (1 - r)) < 0.15
    # tracked frames carry the calibrated noise
    z = [fe.capture(q, w, 0.0) for _ in range(4000)]
    err = np.array([c.marker_px - c.true_px for c in z if not c.lost]).ravel()
    assert abs(err.std() - 0.3) < 0.02


def test_a_scene_moves_both_intercepts(models) -> None:
    """Zero slopes again, base hazard 0.01 and persistence 0.2, and a scene whose offsets make
    them 0.05 and 0.6: the front end in that scene loses p / (p + 1 - r) of its frames."""
    def logit(x: float) -> float:
        return float(np.log(x / (1 - x)))

    write_loss_model(_file(hazard=(logit(0.01), 0.0, 0.0),
                           persistence=(logit(0.2), 0.0, 0.0, 0.0),
                           scene_offsets={"dim": (logit(0.05) - logit(0.01),
                                                  logit(0.6) - logit(0.2))}))
    q, w = np.array([1.0, 0, 0, 0]), np.zeros(3)
    for scene, p, r in (("nominal", 0.01, 0.2), ("dim", 0.05, 0.6)):
        cfg = MeasurementConfig(loss={"kind": "calibrated", "tracker": "kcf_gk", "scene": scene})
        fe = MeasurementFrontEnd(PlantParams(), cfg, np.random.default_rng(2))
        lost = np.array([fe.capture(q, w, 0.0).lost for _ in range(20_000)])
        assert abs(lost.mean() - p / (p + 1 - r)) < 0.01, scene
    with pytest.raises(ValueError, match="no scene 'foggy'; choose one of nominal, dim"):
        MeasurementConfig(loss={"kind": "calibrated", "tracker": "kcf_gk", "scene": "foggy"})


def _calibrated_scenario(seed: int, scene: str = "nominal") -> Scenario:
    return Scenario.model_validate({
        "duration_s": 1.5, "seed": seed, "observer": {"kind": "solver"},
        "reference": {"kind": "random", "args": {"seed": seed, "max_rate_rad_s": 6.0}},
        "pipeline": {"observer": {"kind": "constant", "value_s": 0.031}},
        "measurement": {"loss": {"kind": "calibrated", "tracker": "kcf_gk", "scene": scene}},
    })


@pytest.mark.parametrize("scene", ["nominal", "dim"])
def test_compiled_and_event_loop_lose_the_same_frames(models, scene) -> None:
    # a model that depends on the motion: the offset and blur features must agree too, and
    # the scene's offsets reach both engines
    write_loss_model(_file(hazard=(-4.0, 1.2, 0.5), persistence=(0.5, 0.3, -0.2, -0.5),
                           scene_offsets={"dim": (1.5, -1.0)}))
    scenarios = [_calibrated_scenario(s, scene) for s in (0, 1, 2)]
    assert all(compiled.coverage(build_loop(s)).path == "compiled" for s in scenarios)
    batched = simulate_many(scenarios, engine="batched")
    event = simulate_many(scenarios, engine="event")
    compared = 0
    for a, b in zip(event, batched, strict=True):
        np.testing.assert_array_equal(a.frames["lost"].to_numpy(dtype=float),
                                      b.frames["lost"].to_numpy(dtype=float))
        assert a.summary["lost_frame_fraction"] == pytest.approx(
            b.summary["lost_frame_fraction"], abs=1e-12)
        compared += 1
    assert compared == 3
    assert sum(r.summary["lost_frame_fraction"] for r in event) > 0  # the model did lose frames


def test_unknown_tracker_lists_the_known_ones() -> None:
    with pytest.raises(ValueError, match="gk_transt, dual_transt, kcf_gk, k2cf"):
        MeasurementConfig(loss={"kind": "calibrated", "tracker": "nope"})


def test_missing_file_names_the_command(models) -> None:
    with pytest.raises(ValueError, match="pmspm calibrate-loss --tracker k2cf"):
        MeasurementConfig(loss={"kind": "calibrated", "tracker": "k2cf"})


def test_file_of_another_version_is_refused(models) -> None:
    data = json.loads(_file().model_dump_json())
    data["format_version"] = FORMAT_VERSION + 1
    (models / "kcf_gk.json").write_text(json.dumps(data))
    with pytest.raises(LossModelError, match="format version"):
        load_loss_model("kcf_gk")


def test_file_from_other_weights_is_stale(models) -> None:
    write_loss_model(_file("gk_transt").model_copy(update={"weights_sha256": "0" * 64}))
    with pytest.raises(LossModelError, match="stale.*calibrate-loss --tracker gk_transt"):
        load_loss_model("gk_transt")


def test_a_failed_write_leaves_the_old_file(models, monkeypatch) -> None:
    write_loss_model(_file())
    before = (models / "kcf_gk.json").read_text()

    def broken(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(lm.os, "replace", broken)
    with pytest.raises(OSError):
        write_loss_model(_file(hazard=(0.0, 0.0, 0.0)))
    assert (models / "kcf_gk.json").read_text() == before
    assert [p.name for p in models.iterdir()] == ["kcf_gk.json"]  # no temporary file left


def test_search_window_keys_at_the_top_level_still_work_with_a_warning() -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cfg = MeasurementConfig(search_radius_px=120.0, reacquire_after_frames=3)
    assert cfg.window is not None and cfg.window.search_radius_px == 120.0
    assert cfg.window.reacquire_after_frames == 3
    assert any(issubclass(w.category, DeprecationWarning) for w in caught)
    with pytest.raises(ValueError, match="inside loss"):
        MeasurementConfig(search_radius_px=120.0, loss={"kind": "search_window"})


@pytest.mark.slow
def test_shipped_calibration_agrees_with_image_runs_it_was_not_fitted_on(tmp_path):
    """The shipped GK-TransT model against GK-TransT itself in closed loop, on references the
    fit did not use (reference seeds 2000-2003, 3.5 rad/s, 31.23 ms): lost-frame fraction and
    loss of control within each other's 95 % intervals."""
    from experiments.loss_calibration import (
        CalibrationDesign,
        CameraSetting,
        _run_records,
        validate,
    )

    design = CalibrationDesign(
        holdout_rates_rad_s=(3.5,), delays_ms=(31.23,), holdout_seeds=4,
        holdout_first_seed=2000, cameras=(CameraSetting(frame_rate_hz=36.0, exposure_ms=2.0),),
        appearances=("nominal",), model_replicas=4, duration_s=3.0)
    records = _run_records("gk_transt", design, design.points(True), workers=1)
    records["holdout"] = True
    rows = validate("gk_transt", records, design)
    assert len(rows) == 1 and rows[0]["image_runs"] == 4 and rows[0]["model_runs"] == 16
    assert rows[0]["agree"], rows[0]
