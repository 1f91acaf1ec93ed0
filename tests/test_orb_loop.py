"""The ORB-AEKF observer closes the timed loop on the textured rotor (issue 8: it plugs into the
closed loop with its measured latency)."""

import numpy as np

from latency.frontends import OrbFrontEnd
from latency.loop import ClosedLoop, LoopConfig
from observer.orb import OrbReference
from observer.orb_observer import OrbObserver
from plant.params import PlantParams
from plant.render_analytic import AnalyticRenderer, AnalyticRenderOptions
from plant.texture import TextureParams
from tests.test_loop import PD, TiltStep

P = PlantParams()


def test_orb_aekf_closes_the_loop_with_its_measured_latency():
    renderer = AnalyticRenderer(P, options=AnalyticRenderOptions(texture=TextureParams()), seed=3)
    ref_frame = renderer.render([1.0, 0.0, 0.0, 0.0])
    reference = OrbReference.capture(ref_frame.image, ref_frame.binning, P)
    observer = OrbObserver(P, reference, method="aekf")
    cfg = LoopConfig(duration_s=1.2, observer_latency="measured")
    loop = ClosedLoop(
        P, PD(), TiltStep(tilt_deg=3.0), OrbFrontEnd(renderer, observer), observer, cfg
    )
    r = loop.run()
    assert r.summary["diverged"] == 0.0
    assert r.summary["lost_frame_fraction"] == 0.0
    assert r.steps["error_deg"].iloc[-200:].max() < 0.3
    # The latency is what the ORB front end and the filter measured on this machine.
    processed = r.frames[~r.frames.dropped & r.frames.latency_s.notna()]
    assert np.all(processed.latency_s > 0.5 * P.camera.exposure_s)
    assert np.allclose(
        processed.latency_s, 0.5 * P.camera.exposure_s + processed.observer_compute_s, atol=1e-9
    )
