"""Delay-aware MPC: the weight rule against an independent LQR, the forward prediction against
MuJoCo, and closed loops on the MuJoCo plant (tilt step, a request beyond the tilt stop, a 30 ms
measurement delay).

The simulated loop runs the MPC every 10 ms and holds its torque; currents are re-allocated for
that torque every 1 ms physics step (an ideal inner current loop). Commands act at the call time
in simulated time, so the tests set ``compute_latency_s=0``.
"""

import numpy as np
import pytest
import scipy.linalg

from controller.mpc import MPCController
from controller.mpc_config import MPCConfig
from controller.mpc_problem import lqr_weights, terminal_weight
from controller.pid import truth_estimate
from controller.reference import Steps, pure_tilt
from plant import attitude as A
from plant.dynamics import MujocoPlant
from plant.params import PlantParams

PARAMS = PlantParams()
J_XY = 2.2e-3


def test_weight_rule_gives_the_designed_closed_loop_poles():
    for J, wn, zeta in ((J_XY, 15.0, 0.8), (2.5e-3, 30.0, 1.0), (1.0, 2.0, 0.75)):
        q_th, q_w, r = lqr_weights(J, wn, zeta, torque_limit=0.3)
        Ac = np.array([[0.0, 1.0], [0.0, 0.0]])
        Bc = np.array([[0.0], [1.0 / J]])
        P = scipy.linalg.solve_continuous_are(Ac, Bc, np.diag([q_th, q_w]), np.array([[r]]))
        K = Bc.T @ P / r
        poles = np.linalg.eigvals(Ac - Bc @ K)
        assert np.allclose(
            np.sort_complex(poles), np.sort_complex(np.roots([1, 2 * zeta * wn, wn**2]))
        )


def test_terminal_weight_is_the_infinite_horizon_cost_to_go():
    J, h = J_XY, 0.01
    q_th, q_w, r = lqr_weights(J, 15.0, 0.8, 0.26)
    P = terminal_weight(J, h, q_th, q_w, r)
    A_ = np.array([[1.0, h], [0.0, 1.0]])
    B = np.array([[h * h / (2 * J)], [h / J]])
    K = np.linalg.solve(B.T @ P @ B + h * r, B.T @ P @ A_)
    x0 = np.array([0.05, -0.3])
    x, cost = x0.copy(), 0.0
    for _ in range(5000):  # simulate the optimal loop and add up the stage costs
        u = -(K @ x)
        cost += h * (q_th * x[0] ** 2 + q_w * x[1] ** 2 + r * float(u @ u))
        x = A_ @ x + (B @ u)
    assert cost == pytest.approx(x0 @ P @ x0, rel=1e-9)


def test_config_rejects_inconsistent_settings():
    with pytest.raises(ValueError, match="rk4_substeps"):
        MPCConfig(step_s=0.05, rk4_substeps=1)
    with pytest.raises(ValueError, match="bandwidth_rad_s"):
        MPCConfig(bandwidth_rad_s=200.0)
    with pytest.raises(ValueError, match="tilt_max_deg"):
        MPCConfig(tilt_max_deg=16.0)
    with pytest.raises(ValueError, match="damping"):
        MPCConfig(damping=0.5)
    with pytest.raises(ValueError, match="solver"):
        MPCConfig(solver="cplex")


def prediction_error(h):
    """Predict 30 ms under three held torques and compare with MuJoCo at physics step h."""
    params = PARAMS.model_copy(update={"physics_dt_s": h})
    mpc = MPCController(MPCConfig(horizon_steps=5, prediction_step_s=h), params)
    plant = MujocoPlant(params, A.from_zyz(0.3, 0.1, 1.0), [0.4, -0.2, 1.5])
    x0 = np.r_[plant.q, plant.omega]
    torques = [np.array([0.05, -0.1, 0.02]), np.array([-0.08, 0.03, 0.1]), np.zeros(3)]
    for k, T in enumerate(torques):  # commands at 0, 10, 20 ms
        mpc.record_command(0.01 * k, T)
        for _ in range(round(0.01 / h)):
            plant.step(plant.allocate(T).currents, h)
    x = mpc.predict(x0, 0.0, 0.03)
    assert A.geodesic_angle(x0[:4], plant.q) > 0.03  # the rotor did move
    return A.geodesic_angle(x[:4], plant.q), np.linalg.norm(x[4:] - plant.omega)


def test_prediction_follows_the_mujoco_plant_under_the_command_history():
    # MuJoCo holds the body-frame torque over each physics step (first order in the step h);
    # the prediction integrates the continuous law with RK4. The two must converge as h shrinks.
    e_q_coarse, e_w_coarse = prediction_error(1e-3)
    e_q_fine, e_w_fine = prediction_error(1e-4)
    assert e_q_fine < 1e-6 and e_w_fine < 1e-4  # rad, rad/s
    assert e_q_coarse / e_q_fine > 5 and e_w_coarse / e_w_fine > 5


def run_loop(cfg, tilt_deg, duration, delay_s=0.0, with_rate=True):
    """Tilt step from rest; estimates are ``delay_s`` old (built from stored true states)."""
    mpc = MPCController(cfg, PARAMS)
    plant = MujocoPlant(PARAMS)
    ref = Steps(times_s=(0.0,), attitudes=(tuple(pure_tilt(np.deg2rad(tilt_deg))),))
    dt = PARAMS.physics_dt_s
    n, every, lag = round(duration / dt), round(0.01 / dt), round(delay_s / dt)
    states, tilt, stop, pred = [], np.empty(n), False, []
    T = np.zeros(3)
    for k in range(n):
        t = k * dt
        states.append((t, plant.q, plant.omega))
        if k % every == 0:
            te, q, w = states[max(k - lag, 0)]
            T = mpc.command(truth_estimate(q, w if with_rate else None, te, t), ref, t)
            assert np.linalg.norm(T) <= mpc.torque_limit * (1 + 1e-9)
            pred.append(np.max(mpc.predicted_tilt_rad))
        alloc = plant.allocate(T)
        assert not alloc.saturated
        plant.step(alloc.currents, dt)
        tilt[k] = A.tilt(plant.q)
        stop |= plant.tilt_stop_active()
    return np.arange(1, n + 1) * dt, tilt, stop, np.array(pred), mpc


def metrics(t, y, final):
    overshoot = 100.0 * (y.max() - final) / final
    outside = np.nonzero(np.abs(y - final) > 0.02 * final)[0]
    settle = t[outside[-1] + 1] if outside[-1] + 1 < len(t) else np.inf
    return overshoot, settle


def test_tilt_step_closes_the_loop():
    t, y, stop, _, mpc = run_loop(MPCConfig(compute_latency_s=0.0), 5.0, 0.8)
    overshoot, settle = metrics(t, y, np.deg2rad(5.0))
    # Designed closed loop s² + 2ζω_n s + ω_n² with ω_n = 15 rad/s, ζ = 0.8: 2 % settling
    # ≈ 4/(ζ ω_n) = 0.33 s, overshoot 1.5 %.
    assert overshoot < 3.0
    assert settle < 0.4
    assert abs(np.degrees(y[-1]) - 5.0) < 0.05
    assert not stop
    stats = mpc.solve_stats()
    assert stats["n"] == 80 and np.isfinite(stats["solve_median_s"])
    assert len(mpc.compute_times_s) == 80 and mpc.failures == 0


def test_request_beyond_the_stop_is_held_inside_the_tilt_constraint():
    cfg = MPCConfig(compute_latency_s=0.0)
    t, y, stop, pred, mpc = run_loop(cfg, 20.0, 0.8)
    limit = np.deg2rad(cfg.tilt_max_deg)
    assert np.max(pred) <= limit + 1e-5  # every predicted node within the constraint
    assert np.max(y) < np.deg2rad(15.0)  # the rotor never reaches the stop ...
    assert not stop  # ... so it never touches it
    assert np.degrees(y[-1]) == pytest.approx(cfg.tilt_max_deg, abs=0.2)  # parked at the limit


def test_delay_aware_prediction_improves_a_loop_with_30_ms_delay():
    # A fast design (ω_n = 20 rad/s, loop crossover ~34 rad/s) loses ~58° of phase to 30 ms.
    res = {}
    for aware in (True, False):
        cfg = MPCConfig(compute_latency_s=0.0, bandwidth_rad_s=20.0, delay_aware=aware)
        t, y, _, _, _ = run_loop(cfg, 5.0, 1.0, delay_s=0.03)
        res[aware] = metrics(t, y, np.deg2rad(5.0))
    (os_aware, ts_aware), (os_blind, ts_blind) = res[True], res[False]
    assert os_blind > 15.0
    assert os_aware < 3.0 and os_aware < os_blind / 5
    assert ts_aware < 0.5 * ts_blind


def test_rate_from_attitude_differences_when_the_estimate_has_none():
    t, y, _, _, _ = run_loop(MPCConfig(compute_latency_s=0.0), 5.0, 0.6, with_rate=False)
    overshoot, settle = metrics(t, y, np.deg2rad(5.0))
    assert overshoot < 5.0 and settle < 0.5


def invalid_estimate(t):
    e = truth_estimate([1, 0, 0, 0], [0, 0, 0], t)
    return type(e)(**{**e.__dict__, "valid": False, "q": np.full(4, np.nan)})


@pytest.mark.parametrize("mode", ["zero", "hold"])
def test_invalid_estimate_gives_the_configured_safe_command(mode):
    mpc = MPCController(MPCConfig(horizon_steps=5, invalid_command=mode, compute_latency_s=0.0))
    ref = Steps(times_s=(0.0,), attitudes=(tuple(pure_tilt(0.05)),))
    T0 = mpc.command(truth_estimate([1, 0, 0, 0], [0, 0, 0], 0.0), ref, 0.0)
    assert np.linalg.norm(T0) > 0
    T1 = mpc.command(invalid_estimate(0.01), ref, 0.01)
    assert np.allclose(T1, 0.0 if mode == "zero" else T0)
    assert mpc.invalid_count == 1
    # The safe command enters the history used by the delay compensation.
    assert np.allclose(mpc._history[-1][1], T1)


def test_without_reference_preview_the_mpc_does_not_move_before_a_step():
    """A step 30 ms ahead lies inside the 50 ms horizon: the previewing MPC starts towards it,
    the one without preview regulates to the reference it sees now, where it already rests, so
    its optimal torque is zero."""
    ref = Steps(times_s=(0.0, 0.03), attitudes=((1.0, 0.0, 0.0, 0.0), tuple(pure_tilt(0.05))))
    est = truth_estimate([1, 0, 0, 0], [0, 0, 0], 0.0)
    cfg = {"horizon_steps": 5, "compute_latency_s": 0.0}
    preview = MPCController(MPCConfig(**cfg), PARAMS).command(est, ref, 0.0)
    held = MPCController(MPCConfig(**cfg, reference_preview=False), PARAMS).command(est, ref, 0.0)
    assert np.linalg.norm(preview) > 1e-4
    assert np.linalg.norm(held) < 1e-6
