"""The CasADi twin of the rotor dynamics, for the MPC and for cross-checking MuJoCo.

The same equations as ``plant.dynamics`` (see its docstring), written symbolically:

* state x = (q, omega): unit quaternion (w, x, y, z), rotor to stator, and the body-frame rate
  (rad/s); input u = the 16 coil currents (A);
* ``K(q)`` is the torque map of ``plant.torque`` rebuilt from the same geometry;
* ``f(x, u)`` is the continuous-time right-hand side, for multiple shooting;
* ``step(x, u)`` is one physics step of ``params.physics_dt_s`` discretised as MuJoCo does it:
  the electromagnetic and Coulomb torques are evaluated at the step start and held, and RK4
  integrates the rest.

The twin has no tilt stop (the MPC gets a tilt constraint instead) and no coil lag (it takes the
actual currents).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from plant import attitude
from plant.geometry import coil_axes, magnet_axes, magnet_polarity
from plant.params import PlantParams
from plant.torque import N_COILS, window


def quat_to_matrix(q: ca.SX) -> ca.SX:
    """Symbolic rotation matrix of a quaternion (w, x, y, z), rotor to stator."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return ca.vertcat(
        ca.horzcat(1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        ca.horzcat(2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        ca.horzcat(2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )


def quat_rate(q: ca.SX, omega: ca.SX) -> ca.SX:
    """q_dot = 1/2 q ⊗ (0, omega) for a body-frame rate omega."""
    w, v = q[0], q[1:4]
    return 0.5 * ca.vertcat(-ca.dot(v, omega), w * omega + ca.cross(v, omega))


class CasadiTwin:
    """Symbolic rotor model built from ``PlantParams``; the functions are ``casadi.Function``.

    Attributes
    ----------
    K : Function
        q (4) -> K(q) (3 x 16), N·m/A.
    f : Function
        (x (7), u (16)) -> x_dot (7): continuous-time dynamics.
    f_torque : Function
        (x (7), T (3)) -> x_dot (7): the same with the stator-frame torque T (N·m) as input.
    step : Function
        (x (7), u (16)) -> x after one physics step (quaternion renormalised).
    """

    nx = 7
    nu = N_COILS

    def __init__(self, params: PlantParams | None = None) -> None:
        self.params = p = params or PlantParams()
        r, motor = p.rotor, p.motor
        self.dt = p.physics_dt_s
        d = np.asarray(r.com_offset_m)
        J_O = r.inertia_about_centre_kgm2
        self.J_O = J_O
        J_inv = np.linalg.inv(J_O)

        q = ca.SX.sym("q", 4)
        omega = ca.SX.sym("omega", 3)
        u = ca.SX.sym("I", N_COILS)
        tau_hold = ca.SX.sym("tau_hold", 3)
        R = quat_to_matrix(q)

        # K(q): sum_j k_T s_j w(c_i . r_j) (c_i x r_j), as in plant.torque.TorqueMap.
        C, M, S = coil_axes(motor), magnet_axes(), magnet_polarity()
        cos_c = float(np.cos(np.deg2rad(motor.cutoff_deg)))
        cols = []
        for c_i in C:
            col = ca.SX.zeros(3)
            for m_j, s_j in zip(M, S, strict=True):
                r_j = R @ ca.DM(m_j)
                gain = float(motor.k_T_Nm_per_A * s_j) * window(
                    ca.dot(ca.DM(c_i), r_j), cos_c, ca.fmax
                )
                col += gain * ca.cross(ca.DM(c_i), r_j)
            cols.append(col)
        K = ca.horzcat(*cols)
        self.K = ca.Function("K", [q], [K], ["q"], ["K"])

        mg = r.mass_kg * np.array([0.0, 0.0, -r.gravity_m_s2])
        JO = ca.DM(J_O)

        def passive(q_, w_):
            """Torques re-evaluated inside the step: gravity, viscous, gyroscopic (N·m)."""
            tau_g = ca.cross(ca.DM(d), quat_to_matrix(q_).T @ ca.DM(mg))
            return tau_g - r.viscous_Nms_per_rad * w_ - ca.cross(w_, JO @ w_)

        def coulomb(w_):
            eps2 = r.coulomb_smoothing_rad_s**2
            return -r.coulomb_Nm * w_ / ca.sqrt(ca.dot(w_, w_) + eps2)

        tau_em = R.T @ (K @ u)
        x = ca.vertcat(q, omega)
        xdot = ca.vertcat(
            quat_rate(q, omega), ca.DM(J_inv) @ (tau_em + coulomb(omega) + passive(q, omega))
        )
        self.f = ca.Function("f", [x, u], [xdot], ["x", "u"], ["xdot"])
        # The same dynamics driven by a stator-frame torque instead of currents (for observers
        # that know the delivered torque rather than the coil currents).
        T = ca.SX.sym("T", 3)
        xdot_T = ca.vertcat(
            quat_rate(q, omega), ca.DM(J_inv) @ (R.T @ T + coulomb(omega) + passive(q, omega))
        )
        self.f_torque = ca.Function("f_torque", [x, T], [xdot_T], ["x", "T"], ["xdot"])

        def held(x_):
            q_, w_ = x_[0:4], x_[4:7]
            return ca.vertcat(quat_rate(q_, w_), ca.DM(J_inv) @ (tau_hold + passive(q_, w_)))

        g = ca.Function("g", [x, tau_hold], [held(x)])
        h = self.dt
        th = tau_em + coulomb(omega)
        k1 = g(x, th)
        k2 = g(x + h / 2 * k1, th)
        k3 = g(x + h / 2 * k2, th)
        k4 = g(x + h * k3, th)
        x_next = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x_next = ca.vertcat(x_next[0:4] / ca.norm_2(x_next[0:4]), x_next[4:7])
        self.step = ca.Function("step", [x, u], [x_next], ["x", "u"], ["x_next"])

    def simulate(
        self, q0: ArrayLike, omega0: ArrayLike, currents: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Integrate from (q0, omega0) with one row of currents (A) per physics step.

        Returns the attitudes (N+1, 4) and body rates (N+1, 3), the initial state first.
        """
        U = attitude.check_finite("currents", currents)
        if U.ndim != 2 or U.shape[1] != N_COILS:
            raise ValueError(f"currents must have shape (N, {N_COILS}), got {U.shape}")
        x = np.r_[attitude.normalize(q0, "q0"), attitude.check_finite("omega0", omega0)]
        F = self.step.mapaccum(U.shape[0])
        X = np.asarray(F(x, U.T)).T
        X = np.vstack([x, X])
        return X[:, :4], X[:, 4:]
