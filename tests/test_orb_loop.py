"""The ORB-AEKF observer closes the timed loop on the textured rotor (it plugs into the
closed loop with its measured latency)."""

import numpy as np
import pytest
from pydantic import ValidationError

from latency import Scenario, build_loop
from latency.frontends import OrbFrontEnd
from latency.loop import ClosedLoop
from latency.loop_config import LoopConfig
from observer.orb import OrbReference
from observer.orb_observer import OrbObserver
from plant import attitude as A
from plant.params import PlantParams
from plant.render_analytic import AnalyticRenderer, AnalyticRenderOptions
from plant.texture import TextureParams
from tests.fake_clock import StepClock
from tests.test_loop import PD, TiltStep

P = PlantParams()


def test_orb_aekf_closes_the_loop_with_its_measured_latency():
    renderer = AnalyticRenderer(P, options=AnalyticRenderOptions(texture=TextureParams()), seed=3)
    ref_frame = renderer.render([1.0, 0.0, 0.0, 0.0])
    reference = OrbReference.capture(ref_frame.image, ref_frame.binning, P)
    # The injected clock reads 5-15 ms after its last reading (about the ORB front end's time on
    # this machine), whatever the machine's load.
    clock = StepClock(5e-3, 15e-3, seed=1)
    observer = OrbObserver(P, reference, method="aekf", clock=clock)
    cfg = LoopConfig(duration_s=1.2, observer_latency="measured")
    loop = ClosedLoop(
        P, PD(), TiltStep(tilt_deg=3.0), OrbFrontEnd(renderer, observer), observer, cfg
    )
    r = loop.run()
    assert r.summary["diverged"] == 0.0
    assert r.summary["lost_frame_fraction"] == 0.0
    assert r.steps["error_deg"].iloc[-200:].max() < 0.3
    # The latency is what the ORB front end measured: one step of the clock per frame.
    processed = r.frames[~r.frames.dropped & r.frames.latency_s.notna()]
    assert np.all((processed.observer_compute_s >= 5e-3 - 1e-12)
                  & (processed.observer_compute_s <= 15e-3 + 1e-12))
    assert np.allclose(
        processed.latency_s, 0.5 * P.camera.exposure_s + processed.observer_compute_s, atol=1e-9
    )


# --- from a scenario (latency.scenario) ------------------------------------------------
def test_orb_aekf_scenario_closes_the_loop():
    """``observer.kind: orb_aekf`` in image mode builds the textured rotor, the ORB front end
    and the ORB-AEKF, with the front end's measured latency, and closes the loop."""
    s = Scenario.model_validate(
        {
            "duration_s": 1.5,
            "mode": "image",
            "observer": {"kind": "orb_aekf"},
            "texture": {"seed": 3},
            "controller": {"kind": "pid", "config": {"crossover_rad_s": 25.0}},
            "reference": {"kind": "tilt_step", "tilt_deg": 3.0},
        }
    )
    assert s.observer_latency == "measured" and s.texture.seed == 3
    loop = build_loop(s, StepClock(5e-3, 15e-3, seed=2))  # 5-15 ms per frame, load-free
    assert isinstance(loop.front_end, OrbFrontEnd) and isinstance(loop.observer, OrbObserver)
    assert loop.observer.method == "aekf" and loop.observer.filter_config.adaptive
    assert loop.config.observer_latency == "measured"
    r = loop.run()
    assert r.summary["diverged"] == 0.0 and r.summary["lost_frame_fraction"] == 0.0
    assert r.steps["error_deg"].iloc[-300:].max() < 0.3  # at the 3° target after 1.2 s
    processed = r.frames[~r.frames.dropped & r.frames.latency_s.notna()]
    assert len(processed) > 30 and processed.est_valid.all()
    assert np.allclose(
        processed.latency_s, 0.5 * P.camera.exposure_s + processed.observer_compute_s, atol=1e-9
    )
    # The released estimates follow the truth at their release time (1 ms grid of the log).
    steps = r.steps.set_index(np.round(r.steps.t_s * 1e3).astype(int))
    for _, f in processed.iterrows():
        q_true = steps.loc[round(f.t_release_s * 1e3), ["qw", "qx", "qy", "qz"]].to_numpy()
        q_est = f[["est_qw", "est_qx", "est_qy", "est_qz"]].to_numpy(float)
        assert np.degrees(A.geodesic_angle(q_true, q_est)) < 0.1


def test_orb_scenario_kinds_and_wrong_combinations():
    for kind, method in (("orb", "orb"), ("orb_ekf", "ekf"), ("orb_aekf", "aekf")):
        s = Scenario.model_validate({"mode": "image", "observer": {"kind": kind}})
        assert s.texture is not None and s.texture.seed == 0  # the default print
        assert s.observer.aekf.window_N == 10 and s.observer.aekf.theta == 0.8  # seed 001
        assert Scenario.model_validate(s.model_dump(mode="json")) == s
        observer = build_loop(s).observer
        assert observer.method == method
        assert observer.filter_config.adaptive == (method == "aekf")
    # No measurement model of ORB matches: the error names the field and what to do.
    with pytest.raises(ValidationError) as err:
        Scenario.model_validate({"observer": {"kind": "orb_aekf"}})
    (e,) = err.value.errors()
    assert e["loc"] == ("observer",) and "mode: image" in e["msg"]
    # The textured rotor has no markers for the marker observers.
    with pytest.raises(ValidationError) as err:
        Scenario.model_validate({"mode": "image", "texture": {"seed": 1}})
    (e,) = err.value.errors()
    assert e["loc"] == ("texture",) and "no markers" in e["msg"]
    with pytest.raises(ValidationError) as err:
        Scenario.model_validate({"mode": "image", "observer": {"kind": "orb"}, "texture": None})
    assert err.value.errors()[0]["loc"] == ("texture",)
    with pytest.raises(ValidationError) as err:  # the texture seed is validated
        Scenario.model_validate(
            {"mode": "image", "observer": {"kind": "orb"}, "texture": {"seed": -1}}
        )
    assert err.value.errors()[0]["loc"] == ("texture", "seed")
    # A measured observer latency needs something that computes.
    with pytest.raises(ValidationError) as err:
        Scenario.model_validate({"observer_latency": "measured"})
    assert err.value.errors()[0]["loc"] == ("observer_latency",)
