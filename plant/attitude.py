"""Attitude conversions: unit quaternion <-> rotation matrix <-> the seed's Z-Y-Z angles.

Conventions (docs/architecture.md):

* A quaternion is ``(w, x, y, z)``, scalar first, and maps rotor-frame vectors into the
  stator frame: ``v_stator = R(q) @ v_rotor``.
* The seed's Z-Y-Z angles (seed 000 §2.1) rotate the rotor successively about the *stator's*
  Z axis by the spin angle alpha, about the stator's Y axis by the tilt angle beta, and about
  the stator's Z axis again by the yaw angle gamma, so ``R = Rz(gamma) @ Ry(beta) @ Rz(alpha)``.
  Tilt is the angle between the rotor's z axis (output shaft) and the stator Z axis; yaw is the
  azimuth of the tilt; spin is the rotation about the rotor's own axis.
* At beta = 0 only alpha + gamma is defined (gimbal singularity). The convention there is
  gamma = 0 and alpha carries the whole rotation about Z.

All angles are radians. This is the only module that knows about Euler angles.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

#: A quaternion whose norm differs from 1 by more than this is rejected, not normalised.
UNIT_TOLERANCE = 1e-3
#: Below this sin(beta) the Z-Y-Z decomposition uses the singular-case convention (gamma = 0).
_SINGULAR_SIN_BETA = 1e-12


def check_finite(name: str, value: ArrayLike) -> NDArray[np.float64]:
    """Return ``value`` as a float array, or raise ``ValueError`` naming ``name`` if it has
    NaN or infinite entries."""
    arr = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr!r}")
    return arr


def normalize(q: ArrayLike, name: str = "q") -> NDArray[np.float64]:
    """Validate and normalise a quaternion (w, x, y, z).

    A quaternion within ``UNIT_TOLERANCE`` of unit norm is rescaled to unit norm; any other
    norm (including zero) raises ``ValueError`` naming the argument, since it most likely is not
    an attitude at all.
    """
    q = np.asarray(q, dtype=float)
    if q.shape == (4,):  # one attitude: plain floats (numpy's per-call overhead dominates)
        w, x, y, z = q.tolist()
        n1 = math.sqrt(w * w + x * x + y * y + z * z)
        if abs(n1 - 1.0) <= UNIT_TOLERANCE:
            return q / n1
    if q.shape[-1:] != (4,):
        raise ValueError(f"{name} must have shape (..., 4) as (w, x, y, z), got {q.shape}")
    n = np.sqrt(np.sum(q * q, axis=-1, keepdims=True))
    # A NaN or inf anywhere makes n non-finite, so this one test also rejects non-finite input.
    if not np.all(np.abs(n - 1.0) <= UNIT_TOLERANCE):
        if not np.all(np.isfinite(q)):
            raise ValueError(f"{name} must be finite, got {q!r}")
        raise ValueError(
            f"{name} must be a unit quaternion (|q| within {UNIT_TOLERANCE} of 1), "
            f"got |q| = {np.squeeze(n)}"
        )
    return q / n


def multiply(p: ArrayLike, q: ArrayLike) -> NDArray[np.float64]:
    """Hamilton product ``p ⊗ q`` of quaternions (w, x, y, z); broadcasts over leading axes."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    if p.shape == (4,) and q.shape == (4,):  # one product: plain floats, as in ``normalize``
        return np.array(_hamilton.py_func(*p.tolist(), *q.tolist()))
    return np.stack(_hamilton.py_func(*np.moveaxis(p, -1, 0), *np.moveaxis(q, -1, 0)), axis=-1)


# The formulas below are compiled for the row kernels (``_geodesic_rows``, ``_zyz_rows``); the
# numpy paths call their Python functions (``py_func``) on floats or arrays, so each formula is
# written once.
@njit(cache=True)
def _hamilton(pw, px, py, pz, qw, qx, qy, qz) -> tuple:
    """Components (w, x, y, z) of ``p ⊗ q`` from the components of p and q (floats or arrays)."""
    return (
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    )


def conjugate(q: ArrayLike) -> NDArray[np.float64]:
    """Quaternion conjugate, the inverse rotation for a unit quaternion."""
    q = np.asarray(q, dtype=float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def to_matrix(q: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix R(q) (3x3, or (..., 3, 3)) with ``v_stator = R @ v_rotor``."""
    q = normalize(q)
    if q.ndim == 1:  # one attitude: plain floats
        return np.array(_matrix_elements.py_func(*q.tolist())).reshape(3, 3)
    return np.stack(_matrix_elements.py_func(*np.moveaxis(q, -1, 0)), axis=-1).reshape(
        q.shape[:-1] + (3, 3))


@njit(cache=True)
def _matrix_elements(w, x, y, z) -> tuple:
    """R(q) row by row (R00, R01, ..., R22) from the components of a unit q (floats or
    arrays)."""
    return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


def from_matrix(R: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternion (w >= 0) from a 3x3 rotation matrix (Shepperd's method)."""
    R = check_finite("R", R)
    if R.shape != (3, 3):
        raise ValueError(f"R must have shape (3, 3), got {R.shape}")
    tr = np.trace(R)
    # Pick the largest of 4w^2, 4x^2, 4y^2, 4z^2 for a well-conditioned square root.
    cand = np.array([tr, R[0, 0], R[1, 1], R[2, 2]])
    k = int(np.argmax(cand))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif k == 1:
        s = 2.0 * np.sqrt(max(1.0 + R[0, 0] - R[1, 1] - R[2, 2], 0.0))
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif k == 2:
        s = 2.0 * np.sqrt(max(1.0 + R[1, 1] - R[0, 0] - R[2, 2], 0.0))
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(max(1.0 + R[2, 2] - R[0, 0] - R[1, 1], 0.0))
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def axis_angle(axis: ArrayLike, angle_rad: float) -> NDArray[np.float64]:
    """Quaternion of a rotation by ``angle_rad`` about ``axis`` (any non-zero 3-vector)."""
    a = check_finite("axis", axis)
    n = np.linalg.norm(a)
    if n == 0.0:
        raise ValueError("axis must be non-zero")
    half = 0.5 * float(angle_rad)
    return np.concatenate([[np.cos(half)], np.sin(half) * a / n])


def from_rotvec(rv: ArrayLike) -> NDArray[np.float64]:
    """Quaternion from a rotation vector (axis times angle, rad)."""
    rv = check_finite("rv", rv)
    theta = np.linalg.norm(rv)
    if theta < 1e-12:
        q = np.concatenate([[1.0], 0.5 * rv])
        return q / np.linalg.norm(q)
    return axis_angle(rv, theta)


def to_rotvec(q: ArrayLike) -> NDArray[np.float64]:
    """Rotation vector (rad) of a unit quaternion, angle in [0, pi].

    Mirrored in ``latency.compiled.rotations._rotvec``; keep both in step
    (tests/test_compiled_mirror.py checks them equal)."""
    q = normalize(q)
    if q[0] < 0:
        q = -q
    s = np.linalg.norm(q[1:])
    if s < 1e-12:
        return 2.0 * q[1:]
    return 2.0 * np.arctan2(s, q[0]) * q[1:] / s


def from_zyz(alpha: float, beta: float, gamma: float) -> NDArray[np.float64]:
    """Quaternion from the seed's spin alpha, tilt beta, yaw gamma (rad).

    ``R = Rz(gamma) Ry(beta) Rz(alpha)`` (seed 000 §2.1: rotations about the stator axes in the
    order spin, tilt, yaw).
    """
    for name, v in (("alpha", alpha), ("beta", beta), ("gamma", gamma)):
        check_finite(name, v)
    qz_a = axis_angle([0, 0, 1], alpha)
    qy_b = axis_angle([0, 1, 0], beta)
    qz_g = axis_angle([0, 0, 1], gamma)
    return multiply(qz_g, multiply(qy_b, qz_a))


def to_zyz(q: ArrayLike) -> tuple[float, float, float]:
    """The seed's (spin alpha, tilt beta, yaw gamma) in rad from a unit quaternion.

    Returns alpha and gamma in [0, 2*pi) and beta in [0, pi]. At beta = 0 (or pi) only the sum
    alpha + gamma is observable; then gamma = 0 and alpha holds the rotation about Z. For an
    (N, 4) array use ``to_zyz_array``.
    """
    q = np.asarray(q, dtype=float)
    if q.shape != (4,):
        raise ValueError(f"q must have shape (4,) as (w, x, y, z), got {q.shape}")
    alpha, beta, gamma = _zyz_rows(_unit_rows(q, "q"))[0]
    return float(alpha), float(beta), float(gamma)


def to_zyz_array(q: ArrayLike) -> NDArray[np.float64]:
    """(N, 3) array of (spin, tilt, yaw), rad, for (N, 4) quaternions (see ``to_zyz``)."""
    q = np.asarray(q, dtype=float)
    return _zyz_rows(_unit_rows(q, "q")).reshape(q.shape[:-1] + (3,))


@njit(cache=True)
def _zyz_of_matrix(R00, R01, R02, R10, R11, R12, R20, R21, R22) -> tuple:
    """(spin, tilt, yaw), rad, of the rotation matrix with these elements (see ``to_zyz``)."""
    s_beta = math.hypot(R02, R12)
    beta = math.atan2(s_beta, R22)
    two_pi = 2.0 * math.pi
    if s_beta > _SINGULAR_SIN_BETA:
        return math.atan2(R21, -R20) % two_pi, beta, math.atan2(R12, R02) % two_pi
    # beta = 0: R = Rz(alpha + gamma); beta = pi: R = Ry(pi) Rz(alpha); both with gamma = 0.
    alpha = math.atan2(R10, R00) if R22 > 0 else math.atan2(R10, R11)
    return alpha % two_pi, beta, 0.0


@njit(cache=True)
def _zyz_of(w, x, y, z) -> tuple:
    """(spin, tilt, yaw), rad, of the quaternion (w, x, y, z), normalised first."""
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return _zyz_of_matrix(*_matrix_elements(w / n, x / n, y / n, z / n))


@njit(cache=True)
def _zyz_rows(q):
    """(N, 3) Z-Y-Z angles, rad, of the (N, 4) quaternions q, each normalised."""
    out = np.empty((q.shape[0], 3))
    for i in range(q.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = _zyz_of(q[i, 0], q[i, 1], q[i, 2], q[i, 3])
    return out


@njit(cache=True)
def _geodesic_of(aw, ax, ay, az, bw, bx, by, bz) -> float:
    """Angle, rad, of the rotation taking the quaternion a to b, each normalised:
    2 atan2(|vec(d)|, |d_w|) with d = conj(a) ⊗ b (normalised first, so that a quaternion and
    a rescaled copy of it give exactly 0)."""
    na = math.sqrt(aw * aw + ax * ax + ay * ay + az * az)
    nb = math.sqrt(bw * bw + bx * bx + by * by + bz * bz)
    dw, dx, dy, dz = _hamilton(aw / na, -ax / na, -ay / na, -az / na,
                               bw / nb, bx / nb, by / nb, bz / nb)
    return 2.0 * math.atan2(math.sqrt(dx * dx + dy * dy + dz * dz), abs(dw))


@njit(cache=True)
def _geodesic_rows(a, b):
    """(N,) angles, rad, of the rotations taking the (N, 4) quaternions a to b
    (``_geodesic_of``)."""
    out = np.empty(a.shape[0])
    for i in range(a.shape[0]):
        out[i] = _geodesic_of(a[i, 0], a[i, 1], a[i, 2], a[i, 3],
                              b[i, 0], b[i, 1], b[i, 2], b[i, 3])
    return out


@njit(cache=True)
def _norm_deviation(q):
    """The largest |‖q_i‖ − 1| over the rows of the (N, 4) array q; inf if any is not finite."""
    worst = 0.0
    for i in range(q.shape[0]):
        n = math.sqrt(q[i, 0] * q[i, 0] + q[i, 1] * q[i, 1] + q[i, 2] * q[i, 2]
                      + q[i, 3] * q[i, 3])
        d = abs(n - 1.0)
        if not d <= worst:  # NaN compares false: it stays
            worst = d if math.isfinite(d) else math.inf
    return worst


def _unit_rows(q: ArrayLike, name: str) -> NDArray[np.float64]:
    """q as a C-contiguous (N, 4) float array of quaternions within ``UNIT_TOLERANCE`` of unit
    norm (not rescaled); otherwise ``normalize``'s error, naming ``name``."""
    rows = np.ascontiguousarray(q, dtype=float)
    if rows.shape[-1:] != (4,):
        normalize(rows, name)  # raises: the shape
    rows = rows.reshape(-1, 4)
    if not _norm_deviation(rows) <= UNIT_TOLERANCE:
        normalize(rows, name)  # raises: the norm, or a value that is not finite
    return rows


def tilt(q: ArrayLike) -> float:
    """Tilt beta (rad): angle between the rotor's z axis and the stator Z axis."""
    w, x, y, z = normalize(q)
    # R33 = 1 - 2(x^2 + y^2) = cos(beta); |(R13, R23)| = sin(beta)
    c = 1.0 - 2.0 * (x * x + y * y)
    s = 2.0 * np.hypot(x * z + w * y, y * z - w * x)
    return float(np.arctan2(s, c))


def geodesic_angle(q1: ArrayLike, q2: ArrayLike) -> float | NDArray[np.float64]:
    """Angle (rad, in [0, pi]) of the rotation taking attitude ``q1`` to ``q2``.

    This is the attitude error without the Euler singularity. Broadcasts over leading axes of
    (..., 4) arrays (then returns an array).
    """
    a, b = np.broadcast_arrays(np.asarray(q1, dtype=float), np.asarray(q2, dtype=float))
    angle = _geodesic_rows(_unit_rows(a, "q1"), _unit_rows(b, "q2")).reshape(a.shape[:-1])
    return float(angle[()]) if angle.ndim == 0 else angle


def wrap_angle(a: ArrayLike) -> NDArray[np.float64]:
    """Wrap angles (rad) into (-pi, pi]."""
    a = np.asarray(a, dtype=float)
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)
