"""The coil currents of a command in the compiled run loop: the torque map K(q) and the
least-norm currents. A command whose least-norm currents break the limits returns to Python
for the LP of ``plant.torque.allocate`` (``latency.compiled.run``)."""

from __future__ import annotations

import numpy as np
from numba import njit

from latency.compiled import rotations
from latency.compiled.cache import compiled_in
from latency.compiled.rotations import _matrix
from latency.numba_cache import drop_stale_cache
from observer import cor_solver
from observer.cor_solver import _solve3
from plant import rigid_body
from plant.rigid_body import FASTMATH

#: The modules whose code these kernels compile in (``cache``).
COMPILED_IN = compiled_in((cor_solver, rigid_body), (rotations,))
drop_stale_cache(__file__, COMPILED_IN)


@njit(cache=True, fastmath=FASTMATH)
def _torque_map(q, coils, magnets, gain, cos_cut):
    """K(q) (3, 16), N·m/A (``plant.torque.TorqueMap``); ``gain`` is k_T s_j (18,). The
    magnet axes in the stator frame as three rows, and the windows without a branch, so
    that the sum over the magnets compiles to vector instructions.

    Compiled mirror of ``plant.torque.TorqueMap.from_matrix``."""
    R = _matrix(q)
    n = magnets.shape[0]
    r = np.empty((3, n))
    for j in range(n):
        for k in range(3):
            r[k, j] = (R[3 * k] * magnets[j, 0] + R[3 * k + 1] * magnets[j, 1]
                       + R[3 * k + 2] * magnets[j, 2])
    scale = 1.0 / (1.0 - cos_cut)
    K = np.empty((3, coils.shape[0]))
    for i in range(coils.shape[0]):
        c0, c1, c2 = coils[i, 0], coils[i, 1], coils[i, 2]
        v0 = v1 = v2 = 0.0
        for j in range(n):
            x = max(c0 * r[0, j] + c1 * r[1, j] + c2 * r[2, j] - cos_cut, 0.0) * scale
            g = gain[j] * x * x
            v0 += g * r[0, j]
            v1 += g * r[1, j]
            v2 += g * r[2, j]
        K[0, i] = c1 * v2 - c2 * v1
        K[1, i] = c2 * v0 - c0 * v2
        K[2, i] = c0 * v1 - c1 * v0
    return K


@njit(cache=True)
def _least_norm(K, torque):
    """The least-norm currents I = Kᵀ (K Kᵀ)⁻¹ T (n,), A, of the torque map K (3, n) for the
    torque T (3,), N·m (``plant.torque.allocate`` within the limits), the torque K I they
    deliver, and False when K Kᵀ is singular.

    Compiled mirror of ``plant.torque.allocate``."""
    n = K.shape[1]
    G = np.zeros((3, 3))
    for a in range(3):
        for b in range(3):
            for i in range(n):
                G[a, b] += K[a, i] * K[b, i]
    x, solved = _solve3(G, torque)
    currents = np.empty(n)
    delivered = np.zeros(3)
    for i in range(n):
        currents[i] = K[0, i] * x[0] + K[1, i] * x[1] + K[2, i] * x[2]
        for a in range(3):
            delivered[a] += K[a, i] * currents[i]
    return currents, delivered, solved
