"""Rotations on small tuples for the compiled run loop's kernels.

Small vectors and matrices as tuples of floats, multiplied out: numba hands ``@`` on 2-D
arrays to BLAS, whose call costs more than these few products, and each small array costs an
allocation. The formulas are ``plant.attitude``'s (its compiled ``_hamilton``,
``_matrix_elements`` and ``_geodesic_of``)."""

from __future__ import annotations

import numpy as np
from numba import njit

from latency.compiled.cache import compiled_in
from latency.numba_cache import drop_stale_cache
from plant import attitude
from plant.attitude import _geodesic_of, _hamilton, _matrix_elements

#: The modules whose code these kernels compile in (``cache``).
COMPILED_IN = compiled_in((attitude,))
drop_stale_cache(__file__, COMPILED_IN)


@njit(cache=True)
def _unit(q):
    """The quaternion q (4 numbers) over its norm, as a 4-tuple."""
    n = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return q[0] / n, q[1] / n, q[2] / n, q[3] / n


@njit(cache=True)
def _conj_mul(a, b):
    """a* ⊗ b (4-tuple) for the quaternions a and b, each normalised first
    (``plant.attitude``)."""
    a, b = _unit(a), _unit(b)
    return _hamilton(a[0], -a[1], -a[2], -a[3], b[0], b[1], b[2], b[3])


@njit(cache=True)
def _matrix(q):
    """R(q), rotor to stator, of the normalised q, row by row as a 9-tuple
    (``plant.attitude.to_matrix``)."""
    w, x, y, z = _unit(q)
    return _matrix_elements(w, x, y, z)


@njit(cache=True)
def _mv(R, v):
    """R v (3-tuple) for R a 9-tuple (``_matrix``) and v three numbers."""
    return (R[0] * v[0] + R[1] * v[1] + R[2] * v[2], R[3] * v[0] + R[4] * v[1] + R[5] * v[2],
            R[6] * v[0] + R[7] * v[1] + R[8] * v[2])


@njit(cache=True)
def _mtv(R, v):
    """Rᵀ v (3-tuple) for R a 9-tuple (``_matrix``) and v three numbers."""
    return (R[0] * v[0] + R[3] * v[1] + R[6] * v[2], R[1] * v[0] + R[4] * v[1] + R[7] * v[2],
            R[2] * v[0] + R[5] * v[1] + R[8] * v[2])


@njit(cache=True)
def _rotvec(q):
    """Rotation vector (3-tuple, rad, angle in [0, pi]) of q.

    Compiled mirror of ``plant.attitude.to_rotvec``."""
    w, x, y, z = _unit(q)
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    s = np.sqrt(x * x + y * y + z * z)
    f = 2.0 if s < 1e-12 else 2.0 * np.arctan2(s, w) / s
    return f * x, f * y, f * z


@njit(cache=True)
def _geodesic(q1, q2):
    """Angle (rad) of the rotation from q1 to q2 (``plant.attitude.geodesic_angle``)."""
    return _geodesic_of(q1[0], q1[1], q1[2], q1[3], q2[0], q2[1], q2[2], q2[3])
