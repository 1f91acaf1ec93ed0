"""Attitude conversions against independent constructions (elementary rotation matrices)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plant import attitude as A

angle = st.floats(0.0, 2 * np.pi, allow_nan=False)
# Tilt over [0, pi] with extra weight right at and near the Z-Y-Z singularity beta = 0.
tilt_any = st.one_of(
    st.floats(0.0, np.pi),
    st.floats(0.0, 1e-6),
    st.sampled_from([0.0, 1e-15, 1e-10, 1e-8, np.pi]),
)


def Rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def Ry(b):
    c, s = np.cos(b), np.sin(b)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def same_rotation(q1, q2, tol=1e-9):
    return min(np.abs(q1 - q2).max(), np.abs(q1 + q2).max()) < tol


@given(angle, st.floats(0.0, np.pi), angle)
def test_zyz_matches_elementary_rotations(alpha, beta, gamma):
    # Seed 000 §2.1: about stator Z by spin, stator Y by tilt, stator Z by yaw.
    expected = Rz(gamma) @ Ry(beta) @ Rz(alpha)
    assert np.allclose(A.to_matrix(A.from_zyz(alpha, beta, gamma)), expected, atol=1e-12)


@given(angle, tilt_any, angle)
def test_zyz_round_trip_is_the_same_rotation_everywhere(alpha, beta, gamma):
    q = A.from_zyz(alpha, beta, gamma)
    assert same_rotation(A.from_zyz(*A.to_zyz(q)), q)


@given(angle, st.floats(1e-3, np.pi - 1e-3), angle)
def test_zyz_round_trip_angles_away_from_singularity(alpha, beta, gamma):
    a, b, g = A.to_zyz(A.from_zyz(alpha, beta, gamma))
    assert abs(b - beta) < 1e-9
    assert abs(A.wrap_angle(a - alpha)) < 1e-8
    assert abs(A.wrap_angle(g - gamma)) < 1e-8


@given(angle, angle)
def test_zyz_at_zero_tilt_puts_the_whole_rotation_in_spin(alpha, gamma):
    a, b, g = A.to_zyz(A.from_zyz(alpha, 0.0, gamma))
    assert b == pytest.approx(0.0, abs=1e-12)
    assert g == 0.0
    assert abs(A.wrap_angle(a - (alpha + gamma))) < 1e-9


@given(angle, st.floats(0.0, np.pi), angle)
def test_tilt_is_angle_between_shaft_and_stator_z(alpha, beta, gamma):
    q = A.from_zyz(alpha, beta, gamma)
    shaft = A.to_matrix(q)[:, 2]
    assert A.tilt(q) == pytest.approx(np.arccos(np.clip(shaft[2], -1, 1)), abs=1e-7)
    assert A.tilt(q) == pytest.approx(beta, abs=1e-9)


@given(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1))
def test_matrix_round_trip(v):
    q = np.array(v) / np.linalg.norm(v)
    R = A.to_matrix(q)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    assert same_rotation(A.from_matrix(R), q)


@given(st.lists(st.floats(-3, 3), min_size=3, max_size=3))
def test_rotvec_round_trip(v):
    rv = np.array(v)
    if np.linalg.norm(rv) > np.pi:  # keep the principal branch
        rv *= (np.pi - 1e-6) / np.linalg.norm(rv)
    assert np.allclose(A.to_rotvec(A.from_rotvec(rv)), rv, atol=1e-9)


@settings(deadline=None)
@given(
    st.lists(st.floats(-1, 1), min_size=3, max_size=3).filter(lambda v: np.linalg.norm(v) > 0.1),
    st.floats(0.0, np.pi),
    angle,
    st.floats(0.0, np.pi / 2),
)
def test_geodesic_angle_is_the_relative_rotation_angle(axis, theta, alpha, beta):
    q1 = A.from_zyz(alpha, beta, 0.3)
    q2 = A.multiply(q1, A.axis_angle(axis, theta))
    assert A.geodesic_angle(q1, q2) == pytest.approx(theta, abs=1e-7)
    assert A.geodesic_angle(q2, q1) == pytest.approx(theta, abs=1e-7)
    assert A.geodesic_angle(q1, -q1) == pytest.approx(0.0, abs=1e-12)  # double cover


def test_geodesic_angle_has_no_singularity_at_zero_tilt():
    # Z-Y-Z angles jump near beta = 0, the geodesic angle does not.
    q1 = A.from_zyz(0.0, 1e-9, 0.0)
    q2 = A.from_zyz(np.pi / 2, 1e-9, -np.pi / 2)
    assert A.geodesic_angle(q1, q2) < 1e-8


def test_normalize_rescales_near_unit_and_rejects_the_rest():
    q = np.array([1.0 + 5e-4, 0.0, 0.0, 0.0])
    assert np.linalg.norm(A.normalize(q)) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="q0"):
        A.normalize([2.0, 0, 0, 0], "q0")
    with pytest.raises(ValueError, match="q0"):
        A.normalize([0.0, 0, 0, 0], "q0")
    with pytest.raises(ValueError, match="q0"):
        A.normalize([np.nan, 0, 0, 0], "q0")
    with pytest.raises(ValueError, match="alpha"):
        A.from_zyz(np.inf, 0.0, 0.0)


def test_array_paths_match_scipy_rotations_row_by_row():
    """The compiled row kernels of ``geodesic_angle`` and ``to_zyz_array`` against SciPy's
    rotations (an independent implementation): the relative rotation's magnitude, and the
    extrinsic z-y-z angles (SciPy's first and third in (-pi, pi], ours in [0, 2 pi)); leading
    axes and broadcasting kept."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(5)
    q1, q2 = rng.normal(size=(2, 300, 4))
    q1 /= np.linalg.norm(q1, axis=1, keepdims=True)
    q2 /= np.linalg.norm(q2, axis=1, keepdims=True)
    r1, r2 = (Rotation.from_quat(q[:, [1, 2, 3, 0]]) for q in (q1, q2))
    np.testing.assert_allclose(A.geodesic_angle(q1, q2), (r1.inv() * r2).magnitude(),
                               atol=1e-12)
    np.testing.assert_allclose(A.geodesic_angle(q1[:3], q2[0]),
                               [A.geodesic_angle(q, q2[0]) for q in q1[:3]], atol=0)
    zyz = A.to_zyz_array(q1)
    ref = r1.as_euler("zyz")
    np.testing.assert_allclose(zyz[:, 1], ref[:, 1], atol=1e-12)
    for k in (0, 2):
        np.testing.assert_allclose(A.wrap_angle(zyz[:, k] - ref[:, k]), 0.0, atol=1e-9)
    assert A.to_zyz_array(q1.reshape(3, 100, 4)).shape == (3, 100, 3)
    assert A.geodesic_angle(q1.reshape(3, 100, 4), q2.reshape(3, 100, 4)).shape == (3, 100)


@pytest.mark.parametrize("bad", [[2.0, 0, 0, 0], [0.0, 0, 0, 0], [np.nan, 0, 0, 0]])
def test_array_paths_reject_a_row_that_is_not_an_attitude(bad):
    rows = np.array([[1.0, 0, 0, 0], bad, [1.0, 0, 0, 0]])
    with pytest.raises(ValueError, match="q2"):
        A.geodesic_angle(np.tile([1.0, 0, 0, 0], (3, 1)), rows)
    with pytest.raises(ValueError, match="q"):
        A.to_zyz_array(rows)
