"""The torque map T = K(q) I and the current allocation (seed 000 §2.1; standard PMSpM model).

For coil axis c_i (stator frame), magnet axis r_j = R(q) m_j and polarity s_j = ±1,

    T = sum_i sum_j s_j f(phi_ij) (c_i x r_j) / |c_i x r_j| I_i,      cos(phi_ij) = c_i . r_j

with the torque characteristic f(phi) = k_T sin(phi) w(cos phi) (see ``MotorParams``). Since
|c_i x r_j| = sin(phi_ij), each pair contributes ``k_T s_j w(c_i . r_j) (c_i x r_j)``, which is
smooth everywhere (no division by sin(phi) at phi = 0). T is the torque on the rotor in the stator
frame (N·m) for coil currents I (A).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linprog, lsq_linear

from plant import attitude
from plant.geometry import coil_axes, magnet_axes, magnet_polarity
from plant.params import MotorParams

N_COILS = 16


def window(x: Any, cos_cutoff: float, fmax: Any = np.maximum) -> Any:
    """Torque-characteristic window w(cos phi) = ((x - cos phi_c)/(1 - cos phi_c))^2 for
    x > cos phi_c, else 0. ``fmax`` lets the CasADi twin use the same law (``casadi.fmax``)."""
    t = fmax(x - cos_cutoff, 0.0) / (1.0 - cos_cutoff)
    return t * t


def characteristic(phi_rad: ArrayLike, motor: MotorParams) -> NDArray[np.float64]:
    """f(phi) in N·m/A: the torque of one coil-magnet pair per ampere at axis angle ``phi``."""
    phi = np.asarray(phi_rad, dtype=float)
    c = np.cos(np.deg2rad(motor.cutoff_deg))
    return motor.k_T_Nm_per_A * np.sin(phi) * window(np.cos(phi), c)


class TorqueMap:
    """K(q) for one motor geometry. Cheap to call: a few vectorised products (about 30 µs)."""

    def __init__(self, motor: MotorParams) -> None:
        self.motor = motor
        self.c = coil_axes(motor)  # (16, 3), stator frame
        self.m = magnet_axes()  # (18, 3), rotor frame
        self.s = magnet_polarity()  # (18,)
        self.cos_cutoff = float(np.cos(np.deg2rad(motor.cutoff_deg)))

    def __call__(self, q: ArrayLike) -> NDArray[np.float64]:
        """K(q) (3 x 16), N·m/A: stator-frame torque on the rotor per coil current."""
        return self.from_matrix(attitude.to_matrix(q))

    def from_matrix(self, R: NDArray[np.float64]) -> NDArray[np.float64]:
        """K for the rotation matrix R = R(q) (rotor to stator), N·m/A.

        Mirrored in ``latency.compiled.allocation._torque_map``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        r = self.m @ R.T  # (18, 3) magnet axes in the stator frame
        gain = self.motor.k_T_Nm_per_A * self.s * window(self.c @ r.T, self.cos_cutoff)  # (16, 18)
        # sum_j g_ij (c_i x r_j) = c_i x (sum_j g_ij r_j): one cross product per coil, written
        # out because numpy's cross has a large fixed cost for small arrays.
        c, v = self.c, gain @ r
        return np.stack(
            [
                c[:, 1] * v[:, 2] - c[:, 2] * v[:, 1],
                c[:, 2] * v[:, 0] - c[:, 0] * v[:, 2],
                c[:, 0] * v[:, 1] - c[:, 1] * v[:, 0],
            ]
        )


class Allocation(NamedTuple):
    """Result of ``allocate``: coil currents (16,), A; whether the requested torque had to be
    scaled down to respect the limits; the torque K(q) I actually delivered (3,), N·m."""

    currents: NDArray[np.float64]
    saturated: bool
    delivered: NDArray[np.float64]


def allocate(
    torque: ArrayLike, K: NDArray[np.float64], i_max: float, reg: float = 1e-9
) -> Allocation:
    """Coil currents that produce ``torque`` (stator frame, N·m) through K (3 x 16, N·m/A).

    Within the limits this is the least-norm solution ``I = K^T (K K^T)^-1 T``. If that solution
    breaks ``|I_i| <= i_max``, the current limits bind: a small LP finds the largest fraction
    s in [0, 1] of the request that the bounded currents can deliver *in the requested direction*
    (scaling, never element-wise clipping, which would turn the torque), then a bounded
    least-squares solve (``scipy.optimize.lsq_linear``) finds the smallest currents that deliver
    ``s T``. When s = 1 the torque is met exactly with other, bounded currents and
    ``saturated`` is False.

    Parameters
    ----------
    torque : array_like, shape (3,)
        Requested torque on the rotor in the stator frame, N·m.
    K : ndarray, shape (3, 16)
        Torque map at the current attitude, N·m/A.
    i_max : float
        Per-coil current limit, A.
    reg : float
        Weight of the current norm in the bounded solve (relative; keeps it least-norm).

    Mirrored in ``latency.compiled.allocation._least_norm``; keep both in step
    (tests/test_compiled_mirror.py checks them equal).
    """
    T = attitude.check_finite("torque", torque).reshape(-1)
    if T.shape != (3,):
        raise ValueError(f"torque must have 3 components, got shape {T.shape}")
    K = attitude.check_finite("K", K)
    if not i_max > 0:
        raise ValueError(f"i_max must be positive, got {i_max}")
    I_ln = K.T @ np.linalg.solve(K @ K.T, T)
    if np.max(np.abs(I_ln)) <= i_max:
        return Allocation(I_ln, False, K @ I_ln)
    n = K.shape[1]
    # LP over (I, s): maximise s subject to K I = s T and the current bounds.
    lp = linprog(
        c=np.r_[np.zeros(n), -1.0],
        A_eq=np.hstack([K, -T[:, None]]),
        b_eq=np.zeros(3),
        bounds=[(-i_max, i_max)] * n + [(0.0, 1.0)],
        method="highs",
    )
    s = float(lp.x[-1]) if lp.status == 0 else 0.0
    target = s * T
    scale = float(np.linalg.norm(K))
    A = np.vstack([K, np.sqrt(reg) * scale * np.eye(n)])
    res = lsq_linear(A, np.r_[target, np.zeros(n)], bounds=(-i_max, i_max), method="bvls")
    I = np.clip(res.x, -i_max, i_max)
    delivered = K @ I
    saturated = s < 1.0 - 1e-9
    return Allocation(I, saturated, delivered)


# --- torque capacity ------------------------------------------------------------------------
def inradius(K: NDArray[np.float64], i_max: float) -> float:
    """Largest torque (N·m) that the currents ``|I_k| <= i_max`` (A) deliver in every direction
    through ``K`` (3 x n, N·m/A): the inradius about the origin of the zonotope ``K [-i_max,
    i_max]^n``, ``min over facet normals n of i_max Σ_k |n · k_k|``."""
    K = attitude.check_finite("K", K)
    cols = K.T
    ia, ib = np.triu_indices(cols.shape[0], k=1)
    N = np.cross(cols[ia], cols[ib])
    norms = np.linalg.norm(N, axis=1)
    keep = norms > 1e-12 * max(float(np.max(norms)), 1e-300)
    if not np.any(keep):
        return 0.0
    N = N[keep] / norms[keep, None]
    return float(i_max * np.abs(N @ K).sum(axis=1).min())


@lru_cache(maxsize=8)
def worst_case_capacity(
    motor: MotorParams,
    tilt_max_deg: float = 15.0,
    n_tilt: int = 6,
    n_spin: int = 24,
    n_yaw: int = 24,
) -> float:
    """Minimum over a grid of the tilt workspace (tilt 0..``tilt_max_deg``, all spins and yaws)
    of the all-direction torque capacity ``inradius(K(q), i_max)``, N·m. Cached per motor (the
    controllers' torque limit, ``controller.pid``)."""
    tm = TorqueMap(motor)
    worst = np.inf
    for b in np.linspace(0.0, np.deg2rad(tilt_max_deg), n_tilt):
        for a in np.linspace(0.0, 2 * np.pi, n_spin, endpoint=False):
            for g in np.linspace(0.0, 2 * np.pi, n_yaw, endpoint=False):
                worst = min(worst, inradius(tm(attitude.from_zyz(a, b, g)), motor.i_max_A))
    return float(worst)
