"""The dual TransT's operating point in closed loop: the sequential observer at 31.23 ms (it takes
every other frame, so the PID runs at twice the frame period).

The predictions are the study's (``experiments.study``: the headroom scanned through the
sequential pipeline, the jitter and constant-delay margins of the PID as it runs); the
simulation is the nonlinear MuJoCo loop of tests/test_margin_agreement.py (noise-free pixels,
the per-frame solver, no Coulomb friction) with the sequential ``FrameScheduler`` dropping the
frames that arrive while the observer is busy.
"""

import numpy as np
import pytest
from pydantic import PrivateAttr

from experiments.study import pid_axis_margins, pid_headroom_s
from experiments.study_config import DUAL_MS
from latency.models import Constant, Empirical, LatencyModel, Uniform
from tests.test_margin_agreement import P, simulated_rate_amplitudes

D = DUAL_MS / 1e3


class Cycle(Empirical):
    """Latencies taken in turn from ``samples_s`` (one per processed frame): a deterministic
    switching delay, for the worst case a random draw would rarely produce."""

    _next: int = PrivateAttr(0)

    def sample(self, rng: np.random.Generator) -> float:
        v = self.samples_s[self._next % len(self.samples_s)]
        self._next += 1
        return v


def amplitudes(latency: LatencyModel) -> tuple[float, float, float]:
    """Peak |omega_y| (rad/s) in the middle and the last third of the run, and the fraction
    of frames the sequential observer dropped."""
    mid, late, summary = simulated_rate_amplitudes(10.0, latency, "sequential")
    return mid, late, summary["dropped_frame_fraction"]


@pytest.fixture(scope="module")
def predicted():
    timing, m = pid_axis_margins(P, 10.0, D, "sequential")
    assert timing.frames_per_update == 2 and m.stable
    return {"headroom": pid_headroom_s(P, 10.0, D, "sequential"),
            "delay_margin": m.delay_margin_s, "jitter_margin": m.jitter_margin_s}


def test_decays_below_and_grows_above_the_predicted_headroom(predicted):
    h = predicted["headroom"]
    mid, late, dropped = amplitudes(Constant(value_s=D + 0.9 * h))
    assert late < 0.8 * mid  # decaying: stable
    assert dropped == pytest.approx(1 / 2, abs=0.01)  # every other frame
    mid, late, dropped = amplitudes(Constant(value_s=D + 1.1 * h))
    assert late > 1.25 * mid  # growing: unstable
    assert dropped == pytest.approx(2 / 3, abs=0.01)  # past two frame periods: two in three


def test_random_delays_within_the_jitter_margin_stay_stable(predicted):
    """Each processed frame's latency uniform in [31.23 ms, 31.23 ms + jitter margin] (Kao &
    Lincoln: any time-varying extra delay in [0, jitter margin] keeps the loop stable)."""
    mid, late, dropped = amplitudes(Uniform(low_s=D, high_s=D + predicted["jitter_margin"]))
    assert late < 0.8 * mid
    assert dropped == pytest.approx(1 / 2, abs=0.01)  # the update period stays two frames


def test_a_switching_delay_beyond_the_delay_margin_destabilises(predicted):
    """Three frames at 1.1 x the constant-delay margin of extra latency, then one at none, in
    turn: the loop grows (the long frames also make the sequential observer drop a third frame
    now and then, as it would)."""
    x = 1.1 * predicted["delay_margin"]
    mid, late, _ = amplitudes(Cycle(samples_s=(D + x, D + x, D + x, D)))
    assert late > 1.25 * mid
