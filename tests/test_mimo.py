"""The three-axis (MIMO) attitude loop: linearisation against the CasADi twin, the decoupled
case against the per-axis analysis, and the coupled verdicts against the eigenvalues of the exact
sampled MIMO loop (an independent discretisation)."""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest

from controller.pid import PIDConfig, PIDController
from latency.margins import sampled_plant
from latency.mimo import mimo_loop, mimo_margins, rotor_linearisation
from plant import attitude
from plant.params import PlantParams
from plant.twin import CasadiTwin

T_FRAME = 1.0 / 36.0
Q_TILTED = attitude.from_zyz(0.3, math.radians(15.0), 1.0)


def _params(com_offset_m=(0.0, 0.0, 0.0), coulomb: float | None = None) -> PlantParams:
    p = PlantParams()
    upd = {"com_offset_m": com_offset_m}
    if coulomb is not None:
        upd["coulomb_Nm"] = coulomb
    return p.model_copy(update={"rotor": p.rotor.model_copy(update=upd)})


def _skew(v):
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def _omega_dot(twin: CasadiTwin, q, T) -> np.ndarray:
    x = np.r_[q, 0.0, 0.0, 0.0]
    return np.asarray(twin.f_torque(x, T)).ravel()[4:]


@pytest.mark.parametrize("d", [(2e-3, 1e-3, -3e-3), (-1e-3, 2.5e-3, 4e-3)])
def test_linearisation_matches_the_twin_jacobian(d):
    """Central differences of the CasADi twin's Euler equations about q_op (body-frame
    perturbations of the true and of the estimated attitude) against G, τ_eq and J_O."""
    params = _params(d, coulomb=0.0)
    twin = CasadiTwin(params)
    lin = rotor_linearisation(params, Q_TILTED)
    R_op = attitude.to_matrix(Q_TILTED)
    T_eq = R_op @ lin.tau_eq  # stator-frame torque the PID sends at equilibrium
    np.testing.assert_allclose(_omega_dot(twin, Q_TILTED, T_eq), 0.0, atol=1e-12)
    Ji = np.linalg.inv(lin.J_O)
    h = 1e-6
    d_true = np.zeros((3, 3))
    d_est = np.zeros((3, 3))
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        qp, qm = (attitude.multiply(Q_TILTED, attitude.from_rotvec(s * e)) for s in (1, -1))
        # the true attitude moves, the command is fixed in the stator frame
        d_true[:, i] = (_omega_dot(twin, qp, T_eq) - _omega_dot(twin, qm, T_eq)) / (2 * h)
        # the estimate moves: T = R(q_est) τ_eq, the true attitude stays at q_op
        Tp, Tm = (attitude.to_matrix(q) @ lin.tau_eq for q in (qp, qm))
        d_est[:, i] = (_omega_dot(twin, Q_TILTED, Tp) - _omega_dot(twin, Q_TILTED, Tm)) / (2 * h)
    np.testing.assert_allclose(d_true, Ji @ lin.G, rtol=1e-6, atol=1e-9)
    # the estimate path is the controller's extra term −[τ_eq]× (u = −(C + [τ_eq]×) y)
    np.testing.assert_allclose(d_est, -Ji @ _skew(lin.tau_eq), rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(lin.J_O, twin.J_O, rtol=1e-12)


def test_decoupled_loop_equals_the_per_axis_loops():
    """Centre of mass at the pivot: the MIMO margins are the worst of the three SISO ones."""
    params = _params()
    pid = PIDController(PIDConfig(crossover_rad_s=10.0), params)
    loop = mimo_loop(rotor_linearisation(params), [pid.transfer_function(i) for i in range(3)],
                     delay_s=0.02, sample_period_s=T_FRAME)
    m = mimo_margins(loop)
    assert m.stable and m.delay_margin_confirmed
    k = int(np.argmin([a.phase_margin_deg for a in m.per_axis]))
    assert m.phase_margin_deg == pytest.approx(m.per_axis[k].phase_margin_deg, rel=1e-7)
    assert m.crossover_rad_s == pytest.approx(m.per_axis[k].crossover_rad_s, rel=1e-7)
    assert m.delay_margin_s == pytest.approx(min(a.delay_margin_s for a in m.per_axis), rel=1e-7)
    assert m.gain_margin == pytest.approx(min(a.gain_margin for a in m.per_axis), rel=1e-6)


def _sampled_rho(params, q_op, pid, delay_s: float) -> float:
    """Spectral radius of the exact sampled three-axis loop (ZOH, fractional delay), built
    from the state-space model and the PID's discrete law: no frequency response involved."""
    lin = rotor_linearisation(params, q_op)
    Pd = sampled_plant(lin.state_space(), T_FRAME, delay_s)
    Cs = [ct.ss(pid.discrete_transfer_function(T_FRAME, axis=i)) for i in range(3)]
    Cd = ct.append(*Cs)
    Cd = ct.parallel(Cd, ct.ss(np.zeros((0, 0)), np.zeros((0, 3)), np.zeros((3, 0)),
                               _skew(lin.tau_eq), T_FRAME))
    L = ct.series(Pd, Cd)  # u -> y -> u
    A_cl = L.A - L.B @ np.linalg.solve(np.eye(3) + L.D, L.C)
    return float(np.max(np.abs(np.linalg.eigvals(A_cl))))


@pytest.mark.parametrize("d", [(2e-3, 1e-3, -3e-3), (1e-3, -1e-3, 6e-3)])
def test_coupled_delay_margin_matches_the_sampled_eigenvalues(d):
    """Offset centre of mass at 15° tilt (pendulum, and inverted pendulum with open-loop RHP
    poles): the MIMO delay margin brackets the eigenvalue boundary of the exact sampled loop
    within ±4 %, while the per-axis analysis, which ignores the coupling, does not."""
    params = _params(d)
    pid = PIDController(PIDConfig(crossover_rad_s=10.0), params)
    delay = 0.5 * params.camera.exposure_s + 0.01633
    loop = mimo_loop(rotor_linearisation(params, Q_TILTED),
                     [pid.discrete_transfer_function(T_FRAME, axis=i) for i in range(3)],
                     delay_s=delay)
    m = mimo_margins(loop)
    if d[2] > 0:
        assert loop.open_loop_rhp_poles > 0  # inverted pendulum: the count must include P
    assert m.stable and m.delay_margin_confirmed
    assert _sampled_rho(params, Q_TILTED, pid, delay) < 1.0
    assert _sampled_rho(params, Q_TILTED, pid, delay + 0.96 * m.delay_margin_s) < 1.0
    assert _sampled_rho(params, Q_TILTED, pid, delay + 1.04 * m.delay_margin_s) > 1.0
    axis_dm = min(a.delay_margin_s for a in m.per_axis)
    assert abs(axis_dm - m.delay_margin_s) > 0.04 * m.delay_margin_s
    assert (_sampled_rho(params, Q_TILTED, pid, delay + axis_dm) > 1.0) == (
        axis_dm > m.delay_margin_s
    )


def test_unstable_loop_says_so():
    params = _params((2e-3, 1e-3, -3e-3))
    pid = PIDController(PIDConfig(crossover_rad_s=10.0), params)
    delay = 0.12
    loop = mimo_loop(rotor_linearisation(params, Q_TILTED),
                     [pid.discrete_transfer_function(T_FRAME, axis=i) for i in range(3)],
                     delay_s=delay)
    m = mimo_margins(loop)
    assert not m.stable and m.unstable_poles > 0
    assert math.isnan(m.phase_margin_deg) and math.isnan(m.delay_margin_s)
    assert m.summary().startswith("MIMO loop unstable")
    assert _sampled_rho(params, Q_TILTED, pid, delay) > 1.0


def test_bad_arguments_raise():
    lin = rotor_linearisation()
    with pytest.raises(ValueError, match="three"):
        mimo_loop(lin, [ct.tf([1.0], [1.0, 1.0])] * 2)
    with pytest.raises(ValueError, match="delay_s"):
        mimo_loop(lin, ct.tf([1.0], [1.0, 1.0]), delay_s=-1e-3)
    with pytest.raises(ValueError, match="q_op"):
        rotor_linearisation(q_op=(np.nan, 0, 0, 0))
