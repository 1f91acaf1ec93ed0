"""Run metrics on constructed trajectories whose answers are known by construction: the step
metrics against the commanded step, and the loss-of-control criteria of ``latency.loop``."""

import numpy as np
import pandas as pd
import pytest

from latency import loop, metrics
from latency.loop import _StepLog
from latency.metrics import loss_of_control, summarize

H = 1e-3  # s, the physics step of the constructed runs


def _tilt_q(deg: np.ndarray) -> np.ndarray:
    a = np.radians(deg) / 2
    return np.stack([np.cos(a), np.zeros_like(a), np.sin(a), np.zeros_like(a)], axis=1)


def _steps(theta_deg: np.ndarray, ref_deg: np.ndarray, stop: np.ndarray | None = None):
    n = len(theta_deg)
    log = _StepLog(n)
    q, qr = _tilt_q(theta_deg), _tilt_q(ref_deg)
    seg = loop.Segment(n * H, q, np.zeros((n, 3)), np.zeros((n, 16)))
    flags = np.zeros(n, dtype=bool) if stop is None else np.asarray(stop, dtype=bool)
    log.write_rows(0, np.arange(n) * H, seg, qr, np.zeros(3), np.zeros(3), None, False, flags)
    return log.frame(n)


def _frames(t_exp: np.ndarray, lost: np.ndarray) -> pd.DataFrame:
    return pd.DataFrame({"t_exposure_s": t_exp, "dropped": False, "lost": lost,
                         "latency_s": 0.02})


def test_step_metrics_are_measured_against_the_commanded_step():
    """A controller that previews the reference has moved 1.5° when the 5° step comes; then
    theta = 5 - 3.5 e^{-3 s} cos(8 s), s = t - 0.1. The overshoot is the peak beyond 5° in %
    of the commanded 5° (not of the 3.5° left to go), settling the last exit from ±0.1°."""
    t = np.arange(0, 3.0 + H / 2, H)
    ref = np.where(t >= 0.1, 5.0, 0.0)
    s = t - 0.1
    theta = np.where(t < 0.05, 0.0, np.where(t < 0.1, 1.5 * (t - 0.05) / 0.05,
                                             5.0 - 3.5 * np.exp(-3 * s) * np.cos(8 * s)))
    r = summarize(_steps(theta, ref), _frames(np.arange(0, 3, 1 / 36), np.zeros(108, bool)),
                  pd.DataFrame(), 3.0)
    after = t >= 0.1
    assert r["step_size_deg"] == pytest.approx(5.0, abs=1e-9)
    assert r["overshoot_pct"] == pytest.approx(100 * (theta[after].max() - 5.0) / 5.0, abs=1e-6)
    outside = np.flatnonzero(np.abs(theta[after] - 5.0) > metrics.SETTLE_BAND_DEG)
    assert r["settling_time_s"] == pytest.approx(t[after][outside[-1] + 1] - 0.1, abs=1e-9)
    late = t >= 3.0 - metrics.STEADY_STATE_WINDOW_S
    assert r["steady_state_error_deg"] == pytest.approx(np.mean(np.abs(theta[late] - 5.0)),
                                                        abs=1e-9)
    assert r["loss_of_control"] == 0.0


def test_an_error_that_never_enters_the_band_never_settles_and_shows_its_steady_state_error():
    t = np.arange(0, 2.0 + H / 2, H)
    ref = np.where(t >= 0.1, 5.0, 0.0)
    theta = np.where(t >= 0.1, 5.0 - 0.3 - 0.2 * np.sin(2 * np.pi * 3 * t) ** 2, 0.0)  # hunting
    r = summarize(_steps(theta, ref), _frames(np.arange(0, 2, 1 / 36), np.zeros(72, bool)),
                  pd.DataFrame(), 2.0)
    assert np.isnan(r["settling_time_s"])
    assert 0.3 <= r["steady_state_error_deg"] <= 0.5


def _flat_run(duration: float = 4.0, stop=None, theta=None):
    t = np.arange(0, duration + H / 2, H)
    th = np.full(len(t), 1.0) if theta is None else theta(t)
    return _steps(th, np.zeros(len(t)), None if stop is None else stop(t))


def test_sustained_tilt_stop_contact_is_a_loss_of_control_and_brief_touches_are_not():
    frames = _frames(np.arange(0, 4, 1 / 36), np.zeros(144, bool))
    held = _flat_run(stop=lambda t: (t >= 2.0) & (t < 2.3))
    touches = _flat_run(stop=lambda t: ((t >= 1.0) & (t < 1.2)) | ((t >= 1.25) & (t < 1.45)))
    r_held = loss_of_control(held, frames, False)
    r_touch = loss_of_control(touches, frames, False)
    assert r_held["loc_tilt_stop"] == 1.0 and r_held["loss_of_control"] == 1.0
    assert r_held["longest_tilt_stop_s"] == pytest.approx(0.3, abs=1.5 * H)
    assert r_touch["loss_of_control"] == 0.0
    assert r_touch["longest_tilt_stop_s"] == pytest.approx(0.2, abs=1.5 * H)


def test_losing_the_markers_is_a_loss_of_control():
    t_exp = np.arange(0, 4, 1 / 36)
    steps = _flat_run()
    blind = (t_exp >= 1.0) & (t_exp < 1.7)  # 0.7 s without the markers
    sparse = np.arange(len(t_exp)) % 3 == 0  # a third lost, never two in a row
    most = np.arange(len(t_exp)) % 100 < 54  # the run with 54 % lost frames
    assert loss_of_control(steps, _frames(t_exp, blind), False)["loc_marker_loss"] == 1.0
    assert loss_of_control(steps, _frames(t_exp, sparse), False)["loss_of_control"] == 0.0
    r = loss_of_control(steps, _frames(t_exp, most), False)
    assert r["loc_marker_loss"] == 1.0


def _trailing_run(speed_deg_s, lag_s: float, duration: float = 4.0):
    """A reference tilting at the speed ``speed_deg_s(t)`` (deg/s) and a rotor that trails it
    by ``lag_s``: its attitude is the reference's of ``lag_s`` earlier. Returns the steps and
    the reference's path (deg) and RMS error (deg) over the last half, computed here."""
    t = np.arange(0, duration + H / 2, H)
    ref = np.concatenate([[0.0], np.cumsum(speed_deg_s(t[1:]) * H)])
    theta = np.interp(t - lag_s, t, ref, left=0.0)
    late = t >= duration / 2
    path = float(np.sum(np.abs(np.diff(ref))[late[:-1]]))
    return _steps(theta, ref), path, float(np.sqrt(np.mean((ref - theta)[late] ** 2)))


def test_an_error_beyond_what_the_reference_demands_is_a_loss_of_control():
    """The bound over the last half: 2° plus 0.25 s of the reference's mean speed there. A
    rotor 0.15 s behind a reference at 20°/s (3° of error) is within it (2 + 0.25 x 20 =
    7°); 0.45 s behind (9°) is not."""
    frames = _frames(np.arange(0, 4, 1 / 36), np.zeros(144, bool))
    speed = lambda t: np.full_like(t, 20.0)  # noqa: E731
    near, path, rms = _trailing_run(speed, 0.15)
    r = loss_of_control(near, frames, False)
    assert r["late_error_bound_deg"] == pytest.approx(2.0 + 0.25 * path / 2.0, rel=1e-3)
    assert r["late_error_bound_deg"] == pytest.approx(7.0, rel=1e-3)
    assert r["late_rms_error_deg"] == pytest.approx(rms, rel=1e-3) and rms < 7.0
    assert r["loss_of_control"] == 0.0
    far, _, rms_far = _trailing_run(speed, 0.45)
    r_far = loss_of_control(far, frames, False)
    assert rms_far > 7.0 and r_far["loc_excess_error"] == 1.0 and r_far["loss_of_control"] == 1.0
    # a rotor that oscillates about a resting reference: only the 2° floor applies
    still = _flat_run(theta=lambda t: 4.0 * np.sin(2 * np.pi * 1.4 * t))
    assert loss_of_control(still, frames, False)["loc_excess_error"] == 1.0
    calm = _flat_run(theta=lambda t: 1.5 + 0.5 * np.sin(2 * np.pi * 1.4 * t))
    assert loss_of_control(calm, frames, False)["loss_of_control"] == 0.0


def test_the_verdict_does_not_read_the_reference_schedule():
    """A stable loop that trails its reference by 0.1 s while the reference speeds up from
    10°/s to 40°/s in the last quarter: its error quadruples there (which the former
    quarter-ratio test called a growing oscillation) but stays what the reference demands."""
    frames = _frames(np.arange(0, 4, 1 / 36), np.zeros(144, bool))
    steps, _, _ = _trailing_run(lambda t: np.where(t < 3.0, 10.0, 40.0), 0.1)
    error = steps.error_deg.to_numpy()
    t = steps.t_s.to_numpy()
    second, last = error[(t >= 1.0) & (t < 2.0)], error[t >= 3.2]
    assert np.sqrt(np.mean(last**2)) >= 2.0 * np.sqrt(np.mean(second**2))  # the old trigger
    assert np.sqrt(np.mean(last**2)) >= 2.0
    assert loss_of_control(steps, frames, False)["loss_of_control"] == 0.0


def test_divergence_is_a_loss_of_control():
    frames = _frames(np.arange(0, 4, 1 / 36), np.zeros(144, bool))
    decaying = _flat_run(theta=lambda t: 8.0 * np.exp(-0.9 * t) * np.sin(2 * np.pi * 2 * t))
    assert loss_of_control(decaying, frames, False)["loss_of_control"] == 0.0
    assert loss_of_control(decaying, frames, True)["loc_divergence"] == 1.0
