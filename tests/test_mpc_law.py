"""The MPC's linearised feedback law against the real MPC controller fed the same estimates."""

from __future__ import annotations

import control as ct
import numpy as np
import pytest

from controller.mpc import MPCController
from controller.mpc_config import MPCConfig
from latency.margins import attitude_plant, sampled_margins
from latency.mpc_law import _Hold, frictionless, mpc_discrete_law, mpc_state_gain
from plant import attitude
from plant.estimate import Estimate
from plant.params import PlantParams

T_FRAME = 1.0 / 36.0


@pytest.fixture(scope="module")
def gain():
    return mpc_state_gain()


def test_gain_is_per_axis_and_insensitive_to_the_step(gain):
    """About rest the law decouples the axes, and halving/tripling the difference step changes
    nothing: the solve is converged and the map is linear there."""
    off = gain.copy()
    for i in range(3):
        off[i, i] = off[i, 3 + i] = 0.0
    assert np.abs(off).max() < 1e-6 * np.abs(gain).max()
    assert np.all(np.diag(gain[:, :3]) > 0) and np.all(np.diag(gain[:, 3:]) > 0)
    np.testing.assert_allclose(mpc_state_gain(eps=3e-3), gain, rtol=1e-3)


@pytest.mark.parametrize("vision_delay_s", [0.01633, 0.04])
def test_linear_law_reproduces_the_mpc_on_small_signals(gain, vision_delay_s):
    """Feed the real delay-aware MPC (its own rate estimate and command history, frictionless
    plant, compute latency 0) a random small attitude sequence that starts at rest; its torques
    equal the linear law's to within 0.5 % of their range on every axis."""
    params = frictionless(PlantParams())
    tau = 0.5 * params.camera.exposure_s + vision_delay_s
    mpc = MPCController(MPCConfig(compute_latency_s=0.0), params)
    ref = _Hold(np.array([1.0, 0.0, 0.0, 0.0]))
    rng = np.random.default_rng(3)
    n = 40
    theta = np.cumsum(rng.normal(0.0, 0.002, (n, 3)), axis=0)
    theta[:3] = 0.0  # at rest first: both start with no rate and no command history
    u_mpc = np.array([
        mpc.command(Estimate(t_exposure=k * T_FRAME, t_available=k * T_FRAME + tau,
                             q=attitude.from_rotvec(theta[k]), euler_zyz=np.zeros(3),
                             marker_px=np.zeros((2, 2)), covariance=np.eye(3), valid=True),
                    ref, k * T_FRAME + tau)
        for k in range(n)
    ])
    for ax in range(3):
        law = mpc_discrete_law((gain[ax, ax], gain[ax, 3 + ax]), inertia_kgm2=mpc.J[ax],
                               damping_Nms_per_rad=params.rotor.viscous_Nms_per_rad,
                               period_s=T_FRAME, delay_s=tau)
        _, y = ct.forced_response(law, T=np.arange(n) * T_FRAME, U=theta[:, ax])
        u_lin = -np.asarray(y).ravel()
        assert np.max(np.abs(u_lin - u_mpc[:, ax])) < 0.005 * np.ptp(u_mpc[:, ax])


def test_delay_compensation_buys_delay_margin(gain):
    """With GK-TransT's latency the predictor keeps most of the zero-delay margin; without it
    the margin shrinks by about the delay."""
    p = PlantParams()
    J, b = 2.2e-3, p.rotor.viscous_Nms_per_rad
    tau0, tau = 0.5 * p.camera.exposure_s, 0.5 * p.camera.exposure_s + 0.01633
    res = {}
    for aware in (True, False):
        for d in (tau0, tau):
            law = mpc_discrete_law((gain[0, 0], gain[0, 3]), inertia_kgm2=J,
                                   damping_Nms_per_rad=b, period_s=T_FRAME, delay_s=d,
                                   delay_aware=aware)
            res[aware, d] = sampled_margins(attitude_plant(J, b), law, delay_s=d)
    assert all(m.stable for m in res.values())
    assert res[True, tau].delay_margin_s > 0.9 * res[True, tau0].delay_margin_s
    lost = res[False, tau0].delay_margin_s - res[False, tau].delay_margin_s
    assert lost == pytest.approx(tau - tau0, rel=0.1)


def test_bad_arguments_raise(gain):
    with pytest.raises(ValueError):
        mpc_discrete_law((1.0, 0.1), inertia_kgm2=2e-3, damping_Nms_per_rad=0.0, period_s=0.0,
                         delay_s=0.01)
    with pytest.raises(ValueError, match="predict_s"):
        mpc_discrete_law((1.0, 0.1), inertia_kgm2=2e-3, damping_Nms_per_rad=0.0,
                         period_s=T_FRAME, delay_s=0.01, predict_s=-1.0)
