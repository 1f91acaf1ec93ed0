"""Latency models and the frame pipeline's timing semantics."""

import numpy as np
import pytest
from pydantic import ValidationError

from latency.models import (
    SEED_LATENCY_S,
    Constant,
    Empirical,
    Gamma,
    Normal,
    Uniform,
    parse_latency,
    seed_profile,
)
from latency.pipeline import FrameScheduler, PipelineConfig
from tests.fake_clock import StepClock


def test_seed_profiles_are_table_1():
    assert seed_profile("gk_transt").value_s == pytest.approx(16.33e-3)
    assert seed_profile("dual_transt").value_s == pytest.approx(31.23e-3)
    assert seed_profile("kcf").value_s == pytest.approx(10.86e-3)
    assert seed_profile("csrt").value_s == pytest.approx(67.62e-3)
    # Table 1's FPS column is the inverse of its latency column.
    for name, fps in [("gk_transt", 61.23), ("dual_transt", 32.02), ("kcf", 92.05)]:
        assert 1 / SEED_LATENCY_S[name] == pytest.approx(fps, rel=2e-3)
    with pytest.raises(ValueError, match="gk_transt"):
        seed_profile("transt")


def test_distributions_match_their_moments():
    rng = np.random.default_rng(0)
    n = 20000
    g = Gamma(shape_k=4.0, scale_theta_s=2e-3, offset_s=10e-3)
    x = np.array([g.sample(rng) for _ in range(n)])
    assert x.mean() == pytest.approx(g.mean_s, rel=0.01)
    assert x.var() == pytest.approx(4.0 * (2e-3) ** 2, rel=0.05)  # k theta^2
    u = Uniform(low_s=0.01, high_s=0.02)
    y = np.array([u.sample(rng) for _ in range(n)])
    assert y.min() >= 0.01 and y.max() <= 0.02
    assert y.var() == pytest.approx(0.01**2 / 12, rel=0.05)
    nrm = Normal(mean_value_s=1e-3, std_s=2e-3)  # heavily truncated at 0
    z = np.array([nrm.sample(rng) for _ in range(n)])
    assert z.min() >= 0.0


def test_same_seed_same_latencies():
    m = Normal(mean_value_s=0.02, std_s=0.003)
    a = [m.sample(np.random.default_rng(5)) for _ in range(3)]
    b = [m.sample(np.random.default_rng(5)) for _ in range(3)]
    assert a == b


def test_empirical_profile_round_trip(tmp_path):
    measured = [0.012, 0.013, 0.0125, 0.020]
    prof = Empirical.from_measurements(measured, source="unit test")
    prof.save(tmp_path / "p.json")
    back = Empirical.load(tmp_path / "p.json")
    assert back == prof
    assert back.mean_s == pytest.approx(np.mean(measured))
    rng = np.random.default_rng(1)
    assert {back.sample(rng) for _ in range(200)} == set(measured)


def test_bad_latency_configs_name_the_field():
    with pytest.raises(ValidationError, match="value_s"):
        Constant(value_s=-0.01)
    with pytest.raises(ValidationError, match="high_s"):
        Uniform(low_s=0.02, high_s=0.01)
    with pytest.raises(ValidationError, match="samples_s"):
        Empirical(samples_s=(0.01, -0.002))
    with pytest.raises(ValidationError, match="frame_rate_hz"):
        PipelineConfig(frame_rate_hz=0.0)
    assert parse_latency({"kind": "gamma", "shape_k": 2, "scale_theta_s": 0.001}).mean_s == 0.002


def releases(profile, mode, duration=1.0):
    cfg = PipelineConfig(observer=seed_profile(profile), mode=mode)
    return FrameScheduler(cfg, np.random.default_rng(0)).schedule(duration)


def test_sequential_observer_drops_frames_while_busy():
    # 31.23 ms of processing at a 27.8 ms frame period: every second frame is dropped, so the
    # update rate halves; CSRT's 67.62 ms keeps one frame in three.
    for profile, keep_every in [("kcf", 1), ("gk_transt", 1), ("dual_transt", 2), ("csrt", 3)]:
        frames = releases(profile, "sequential")
        kept = [f.index for f in frames if not f.dropped]
        assert kept == list(range(0, 36, keep_every))
        for f in frames:
            if not f.dropped:
                assert f.latency_s == pytest.approx(1e-3 + SEED_LATENCY_S[profile])


def test_pipelined_observer_keeps_every_frame_in_order():
    frames = releases("csrt", "pipelined")
    assert not any(f.dropped for f in frames) and len(frames) == 36
    rel = [f.t_release for f in frames]
    assert rel == sorted(rel)
    assert frames[0].latency_s == pytest.approx(1e-3 + 67.62e-3)


def test_exposure_longer_than_the_frame_period_is_rejected():
    with pytest.raises(ValueError, match="exposure_s"):
        cfg = PipelineConfig(frame_rate_hz=500.0, exposure_s=0.004)
        FrameScheduler(cfg, np.random.default_rng())


def test_measuring_a_profile_is_one_call(tmp_path):
    from latency.profile import measure_locator_latency
    from observer.trackers import make_pair_tracker
    from plant.params import PlantParams

    p = PlantParams()
    # An injected clock (each reading 1-5 ms after the last) times each step as one clock
    # step, independently of the machine's load; the warm-up frames are not recorded.
    clock = StepClock(1e-3, 5e-3, seed=6)
    prof = measure_locator_latency(p, make_pair_tracker("kcf_gk", p, clock=clock), n_frames=15,
                                   warmup=2)
    assert len(prof.samples_s) == 15 and clock.calls == 2 * 17
    assert all(1e-3 - 1e-12 <= s <= 5e-3 + 1e-12 for s in prof.samples_s)
    assert "kcf_gk" in prof.source
    prof.save(tmp_path / "kcf.json")
    cfg = PipelineConfig(observer=Empirical.load(tmp_path / "kcf.json"))
    assert cfg.observer.mean_s == pytest.approx(prof.mean_s)


def test_measuring_the_orb_observer_profile_is_one_call(tmp_path):
    """The textured rotor's ORB-AEKF: one call gives its per-frame compute time as a
    profile, which a scenario with an ORB observer then takes as its (reproducible) latency."""
    from latency import Scenario, build_loop
    from latency.profile import measure_orb_latency
    from plant.params import PlantParams
    from plant.texture import TextureParams

    p = PlantParams()
    # The front end and the filter each read the injected clock twice per frame: two steps.
    clock = StepClock(2e-3, 20e-3, seed=7)
    prof = measure_orb_latency(p, "aekf", TextureParams(seed=2), n_frames=8, warmup=2,
                               clock=clock)
    assert len(prof.samples_s) == 8 and clock.calls == 4 * 10
    assert all(4e-3 - 1e-12 <= s <= 40e-3 + 1e-12 for s in prof.samples_s)
    assert "ORB-AEKF" in prof.source and "seed 2" in prof.source
    prof.save(tmp_path / "orb.json")
    s = Scenario.model_validate(
        {
            "mode": "image",
            "observer": {"kind": "orb_aekf"},
            "observer_latency": "model",
            "pipeline": {"observer": Empirical.load(tmp_path / "orb.json").model_dump()},
        }
    )
    assert build_loop(s).config.pipeline.observer.mean_s == pytest.approx(prof.mean_s)
    with pytest.raises(ValueError, match="method"):
        measure_orb_latency(p, "sift", n_frames=1)
