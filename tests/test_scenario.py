"""Scenario defaults that depend on the controller: the MPC's compute time counts as latency
, by default as its median call time measured here, or measured per call."""

import json
import time
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from controller.registry import MPCSpec
from latency import Scenario, build_loop
from latency.models import Constant
from latency.scenario import MPC_CALL_MEDIAN_S
from tests.fake_clock import StepClock

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"


class Spy:
    """Wraps the loop's observer and records when each command takes effect
    (``ClosedLoop._on_command`` reports every applied torque to ``record_torque``)."""

    def __init__(self, observer) -> None:
        self.observer = observer
        self.command_times: list[float] = []

    def record_torque(self, t, torque) -> None:
        self.command_times.append(t)
        self.observer.record_torque(t, torque)

    def __getattr__(self, name):
        return getattr(self.observer, name)


def run_with_spy(s: Scenario, clock=time.perf_counter):
    loop = build_loop(s, clock)
    loop.observer = spy = Spy(loop.observer)
    r = loop.run()
    released = r.frames[~r.frames.dropped & r.frames.latency_s.notna()]
    assert len(spy.command_times) == len(released) > 10  # one command per released estimate
    delay = np.asarray(spy.command_times) - released.t_release_s.to_numpy()
    return loop, released, delay


MPC_SCENARIO = {
    "duration_s": 0.5,
    "observer": {"kind": "solver"},
    "controller": {"kind": "mpc"},
    "reference": {"kind": "tilt_step", "tilt_deg": 3.0},
}


def test_mpc_latency_defaults_to_its_measured_median_call_time():
    # The defaults are an earlier record of the same benchmark (before the compiled
    # derivatives); they must stay at or above the median call the benchmark measures now,
    # so that the loop never assumes a faster controller than it has.
    figures = json.loads((RESULTS / "bench_controllers.json").read_text())
    for (solver, hessian), value in MPC_CALL_MEDIAN_S.items():
        name = solver if hessian == "gauss_newton" else f"{solver}_exact_hessian"
        assert value >= figures[f"mpc_{name}_command_median_s"]
    s = Scenario.model_validate(MPC_SCENARIO)
    default = MPC_CALL_MEDIAN_S[("sqp_hpipm", "gauss_newton")]  # 4.0 ms
    assert s.controller_latency == Constant(value_s=default)
    assert Scenario(controller=MPCSpec()).controller_latency == s.controller_latency
    assert Scenario().controller_latency == Constant(value_s=0.0)  # PID
    ipopt = Scenario.model_validate({"controller": {"kind": "mpc", "config": {"solver": "ipopt"}}})
    assert ipopt.controller_latency.value_s == MPC_CALL_MEDIAN_S[("ipopt", "gauss_newton")]
    # An explicit value wins; the dump carries the resolved default (reproducible sweeps).
    zero = Scenario.model_validate({**MPC_SCENARIO, "controller_latency": {"kind": "constant",
                                                                         "value_s": 0.0}})
    assert zero.controller_latency.value_s == 0.0
    assert Scenario.model_validate(s.model_dump(mode="json")) == s
    # Settings without a measured figure must say what they want.
    with pytest.raises(ValidationError) as err:
        Scenario.model_validate({"controller": {"kind": "mpc", "config": {"hessian": "exact"}}})
    (e,) = err.value.errors()
    assert e["loc"] == ("controller_latency",) and "no measured MPC call time" in e["msg"]
    # The loop applies it, deterministically, and the MPC's prediction assumes it.
    loop, _, delay = run_with_spy(s)
    assert np.allclose(delay, s.controller_latency.value_s, rtol=0, atol=1e-12)
    assert loop.controller.config.compute_latency_s == s.controller_latency.value_s


def test_measured_controller_latency_is_the_compute_time_of_each_command():
    """The loop and the MPC read an injected clock (each reading 0.1-1 ms after the last), so
    the bookkeeping is checked independently of the machine's load."""
    s = Scenario.model_validate({**MPC_SCENARIO, "controller_latency": "measured"})
    clock = StepClock(1e-4, 1e-3, seed=5)
    loop, released, delay = run_with_spy(s, clock)
    mpc = loop.controller
    assert loop.clock is clock and mpc.clock is clock
    assert mpc.config.compute_latency_s is None  # predicts with its own measured times
    loop_times = released.controller_compute_s.to_numpy()
    # Each command takes effect after exactly the compute time the loop measured for it ...
    assert np.allclose(delay, loop_times, rtol=0, atol=1e-9)
    # ... which is the MPC's own per-call measurement (the loop's timer wraps the same call:
    # its two readings add two steps of the clock to the MPC's own).
    own = np.asarray(mpc.compute_times_s)
    assert len(own) == len(loop_times)
    extra = loop_times - own
    assert np.all(extra >= 2e-4 - 1e-12) and np.all(extra <= 2e-3 + 1e-12)
    assert np.all(loop_times > 0) and np.ptp(loop_times) > 0  # measured, not a constant


def test_image_mode_runs_k2cf_on_rendered_frames():
    """``tracker: k2cf`` closes the loop with K²CF on both markers: every frame measured,
    within 5 sensor px of the renderer's truth."""
    sc = Scenario.model_validate({"duration_s": 0.4, "mode": "image", "tracker": "k2cf"})
    loop = build_loop(sc)
    assert loop.front_end.locator.name == "k2cf"
    r = loop.run()
    assert r.summary["lost_frame_fraction"] == 0.0
    assert r.frames.centre_error_px.max() < 5.0


def test_image_mode_takes_the_transt_tracker_and_rejects_it_elsewhere():
    """``tracker: gk_transt`` runs GK-TransT (the shipped network in the GK assistance) on the
    rendered frames; a tracker other than the default outside image mode names the field."""
    from observer.transt.tracker import TransTTracker

    sc = Scenario.model_validate({"duration_s": 0.4, "mode": "image", "tracker": "gk_transt"})
    loop = build_loop(sc)
    assert isinstance(loop.front_end.locator.tracker, TransTTracker)
    r = loop.run()
    assert r.summary["lost_frame_fraction"] == 0.0
    assert r.frames.centre_error_px.max() < 5.0  # sensor px, against the renderer's truth
    with pytest.raises(ValidationError, match="tracker"):
        Scenario.model_validate({"tracker": "csrt_gk"})


def test_tracker_names_say_what_they_are():
    """Scenario tracker names are the registry's: ``kcf`` is OpenCV's KCF alone on each marker
    (with a warning that scenarios used to mean the GK-assisted one), ``kcf_gk`` the assisted
    one; the former ``transt`` is accepted for ``gk_transt`` with a warning; an unknown name
    lists the known ones."""
    image = {"duration_s": 0.4, "mode": "image"}
    with pytest.warns(FutureWarning, match="kcf_gk"):
        plain = Scenario.model_validate({**image, "tracker": "kcf"})
    assert build_loop(plain).front_end.locator.name == "kcf"
    assert build_loop(Scenario.model_validate(image)).front_end.locator.name == "kcf_gk"
    with pytest.warns(FutureWarning, match="now called 'gk_transt'"):
        assert Scenario.model_validate({**image, "tracker": "transt"}).tracker == "gk_transt"
    with pytest.raises(ValidationError, match="unknown tracker 'magic'; choose one of gk_transt"):
        Scenario.model_validate({**image, "tracker": "magic"})
