"""Metrics that fit the reference: step metrics only where the reference is piecewise
constant, NaN on smooth references (random, ramp, cone), whichever engine ran; the time to the
first lost frame; a step-metrics request on a smooth reference is refused."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from pydantic import ValidationError

from latency import Scenario, simulate
from latency.metrics import summarize
from tests.test_loss_of_control import H, _frames, _steps

pytestmark = pytest.mark.engine  # runs the compiled engines

STEP_KEYS = ("overshoot_pct", "settling_time_s", "step_size_deg", "steady_state_error_deg")


def test_a_smooth_reference_has_no_step_metrics_but_its_errors_are_measured():
    """A reference that moves on every row (a 2 Hz, 3° sine) followed 0.5° behind: the RMS
    and maximum error are 0.5°; the step metrics are NaN (with them on, the last row's change
    would be measured as a step of a few thousandths of a degree)."""
    t = np.arange(0, 2.0 + H / 2, H)
    ref = 3.0 * np.sin(2 * np.pi * 2 * t)
    steps = _steps(ref - 0.5, ref)
    frames = _frames(np.arange(0, 2, 1 / 36), np.zeros(72, bool))
    smooth = summarize(steps, frames, pd.DataFrame(), 2.0, step_metrics=False)
    assert smooth["rms_error_deg"] == pytest.approx(0.5, abs=1e-9)
    assert smooth["max_error_deg"] == pytest.approx(0.5, abs=1e-9)
    assert all(np.isnan(smooth[k]) for k in STEP_KEYS)
    as_step = summarize(steps, frames, pd.DataFrame(), 2.0)  # what measuring it as a step gives
    assert as_step["step_size_deg"] < 0.1


def test_time_to_first_loss_is_the_first_lost_frames_exposure():
    t_exp = np.arange(0, 2, 1 / 36)
    lost = (t_exp > 0.8) & (np.arange(len(t_exp)) % 2 == 0)
    t = np.arange(0, 2.0 + H / 2, H)
    r = summarize(_steps(np.zeros(len(t)), np.zeros(len(t))), _frames(t_exp, lost),
                  pd.DataFrame(), 2.0)
    assert r["time_to_first_loss_s"] == t_exp[lost][0]
    none = summarize(_steps(np.zeros(len(t)), np.zeros(len(t))),
                     _frames(t_exp, np.zeros(len(t_exp), bool)), pd.DataFrame(), 2.0)
    assert np.isnan(none["time_to_first_loss_s"])


@pytest.mark.parametrize("engine", ["batched", "event"])
def test_scenarios_measure_steps_on_step_references_only(engine):
    random_ref = {"kind": "random", "args": {"max_rate_rad_s": 2.0, "seed": 3}}
    ramp = {"kind": "ramp", "args": {"start_deg": [0, 0, 0], "stop_deg": [0, 4, 0],
                                     "duration_s": 0.3}}
    common = dict(duration_s=0.5, observer={"kind": "solver"})
    for ref in (random_ref, ramp):
        r = simulate(Scenario(reference=ref, **common), engine=engine).summary
        assert all(np.isnan(r[k]) for k in STEP_KEYS) and np.isfinite(r["rms_error_deg"])
    step = simulate(Scenario(reference={"kind": "tilt_step", "tilt_deg": 3.0}, **common),
               engine=engine).summary
    assert step["step_size_deg"] == pytest.approx(3.0)
    seed_steps = Scenario(reference={"kind": "seed_steps", "args": {"axis": "tilt",
                                                                   "dwell_s": 0.2}}, **common)
    assert seed_steps.loop_config().step_metrics


def test_asking_for_step_metrics_on_a_smooth_reference_is_an_error():
    for kind, args in (("random", {"max_rate_rad_s": 2.0}),
                       ("cone", {"tilt_deg": 5.0, "yaw_rate_rad_s": 1.0})):
        with pytest.raises(ValidationError, match=f"reference '{kind}': step_metrics needs a "
                           "piecewise-constant reference"):
            Scenario(reference={"kind": kind, "args": args, "step_metrics": True})
