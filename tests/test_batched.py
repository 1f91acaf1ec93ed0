"""The batched engine against the event loop, run by run, and the engine choice."""

import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from experiments.cli import app
from latency import Scenario, batched, build_loop, compiled, simulate_many
from latency.batched import run_batched
from latency.metrics import SETTLE_BAND_DEG
from plant import attitude as A

pytestmark = pytest.mark.engine  # runs the compiled engines

QUAT = ["qw", "qx", "qy", "qz"]


def _scenario(**kw) -> Scenario:
    base = {"duration_s": 0.8, "observer": {"kind": "solver"}}
    return Scenario.model_validate({**base, **kw})


#: The grid: one run per case, each with its own seed (so its own noise, latency and loss
#: streams). Delays inside and past the PID's stability boundary (crossover 25 rad/s, phase
#: margin 47°: about 33 ms of delay margin), saturation and the tilt stop (a 15° step onto the
#: stop with a stiff loop, 50 rad/s with a 5 ms observer, whose torque limit is beyond the
#: motor's capacity), lost frames (dropouts and a narrow tracker window on a fast cone),
#: a random observer latency and the three observers.
GRID = {
    "nominal": _scenario(seed=0),
    "past the stability boundary": _scenario(
        seed=1, duration_s=1.2, controller={"kind": "pid", "config": {"crossover_rad_s": 25.0}},
        pipeline={"observer": {"kind": "constant", "value_s": 0.06}, "mode": "pipelined"},
    ),
    "saturation and tilt stop": _scenario(
        seed=2, controller={"kind": "pid", "config": {"crossover_rad_s": 50.0,
                                                      "torque_limit_Nm": 2.0}},
        reference={"kind": "tilt_step", "tilt_deg": 15.0, "t_step_s": 0.05},
        pipeline={"observer": {"kind": "constant", "value_s": 0.005}},
    ),
    "lost frames": _scenario(
        seed=3, measurement={"dropout_prob": 0.2, "search_radius_px": 25.0, "sigma_px": 1.0},
        reference={"kind": "cone", "args": {"tilt_deg": 10.0, "yaw_rate_rad_s": 6.0}},
    ),
    "random latency, pixel Kalman": _scenario(
        seed=4, observer={"kind": "pixel_kalman"},
        pipeline={"observer": {"kind": "gamma", "shape_k": 9.0, "scale_theta_s": 0.003}},
    ),
    "aekf": _scenario(seed=5, observer={"kind": "aekf"}),
    # The compiled run loop's case (latency.compiled.coverage): PID and the per-frame solver,
    # sequential and pipelined, constant and random observer and controller latencies,
    # outliers.
    "compiled, sequential, random latencies": _scenario(
        seed=6, measurement={"outlier_prob": 0.1},
        pipeline={"observer": {"kind": "uniform", "low_s": 0.01, "high_s": 0.05}},
        controller_latency={"kind": "gamma", "shape_k": 4.0, "scale_theta_s": 0.001},
    ),
    "compiled, pipelined, random latency": _scenario(
        seed=7, reference={"kind": "cone", "args": {"tilt_deg": 8.0, "yaw_rate_rad_s": 3.0}},
        pipeline={"observer": {"kind": "normal", "mean_value_s": 0.045, "std_s": 0.01},
                  "mode": "pipelined"},
        controller_latency={"kind": "constant", "value_s": 0.002},
    ),
    "pixel Kalman coasting on lost frames": _scenario(
        seed=8, observer={"kind": "pixel_kalman", "pixel_q_scale": 0.5},
        measurement={"dropout_prob": 0.3, "outlier_prob": 0.05},
        reference={"kind": "cone", "args": {"tilt_deg": 8.0, "yaw_rate_rad_s": 4.0}},
        pipeline={"mode": "pipelined"},
    ),
    "compiled, PID variants": _scenario(
        seed=9, controller={"kind": "pid", "config": {
            "anti_windup": "conditional", "friction_compensation_Nm": 0.002, "feedforward": False,
            "invalid_command": "zero", "crossover_rad_s": 40.0, "torque_limit_Nm": 0.05}},
        measurement={"dropout_prob": 0.5},
        reference={"kind": "cone", "args": {"tilt_deg": 10.0, "yaw_rate_rad_s": 6.0}},
    ),
    "compiled, region of interest and blur limit": _scenario(
        seed=10, measurement={"roi": {"rows": 600, "cols": 1000, "follow": True},
                              "blur_limit_px": 4.0, "search_radius_px": 240.0},
        reference={"kind": "cone", "args": {"tilt_deg": 6.0, "yaw_rate_rad_s": 8.0}},
    ),
}
#: The cases that the compiled run loop computes; the others advance in lockstep.
COMPILED = {"nominal", "past the stability boundary", "saturation and tilt stop", "lost frames",
            "random latency, pixel Kalman", "compiled, sequential, random latencies",
            "compiled, pipelined, random latency", "pixel Kalman coasting on lost frames",
            "compiled, PID variants", "compiled, region of interest and blur limit"}


@pytest.fixture(scope="module")
def both_engines():
    scenarios = list(GRID.values())
    event = [build_loop(s).run() for s in scenarios]
    batched = run_batched([build_loop(s) for s in scenarios])
    return dict(zip(GRID, zip(event, batched, strict=True), strict=True))


#: Summary keys that count flags, rows or events, or read only the reference, the configuration
#: or the frames' timings: equal when the flags and timings are (checked beside them). The
#: loss-of-control flags are thresholds on such counts and on the RMS errors of the run's
#: quarters: equal unless one of those lies within its tolerance of a threshold.
EXACT = {"duration_s", "simulated_s", "diverged", "lost_frame_fraction",
         "dropped_frame_fraction", "longest_marker_loss_s", "longest_tilt_stop_s",
         "step_size_deg", "n_events", "loc_tilt_stop", "loc_marker_loss",
         "loc_growing_oscillation", "loc_divergence", "loss_of_control"}
#: Summary keys that are an RMS, a maximum or a mean of a per-row geodesic error or tilt error:
#: each row's value moves by at most the geodesic distance between the two attitudes (the
#: triangle inequality on SO(3); the tilt is the angle of the body Z axis from the stator's,
#: which a rotation by d moves by at most d), and an RMS, a maximum or a mean of rows each
#: within d of the other's are within d of each other.
LIPSCHITZ = {"rms_error_deg", "max_error_deg", "rms_tilt_error_deg", "max_tilt_error_deg",
             "steady_state_error_deg"}
#: Our bound on the Z-Y-Z spin and yaw errors' sensitivity: spin and yaw are counted only where
#: both tilts exceed 1°, and a rotation by d moves either by at most 2 d / sin(tilt)
#: (the inverse of the Z-Y-Z Jacobian, which is singular at zero tilt).
ZYZ_GAIN = 2.0 / np.sin(np.radians(1.0))
#: Round-off allowance: both engines summarise with the same functions (``latency.metrics``);
#: 1e-12 covers the last bits of float64 sums of this size (far below every bound above).
ROUNDING = 1e-12


def summary_tolerances(ev, bt) -> dict[str, float]:
    """Absolute tolerance of each summary key of the batched run ``bt`` against the event
    loop's ``ev``, derived from how the metric is computed and from how far the two runs'
    trajectories are apart (``d``, the largest geodesic distance between their attitudes, rad;
    ``dT``, the largest norm of the difference of their delivered torques, N·m):

    * ``EXACT`` keys: round-off only;
    * ``LIPSCHITZ`` keys (errors in degrees): ``degrees(d)``;
    * the RMS and maximum spin and yaw errors: ``ZYZ_GAIN degrees(d)``;
    * ``rms_torque_Nm``: ``dT`` (an RMS of row norms each within ``dT``);
    * ``control_effort_N2m2s`` = ∫|T|² dt over the same times: ``(2 T_max + dT) dT t_end``;
    * ``overshoot_pct``, 100 x (peak progress along the step's axis - 1): progress moves by at
      most ``1.01 d / step`` (the rotation vector's sensitivity to the attitude is within 1 %
      of 1 for angles below 20°, far above every step of the grid), so ``101 d / step``;
    * ``settling_time_s``: equal, unless a row's error to the target lies within
      ``degrees(d)`` of the settling band, where the two runs may settle a row apart: then
      the run's length;
    * ``mean_latency_s``: the same latency draws averaged: round-off, relative;
    * ``late_rms_error_deg`` (an RMS of errors each within ``degrees(d)``): ``degrees(d)``;
      ``late_error_bound_deg`` (from the reference alone) and ``time_to_first_loss_s`` (a
      frame's exposure time; the tables' frames are compared exactly elsewhere): round-off;
    * ``loc_excess_error``, late RMS error above its bound: equal, unless the late RMS error
      lies within ``degrees(d)`` of the bound, where the flag may differ (1).
    """
    d = float(np.max(A.geodesic_angle(ev.steps[QUAT].to_numpy(), bt.steps[QUAT].to_numpy())))
    cols = [f"torque_delivered_{c}_Nm" for c in "xyz"]
    T_ev, T_bt = ev.steps[cols].to_numpy(), bt.steps[cols].to_numpy()
    dT = float(np.max(np.linalg.norm(T_ev - T_bt, axis=1)))
    t_end = float(ev.steps.t_s.iloc[-1])
    d_deg = np.degrees(d) + ROUNDING
    tol = dict.fromkeys(EXACT, ROUNDING) | dict.fromkeys(LIPSCHITZ, d_deg)
    for key in ("rms_spin_error_deg", "max_spin_error_deg", "rms_yaw_error_deg",
                "max_yaw_error_deg"):
        tol[key] = ZYZ_GAIN * d_deg
    T_max = float(np.max(np.linalg.norm(T_ev, axis=1)))
    tol["rms_torque_Nm"] = dT + ROUNDING
    tol["control_effort_N2m2s"] = (2.0 * T_max + dT) * dT * t_end + ROUNDING
    step = ev.summary["step_size_deg"]
    tol["overshoot_pct"] = 101.0 * d_deg / step if np.isfinite(step) else ROUNDING
    near_band = np.abs(ev.steps.error_deg.to_numpy() - SETTLE_BAND_DEG) <= d_deg
    tol["settling_time_s"] = t_end if near_band.any() else ROUNDING
    tol["mean_latency_s"] = ROUNDING * max(abs(ev.summary.get("mean_latency_s", 0.0)), 1.0)
    tol["late_rms_error_deg"] = d_deg
    tol["late_error_bound_deg"] = tol["time_to_first_loss_s"] = ROUNDING
    margin = abs(ev.summary["late_rms_error_deg"] - ev.summary["late_error_bound_deg"])
    tol["loc_excess_error"] = 1.0 if margin <= d_deg else ROUNDING
    return tol


@pytest.mark.parametrize("case", list(GRID))
def test_batched_runs_follow_the_event_loop_run_by_run(both_engines, case):
    """Same seed, same trajectory: every step's attitude within 1e-6 rad, the same frames lost
    and dropped, the same events, and every summary metric within the tolerance derived for
    it from the trajectories' distance (``summary_tolerances``)."""
    ev, bt = both_engines[case]
    assert len(ev.steps) == len(bt.steps)
    q_ev, q_bt = ev.steps[QUAT].to_numpy(), bt.steps[QUAT].to_numpy()
    assert np.max(A.geodesic_angle(q_ev, q_bt)) < 1e-6
    flags = [col for col in ("lost", "dropped") if col in ev.frames]
    assert flags == ["lost", "dropped"] or ev.frames.empty
    for col in flags:
        assert ev.frames[col].fillna(False).tolist() == bt.frames[col].fillna(False).tolist()
    assert ev.steps.tilt_stop.tolist() == bt.steps.tilt_stop.tolist()
    assert ev.events.kind.tolist() == bt.events.kind.tolist()
    tol = summary_tolerances(ev, bt)
    assert ev.summary.keys() == bt.summary.keys()
    assert set(ev.summary) <= set(tol), set(ev.summary) - set(tol)  # a new metric needs one
    for key, value in ev.summary.items():
        assert bt.summary[key] == pytest.approx(value, rel=0, abs=tol[key], nan_ok=True), key


def test_the_compiled_run_loop_takes_exactly_its_cases():
    """The engine's choice per run: the compiled loop for PID + per-frame solver with model
    latencies, the lockstep rounds for the other observers, a region of interest, a blur limit,
    a measured controller latency or a disturbance."""
    for case, s in GRID.items():
        assert (compiled.coverage(build_loop(s)).path == "compiled") == (case in COMPILED), case
    base = GRID["nominal"]
    measured = Scenario.model_validate({**base.model_dump(mode="json"),
                                        "controller_latency": "measured"})
    assert compiled.coverage(build_loop(measured)).path == "lockstep"
    disturbed = build_loop(base)
    disturbed.config = disturbed.config.model_copy(update={"disturbance_psd_Nm2s": (1e-8,) * 3})
    assert compiled.coverage(disturbed).path == "lockstep"


def test_runs_that_leave_the_compiled_loop_are_logged_once_per_reason(caplog, monkeypatch):
    """Three AEKF runs and a measured controller latency beside a compiled run: one INFO line
    per reason, with the number of runs it sends to the lockstep rounds (stubbed here: the
    test is about the choice, not the rounds); none for the compiled run."""
    monkeypatch.setattr(batched, "_run_group", lambda group: [None] * len(group))
    short = {"duration_s": 0.15, "observer": {"kind": "aekf"}}
    loops = [build_loop(_scenario(seed=s, **short)) for s in range(3)]
    loops += [build_loop(_scenario(duration_s=0.15, controller_latency="measured")),
              build_loop(_scenario(duration_s=0.15))]
    with caplog.at_level("INFO", logger="latency.batched"):
        run_batched(loops)
    lines = [r.getMessage() for r in caplog.records if r.name == "latency.batched"]
    assert len(lines) == 2 and all(r.levelname == "INFO" for r in caplog.records)
    assert lines[0].startswith("3 of 5 runs not in the compiled run loop: observer FilterObserver")
    assert lines[1].startswith("1 of 5 runs not in the compiled run loop: a measured controller")


@pytest.mark.parametrize("case", sorted(COMPILED))
def test_compiled_runs_give_the_event_loops_tables(both_engines, case):
    """The compiled loop's frames and events tables are the event loop's: the same columns and
    types, every timing, pixel, flag and estimate (to 1e-9), the same event texts; only the
    controller's compute time is not timed per call (NaN)."""
    ev, bt = both_engines[case]
    assert bt.frames["controller_compute_s"].isna().all()
    pd.testing.assert_frame_equal(ev.frames.drop(columns="controller_compute_s"),
                                  bt.frames.drop(columns="controller_compute_s"),
                                  check_exact=False, rtol=1e-9, atol=1e-9)
    assert ev.events.detail.tolist() == bt.events.detail.tolist()
    pd.testing.assert_frame_equal(ev.steps, bt.steps, check_exact=False, rtol=1e-6, atol=1e-9)


def test_the_grid_covers_what_it_claims(both_engines):
    """The grid's cases do what their names say (on the event loop, the reference)."""
    kinds = {case: set(ev.events.kind) for case, (ev, _) in both_engines.items()}
    assert {"saturation", "tilt_stop_contact"} <= kinds["saturation and tilt stop"]
    assert "tracking_loss" in kinds["lost frames"]
    assert both_engines["lost frames"][0].summary["lost_frame_fraction"] > 0.1
    nominal = both_engines["nominal"][0].summary["max_error_deg"]
    unstable = both_engines["past the stability boundary"][0]
    # a growing oscillation: the error late in the run exceeds the step itself
    late = unstable.steps[unstable.steps.t_s > 0.8].error_deg
    assert late.max() > 5.0 and late.max() > nominal
    seq = both_engines["compiled, sequential, random latencies"][0]
    assert seq.frames.dropped.any() and seq.frames.latency_s.std() > 1e-3
    assert not both_engines["compiled, pipelined, random latency"][0].frames.dropped.any()
    windowed = both_engines["compiled, region of interest and blur limit"][0].frames
    lost_by = set(windowed.est_reason.dropna().str.split(";").str[0])
    assert {"marker outside the region of interest",
            "motion blur beyond the tracker's limit"} <= lost_by
    coasting = both_engines["pixel Kalman coasting on lost frames"][0].frames
    # frames lost by the front end whose estimate the filters' prior still gives (not lost)
    assert (coasting.lost.astype(bool) & ~coasting.est_reason.str.contains("dropout")).any()


def test_run_many_keeps_the_order_and_sends_image_runs_to_the_image_engine():
    a, b = _scenario(seed=7, duration_s=0.3), _scenario(seed=8, duration_s=0.3)
    image = Scenario(mode="image", duration_s=0.3, seed=9)
    ra, ri, rb = simulate_many([a, image, b], engine="batched")
    assert ra.config["seed"] == 7 and rb.config["seed"] == 8 and ri.config["seed"] == 9
    assert ri.summary == pytest.approx(simulate_many([image], engine="event")[0].summary,
                                       nan_ok=True)
    measured = Scenario(mode="image", duration_s=0.3, observer_latency="measured")
    with pytest.raises(ValueError, match="needs model latencies"):
        simulate_many([measured], engine="batched")


def test_summary_only_runs_give_the_event_loops_summary_without_tables():
    """A sweep's runs (``tables=False``) skip the steps, frames and events tables, not the
    metrics (the event count included): their summaries equal the event loop's, on a run
    with lost frames and one in contact with the tilt stop."""
    cases = [GRID["lost frames"], GRID["saturation and tilt stop"]]
    light = simulate_many(cases, tables=False)
    for s, res in zip(cases, light, strict=True):
        assert compiled.coverage(build_loop(s)).path == "compiled"
        assert res.steps.empty and res.frames.empty and res.events.empty
        ref = build_loop(s).run().summary
        assert res.summary.keys() == ref.keys()
        for key, value in ref.items():
            assert res.summary[key] == pytest.approx(value, rel=1e-9, abs=1e-12, nan_ok=True)
    assert light[1].summary["longest_tilt_stop_s"] > 0
    assert light[0].summary["lost_frame_fraction"] > 0


def test_cli_engine_option(tmp_path):
    """``--engine event`` and the default (batched) give the same summary; batched on an image
    scenario that measures its latency is a configuration error (exit status 2, the reason
    named)."""
    runner = CliRunner()
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump({"duration_s": 0.3, "observer": {"kind": "solver"}}))
    out = {}
    for engine in ("event", None):
        args = ["simulate", str(path), "--out", str(tmp_path / str(engine))]
        res = runner.invoke(app, args + (["--engine", engine] if engine else []))
        assert res.exit_code == 0, res.output
        out[engine] = [ln for ln in res.output.splitlines() if "rms_error_deg" in ln]
    assert out["event"] == out[None] and out["event"]
    path.write_text(yaml.safe_dump({"duration_s": 0.3, "mode": "image",
                                    "observer_latency": "measured"}))
    res = runner.invoke(app, ["simulate", str(path), "--engine", "batched"])
    assert res.exit_code == 2
    assert "needs model latencies" in res.output


def test_sweep_batches_write_one_row_per_run_and_record_a_bad_config(tmp_path):
    """``execute_batch`` with the batched entry point: one row per config, the same summary as
    the event loop's entry point for the same config, and an invalid config's error in its
    own row while the others run."""
    from experiments import sweep
    from latency.simulation import run_summary

    good = [{"duration_s": 0.3, "seed": s, "observer": {"kind": "solver"}} for s in (0, 1)]
    bad = {"duration_s": -1.0}
    ids = sweep.execute_batch("latency.simulation:run_summaries", [*good, bad], str(tmp_path))
    table = sweep.table(tmp_path).set_index("run_id")
    assert len(table) == 3
    assert "duration_s" in table.loc[ids[2], "error"]
    for rid, config in zip(ids[:2], good, strict=True):
        assert table.loc[rid, "error"] == ""
        event = run_summary(config)
        assert table.loc[rid, "result.rms_error_deg"] == pytest.approx(event["rms_error_deg"],
                                                                       rel=1e-9)
