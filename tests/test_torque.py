"""Geometry, torque map and current allocation."""

import itertools

import numpy as np
import pytest
from scipy.optimize import linprog

from plant import attitude as A
from plant.geometry import coil_axes, icosahedron_face_normals, magnet_axes, magnet_polarity
from plant.params import MotorParams
from plant.torque import TorqueMap, allocate, characteristic
from plant.twin import CasadiTwin

MOTOR = MotorParams()
TM = TorqueMap(MOTOR)


def workspace_grid(n_tilt=6, n_spin=24, n_yaw=24):
    """Dense grid over the workspace: tilt 0–15°, all spin and yaw."""
    for b, a, g in itertools.product(
        np.linspace(0, np.deg2rad(15), n_tilt),
        np.linspace(0, 2 * np.pi, n_spin, endpoint=False),
        np.linspace(0, 2 * np.pi, n_yaw, endpoint=False),
    ):
        yield A.from_zyz(a, b, g)


def test_magnets_sit_on_the_seed_latitudes():
    lat = np.degrees(np.arcsin(magnet_axes()[:, 2]))
    assert len(lat) == 18
    for band, count in [(48.19, 3), (19.47, 6), (-19.47, 6), (-48.19, 3)]:
        assert np.sum(np.abs(lat - band) < 0.01) == count


def test_icosahedron_faces_are_regular():
    N = icosahedron_face_normals()
    assert N.shape == (20, 3)
    # Every face has exactly 3 neighbours at the inter-normal angle 180° - 138.19° (dihedral).
    cosines = N @ N.T
    neighbour = np.abs(np.degrees(np.arccos(np.clip(cosines, -1, 1))) - 41.81) < 0.01
    assert np.all(neighbour.sum(axis=1) == 3)


def test_polarity_alternates_by_band_and_coils_split_in_two_layers():
    s, lat = magnet_polarity(), magnet_axes()[:, 2]
    for band in np.unique(lat.round(6)):
        assert len(set(s[lat.round(6) == band])) == 1
    assert sorted(set(s)) == [-1.0, 1.0]
    c = coil_axes(MOTOR)
    assert np.sum(c[:, 2] > 0) == 8 and np.sum(c[:, 2] < 0) == 8


def test_characteristic_is_a_bump_that_vanishes_past_the_cutoff():
    phi_c = np.deg2rad(MOTOR.cutoff_deg)
    phi = np.linspace(0, np.pi, 2001)
    f = characteristic(phi, MOTOR)
    assert f[0] == 0.0
    assert np.all(f[(phi > 0) & (phi < phi_c)] > 0)
    assert np.all(f[phi >= phi_c] == 0)
    # C1 at the cutoff: the slope just inside tends to zero.
    h = 1e-6
    assert abs(characteristic(phi_c - h, MOTOR) / h) < 1e-4


def K_by_definition(q):
    """The issue's formula term by term: f(phi) (c x r)/|c x r| s_j, with phi from arccos."""
    R = A.to_matrix(q)
    K = np.zeros((3, 16))
    for i, c in enumerate(coil_axes(MOTOR)):
        for m, s in zip(magnet_axes(), magnet_polarity(), strict=True):
            r = R @ m
            cr = np.cross(c, r)
            phi = np.arccos(np.clip(c @ r, -1, 1))
            if np.linalg.norm(cr) > 1e-12:
                K[:, i] += s * characteristic(phi, MOTOR) * cr / np.linalg.norm(cr)
    return K


def test_torque_map_equals_the_pairwise_definition():
    rng = np.random.default_rng(3)
    for _ in range(10):
        q = A.from_zyz(rng.uniform(0, 2 * np.pi), rng.uniform(0, 0.3), rng.uniform(0, 2 * np.pi))
        assert np.allclose(TM(q), K_by_definition(q), atol=1e-12)


def test_casadi_twin_torque_map_matches_numpy():
    twin = CasadiTwin()
    rng = np.random.default_rng(4)
    for _ in range(10):
        q = A.from_zyz(*rng.uniform(0, 2 * np.pi, 3))
        assert np.allclose(np.asarray(twin.K(q)), TM(q), atol=1e-12)


def test_three_fold_symmetry_of_the_rotor():
    # The 18 magnets map onto themselves under 120° about the rotor axis, polarity included.
    q = A.from_zyz(0.4, np.deg2rad(9), 1.3)
    q_turned = A.multiply(q, A.axis_angle([0, 0, 1], 2 * np.pi / 3))
    assert np.allclose(TM(q), TM(q_turned), atol=1e-12)


def test_full_rank_over_the_workspace_grid():
    conds = [np.linalg.cond(TM(q)) for q in workspace_grid()]
    # 3456 attitudes. The worst value is quoted in docs/plant.md.
    assert len(conds) == 6 * 24 * 24
    assert max(conds) < 3.0


def test_allocation_within_limits_is_least_norm():
    q = A.from_zyz(0.2, 0.1, 0.7)
    K = TM(q)
    T = np.array([0.02, -0.05, 0.03])
    I, saturated, delivered = allocate(T, K, MOTOR.i_max_A)
    assert not saturated
    assert np.allclose(delivered, T, atol=1e-12)
    assert np.allclose(I, np.linalg.pinv(K) @ T, atol=1e-10)


def capacity(K, d, i_max):
    """Independent: largest s with K I = s d, |I| <= i_max, by an LP over (I, s)."""
    res = linprog(
        np.r_[np.zeros(16), -1.0],
        A_eq=np.hstack([K, -d[:, None]]),
        b_eq=np.zeros(3),
        bounds=[(-i_max, i_max)] * 16 + [(0, None)],
    )
    return res.x[-1]


def test_allocation_beyond_capacity_keeps_direction_and_bounds():
    rng = np.random.default_rng(5)
    i_max = MOTOR.i_max_A
    for _ in range(20):
        q = A.from_zyz(rng.uniform(0, 2 * np.pi), rng.uniform(0, 0.26), rng.uniform(0, 6.28))
        K = TM(q)
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        T = 5.0 * d  # far beyond the motor's ~0.4 N·m
        I, saturated, delivered = allocate(T, K, i_max)
        assert saturated
        assert np.all(np.abs(I) <= i_max + 1e-9)
        assert delivered @ d / np.linalg.norm(delivered) > 1 - 1e-6
        assert np.linalg.norm(delivered) == pytest.approx(capacity(K, d, i_max), rel=1e-4)
        # Element-wise clipping of the least-norm currents would turn the torque.
        clipped = K @ np.clip(np.linalg.pinv(K) @ T, -i_max, i_max)
        assert clipped @ d / np.linalg.norm(clipped) < delivered @ d / np.linalg.norm(delivered)


def test_allocation_uses_the_null_space_before_saturating():
    # A request whose least-norm currents break the limit but which bounded currents meet.
    q = A.from_zyz(0.0, 0.0, 0.0)
    K = TM(q)
    d = np.array([0.0, 0.0, 1.0])
    cap = capacity(K, d, MOTOR.i_max_A)
    T = 0.98 * cap * d
    assert np.abs(np.linalg.pinv(K) @ T).max() > MOTOR.i_max_A  # least-norm breaks the limit
    I, saturated, delivered = allocate(T, K, MOTOR.i_max_A)
    assert not saturated
    assert np.allclose(delivered, T, atol=1e-6)
    assert np.abs(I).max() <= MOTOR.i_max_A + 1e-9


def test_motor_torque_magnitude_is_plausible():
    # Documented design point: 0.1–1 N·m deliverable at the current limit in every direction.
    rng = np.random.default_rng(6)
    K = TM(A.from_zyz(0.3, 0.1, 0.2))
    caps = [capacity(K, d / np.linalg.norm(d), MOTOR.i_max_A) for d in rng.normal(size=(50, 3))]
    assert 0.1 < min(caps) and max(caps) < 1.0


def test_allocation_rejects_bad_input():
    K = TM(np.array([1.0, 0, 0, 0]))
    with pytest.raises(ValueError, match="torque"):
        allocate([np.nan, 0, 0], K, 2.0)
    with pytest.raises(ValueError, match="torque"):
        allocate([0, 0], K, 2.0)
    with pytest.raises(ValueError, match="i_max"):
        allocate([0, 0, 0.1], K, 0.0)
