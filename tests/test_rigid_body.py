"""The shared rigid-body step against a continuous reference, the twin on the group, and a
steady tilt stop."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from plant import attitude as A
from plant.dynamics import MujocoPlant
from plant.params import PlantParams
from plant.rigid_body import (
    PAIR_REUSE_RAD,
    RigidBody,
    _step_series,
    stop_gains,
    tilt_stop_contact,
)
from plant.torque import TorqueMap
from plant.twin import TWIN_SUBSTEPS, CasadiTwin
from tests.test_dynamics import balanced_currents

ARCSEC_RAD = np.deg2rad(1.0 / 3600.0)


def reference_acceleration(p: PlantParams, tm: TorqueMap, q, w, current, torque_body=None):
    """omega_dot (3,), rad/s², of the equations of ``plant.dynamics`` written out in numpy:
    K(q) by ``plant.torque.TorqueMap`` (independent of ``plant.rigid_body``), the tilt stop's
    spring-damper on beta = acos(R_zz) about u = Z x s / |Z x s| with the gains of
    ``stop_gains``, and a body torque (N·m)."""
    r = p.rotor
    d = np.asarray(r.com_offset_m)
    J = np.diag(r.inertia_com_kgm2) + r.mass_kg * (d @ d * np.eye(3) - np.outer(d, d))
    mg = r.mass_kg * np.array([0.0, 0.0, -r.gravity_m_s2])
    R = A.to_matrix(q)
    T = tm.from_matrix(R) @ current
    k, c, beta_max = stop_gains(p)
    s = R[:, 2]  # the shaft in the stator frame
    beta = np.arccos(np.clip(s[2], -1.0, 1.0))
    if beta > beta_max:
        u = np.cross([0.0, 0.0, 1.0], s)
        u /= np.linalg.norm(u)
        T = T - max(0.0, k * (beta - beta_max) + c * (R @ w) @ u) * u
    tau = R.T @ T + np.cross(d, R.T @ mg) - r.viscous_Nms_per_rad * w - np.cross(w, J @ w)
    tau -= r.coulomb_Nm * w / np.sqrt(w @ w + r.coulomb_smoothing_rad_s**2)
    return np.linalg.solve(J, tau + (0.0 if torque_body is None else torque_body))


def reference(p: PlantParams, q0, w0, U):
    """The equations of ``plant.dynamics`` integrated by scipy's DOP853 at tight tolerances,
    K(q) evaluated continuously (``reference_acceleration``), the quaternion's components
    integrated as a vector ODE. One solve per run of equal currents; returns the attitudes
    (N+1, 4) at the physics steps."""
    tm, h = TorqueMap(p.motor), p.physics_dt_s

    def rhs(_t, x, current):
        q, w = x[:4] / np.linalg.norm(x[:4]), x[4:]
        return np.r_[0.5 * A.multiply(x[:4], np.r_[0.0, w]),
                     reference_acceleration(p, tm, q, w, current)]

    change = np.r_[0, np.flatnonzero(np.any(np.diff(U, axis=0) != 0, axis=1)) + 1, len(U)]
    x = np.r_[q0, w0]
    out = [q0]
    for a, b in zip(change[:-1], change[1:], strict=True):
        t_eval = np.arange(a + 1, b + 1) * h
        sol = solve_ivp(rhs, (a * h, b * h), x, args=(U[a],), method="DOP853", rtol=1e-12,
                        atol=1e-13, t_eval=t_eval)
        out.extend(sol.y[:4].T / np.linalg.norm(sol.y[:4].T, axis=1, keepdims=True))
        x = sol.y[:, -1]
    return np.array(out)


def max_angle(Q1, Q2) -> float:
    return max(A.geodesic_angle(a, b) for a, b in zip(Q1, Q2, strict=True))


@pytest.mark.parametrize(
    "duration_s", [0.25, pytest.param(1.0, marks=pytest.mark.slow)]
)
def test_plant_converges_to_the_continuous_reference_at_30_rad_s(duration_s):
    """K(q) evaluated inside the integrator's stages: the ±0.3 A test sequence at 30 rad/s spin
    stays within 1e-6 rad of the continuous reference, over 1 s (slow: the reference takes
    40 s) and over its first 0.25 s (K held over each step: 7e-2 rad after 1 s)."""
    p = PlantParams()
    q0, w0 = A.from_zyz(0.3, np.deg2rad(5), 1.0), np.array([0.1, -0.1, 30.0])
    U = balanced_currents(np.random.default_rng(0), 0.3)[: round(duration_s / p.physics_dt_s)]
    Q_ref = reference(p, q0, w0, U)
    Q, _ = MujocoPlant(p, q0, w0).simulate(U)
    assert max(A.tilt(q) for q in Q_ref) < np.deg2rad(14)  # the stop is not involved
    turned = sum(A.geodesic_angle(a, b) for a, b in zip(Q_ref[:-1], Q_ref[1:], strict=True))
    assert turned > 15.0 * duration_s  # rad: a fast spin all along (it decays viscously)
    assert max_angle(Q, Q_ref) < 1e-6


@pytest.mark.parametrize("spin_rad_s", [100.0, 235.0])
def test_twin_on_the_group_stays_on_the_reference_up_to_the_terminal_speed(spin_rad_s):
    """The CasADi twin's step (exponential map, torques in the stages) within 1e-6 rad of the
    continuous reference over 0.25 s of free spin with a nutation, up to the free-spin terminal
    speed (about 235 rad/s)."""
    p = PlantParams()
    q0, w0 = A.from_zyz(0.2, np.deg2rad(5), -0.4), np.array([0.3, -0.2, spin_rad_s])
    U = np.zeros((250, 16))
    Q_ref = reference(p, q0, w0, U)
    Qt, _ = CasadiTwin(p).simulate(q0, w0, U)
    assert A.geodesic_angle(Q_ref[0], Q_ref[-1]) > 1.0
    assert max_angle(Qt, Q_ref) < 1e-6


def test_compiled_step_and_twin_take_the_same_step():
    """The two codes of the step (the compiled kernel of ``plant.rigid_body``, which the plant
    runs for one rotor and the batched engine for many; the CasADi twin's ``step``) discretise
    the same equations with the same method: over the 1 s test sequence at 30 rad/s, with the
    twin's fixed two sub-steps per step, they agree to rounding (far inside the 1e-6 rad of
    each to the reference). The plant's own rule (the spin decays from 30 to 12 rad/s, so it
    goes from two sub-steps to one) is the same kernel in a batch: the batch holds two rotors,
    the second at rest."""
    p = PlantParams()
    q0, w0 = A.from_zyz(0.3, np.deg2rad(5), 1.0), np.array([0.1, -0.1, 30.0])
    U = balanced_currents(np.random.default_rng(1), 0.3)
    Q, W = MujocoPlant(p, q0, w0).simulate(U)
    Qt, Wt = CasadiTwin(p).simulate(q0, w0, U)
    body, fixed = RigidBody(p), RigidBody(p, TWIN_SUBSTEPS, np.inf)
    q, w = np.stack([q0, [1.0, 0.0, 0.0, 0.0]]), np.stack([w0, np.zeros(3)])
    qf, wf = q[:1], w[:1]
    Qb, Qf, Wf = [q[0]], [qf[0]], [wf[0]]
    for u in U:
        q, w = body.step(q, w, np.stack([u, np.zeros(16)]), p.physics_dt_s)
        qf, wf = fixed.step(qf, wf, u[None], p.physics_dt_s)
        Qb.append(q[0])
        Qf.append(qf[0])
        Wf.append(wf[0])
    assert max_angle(Qf, Qt) < 1e-9
    assert np.abs(np.array(Wf) - Wt).max() < 1e-8
    assert max_angle(Q, Qb) < 1e-12  # one rotor or a batch: the same kernel
    assert np.abs(W[-1] - w[0]).max() < 1e-10
    assert A.geodesic_angle(q[1], [1.0, 0.0, 0.0, 0.0]) == 0.0  # no torque, no motion


def test_a_slow_rotor_takes_one_substep_and_stays_on_the_reference():
    """At the study's rates (6 rad/s spin, the ±0.3 A test sequence) every physics step takes
    one RKMK4 sub-step (four evaluations of the acceleration, counted by the kernel), and over
    0.25 s the attitude stays within 2e-8 rad of the continuous reference (measured 1.0e-8 rad;
    the fast rows' bound is 1e-6 rad)."""
    p = PlantParams()
    q0, w0 = A.from_zyz(0.3, np.deg2rad(5), 1.0), np.array([0.1, -0.1, 6.0])
    U = balanced_currents(np.random.default_rng(0), 0.3)[:250]
    Q_ref = reference(p, q0, w0, U)
    body = RigidBody(p)
    q, w = q0[None], w0[None]
    Q, evaluations = [q0], []
    for u in U:
        q, w = body.step(q, w, u[None], p.physics_dt_s)
        Q.append(q[0])
        evaluations.append(body.evaluations[0])
    assert set(evaluations) == {4}
    assert max(A.tilt(q) for q in Q_ref) > np.deg2rad(5)  # the currents move the rotor
    assert max_angle(Q, Q_ref) < 2e-8


def test_fast_rows_take_the_substeps_their_rotation_needs():
    """Rows of one batch take their own number of sub-steps: ceil(h |omega| / 0.016 rad) from
    the documented rule (``SUBSTEP_ANGLE_RAD``), at least one: at rest, 6 and 15 rad/s one
    (four evaluations), 30 rad/s two, 235 rad/s (the free-spin terminal speed) fifteen; a
    shortened step of 0.4 ms at 60 rad/s two. Each row's result is the one it gets alone."""
    p = PlantParams()
    body = RigidBody(p)
    spins = np.array([0.0, 6.0, 15.0, 30.0, 235.0, 60.0])
    h = np.array([1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 4e-4])
    q = np.tile(A.from_zyz(0.3, np.deg2rad(5), 1.0), (6, 1))
    w = np.column_stack([np.zeros(6), np.zeros(6), spins])
    cur = np.tile(np.random.default_rng(3).uniform(-0.3, 0.3, 16), (6, 1))
    q1, w1 = body.step(q, w, cur, h)
    n = body.evaluations
    assert n.tolist() == [4, 4, 4, 8, 60, 8]
    for i in range(6):
        qi, wi = body.step(q[i : i + 1], w[i : i + 1], cur[i : i + 1], h[i])
        assert body.evaluations[0] == n[i]
        assert np.array_equal(qi[0], q1[i]) and np.array_equal(wi[0], w1[i])


def _reference_step(p: PlantParams, tm: TorqueMap, q, w, current, h, n, torque_body):
    """n RKMK4 sub-steps of h/n (the method of ``plant.rigid_body``) written out in numpy on
    ``reference_acceleration``."""
    hs = h / n
    for _ in range(n):
        k_phi, k_w = [], []
        for a in (0.0, 0.5, 0.5, 1.0):
            phi = a * hs * k_phi[-1] if k_phi else np.zeros(3)
            ws = w + a * hs * k_w[-1] if k_w else w
            k_w.append(reference_acceleration(p, tm, A.multiply(q, A.from_rotvec(phi)), ws,
                                              current, torque_body))
            theta = np.linalg.norm(phi)  # the Bortz equation
            c = 1.0 / 12.0 if theta < 1e-6 else (1.0 - theta / 2.0 / np.tan(theta / 2.0)) / theta**2
            k_phi.append(ws + 0.5 * np.cross(phi, ws) + c * np.cross(phi, np.cross(phi, ws)))
        phi = hs / 6.0 * (k_phi[0] + 2.0 * k_phi[1] + 2.0 * k_phi[2] + k_phi[3])
        w = w + hs / 6.0 * (k_w[0] + 2.0 * k_w[1] + 2.0 * k_w[2] + k_w[3])
        q = A.multiply(q, A.from_rotvec(phi))
        q = q / np.linalg.norm(q)
    return q, w


def test_compiled_acceleration_and_step_are_the_straightforward_formula():
    """The compiled kernel (window pairs listed once per step, series for the exponential map)
    against the formula written out in numpy, on random rows: attitudes anywhere (the tilt stop
    in contact on many), rates from 0 to 200 rad/s, currents up to the 2 A limit with some coils
    off, body torques, one of 60 N·m that turns the rotor beyond the pair lists' margin within
    the step. omega_dot to 1e-12 relative; one step with the kernel's own number of sub-steps
    to 1e-12 rad and 1e-12 relative in omega."""
    p = PlantParams()
    tm, body = TorqueMap(p.motor), RigidBody(p)
    rng = np.random.default_rng(4)
    B = 24
    q = np.stack([A.from_zyz(*rng.uniform(-np.pi, np.pi, 3)) for _ in range(B)])
    w = rng.normal(size=(B, 3)) * rng.choice([0.0, 0.5, 5.0, 30.0, 200.0], size=(B, 1))
    cur = rng.uniform(-2.0, 2.0, (B, 16)) * (rng.uniform(size=(B, 16)) > 0.2)
    dist = rng.normal(size=(B, 3)) * 0.1
    dist[0], w[0] = [60.0, 0.0, 0.0], 0.0
    assert tilt_stop_contact(q, p).sum() > B // 2
    acc = body.acceleration(q, w, cur, dist)
    for b in range(B):
        ref = reference_acceleration(p, tm, q[b], w[b], cur[b], dist[b])
        assert np.abs(acc[b] - ref).max() < 1e-12 * np.abs(ref).max()
    q1, w1 = body.step(q, w, cur, p.physics_dt_s, dist)
    n = body.evaluations
    assert n[0] > 4  # the 60 N·m row: 27 rad/s after the step, two sub-steps
    for b in range(B):
        qr, wr = _reference_step(p, tm, q[b], w[b], cur[b], p.physics_dt_s, n[b] // 4, dist[b])
        assert A.geodesic_angle(q1[b], qr) < 1e-12
        assert np.abs(w1[b] - wr).max() < 1e-12 * max(np.abs(wr).max(), 1.0)


def test_pair_lists_kept_across_steps_give_the_fresh_lists_steps():
    """The compiled run loop keeps a rotor's pair lists from step to step while they cover its
    turn (``PAIR_REUSE_RAD``). Over 300 steps with new currents at every step (some coils off),
    rotors from rest to 30 rad/s and a body-torque kick that turns one beyond the lists within a
    step, the trajectory equals the one with lists made at every step to rounding (1e-12 rad,
    1e-12 relative in omega). The slow rotors turn by under a tenth of the reuse margin per
    step, so their lists serve many steps; a list kept beyond its margin would miss pairs that
    open and show as a difference."""
    p = PlantParams()
    body = RigidBody(p)
    rng = np.random.default_rng(11)
    B, n = 6, 300
    q = np.stack([A.from_zyz(*rng.uniform(-0.2, 0.2, 3)) for _ in range(B)])
    w = rng.normal(size=(B, 3)) * np.array([0.0, 0.3, 1.0, 3.0, 10.0, 30.0])[:, None]
    cur = rng.uniform(-0.5, 0.5, (B, n, 16)) * (rng.uniform(size=(B, n, 16)) > 0.1)
    dist = np.zeros((B, n, 3))
    dist[2, 100] = [40.0, 0.0, 0.0]  # 40 N·m for one step: beyond the lists' margin
    q_kept, w_kept = _step_series(q, w, cur, p.physics_dt_s, dist, False, *body.consts)
    q_new, w_new = _step_series(q, w, cur, p.physics_dt_s, dist, True, *body.consts)
    assert np.all(A.geodesic_angle(q_kept, q_new) < 1e-12)
    assert np.abs(w_kept - w_new).max() < 1e-12 * max(np.abs(w_new).max(), 1.0)
    turn = np.linalg.norm(w_new[:2], axis=-1).max() * p.physics_dt_s  # rad per step, slow rows
    assert turn < PAIR_REUSE_RAD / 10  # so their lists last ten steps and more


def test_each_row_takes_its_own_step_length():
    """A batch with a step length per row gives each row what a batch of one gives with that
    length (the batched engine's shortened steps), whatever the other rows do."""
    p = PlantParams()
    body = RigidBody(p)
    rng = np.random.default_rng(2)
    q = np.stack([A.from_zyz(*rng.uniform(0.0, 0.2, 3)) for _ in range(3)])
    w = rng.normal(size=(3, 3)) * 5.0
    cur = rng.uniform(-0.3, 0.3, size=(3, 16))
    h = np.array([1e-3, 3.7e-4, 1e-3])
    qb, wb = body.step(q, w, cur, h)
    for i in range(3):
        q1, w1 = body.step(q[i : i + 1], w[i : i + 1], cur[i : i + 1], h[i])
        assert np.array_equal(q1[0], qb[i]) and np.array_equal(w1[0], wb[i])
    assert not np.allclose(qb[0], body.step(q[:1], w[:1], cur[:1], h[1])[0][0])


def _push(plant: MujocoPlant, steps: int, torque_stator=None) -> tuple[np.ndarray, np.ndarray]:
    h = plant.params.physics_dt_s
    tilts, rates = [], []
    for _ in range(steps):
        cmd = np.zeros(16) if torque_stator is None else plant.allocate(torque_stator).currents
        plant.step(cmd, h)
        tilts.append(A.tilt(plant.q))
        rates.append(np.linalg.norm(plant.omega))
    return np.array(tilts), np.array(rates)


def test_tilt_stop_contact_is_steady_under_a_steady_push():
    """0.3 N·m from the coils pushed steadily about the tilt axis against the 15° stop (currents
    re-allocated every step at the true attitude): after the impact settles the tilt moves by
    less than 1 arcsec peak to peak and the rotor is at rest; likewise for a 5 N·m body torque."""
    p = PlantParams()
    plant = MujocoPlant(p, A.from_zyz(0.0, np.deg2rad(14.0), 0.0))
    tilts, rates = _push(plant, 600, [0.0, 0.3, 0.0])
    assert plant.tilt_stop_active()
    assert np.degrees(tilts[-1]) == pytest.approx(15.0, abs=0.1)
    assert np.ptp(tilts[300:]) < ARCSEC_RAD
    assert rates[300:].max() < 1e-6
    plant = MujocoPlant(p, A.from_zyz(0.0, np.deg2rad(14.0), 0.0))
    plant.disturbance = lambda h: np.array([0.0, 5.0, 0.0])  # body frame, about the tilt axis
    tilts, rates = _push(plant, 1000)
    assert np.degrees(tilts[-1]) == pytest.approx(15.0, abs=1.0)
    assert np.ptp(tilts[500:]) < ARCSEC_RAD
    assert rates[500:].max() < 1e-6


def test_tilt_stop_leaves_spin_and_yaw_free():
    """At the stop, a torque along the shaft spins the rotor up at T / J_z (the stop's torque is
    perpendicular to the shaft and to Z)."""
    p = PlantParams(rotor=PlantParams().rotor.model_copy(update={"coulomb_Nm": 0.0,
                                                                  "viscous_Nms_per_rad": 0.0}))
    body = RigidBody(p)
    q = A.from_zyz(0.0, np.deg2rad(15.2), 0.0)[None]
    w = np.zeros((1, 3))
    dist = np.array([[0.0, 0.0, 0.05]])  # body frame: along the shaft
    acc = body.acceleration(q, w, np.zeros((1, 16)), dist)
    assert acc[0, 2] == pytest.approx(0.05 / body.J[2, 2], rel=1e-12)
    assert tilt_stop_contact(q, p)[0]
