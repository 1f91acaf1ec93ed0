"""The rotor's rigid-body step, vectorised over a batch of B rotors (shared by both engines).

Equations (body frame, about the fixed centre O; the model of ``plant.dynamics``):

    q_dot = 1/2 q ⊗ (0, omega)
    J_O omega_dot = R^T K(q) I + d x (R^T m g) - b omega - tau_c omega/sqrt(|omega|^2 + omega_s^2)
                    - omega x J_O omega + R^T T_stop + tau_dist

The step is a fourth-order Runge-Kutta-Munthe-Kaas method on the rotation group (Munthe-Kaas,
BIT 38 (1998) 92-111; Iserles et al., Acta Numerica 9 (2000) §4): the attitude is written as
``q = q0 ⊗ exp(phi)`` over the step, the rotation vector phi obeys the exact body-frame
kinematics (Bortz, IEEE Trans. AES 7 (1971) 61-66)

    phi_dot = omega + 1/2 phi x omega + (1/|phi|^2)(1 - (|phi|/2) cot(|phi|/2)) phi x (phi x omega)

and classical RK4 integrates (phi, omega) from (0, omega0). Every torque, K(q) I included, is
evaluated at each stage's attitude and rate, so the method keeps its fourth order in the step
(holding K(q) over the step, as a zero-order hold of the torque, is only first order). The
coil currents are held over the step; the disturbance torque too.

Tilt stop: a one-sided spring-damper on the tilt beta (angle of the shaft, rotor +z, from the
stator +Z), active beyond ``RotorParams.tilt_stop_deg``. Its generalised force on beta is
``-max(0, k (beta - beta_max) + c beta_dot)``; its torque acts about ``u = Z x s / |Z x s|`` (s the
shaft in the stator frame), the axis about which beta grows, so spin and yaw stay free. k and c
make it a critically damped contact with time constant ``STOP_TIMECONST_S`` for the inertia
about u; pushed steadily, the rotor rests at a constant penetration ``T / k`` (0.03° at
0.3 N·m).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from plant import attitude
from plant.geometry import coil_axes, magnet_axes, magnet_polarity
from plant.params import PlantParams

#: RKMK4 steps per physics step: our choice, measured. On the ±0.3 A test sequence at 30 rad/s
#: spin, one step of 1 ms is 5.2e-6 rad off a tight ``solve_ivp`` reference after 1 s, two are
#: 1.6e-7 rad (tests/test_dynamics.py checks < 1e-6 rad).
PHYSICS_SUBSTEPS = 2
#: Time constant of the tilt stop's critically damped contact, s: our choice, two default physics
#: steps (stiff enough to hold 0.5 N·m within 0.01°, well inside RK4's stability limit).
STOP_TIMECONST_S = 0.002


def quat_exp(phi: NDArray[np.float64]) -> NDArray[np.float64]:
    """Unit quaternions of the rotation vectors phi (..., 3), rad (the exponential map)."""
    theta = np.sqrt(np.sum(phi * phi, axis=-1))
    half = 0.5 * theta
    # sin(theta/2)/theta, with its series below 1e-4 rad (error < 1e-17)
    s = np.where(theta > 1e-4, np.sin(half) / np.where(theta > 1e-4, theta, 1.0),
                 0.5 - theta * theta / 48.0)
    return np.concatenate([np.cos(half)[..., None], s[..., None] * phi], axis=-1)


def quat_matrix(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrices (..., 3, 3), rotor to stator, of unit quaternions (..., 4)."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (yy + zz)
    R[..., 0, 1] = 2 * (xy - wz)
    R[..., 0, 2] = 2 * (xz + wy)
    R[..., 1, 0] = 2 * (xy + wz)
    R[..., 1, 1] = 1 - 2 * (xx + zz)
    R[..., 1, 2] = 2 * (yz - wx)
    R[..., 2, 0] = 2 * (xz - wy)
    R[..., 2, 1] = 2 * (yz + wx)
    R[..., 2, 2] = 1 - 2 * (xx + yy)
    return R


def _cross(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Row-wise cross products (..., 3), written out (numpy's cross is slow on small arrays)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def dexpinv(phi: NDArray[np.float64], omega: NDArray[np.float64]) -> NDArray[np.float64]:
    """phi_dot of q = q0 ⊗ exp(phi) for the body rate omega (the Bortz equation), (B, 3)."""
    theta2 = np.sum(phi * phi, axis=-1)
    theta = np.sqrt(theta2)
    big = theta > 1e-3
    tb = np.where(big, theta, 1.0)
    # (1 - (theta/2) cot(theta/2)) / theta^2, with its series 1/12 + theta^2/720 when small
    c = np.where(big, (1.0 - 0.5 * tb / np.tan(0.5 * tb)) / (tb * tb), 1.0 / 12.0 + theta2 / 720.0)
    pxw = _cross(phi, omega)
    return omega + 0.5 * pxw + c[:, None] * _cross(phi, pxw)


def stop_gains(params: PlantParams) -> tuple[float, float, float]:
    """The tilt stop's stiffness k (N·m/rad), damping c (N·m·s/rad) and limit (rad): critically
    damped with time constant ``STOP_TIMECONST_S`` for the largest inertia about a horizontal
    axis (the tilt axis)."""
    J = params.rotor.inertia_about_centre_kgm2
    j_tilt = float(np.max(np.linalg.eigvalsh(J[:2, :2])))
    rate = 1.0 / STOP_TIMECONST_S
    return j_tilt * rate * rate, 2.0 * j_tilt * rate, float(np.deg2rad(params.rotor.tilt_stop_deg))


def tilt_stop_contact(q: NDArray[np.float64], params: PlantParams) -> NDArray[np.bool_]:
    """(B,) True where the attitudes q (B, 4) tilt beyond the stop's limit (in contact)."""
    cos_b = 1.0 - 2.0 * (q[:, 1] ** 2 + q[:, 2] ** 2)
    return cos_b < np.cos(np.deg2rad(params.rotor.tilt_stop_deg))


class RigidBody:
    """The rotor's dynamics for a batch of rotors with the same ``PlantParams``.

    States are arrays over the batch: ``q`` (B, 4) unit quaternions (w, x, y, z), rotor to
    stator; ``omega`` (B, 3) body rates, rad/s; ``currents`` (B, 16) coil currents, A.
    """

    def __init__(self, params: PlantParams) -> None:
        self.params = p = params
        r, motor = p.rotor, p.motor
        self.J = p.rotor.inertia_about_centre_kgm2
        self.J_inv = np.linalg.inv(self.J)
        self.com = np.asarray(r.com_offset_m, dtype=float)
        self.m_g = r.mass_kg * np.array([0.0, 0.0, -r.gravity_m_s2])  # stator frame, N
        self.viscous = r.viscous_Nms_per_rad
        self.tau_c, self.omega_s = r.coulomb_Nm, r.coulomb_smoothing_rad_s
        self.coils = coil_axes(motor)  # (16, 3) stator frame
        self.magnets = magnet_axes()  # (18, 3) rotor frame
        self.cos_cutoff = float(np.cos(np.deg2rad(motor.cutoff_deg)))
        # k_T s_j / (1 - cos phi_c)^2 (18, 1), N·m/A: the window's scale folded into the gain
        self.gain_scaled = (
            motor.k_T_Nm_per_A * magnet_polarity() / (1.0 - self.cos_cutoff) ** 2
        )[:, None]
        self.stop_k, self.stop_c, self.tilt_max_rad = stop_gains(p)
        self.cos_tilt_max = float(np.cos(self.tilt_max_rad))

    # --- torques ---------------------------------------------------------------------------
    def _windows(self, R: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
        """Magnet axes r (B, 18, 3) in the stator frame and the pair gains
        g_ij = k_T s_j w(c_i . r_j) (B, 18, 16), N·m/A."""
        r = np.matmul(self.magnets, np.swapaxes(R, 1, 2))
        x = np.matmul(r, self.coils.T) - self.cos_cutoff
        np.maximum(x, 0.0, out=x)
        x *= x
        x *= self.gain_scaled
        return r, x

    def em_torque(self, R: NDArray[np.float64], currents: NDArray[np.float64]) -> NDArray:
        """K(q) I (B, 3), stator frame, N·m (``plant.torque.TorqueMap``: column i of K is
        c_i x sum_j g_ij r_j), summed as sum_j a_j x r_j with a_j = sum_i g_ij I_i c_i."""
        r, g = self._windows(R)
        a = np.matmul(g * currents[:, None, :], self.coils)  # (B, 18, 3)
        return np.sum(_cross(a, r), axis=1)

    def stop_torque(
        self, R: NDArray[np.float64], omega_stator: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """Stator-frame torque (B, 3), N·m, of the tilt stop (zero inside the limit)."""
        s = R[:, :, 2]  # shaft, stator frame
        cos_b = np.clip(s[:, 2], -1.0, 1.0)
        out = np.zeros_like(s)
        hit = cos_b < self.cos_tilt_max
        if not hit.any():
            return out
        s, w = s[hit], omega_stator[hit]
        z_x_s = np.stack([-s[:, 1], s[:, 0], np.zeros(len(s))], axis=-1)  # Z x s
        u = z_x_s / np.linalg.norm(z_x_s, axis=-1, keepdims=True)
        beta = np.arccos(cos_b[hit])
        beta_dot = np.sum(w * u, axis=-1)
        force = np.maximum(self.stop_k * (beta - self.tilt_max_rad) + self.stop_c * beta_dot, 0.0)
        out[hit] = -force[:, None] * u
        return out

    def acceleration(
        self,
        q: NDArray[np.float64],
        omega: NDArray[np.float64],
        currents: NDArray[np.float64],
        disturbance: NDArray[np.float64] | None = None,
    ) -> NDArray[np.float64]:
        """omega_dot (B, 3), rad/s², of the equations in the module docstring."""
        R = quat_matrix(q)
        Rt = np.swapaxes(R, 1, 2)
        w_stator = np.matmul(R, omega[:, :, None])[:, :, 0]
        T_stator = self.em_torque(R, currents) + self.stop_torque(R, w_stator)
        tau = np.matmul(Rt, T_stator[:, :, None])[:, :, 0]
        tau += _cross(self.com, Rt @ self.m_g) if self.com.any() else 0.0
        tau -= self.viscous * omega + _cross(omega, omega @ self.J.T)
        norm = np.sqrt(np.sum(omega * omega, axis=-1, keepdims=True) + self.omega_s**2)
        tau -= self.tau_c * omega / norm
        if disturbance is not None:
            tau += disturbance
        return tau @ self.J_inv.T

    # --- time ------------------------------------------------------------------------------
    def step(
        self,
        q: NDArray[np.float64],
        omega: NDArray[np.float64],
        currents: NDArray[np.float64],
        h: float | NDArray[np.float64],
        disturbance: NDArray[np.float64] | None = None,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Advance by ``h`` (s; a scalar or one per rotor, (B,)) with the ``currents`` (B, 16),
        A, and the body-frame ``disturbance`` (B, 3), N·m, held: ``PHYSICS_SUBSTEPS`` RKMK4
        steps. Returns the new ``(q, omega)``; ``q`` is renormalised."""
        hb = np.broadcast_to(np.asarray(h, dtype=float), (q.shape[0],))[:, None]
        hb = hb / PHYSICS_SUBSTEPS
        for _ in range(PHYSICS_SUBSTEPS):
            q, omega = self._rkmk4(q, omega, currents, hb, disturbance)
        return q, omega

    def _rkmk4(self, q, omega, currents, hb, disturbance):
        """One RKMK4 step of length ``hb`` (B, 1), s."""
        phi = np.zeros_like(omega)
        k_phi, k_w = [], []
        for a in (0.0, 0.5, 0.5, 1.0):
            if a == 0.0:
                qs, ws = q, omega
            else:
                phi = a * hb * k_phi[-1]
                ws = omega + a * hb * k_w[-1]
                qs = attitude.multiply(q, quat_exp(phi))
            k_w.append(self.acceleration(qs, ws, currents, disturbance))
            k_phi.append(ws if a == 0.0 else dexpinv(phi, ws))
        phi = hb / 6.0 * (k_phi[0] + 2.0 * k_phi[1] + 2.0 * k_phi[2] + k_phi[3])
        omega_next = omega + hb / 6.0 * (k_w[0] + 2.0 * k_w[1] + 2.0 * k_w[2] + k_w[3])
        q_next = attitude.multiply(q, quat_exp(phi))
        q_next /= np.linalg.norm(q_next, axis=-1, keepdims=True)
        return q_next, omega_next
