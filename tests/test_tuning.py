"""Kalman Q/R tuning against closed-loop cost (experiments.tuning).

The steady-state filter is checked against filterpy's filter run on a test signal; the margins
with a transparent filter against the margins without one; the objective's lost-frame penalty
against a frame count taken from an independent run of the same scenario; the grid's shape and
the optuna study's resumption with tiny budgets.
"""

import numpy as np
import optuna
import pandas as pd
import pytest
import scipy.signal

from controller.pid import PIDController
from experiments import tuning
from latency import Scenario, simulate
from latency.margins import attitude_plant, loop_margins, loop_model
from latency.pipeline import PipelineConfig
from observer.gk.pixel_kalman import PixelKalman, PixelKalmanConfig
from plant.params import PlantParams

pytestmark = pytest.mark.engine  # runs the compiled engines

TINY = tuning.TuningObjective(
    duration_s=0.3,
    seeds=(0,),
    references=({"kind": "tilt_step", "tilt_deg": 2.0, "t_step_s": 0.05},),
)


# --- the steady-state filter ------------------------------------------------------------------


def _filterpy_run(q: float, r: float, z: np.ndarray) -> tuple[np.ndarray, PixelKalman]:
    """Posterior u of the seed's pixel filter (filterpy) on the signal z (u only; v = 0)."""
    kf = PixelKalman(PixelKalmanConfig(Q=(q * np.eye(4)).tolist(), R=(r * np.eye(2)).tolist()))
    out = np.empty(len(z))
    for k, zk in enumerate(z):
        kf.predict()
        kf.update([zk, 0.0])
        out[k] = kf.position[0]
    return out, kf


@pytest.mark.parametrize("q, r", [(0.01, 0.1), (1e-3, 1.0), (1.0, 0.1)])
def test_steady_state_transfer_function_matches_the_filterpy_filter(q, r):
    rng = np.random.default_rng(3)
    n = 600
    k = np.arange(n)
    z = 0.3 * k + 20.0 * np.sin(2 * np.pi * k / 37.0) + rng.normal(scale=1.5, size=n)
    y_kf, kf = _filterpy_run(q, r, z)
    # The transfer function simulated from rest, as a plain difference equation (scipy).
    F = tuning.kalman_transfer_function(q, r, 1.0)
    num = np.asarray(F.num[0][0], dtype=float)
    den = np.asarray(F.den[0][0], dtype=float)
    y_tf = scipy.signal.lfilter(num, den, z)
    # Different start-up transients; both decay through the same stable closed-loop matrix.
    tail = slice(400, None)
    assert np.max(np.abs(y_tf[tail] - y_kf[tail])) < 1e-6 * np.max(np.abs(z))
    # The Riccati gain is the one filterpy converges to.
    K, P = tuning.kalman_steady_state(q, r)
    np.testing.assert_allclose(kf.kf.K[[0, 2], 0], K[:, 0], rtol=1e-8)
    np.testing.assert_allclose(kf.kf.P_prior[np.ix_([0, 2], [0, 2])], P, rtol=1e-8)


def test_filter_passes_constants_and_depends_on_the_ratio_only():
    F = tuning.kalman_transfer_function(0.01, 0.1, 0.02)
    assert complex(F(1.0)) == pytest.approx(1.0, abs=1e-12)
    K1, P1 = tuning.kalman_steady_state(0.01, 0.1)
    K2, P2 = tuning.kalman_steady_state(3.0, 30.0)
    np.testing.assert_allclose(K1, K2, rtol=1e-9)
    np.testing.assert_allclose(P2, 300.0 * P1, rtol=1e-9)
    # Noise gain: the filtered noise is smaller for a smaller q/r, and below 1.
    assert tuning.filter_noise_gain(1e-3, 1.0) < tuning.filter_noise_gain(1.0, 1.0) < 1.0


def test_processed_frame_period_counts_dropped_frames():
    T = 1.0 / 36.0
    seq = {"frame_rate_hz": 36.0, "mode": "sequential"}
    fast = PipelineConfig(**seq, observer={"kind": "constant", "value_s": 16.33e-3})
    slow = PipelineConfig(**seq, observer={"kind": "constant", "value_s": 31.23e-3})
    piped = slow.model_copy(update={"mode": "pipelined"})
    assert tuning.processed_frame_period(fast) == pytest.approx(T)
    assert tuning.processed_frame_period(slow) == pytest.approx(2 * T)
    assert tuning.processed_frame_period(piped) == pytest.approx(T)


def test_margins_with_a_transparent_filter_equal_the_margins_without_one():
    obj = tuning.TuningObjective(delay_s=16.33e-3)
    m, extra = tuning.filter_loop_margins(obj, 1e6, 1.0, formulation="hybrid")  # F(z) -> 1
    p = PlantParams()
    pid = PIDController(params=p)
    T = 1.0 / 36.0
    ref = loop_margins(
        loop_model(
            attitude_plant(float(pid.J[1]), p.rotor.viscous_Nms_per_rad),
            pid.discrete_transfer_function(T, axis=1),
            delay_s=0.5 * p.camera.exposure_s + 16.33e-3,
            sample_period_s=T,
        )
    )
    assert extra["period_s"] == pytest.approx(T)
    assert extra["delay_total_s"] == pytest.approx(0.5 * p.camera.exposure_s + 16.33e-3)
    assert m.phase_margin_deg == pytest.approx(ref.phase_margin_deg, abs=0.02)
    # More filtering, more lag, less phase margin.
    pm = [
        tuning.filter_loop_margins(obj, x, 1.0, formulation="hybrid")[0].phase_margin_deg
        for x in (10.0, 1.0, 0.1)
    ]
    assert pm[0] > pm[1] > pm[2]
    # The exact sampled loop agrees with the hybrid model at the seed's setting.
    exact, _ = tuning.filter_loop_margins(obj, 0.01, 0.1)
    assert exact.phase_margin_deg == pytest.approx(pm[2], abs=0.1)


# --- the objective ----------------------------------------------------------------------------


def test_cost_terms_add_the_penalty_per_lost_frame():
    w = tuning.CostWeights(
        effort_weight_deg_per_N2m2=100.0, lost_frame_penalty_deg=0.5, divergence_penalty_deg=7
    )
    base = tuning.cost_terms(1.0, 1e-3, 0, False, w)
    assert base["cost"] == pytest.approx(1.0 + 0.1)
    lost = tuning.cost_terms(1.0, 1e-3, 4, False, w)
    assert lost["cost"] - base["cost"] == pytest.approx(4 * 0.5)
    assert tuning.cost_terms(1.0, 1e-3, 4, True, w)["cost"] == pytest.approx(lost["cost"] + 7)


def test_run_cost_counts_lost_frames_and_penalises_them():
    obj = TINY.model_copy(update={"measurement": {"dropout_prob": 0.4}})
    (config,) = obj.configs(0.01, 0.1)
    res = tuning.run_cost(config)
    # Independent count: the same scenario run again, lost frames counted from its table.
    frames = simulate(Scenario.model_validate(config["scenario"])).frames
    processed = frames[~frames.dropped]
    n_lost = int(processed["lost"].astype(bool).sum())
    assert n_lost > 0
    assert res["n_lost_frames"] == n_lost
    w = obj.weights
    assert res["cost_lost_deg"] == pytest.approx(w.lost_frame_penalty_deg * n_lost)
    assert res["cost"] == pytest.approx(
        res["rms_error_deg"]
        + w.effort_weight_deg_per_N2m2 * res["mean_square_torque_N2m2"]
        + w.lost_frame_penalty_deg * n_lost
        + w.divergence_penalty_deg * res["diverged"]
    )


def test_scenario_of_the_objective():
    obj = tuning.TuningObjective(delay_s=31.23e-3, seeds=(4,))
    d = obj.scenario_dict(0.5, 2.0, 4, {"kind": "random", "args": {"max_rate_rad_s": 1.0}})
    s = Scenario.model_validate(d)
    assert s.observer.kind == "pixel_kalman"
    assert (s.observer.pixel_q_scale, s.observer.pixel_r_scale) == (0.5, 2.0)
    assert s.pipeline.observer.mean_s == pytest.approx(31.23e-3)
    assert s.measurement.sigma_px == 1.5
    assert s.reference.args["seed"] == 4  # the trajectory follows the run seed
    with pytest.raises(ValueError, match="observer"):
        tuning.TuningObjective(scenario={"observer": {"kind": "solver"}}).configs(0.01, 0.1)


# --- grid and optuna --------------------------------------------------------------------------


def test_log_grid_contains_the_centre_exactly():
    g = tuning.log_grid(0.01, 4, 1.5)
    assert 0.01 in g
    assert len(g) == 5
    assert g[0] == pytest.approx(0.01 * 10**-1.5)
    assert g[-1] == pytest.approx(0.01 * 10**1.5)
    np.testing.assert_array_equal(tuning.log_grid(0.1, 5, 1.0), 0.1 * 10.0 ** np.linspace(-1, 1, 5))


def test_grid_has_one_row_per_point_and_includes_the_seed(tmp_path):
    objs = [TINY, TINY.model_copy(update={"delay_s": 31.23e-3})]
    qs, rs = [0.01, 0.1], [0.1, 1.0]
    grid = tuning.grid_search(objs, qs, rs, tmp_path, workers=1, progress=False)
    assert len(grid) == 2 * 2 * 2
    assert set(zip(grid.q, grid.r, strict=True)) == {(q, r) for q in qs for r in rs}
    assert grid.is_seed.sum() == 2  # (0.01, 0.1) at each delay
    assert (grid.n_failed == 0).all() and grid.cost.notna().all()
    assert {"phase_margin_deg", "stable", "filter_lag_deg"} <= set(grid.columns)
    files = sorted((tmp_path / "runs").glob("*.parquet"))
    assert len(files) == 8
    fig = tuning.plot_heatmap(grid)
    assert len(fig.axes) == 3  # two panels and the colour bar
    # Resumable: a second call recomputes nothing and returns the same table.
    mtimes = [f.stat().st_mtime_ns for f in files]
    again = tuning.grid_search(objs, qs, rs, tmp_path, workers=1, progress=False)
    assert [f.stat().st_mtime_ns for f in files] == mtimes
    pd.testing.assert_frame_equal(again, grid)


def test_optuna_study_in_sqlite_resumes(tmp_path):
    study = tuning.optuna_search(TINY, tmp_path, 2, q_bounds=(1e-3, 1.0), r_bounds=(1e-2, 1.0))
    assert (tmp_path / "optuna.db").exists()
    first = [(t.params["q"], t.params["r"]) for t in study.trials]
    assert len(first) == 2
    assert first[0] == (tuning.SEED_Q_SCALE, tuning.SEED_R_SCALE)  # enqueued seed point
    study = tuning.optuna_search(TINY, tmp_path, 3, q_bounds=(1e-3, 1.0), r_bounds=(1e-2, 1.0))
    again = [(t.params["q"], t.params["r"]) for t in study.trials]
    assert len(again) == 3 and again[:2] == first
    # The budget is reached: nothing more runs.
    study = tuning.optuna_search(TINY, tmp_path, 3, q_bounds=(1e-3, 1.0), r_bounds=(1e-2, 1.0))
    assert len(study.trials) == 3
    # The same study, loaded by optuna directly from the file.
    loaded = optuna.load_study(
        study_name=tuning.study_name_for(TINY), storage=f"sqlite:///{tmp_path / 'optuna.db'}"
    )
    assert len(loaded.trials) == 3
    # Its trial values are the objective's mean cost.
    t0 = loaded.trials[0]
    assert t0.value == pytest.approx(tuning.evaluate(TINY, 0.01, 0.1)["cost"])


def test_tune_kalman_writes_its_tables_and_a_verdict(tmp_path):
    res = tuning.tune_kalman(
        tmp_path,
        delays_s=(31.23e-3,),
        grid_points=2,
        grid_decades=1.0,
        n_trials=2,
        seeds=(0,),
        validation_seeds=(100,),
        duration_s=0.3,
        workers=1,
        objective=TINY,
        progress=False,
    )
    assert len(res.grid) == 9  # 3 x 3: the two ends and the seed's value
    assert len(res.trials) == 2
    assert set(res.comparison.setting) >= {"seed", "grid best", "optuna best"}
    assert res.comparison.loc[res.comparison.setting == "seed", "diff_vs_seed"].iloc[0] == 0.0
    for key in ("grid", "heatmap", "trials", "comparison", "summary"):
        assert res.paths[key].exists()
    (line,) = res.summary_lines()
    assert line.startswith("31.23 ms:")
    assert "seed" in line
