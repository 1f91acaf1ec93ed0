"""One timing model: the loop delay and update period of ``latency.pipeline.loop_timing`` against
the frame timeline the closed loop runs (``FrameScheduler``), and the scenario's camera check."""

import numpy as np
import pytest
from pydantic import ValidationError

from latency import Scenario
from latency.models import Constant
from latency.pipeline import FrameScheduler, PipelineConfig, loop_timing


@pytest.mark.parametrize("mode", ["sequential", "pipelined"])
@pytest.mark.parametrize("latency_ms", [0.0, 5.0, 16.33, 27.0, 31.23, 60.0, 90.0])
def test_loop_timing_matches_the_frame_timeline(mode, latency_ms):
    d = latency_ms / 1e3
    pipe = PipelineConfig(frame_rate_hz=36.0, exposure_s=2e-3, readout_s=1e-3,
                          observer=Constant(value_s=d), mode=mode)
    frames = FrameScheduler(pipe, np.random.default_rng(0)).schedule(3.0)
    kept = [f for f in frames if not f.dropped]
    period = np.diff([f.t_exposure for f in kept])
    latency = np.array([f.t_release - f.t_exposure for f in kept])
    t = loop_timing(d, mode=mode, frame_rate_hz=36.0, exposure_s=2e-3, readout_s=1e-3,
                    controller_compute_s=4e-3)
    assert period == pytest.approx(t.update_period_s, abs=1e-12)
    assert latency + 4e-3 == pytest.approx(t.delay_s, abs=1e-12)
    assert pipe.timing(4e-3) == t


def test_the_describe_line_names_the_case():
    t = loop_timing(0.03123, mode="sequential", frame_rate_hz=36.0, exposure_s=2e-3)
    line = t.describe()
    assert "sequential" in line and "1 frame in 2" in line and "55.56 ms" in line


def test_a_scenario_has_one_camera_timing():
    s = Scenario.model_validate({"plant": {"camera": {"frame_rate_hz": 60.0, "exposure_s": 1e-3}}})
    assert s.pipeline.frame_rate_hz == 60.0 and s.pipeline.exposure_s == 1e-3
    with pytest.raises(ValidationError, match="plant.camera.frame_rate_hz"):
        Scenario.model_validate({"pipeline": {"frame_rate_hz": 60.0}})
