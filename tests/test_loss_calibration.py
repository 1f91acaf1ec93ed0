"""The loss calibration's design: cameras and scene appearances reach the image runs, the design
is balanced, and a collection resumes instead of running again."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pandas as pd
import pytest
from pydantic import ValidationError

import experiments.loss_calibration as cal
from experiments.loss_calibration import APPEARANCES, CalibrationDesign, CameraSetting, collect
from latency import Scenario, build_loop

pytestmark = pytest.mark.engine

IMAGE = {"mode": "image", "observer": {"kind": "solver"}, "duration_s": 0.5}


def _mean_grey(camera_effects: dict | None) -> float:
    """Mean grey level (0-255) of the first rendered frame of an image scenario at rest."""
    body = {**IMAGE, "camera_effects": camera_effects}
    renderer = build_loop(Scenario.model_validate(body)).front_end.renderer
    return float(renderer.render(np.array([1.0, 0.0, 0.0, 0.0])).image.mean())


def test_camera_effects_reach_the_renderer() -> None:
    """The renderer multiplies the scene's brightness by ``illumination`` (no read noise here,
    gain 1): the frame's mean grey level scales with it, to the rounding to 8 bits."""
    bright = _mean_grey({"noise_sigma_dn": 0.0})
    dim = _mean_grey({"noise_sigma_dn": 0.0, "illumination": 0.35})
    assert bright > 20.0
    assert dim / bright == pytest.approx(0.35, abs=0.02)


@pytest.mark.parametrize(("extra", "match"), [
    ({"mode": "measurement"}, "need mode: image"),
    ({"renderer": "mujoco"}, "renderer: analytic"),
    ({"camera_effects": {"texture": {"seed": 1}}}, "texture field"),
    ({"camera_effects": {"illumination": -1.0}}, "illumination"),
])
def test_camera_effects_where_they_do_not_apply_are_refused(extra: dict, match: str) -> None:
    body = {**IMAGE, "camera_effects": {"illumination": 0.5}, **extra}
    with pytest.raises(ValidationError, match=match):
        Scenario.model_validate(body)


def test_design_meets_every_appearance_with_every_camera_and_keeps_seeds_apart() -> None:
    design = CalibrationDesign()
    fit, held = design.points(False), design.points(True)
    assert len(fit) == len(design.fit_rates_rad_s) * len(design.delays_ms) * \
        len(design.cameras) * design.fit_seeds
    pairs = {(p.appearance, p.camera) for p in fit}
    assert pairs == {(a, c) for a in design.appearances for c in design.cameras}
    n_app = len(design.appearances)
    for seed in range(design.fit_seeds):  # each seed's runs spread evenly over the scenes
        counts = Counter(p.appearance for p in fit if p.reference_seed == seed)
        per_seed = len(fit) // design.fit_seeds
        assert set(counts) == set(design.appearances)
        assert set(counts.values()) <= {per_seed // n_app, -(-per_seed // n_app)}
    for d, r, c in {(p.delay_ms, p.rate_rad_s, p.camera) for p in fit}:  # and over seeds
        assert {p.appearance for p in fit if (p.delay_ms, p.rate_rad_s, p.camera) == (d, r, c)} \
            == set(design.appearances)
    assert {p.reference_seed for p in fit}.isdisjoint({p.reference_seed for p in held})
    assert len({p.name for p in fit + held}) == len(fit) + len(held)
    with pytest.raises(ValidationError, match="among the fit's"):
        CalibrationDesign(fit_seeds=8, holdout_first_seed=5)
    with pytest.raises(ValidationError, match="unknown appearance"):
        CalibrationDesign(appearances=("nominal", "foggy"))
    assert set(APPEARANCES) >= set(design.appearances)


def test_collection_records_the_camera_and_resumes(tmp_path, monkeypatch) -> None:
    """A small design (two cameras, two appearances, one seed each side) of KCF inside the GK
    assistance: every run's processed frames number its duration times its frame rate, each
    record carries its run's camera and appearance, and a second call reads the batches back
    instead of running them."""
    design = CalibrationDesign(
        fit_rates_rad_s=(3.0,), holdout_rates_rad_s=(2.0,), delays_ms=(0.0,), fit_seeds=1,
        holdout_seeds=1, cameras=(CameraSetting(frame_rate_hz=36.0, exposure_ms=2.0),
                                  CameraSetting(frame_rate_hz=60.0, exposure_ms=6.0)),
        appearances=("nominal", "dim"), duration_s=0.6)
    records = collect("kcf_gk", design, tmp_path, workers=1, batch_runs=3, progress=False)
    runs = records.groupby("run").agg(frames=("lost", "size"), fps=("frame_rate_hz", "first"),
                                      exp=("exposure_ms", "first"),
                                      app=("appearance", "first"), holdout=("holdout", "first"))
    assert len(runs) == 4 and runs["holdout"].sum() == 2
    np.testing.assert_allclose(runs["frames"], design.duration_s * runs["fps"], atol=1.0)
    for pt in design.points(False) + design.points(True):
        row = runs.loc[f"kcf_gk-{pt.name}"]
        assert (row["fps"], row["exp"], row["app"]) == (
            pt.camera.frame_rate_hz, pt.camera.exposure_ms, pt.appearance)
    assert sorted(p.name for p in tmp_path.glob("records-*.parquet")) == \
        ["records-000.parquet", "records-001.parquet"]

    def no_runs(*args, **kwargs):
        raise AssertionError("a resumed collection ran again")

    monkeypatch.setattr(cal, "_run_records", no_runs)
    again = collect("kcf_gk", design, tmp_path, workers=1, batch_runs=3, progress=False)
    pd.testing.assert_frame_equal(again, records)
    with pytest.raises(ValueError, match="another design"):
        collect("kcf_gk", design.model_copy(update={"duration_s": 0.7}), tmp_path,
                workers=1, progress=False)
    for bad in (0, True, 2.0):
        with pytest.raises(ValueError, match="workers must be an integer"):
            collect("kcf_gk", design, tmp_path, workers=bad, progress=False)


def test_fit_recovers_known_scene_offsets_and_the_model_applies_them(tmp_path, monkeypatch):
    """Records drawn from a known two-state model whose intercepts differ by scene: the fit
    recovers the shared slopes and each scene's offsets (about 0.05-0.1 standard error at this
    size), and the loaded model's loss probability in a scene is the logistic of the offset
    intercept, computed here by hand."""
    import latency.loss_model as lm

    rng = np.random.default_rng(3)
    design = CalibrationDesign(appearances=("nominal", "dim", "highlights"))
    h, r = np.array([-3.0, 0.8, 0.3]), np.array([1.0, -0.5, 0.2, -0.6])
    true = {"nominal": (0.0, 0.0), "dim": (1.2, -0.7), "highlights": (-0.8, 0.9)}
    n = 60_000
    scene = rng.choice(list(true), size=n)
    offset, blur = rng.gamma(2.0, 3.0, n), rng.gamma(2.0, 1.5, n)
    frames_lost = rng.integers(0, 6, n)
    a, b, c = np.log1p(offset), np.log1p(blur), np.log1p(frames_lost)
    dh = np.array([true[s][0] for s in scene])
    dr = np.array([true[s][1] for s in scene])
    logit = np.where(frames_lost == 0, h[0] + dh + h[1] * a + h[2] * b,
                     r[0] + dr + r[1] * a + r[2] * b + r[3] * c)
    records = pd.DataFrame({
        "offset_px": offset, "blur_px": blur, "frames_lost": frames_lost,
        "lost": rng.random(n) < 0.5 * (1 + np.tanh(0.5 * logit)), "appearance": scene,
        "holdout": False, "run": "r", "frame_rate_hz": 36.0, "exposure_ms": 2.0,
        **{f"err_{k}_px": rng.normal(0, 0.3, n) for k in ("red_u", "red_v")}})
    data = cal.fit("kcf_gk", records, design)
    np.testing.assert_allclose(data.hazard, h, atol=0.25)
    np.testing.assert_allclose(data.persistence, r, atol=0.25)
    assert set(data.scene_offsets) == {"dim", "highlights"}
    for s in ("dim", "highlights"):
        np.testing.assert_allclose(data.scene_offsets[s], true[s], atol=0.25)

    monkeypatch.setattr(lm, "MODELS_DIR", tmp_path)
    lm._load.cache_clear()
    lm.write_loss_model(data)
    dim = lm.load_loss_model("kcf_gk", scene="dim")
    base = lm.load_loss_model("kcf_gk")
    assert dim.scenes == ("nominal", "dim", "highlights")
    for lost_before in (0, 3):
        hz = data.hazard if lost_before == 0 else data.persistence
        off = data.scene_offsets["dim"][0 if lost_before == 0 else 1]
        feats = [np.log1p(4.0), np.log1p(2.0)] + ([np.log1p(3)] if lost_before else [])
        want = 1.0 / (1.0 + np.exp(-(hz[0] + off + np.dot(hz[1:], feats))))
        assert dim.p_lost(4.0, 2.0, lost_before) == pytest.approx(want, rel=1e-12)
        assert base.p_lost(4.0, 2.0, lost_before) != pytest.approx(want, rel=1e-3)
    with pytest.raises(lm.LossModelError, match="choose one of nominal, dim, highlights"):
        lm.load_loss_model("kcf_gk", scene="foggy")
    lm._load.cache_clear()


def test_validation_counts_the_image_runs_frames(monkeypatch) -> None:
    """Held-out image runs that lost no frame against model twins that lose a few: the image
    side's interval is the exact binomial one of its pooled frames, not a bootstrap's [0, 0],
    so a model losing 0.05 % agrees and one losing 2 % does not (the runs' frames are counted
    from the records; the twins are stubbed)."""
    design = CalibrationDesign(
        fit_rates_rad_s=(3.0,), holdout_rates_rad_s=(2.0,), delays_ms=(0.0,), holdout_seeds=4,
        cameras=(CameraSetting(frame_rate_hz=36.0, exposure_ms=2.0),), appearances=("nominal",),
        model_replicas=2)
    points = design.points(True)
    records = pd.DataFrame(
        [{"run": pt.run_name("kcf_gk"), "holdout": True, "lost": False,
          "run_lost_frame_fraction": 0.0, "run_loss_of_control": 0.0}
         for pt in points for _ in range(500)])

    class Twin:
        def __init__(self, lost: float) -> None:
            self.summary = {"lost_frame_fraction": lost, "loss_of_control": 0.0}

    def twins_losing(rates: list[float]):
        return lambda scenarios, tables: [Twin(rates[i % len(rates)])
                                          for i in range(len(scenarios))]

    monkeypatch.setattr(cal, "simulate_many", twins_losing([0.0, 0.001]))
    (row,) = cal.validate("kcf_gk", records, design)
    n = 4 * 500  # pooled frames of the four image runs
    assert row["image_lost_frame_fraction"][2] == pytest.approx(1 - 0.025 ** (1 / n))
    assert row["agree"]
    monkeypatch.setattr(cal, "simulate_many", twins_losing([0.01, 0.03]))
    (row,) = cal.validate("kcf_gk", records, design)
    assert not row["agree"]
