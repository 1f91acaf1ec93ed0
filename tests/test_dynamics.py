"""Rotor dynamics: MuJoCo against the CasADi twin and against closed-form mechanics."""

import numpy as np
import pytest

from plant import attitude as A
from plant.dynamics import MujocoPlant
from plant.params import MotorParams, PlantParams, RotorParams
from plant.twin import CasadiTwin

FRICTIONLESS = RotorParams(viscous_Nms_per_rad=0.0, coulomb_Nm=0.0)


def run_mujoco(params, q0, w0, U):
    return MujocoPlant(params, q0, w0).simulate(U)


def balanced_currents(rng, amp_A, n_patterns=10, block_steps=25):
    """Random 16-coil patterns u, uniform in ±``amp_A`` (A), each applied as +u, −u, −u, +u for
    ``block_steps`` physics steps apiece: the net impulse of each pattern and its first moment
    cancel, so large currents shake the rotor without walking it into the tilt stop."""
    B = rng.uniform(-amp_A, amp_A, (n_patterns, 16))
    return np.repeat(np.stack([B, -B, -B, B], axis=1).reshape(-1, 16), block_steps, axis=0)


@pytest.mark.parametrize("com", [(0.0, 0.0, 0.0), (3e-4, -2e-4, -2e-3)])
def test_twin_and_mujoco_agree_over_one_second(com):
    """Same state, same 1 s current sequence, agreement within 1e-4 rad away from the
    stop, at a realistic current level (±0.3 A = 15 % of i_max, new currents every 25 ms)."""
    p = PlantParams(rotor=RotorParams(com_offset_m=com))
    rng = np.random.default_rng(0)
    q0 = A.from_zyz(0.3, np.deg2rad(5), 1.0)
    w0 = np.array([0.1, -0.1, 4.0])
    U = balanced_currents(rng, 0.3)
    assert U.shape == (1000, 16) and len(U) * p.physics_dt_s == pytest.approx(1.0)
    assert np.abs(U).max() > 0.29
    Qm, Wm = run_mujoco(p, q0, w0, U)
    Qt, Wt = CasadiTwin(p).simulate(q0, w0, U)
    tilts = [A.tilt(q) for q in Qm]
    assert max(tilts) < np.deg2rad(14)  # away from the stop
    assert max(A.tilt(q) for q in Qt) < np.deg2rad(14)
    assert max(A.geodesic_angle(a, b) for a, b in zip(Qm, Qt, strict=True)) < 1e-4
    assert np.abs(Wm - Wt).max() < 1e-4  # rad/s
    # and the motion is not trivial: a large turn, and torques of the motor's order
    assert A.geodesic_angle(Qm[0], Qm[-1]) > 0.5
    tm = MujocoPlant(p).torque_map
    torques = np.array([np.linalg.norm(tm(q) @ u) for q, u in zip(Qm[:-1], U, strict=True)])
    assert torques.max() > 0.02  # N·m; the capacity at i_max is 0.28-0.53 N·m (bench_plant)
    # the tilt really moves under these currents (not only the free spin)
    assert np.ptp(tilts) > np.deg2rad(3)


def test_torque_free_rotor_conserves_energy_and_momentum():
    p = PlantParams(rotor=FRICTIONLESS)
    plant = MujocoPlant(p, A.from_zyz(0.1, 0.1, 0.2), [1.0, -2.0, 3.0])
    J = np.diag(p.rotor.inertia_com_kgm2)

    def invariants():
        w = plant.omega
        return 0.5 * w @ J @ w, A.to_matrix(plant.q) @ J @ w  # energy, stator-frame momentum

    E0, L0 = invariants()
    plant.step(np.zeros(16), 0.02)  # short: the tilt stays below the stop
    E1, L1 = invariants()
    assert E1 == pytest.approx(E0, rel=1e-9)
    assert np.allclose(L1, L0, rtol=1e-9, atol=1e-12)


def test_viscous_spin_decay_is_exponential():
    b = 2e-3
    p = PlantParams(rotor=RotorParams(viscous_Nms_per_rad=b, coulomb_Nm=0.0))
    Jz = p.rotor.inertia_com_kgm2[2]
    plant = MujocoPlant(p, omega0=[0, 0, 10.0])
    plant.step(np.zeros(16), 0.5)
    assert plant.omega[2] == pytest.approx(10.0 * np.exp(-b / Jz * 0.5), rel=1e-6)


def test_coulomb_friction_decelerates_at_tau_c_over_J():
    tau_c = 3e-3
    p = PlantParams(rotor=RotorParams(viscous_Nms_per_rad=0.0, coulomb_Nm=tau_c))
    Jz = p.rotor.inertia_com_kgm2[2]
    plant = MujocoPlant(p, omega0=[0, 0, 5.0])
    plant.step(np.zeros(16), 0.2)
    # |omega| >> omega_s, so the smooth law is within 0.01 % of tau_c.
    assert plant.omega[2] == pytest.approx(5.0 - tau_c / Jz * 0.2, rel=1e-4)


def test_constant_torque_gives_the_angular_acceleration_of_euler_equations():
    p = PlantParams(rotor=FRICTIONLESS)
    plant = MujocoPlant(p)
    T = np.array([0.0, 0.0, 0.1])  # about the shaft: pure spin, no tilt
    alloc = plant.allocate(T)
    plant.step(alloc.currents, 0.1)
    Jz = p.rotor.inertia_com_kgm2[2]
    # K(q) changes as the rotor spins, so held currents give a drifting torque: over the first
    # physics step the rotor turns by 0.5 (T/Jz) h^2 = 2.3e-5 rad, so the Euler-equation value
    # holds to that order and the torque's direction turns by as little,
    plant2 = MujocoPlant(p)
    plant2.step(alloc.currents, p.physics_dt_s)
    assert plant2.omega[2] == pytest.approx(0.1 / Jz * p.physics_dt_s, rel=1e-6)
    assert np.linalg.norm(plant2.omega[:2]) < 2.3e-5 * plant2.omega[2]
    # and the whole 0.1 s run matches the twin fed the same currents.
    Q, W = CasadiTwin(p).simulate([1, 0, 0, 0], [0, 0, 0], np.tile(alloc.currents, (100, 1)))
    assert np.allclose(plant.omega, W[-1], atol=1e-9)


def test_gravity_pendulum_period():
    # Centre of mass 5 mm below O: small tilt oscillation with T = 2 pi sqrt(J_O / (m g d)).
    d = 5e-3
    p = PlantParams(
        rotor=RotorParams(com_offset_m=(0, 0, -d), viscous_Nms_per_rad=0.0, coulomb_Nm=0.0)
    )
    r = p.rotor
    J_O = r.inertia_com_kgm2[0] + r.mass_kg * d * d
    period = 2 * np.pi * np.sqrt(J_O / (r.mass_kg * r.gravity_m_s2 * d))
    plant = MujocoPlant(p, A.axis_angle([0, 1, 0], np.deg2rad(2.0)))
    tilt_y = []
    for _ in range(int(2.2 * period / p.physics_dt_s)):
        plant.step(np.zeros(16), p.physics_dt_s)
        tilt_y.append(A.to_rotvec(plant.q)[1])
    tilt_y = np.array(tilt_y)
    ups = np.flatnonzero((tilt_y[:-1] < 0) & (tilt_y[1:] >= 0)) * p.physics_dt_s
    assert len(ups) >= 2
    assert ups[1] - ups[0] == pytest.approx(period, rel=2e-3)


def test_tilt_stop_clamps_tilt_but_not_spin():
    p = PlantParams()
    plant = MujocoPlant(p)
    for _ in range(300):  # push hard about +Y for 0.3 s
        plant.step(plant.allocate([0.0, 0.35, 0.0]).currents, p.physics_dt_s)
    assert A.tilt(plant.q) == pytest.approx(np.deg2rad(15), abs=np.deg2rad(0.1))
    assert plant.tilt_stop_active()
    spin0 = plant.omega[2]
    for _ in range(200):  # keep pushing on the stop and add a torque along the shaft
        shaft = A.to_matrix(plant.q)[:, 2]
        plant.step(plant.allocate([0.0, 0.2, 0.0] + 0.1 * shaft).currents, p.physics_dt_s)
    assert A.tilt(plant.q) < np.deg2rad(15.1)
    assert plant.omega[2] - spin0 > 5.0  # spin accelerates freely at the stop


def test_coil_current_lag_is_first_order():
    tau = 2e-3
    p = PlantParams(motor=MotorParams(coil_time_constant_s=tau))
    plant = MujocoPlant(p)
    cmd = np.full(16, 1.0)
    plant.step(cmd, tau)
    assert plant.currents == pytest.approx(np.full(16, 1 - np.exp(-1)), rel=1e-9)


def test_bad_input_names_the_argument():
    plant = MujocoPlant()
    with pytest.raises(ValueError, match="currents"):
        plant.step(np.full(16, np.nan), 1e-3)
    with pytest.raises(ValueError, match="currents"):
        plant.step(np.zeros(15), 1e-3)
    with pytest.raises(ValueError, match="limit"):
        plant.step(np.full(16, 10.0), 1e-3)
    with pytest.raises(ValueError, match="dt"):
        plant.step(np.zeros(16), 1.5e-3)
    with pytest.raises(ValueError, match="q0"):
        MujocoPlant(q0=[2.0, 0, 0, 0])
    with pytest.raises(ValueError, match="omega0"):
        MujocoPlant(omega0=[np.inf, 0, 0])
    near = MujocoPlant(q0=[1.0 + 1e-4, 0, 0, 0])
    assert np.linalg.norm(near.q) == pytest.approx(1.0)


def test_impossible_config_is_rejected_with_the_field_name():
    with pytest.raises(ValueError, match="exposure_s"):
        PlantParams.model_validate({"camera": {"exposure_s": 0.5}})
    with pytest.raises(ValueError, match="i_max_A"):
        PlantParams.model_validate({"motor": {"i_max_A": -1}})
    with pytest.raises(ValueError, match="bogus"):
        PlantParams.model_validate({"rotor": {"bogus": 1}})


@pytest.mark.parametrize("dt", [np.nan, np.inf, -np.inf, "0.001", None])
def test_non_finite_dt_raises_a_value_error_naming_dt(dt):
    plant = MujocoPlant()
    for method in (plant.step, plant.advance):
        with pytest.raises(ValueError, match=r"^dt must be") as info:
            method(np.zeros(16), dt)
        assert "cannot convert" not in str(info.value)
    assert plant.time == 0.0  # nothing was integrated


def test_allocate_takes_an_optional_current_limit():
    """``allocate(torque, q, i_max)``: a smaller limit binds where the motor's does
    not; the delivered torque keeps the requested direction and is the largest such torque
    within the smaller limit (an independent LP over the bounded currents)."""
    from scipy.optimize import linprog

    plant = MujocoPlant()
    q = A.from_zyz(0.4, np.deg2rad(8.0), 1.1)
    K = plant.torque_map(q)
    d = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    T = 0.1 * d  # N·m: within the 2 A capacity (0.28 N·m at the least, bench_plant)
    full = plant.allocate(T, q)
    assert not full.saturated and np.allclose(full.delivered, T, atol=1e-9)
    assert np.allclose(plant.allocate(T, q, i_max=plant.params.motor.i_max_A).currents,
                       full.currents)
    i_small = 0.25  # A
    assert np.abs(full.currents).max() > i_small  # the request needs more than 0.25 A
    small = plant.allocate(T, q, i_max=i_small)
    assert small.saturated
    assert np.abs(small.currents).max() <= i_small + 1e-9
    assert np.allclose(K @ small.currents, small.delivered, atol=1e-12)
    delivered = np.linalg.norm(small.delivered)
    assert small.delivered @ d / delivered > 1 - 1e-6  # same direction, only scaled down
    lp = linprog(np.r_[np.zeros(16), -1.0], A_eq=np.hstack([K, -d[:, None]]), b_eq=np.zeros(3),
                 bounds=[(-i_small, i_small)] * 16 + [(0, None)])
    assert delivered == pytest.approx(lp.x[-1], rel=1e-4)
    assert delivered < np.linalg.norm(T)
    # The default q is the plant's own attitude.
    plant.reset(q)
    assert np.allclose(plant.allocate(T, i_max=i_small).currents, small.currents)


@pytest.mark.parametrize("i_max", [0.0, -1.0, np.nan, 2.5, True])
def test_allocate_rejects_a_bad_current_limit(i_max):
    with pytest.raises(ValueError, match="i_max"):
        MujocoPlant().allocate([0.0, 0.0, 0.01], i_max=i_max)


def test_set_state_moves_the_rotor_and_refuses_a_plant_with_the_delayed_sensor():
    plant = MujocoPlant(PlantParams())
    q = A.from_zyz(0.1, 0.05, -0.1)
    plant.set_state(q, [0.1, -0.2, 0.3], np.full(16, 0.25), 0.125)
    assert np.array_equal(plant.q, q) and np.array_equal(plant.omega, [0.1, -0.2, 0.3])
    assert np.array_equal(plant.currents, np.full(16, 0.25)) and plant.time == 0.125
    with pytest.raises(ValueError, match="delayed sensor"):
        MujocoPlant(PlantParams(), sensor_delay_s=0.01).set_state(q, np.zeros(3), np.zeros(16),
                                                                   0.0)
