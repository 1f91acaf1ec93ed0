"""The rotor's rigid-body step over a batch of B rotors, compiled (shared by both engines).

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

Sub-steps: each row takes as many RKMK4 sub-steps as keep the rotor's turn per sub-step within
``SUBSTEP_ANGLE_RAD`` (0.016 rad), judged from its rate and acceleration at the step's start:
one per 1 ms step up to 16 rad/s, two up to 32 rad/s, fifteen at the 235 rad/s free-spin
terminal speed. K(q) I is a function of the attitude whose windows sweep past at the rotor's
rate, so the integration error follows the angle turned per sub-step (measured: at most
1.3e-7 rad after 0.25 s from 6 to 235 rad/s on ±0.3 A and ±1 A sequences).

Tilt stop: a one-sided spring-damper on the tilt beta (angle of the shaft, rotor +z, from the
stator +Z), active beyond ``RotorParams.tilt_stop_deg``. Its generalised force on beta is
``-max(0, k (beta - beta_max) + c beta_dot)``; its torque acts about ``u = Z x s / |Z x s|`` (s the
shaft in the stator frame), the axis about which beta grows, so spin and yaw stay free. k and c
make it a critically damped contact with time constant ``STOP_TIMECONST_S`` for the inertia
about u; pushed steadily, the rotor rests at a constant penetration ``T / k`` (0.03° at
0.3 N·m).

Code: one numba-compiled loop over the batch rows (``_step_rows_counted``), each row with its own
step length, the rotor's maths on scalars (no array per stage). The event loop calls it with one
row (``plant.dynamics.MujocoPlant``), the batched engine with many (``latency.batched``). The cost
is the torque map: 16 x 18 coil-magnet windows, of which about 12 % are open. One scan lists the
coil-magnet pairs whose window can open while the rotor turns by a margin (``_MARGIN_TURNS`` h
|omega| + ``_MARGIN_RAD``), as columns (magnet axis, coil axis, gain times coil axis, and that
times the coil's current of the step); the stages then visit only those pairs (about 36) in one
flat loop that compiles to vector instructions, and a stage that has turned further than the margin
lists its own, so the result does not depend on the margin (equal to the full sum to rounding,
tests/test_rigid_body.py). Apart from the current row, folded in once per step, the lists do not
depend on the currents: a rotor stepped over and over (the compiled run loop, ``_step_series``)
keeps them, made with ``PAIR_REUSE_RAD`` more margin, until its turn since they were made could
leave it, which saves most scans (a scan cost about as much as two stages before their pair loop
was vectorised). The rotor's constants travel as tuples of floats, the exponential map and the
Bortz coefficient use their series below 0.05 rad, and the compiled step runs with LLVM's fast-math
licences except the NaN and infinity ones (``FASTMATH``). numba caches the machine code on disk
(``cache=True``): the first call in a fresh process loads it (about 0.4 s measured under load) or,
without a cache, compiles it (4-8 s under load).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

from plant.geometry import coil_axes, magnet_axes, magnet_polarity
from plant.params import PlantParams

#: The fewest RKMK4 sub-steps per physics step (``RigidBody.step``): one, more where the rule of
#: ``SUBSTEP_ANGLE_RAD`` asks for them.
PHYSICS_SUBSTEPS = 1
#: Largest rotation of the rotor per RKMK4 sub-step, rad: our choice, measured. A row of step h
#: takes ``ceil(h omega_hat / SUBSTEP_ANGLE_RAD)`` sub-steps, at least ``PHYSICS_SUBSTEPS``, with
#: ``omega_hat = |omega| + h |omega_dot|`` its rate bound over the step (from the first stage,
#: which every sub-step count shares). Why the angle: K(q) I is a function of the attitude whose
#: windows (C1, cut off at phi_c) sweep past at the rotor's rate, so RK4's error is set by the
#: angle turned per sub-step, not by the time. 0.016 rad gives one sub-step of 1 ms up to
#: 16 rad/s (the study's references run at <= 6 rad/s), two up to 32 rad/s; measured on the
#: ±0.3 A and ±1 A test sequences from 6 to 235 rad/s against the same step with many
#: sub-steps, the error after 0.25 s stays at or below 1.3e-7 rad at every rate (docs/plant.md).
SUBSTEP_ANGLE_RAD = 0.016
#: The margin of the pair lists (``_window_pairs``), rad: ``_MARGIN_TURNS`` times the turn over
#: the step at the starting rate plus ``_MARGIN_RAD`` for the acceleration (5 N·m turns the rotor
#: at rest by 1.1e-3 rad in 1 ms). Our choice: each 0.005 rad of margin lists about 1.4 % more
#: pairs (sin phi_c / (1 - cos phi_c) per rad at phi_c = 40°); a smaller one makes more stages
#: list their own pairs. The results do not depend on it.
_MARGIN_TURNS = 1.5
_MARGIN_RAD = 0.005
#: The margin added to the pair lists of a rotor stepped over and over (the compiled run loop),
#: rad: its lists then serve the steps until the rotor has turned by about this much (a scan
#: of the 288 pairs cost about as much as the four stages together, measured before the
#: stages' pair loop was vectorised, which made the stages cheaper still). Our choice.
PAIR_REUSE_RAD = 0.02
#: The floating-point licences of the compiled step (LLVM's fast-math flags), for every function
#: that compiles it in (its inlined pieces take their caller's): contraction into fused
#: multiply-adds, reassociation (so the pair loop's sums can be vectorised), reciprocals and
#: approximate functions, no signed zeros; not ``nnan``/``ninf``, so a state that turns NaN or
#: infinite stays so and the checks downstream see it. Measured: the step takes 0.6 of the
#: time it takes without them; the results move by rounding (1e-16).
FASTMATH = {"contract", "reassoc", "arcp", "nsz", "afn"}
#: Time constant of the tilt stop's critically damped contact, s: our choice, two default physics
#: steps (stiff enough to hold 0.5 N·m within 0.01°, well inside RK4's stability limit).
STOP_TIMECONST_S = 0.002


# --- the compiled step ---------------------------------------------------------------------
# One rotor's maths on scalars (numba compiles these into the loop over the batch rows; tuples
# of floats stay in registers, no arrays are allocated per stage). The constants of the rotor
# come in ``RigidBody.consts``; the order of the scalars in ``scal`` is ``_SCALARS``.
_SCALARS = ("viscous", "tau_c", "omega_s", "cos_cutoff", "stop_k", "stop_c", "tilt_max",
            "cos_tilt_max")


@njit(cache=True, inline="always", fastmath=FASTMATH)
def _qmul(a, b):
    """Hamilton product of two quaternions given as 4-tuples (w, x, y, z)."""
    return (a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
            a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
            a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
            a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0])


@njit(cache=True, inline="always", fastmath=FASTMATH)
def _cross3(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


#: Below this angle (rad) the exponential map and the Bortz coefficient use their Taylor series
#: (the sub-steps' rotations are smaller; the first term left out is below 1e-17 there, and
#: the series needs no sine, cosine or tangent).
_SERIES_RAD = 0.05


@njit(cache=True, inline="always", fastmath=FASTMATH)
def _quat_exp(p0, p1, p2):
    """The unit quaternion of the rotation vector (p0, p1, p2), rad (the exponential map)."""
    t2 = p0 * p0 + p1 * p1 + p2 * p2
    if t2 < _SERIES_RAD * _SERIES_RAD:
        # cos(theta/2) and sin(theta/2)/theta to theta^8 and theta^6
        c = 1.0 - t2 / 8.0 * (1.0 - t2 / 48.0 * (1.0 - t2 / 120.0 * (1.0 - t2 / 224.0)))
        s = 0.5 - t2 / 48.0 * (1.0 - t2 / 80.0 * (1.0 - t2 / 168.0))
    else:
        theta = np.sqrt(t2)
        c, s = np.cos(0.5 * theta), np.sin(0.5 * theta) / theta
    return (c, s * p0, s * p1, s * p2)


@njit(cache=True, inline="always", fastmath=FASTMATH)
def _dexpinv(phi, w):
    """phi_dot of q = q0 ⊗ exp(phi) for the body rate w (the Bortz equation)."""
    theta2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
    # (1 - (theta/2) cot(theta/2)) / theta^2, with its series to theta^6 when small
    if theta2 < _SERIES_RAD * _SERIES_RAD:
        c = 1.0 / 12.0 + theta2 / 720.0 * (1.0 + theta2 / 42.0 * (1.0 + theta2 / 40.0))
    else:
        theta = np.sqrt(theta2)
        c = (1.0 - 0.5 * theta / np.tan(0.5 * theta)) / theta2
    pxw = _cross3(phi, w)
    ppw = _cross3(phi, pxw)
    return (w[0] + 0.5 * pxw[0] + c * ppw[0], w[1] + 0.5 * pxw[1] + c * ppw[1],
            w[2] + 0.5 * pxw[2] + c * ppw[2])


@njit(cache=True, inline="always", fastmath=FASTMATH)
def _rotation(q):
    """The rotation matrix R(q) (rotor to stator) of the quaternion q (4-tuple), as a 9-tuple
    (R00, R01, R02, R10, ..., R22)."""
    qw, qx, qy, qz = q
    return (1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy),
            2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx),
            2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy))


#: Rows of the pair lists (``_window_pairs``), one column per listed coil-magnet pair: the
#: magnet's axis m_j in the rotor frame, the coil's axis c_i, g_j c_i and g_j I_i c_i.
_M, _C, _GC, _GIC, _N_ROWS = 0, 3, 6, 9, 12


@njit(cache=True, fastmath=FASTMATH)
def _window_pairs(R, cur, coils, magnets, gain, cut, cos_wide, count, pv, coil):
    """List the coil-magnet pairs whose window can be open for the rotor at R (9-tuple), and
    return K(q) I there (3-tuple, N·m, stator frame) with the coil currents ``cur`` (16,), A.

    The pairs (i, j) with ``c_i . R m_j > cos_wide`` go to the columns ``pv[:, :count[0]]``
    (rows ``_M``, ``_C``, ``_GC``, ``_GIC``: m_j, c_i, g_j c_i, g_j I_i c_i, the window's scale
    folded into ``gain``), magnet by magnet, with ``coil`` = i. Apart from the last rows
    (``_fold_currents``) the lists do not depend on the currents, so they serve every step
    while the rotor stays within their margin. With ``cos_wide = cos(phi_c + M)`` they hold
    every pair that can open while the rotor turns by at most M rad from R (a rotation by M
    moves each axis by at most M); ``cut = cos(phi_c)``."""
    R00, R01, R02, R10, R11, R12, R20, R21, R22 = R
    n = 0
    for j in range(magnets.shape[0]):
        m0, m1, m2 = magnets[j, 0], magnets[j, 1], magnets[j, 2]
        r0 = R00 * m0 + R01 * m1 + R02 * m2
        r1 = R10 * m0 + R11 * m1 + R12 * m2
        r2 = R20 * m0 + R21 * m1 + R22 * m2
        for i in range(coils.shape[0]):
            if coils[i, 0] * r0 + coils[i, 1] * r1 + coils[i, 2] * r2 > cos_wide:
                s = gain[j]
                for k in range(3):
                    pv[_M + k, n], pv[_C + k, n] = magnets[j, k], coils[i, k]
                    pv[_GC + k, n] = s * coils[i, k]
                coil[n] = i
                n += 1
    count[0] = n
    _fold_currents(cur, count, pv, coil)
    return _coil_torque(R, count, pv, cut)


@njit(cache=True, inline="always", fastmath=FASTMATH)
def _fold_currents(cur, count, pv, coil):
    """The rows ``_GIC`` of the listed pairs for the coil currents ``cur`` (16,), A: g_j I_i c_i,
    once per step (the currents are held over it)."""
    for k in range(count[0]):
        current = cur[coil[k]]
        for d in range(3):
            pv[_GIC + d, k] = current * pv[_GC + d, k]


@njit(cache=True, inline="always", fastmath=FASTMATH)
def _coil_torque(R, count, pv, cut):
    """K(q) I (3-tuple, N·m, stator frame) for the rotor at R (9-tuple) from the pair lists of
    ``_window_pairs`` made at an attitude within their margin of R (only the listed pairs can
    be inside their window) with their currents folded in (``_fold_currents``):

        K(q) I = sum_(i, j) w(c_i . r_j) (g_j I_i c_i) x r_j,  r_j = R m_j,

    the window w = max(x - cos phi_c, 0)^2 without a branch (a listed pair near its cut-off
    opens and closes unpredictably) (``plant.torque.TorqueMap``). One flat loop over the
    pairs' columns, which the compiler turns into vector instructions."""
    R00, R01, R02, R10, R11, R12, R20, R21, R22 = R
    m0, m1, m2 = pv[_M], pv[_M + 1], pv[_M + 2]
    c0, c1, c2 = pv[_C], pv[_C + 1], pv[_C + 2]
    a0, a1, a2 = pv[_GIC], pv[_GIC + 1], pv[_GIC + 2]
    T0 = T1 = T2 = 0.0
    for k in range(count[0]):
        r0 = R00 * m0[k] + R01 * m1[k] + R02 * m2[k]
        r1 = R10 * m0[k] + R11 * m1[k] + R12 * m2[k]
        r2 = R20 * m0[k] + R21 * m1[k] + R22 * m2[k]
        x = max(c0[k] * r0 + c1[k] * r1 + c2[k] * r2 - cut, 0.0)
        x2 = x * x
        T0 += x2 * (a1[k] * r2 - a2[k] * r1)
        T1 += x2 * (a2[k] * r0 - a0[k] * r2)
        T2 += x2 * (a0[k] * r1 - a1[k] * r0)
    return T0, T1, T2


@njit(cache=True)
def _rotor_tuples(J, J_inv, com, m_g, scal):
    """The rotor's constants of ``RigidBody.consts`` as tuples of floats: J and J^-1 row by row
    (9 each), the centre of mass offset, m g and the scalars of ``_SCALARS``. The compiled
    functions pass them by value (arrays would cost a reference count per call)."""
    return ((J[0, 0], J[0, 1], J[0, 2], J[1, 0], J[1, 1], J[1, 2], J[2, 0], J[2, 1], J[2, 2]),
            (J_inv[0, 0], J_inv[0, 1], J_inv[0, 2], J_inv[1, 0], J_inv[1, 1], J_inv[1, 2],
             J_inv[2, 0], J_inv[2, 1], J_inv[2, 2]),
            (com[0], com[1], com[2]), (m_g[0], m_g[1], m_g[2]),
            (scal[0], scal[1], scal[2], scal[3], scal[4], scal[5], scal[6], scal[7]))


@njit(cache=True, inline="always", fastmath=FASTMATH)
def _dynamics(R, T, w, d, rotor):
    """omega_dot (3-tuple), rad/s², of one rotor at attitude R (9-tuple) and body rate w
    (3-tuple) with the coils' torque T = K(q) I (3-tuple, N·m, stator frame) and the body
    torque d (3-tuple), N·m: the equations of the module docstring. ``rotor`` holds the
    constants (``_rotor_tuples``)."""
    J, J_inv, com, m_g, scal = rotor
    R00, R01, R02, R10, R11, R12, R20, R21, R22 = R
    T0, T1, T2 = T
    # The tilt stop: force -max(0, k (beta - beta_max) + c beta_dot) about u = Z x s / |Z x s|
    cos_b = min(max(R22, -1.0), 1.0)
    if cos_b < scal[7]:
        n = np.sqrt(R12 * R12 + R02 * R02)
        u0, u1 = -R12 / n, R02 / n
        ws0 = R00 * w[0] + R01 * w[1] + R02 * w[2]
        ws1 = R10 * w[0] + R11 * w[1] + R12 * w[2]
        beta_dot = ws0 * u0 + ws1 * u1
        force = max(scal[4] * (np.arccos(cos_b) - scal[6]) + scal[5] * beta_dot, 0.0)
        T0 -= force * u0
        T1 -= force * u1
    # Body frame: R^T T, gravity about the centre, viscous and Coulomb friction, gyroscopic
    tb = (R00 * T0 + R10 * T1 + R20 * T2, R01 * T0 + R11 * T1 + R21 * T2,
          R02 * T0 + R12 * T1 + R22 * T2)
    gb = (R00 * m_g[0] + R10 * m_g[1] + R20 * m_g[2], R01 * m_g[0] + R11 * m_g[1] + R21 * m_g[2],
          R02 * m_g[0] + R12 * m_g[1] + R22 * m_g[2])
    grav = _cross3(com, gb)
    Jw = (J[0] * w[0] + J[1] * w[1] + J[2] * w[2],
          J[3] * w[0] + J[4] * w[1] + J[5] * w[2],
          J[6] * w[0] + J[7] * w[1] + J[8] * w[2])
    gyro = _cross3(w, Jw)
    coulomb = scal[1] / np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2] + scal[2] * scal[2])
    t0 = tb[0] + grav[0] - scal[0] * w[0] - gyro[0] - coulomb * w[0] + d[0]
    t1 = tb[1] + grav[1] - scal[0] * w[1] - gyro[1] - coulomb * w[1] + d[1]
    t2 = tb[2] + grav[2] - scal[0] * w[2] - gyro[2] - coulomb * w[2] + d[2]
    return (J_inv[0] * t0 + J_inv[1] * t1 + J_inv[2] * t2,
            J_inv[3] * t0 + J_inv[4] * t1 + J_inv[5] * t2,
            J_inv[6] * t0 + J_inv[7] * t1 + J_inv[8] * t2)


@njit(cache=True, fastmath=FASTMATH)
def _acceleration(q, w, d, pairs, rotor):
    """omega_dot (3-tuple), rad/s², of one rotor at attitude q (4-tuple) and body rate w
    (3-tuple) with the body torque d (3-tuple), N·m, from ``pairs`` (``_pair_lists`` made at
    an attitude within their margin of q, with the step's coil currents folded in)."""
    R = _rotation(q)
    return _dynamics(R, _coil_torque(R, pairs[0], pairs[1], rotor[4][3]), w, d, rotor)


@njit(cache=True)
def _pair_lists(n_magnets, n_coils, reuse_rad=0.0):
    """Empty ``_window_pairs`` lists (count, columns, coil) for every pair of a rotor, and
    their state (margin M, rad; bound on the rotation since they were made, rad (inf: not made
    yet); ``reuse_rad``, the margin added so that the lists last over several steps)."""
    n = n_magnets * n_coils
    return (np.zeros(1, dtype=np.int64), np.empty((_N_ROWS, n)), np.empty(n, dtype=np.int64),
            np.array([0.0, np.inf, reuse_rad]))


@njit(cache=True, inline="always", fastmath=FASTMATH)
def _stage(qb, phi, turned, margin, ws, cur, d, pairs, rotor, coils, magnets, gain):
    """The acceleration at the stage attitude qb ⊗ exp(phi) and rate ws (``_acceleration``):
    with the step's pair lists while the rotor has turned by at most ``turned + |phi|`` <=
    ``margin`` rad from the attitude they were made at, else with lists made at the stage."""
    qs = _qmul(qb, _quat_exp(phi[0], phi[1], phi[2]))
    if turned + np.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]) > margin:
        own = _pair_lists(magnets.shape[0], coils.shape[0])
        R = _rotation(qs)
        cut = rotor[4][3]
        return _dynamics(R, _window_pairs(R, cur, coils, magnets, gain, cut, cut, own[0],
                                          own[1], own[2]), ws, d, rotor)
    return _acceleration(qs, ws, d, pairs, rotor)


@njit(cache=True, inline="always", fastmath=FASTMATH)
def _step_row(qb, wb, cur, h, d, substeps, rotor, coils, magnets, gain, cutoff, pairs,
              max_angle):
    """Advance one rotor, at attitude qb (4-tuple) and body rate wb (3-tuple, rad/s), by h s
    with the coil currents ``cur`` (16,), A, and the body torque d (3-tuple, N·m) held: RKMK4
    sub-steps as ``_step_rows_counted`` says. ``rotor`` holds the constants (``_rotor_tuples``),
    ``cutoff`` is the windows' cut-off angle phi_c, rad, and ``pairs`` the lists of
    ``_pair_lists``: kept while they cover the step, else made again at its start. Returns
    (q, omega, acceleration evaluations)."""
    scal = rotor[4]
    state = pairs[3]
    # The pairs that can open during the step: the lists cover a turn of M = state[0] rad
    # from where they were made, the rotor has turned by at most state[1] since, and this
    # step turns it by about h |omega| (with room to spare). If that does not fit, they are
    # listed again here, with a margin of the turn at the starting rate plus the reuse margin
    # state[2]. A stage that turns beyond the margin is evaluated with lists of its own
    # (``_stage``), so the result never depends on the margin.
    turn = _MARGIN_TURNS * h * np.sqrt(wb[0] * wb[0] + wb[1] * wb[1] + wb[2] * wb[2])
    R = _rotation(qb)
    if state[1] + turn > state[0]:
        wide = cutoff + turn + _MARGIN_RAD + state[2]
        T = _window_pairs(R, cur, coils, magnets, gain, scal[3],
                          np.cos(wide) if wide < np.pi else -2.0, pairs[0], pairs[1], pairs[2])
        state[0], state[1] = turn + _MARGIN_RAD + state[2], 0.0
    else:
        _fold_currents(cur, pairs[0], pairs[1], pairs[2])
        T = _coil_torque(R, pairs[0], pairs[1], scal[3])
    margin = state[0]
    # The first stage is the same for any number of sub-steps: its rate and acceleration
    # bound the rotation over the step, which sets the number (SUBSTEP_ANGLE_RAD).
    k1w = _dynamics(R, T, wb, d, rotor)
    rate = (np.sqrt(wb[0] * wb[0] + wb[1] * wb[1] + wb[2] * wb[2])
            + h * np.sqrt(k1w[0] * k1w[0] + k1w[1] * k1w[1] + k1w[2] * k1w[2]))
    n_sub = max(substeps, int(np.ceil(h * rate / max_angle)))
    hs = h / n_sub
    turned = state[1]  # rad, a bound on the rotation from where the lists were made to qb
    for s in range(n_sub):
        # stage 1 at (q, w); stages 2-4 at q ⊗ exp(phi), phi from the previous stage
        if s > 0:
            k1w = _stage(qb, (0.0, 0.0, 0.0), turned, margin, wb, cur, d, pairs, rotor,
                         coils, magnets, gain)
        k1p = wb
        phi = (0.5 * hs * k1p[0], 0.5 * hs * k1p[1], 0.5 * hs * k1p[2])
        ws = (wb[0] + 0.5 * hs * k1w[0], wb[1] + 0.5 * hs * k1w[1], wb[2] + 0.5 * hs * k1w[2])
        k2w = _stage(qb, phi, turned, margin, ws, cur, d, pairs, rotor, coils, magnets, gain)
        k2p = _dexpinv(phi, ws)
        phi = (0.5 * hs * k2p[0], 0.5 * hs * k2p[1], 0.5 * hs * k2p[2])
        ws = (wb[0] + 0.5 * hs * k2w[0], wb[1] + 0.5 * hs * k2w[1], wb[2] + 0.5 * hs * k2w[2])
        k3w = _stage(qb, phi, turned, margin, ws, cur, d, pairs, rotor, coils, magnets, gain)
        k3p = _dexpinv(phi, ws)
        phi = (hs * k3p[0], hs * k3p[1], hs * k3p[2])
        ws = (wb[0] + hs * k3w[0], wb[1] + hs * k3w[1], wb[2] + hs * k3w[2])
        k4w = _stage(qb, phi, turned, margin, ws, cur, d, pairs, rotor, coils, magnets, gain)
        k4p = _dexpinv(phi, ws)
        c = hs / 6.0
        phi = (c * (k1p[0] + 2.0 * k2p[0] + 2.0 * k3p[0] + k4p[0]),
               c * (k1p[1] + 2.0 * k2p[1] + 2.0 * k3p[1] + k4p[1]),
               c * (k1p[2] + 2.0 * k2p[2] + 2.0 * k3p[2] + k4p[2]))
        wb = (wb[0] + c * (k1w[0] + 2.0 * k2w[0] + 2.0 * k3w[0] + k4w[0]),
              wb[1] + c * (k1w[1] + 2.0 * k2w[1] + 2.0 * k3w[1] + k4w[1]),
              wb[2] + c * (k1w[2] + 2.0 * k2w[2] + 2.0 * k3w[2] + k4w[2]))
        turned += np.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
        qn = _qmul(qb, _quat_exp(phi[0], phi[1], phi[2]))
        n = np.sqrt(qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3])
        qb = (qn[0] / n, qn[1] / n, qn[2] / n, qn[3] / n)
    state[1] = turned
    return qb, wb, 4 * n_sub


@njit(cache=True, fastmath=FASTMATH)
def _step_rows_counted(q, omega, currents, h, dist, substeps, J, J_inv, com, m_g, coils, magnets,
                       gain, scal, max_angle=SUBSTEP_ANGLE_RAD):
    """Advance every row b of the batch by h[b] s: RKMK4 sub-steps (module docstring), at least
    ``substeps`` of them and more where a sub-step would turn the rotor by more than
    ``max_angle`` rad (``SUBSTEP_ANGLE_RAD``; ``np.inf``: exactly ``substeps``), currents and
    disturbance held. Returns the new (q (B, 4), omega (B, 3)) and the number of acceleration
    evaluations of each row (B,) (four per RKMK4 sub-step)."""
    B = q.shape[0]
    q_out = np.empty((B, 4))
    w_out = np.empty((B, 3))
    evaluations = np.empty(B, dtype=np.int64)
    pairs = _pair_lists(magnets.shape[0], coils.shape[0])
    rotor = _rotor_tuples(J, J_inv, com, m_g, scal)
    cutoff = np.arccos(scal[3])  # rad, the windows' cut-off angle phi_c
    for b in range(B):
        pairs[3][1] = np.inf  # another rotor: its lists are made at its step's start
        qb, wb, n_eval = _step_row(
            (q[b, 0], q[b, 1], q[b, 2], q[b, 3]), (omega[b, 0], omega[b, 1], omega[b, 2]),
            currents[b], h[b], (dist[b, 0], dist[b, 1], dist[b, 2]), substeps, rotor, coils,
            magnets, gain, cutoff, pairs, max_angle)
        q_out[b, 0], q_out[b, 1], q_out[b, 2], q_out[b, 3] = qb
        w_out[b, 0], w_out[b, 1], w_out[b, 2] = wb
        evaluations[b] = n_eval
    return q_out, w_out, evaluations


@njit(cache=True, fastmath=FASTMATH)
def _step_series(q, omega, currents, h, dist, fresh, J, J_inv, com, m_g, coils, magnets, gain,
                 scal):
    """Step each rotor b of a batch n times as the compiled run loop does (``_step_row`` with
    one set of pair lists kept while they cover its turn, ``PAIR_REUSE_RAD``; with ``fresh``
    made again at every step), with the currents ``currents[b, k]`` (B, n, 16), A, and the body
    torque ``dist[b, k]`` (B, n, 3), N·m, of step k held. Returns the attitudes (B, n, 4) and
    rates (B, n, 3) after each step."""
    B, n = currents.shape[0], currents.shape[1]
    rotor = _rotor_tuples(J, J_inv, com, m_g, scal)
    cutoff = np.arccos(scal[3])
    q_out, w_out = np.empty((B, n, 4)), np.empty((B, n, 3))
    for b in range(B):
        pairs = _pair_lists(magnets.shape[0], coils.shape[0], PAIR_REUSE_RAD)
        qb = (q[b, 0], q[b, 1], q[b, 2], q[b, 3])
        wb = (omega[b, 0], omega[b, 1], omega[b, 2])
        for k in range(n):
            if fresh:
                pairs[3][1] = np.inf
            qb, wb, _ = _step_row(qb, wb, currents[b, k], h,
                                  (dist[b, k, 0], dist[b, k, 1], dist[b, k, 2]),
                                  PHYSICS_SUBSTEPS, rotor, coils, magnets, gain, cutoff, pairs,
                                  SUBSTEP_ANGLE_RAD)
            q_out[b, k, 0], q_out[b, k, 1], q_out[b, k, 2], q_out[b, k, 3] = qb
            w_out[b, k, 0], w_out[b, k, 1], w_out[b, k, 2] = wb
    return q_out, w_out


@njit(cache=True)
def _acceleration_rows(q, omega, currents, dist, J, J_inv, com, m_g, coils, magnets, gain, scal):
    """omega_dot (B, 3), rad/s², for every row of a batch (``_dynamics``)."""
    out = np.empty((q.shape[0], 3))
    pairs = _pair_lists(magnets.shape[0], coils.shape[0])
    rotor = _rotor_tuples(J, J_inv, com, m_g, scal)
    for b in range(q.shape[0]):
        R = _rotation((q[b, 0], q[b, 1], q[b, 2], q[b, 3]))
        T = _window_pairs(R, currents[b], coils, magnets, gain, scal[3], scal[3], pairs[0],
                          pairs[1], pairs[2])
        out[b] = _dynamics(R, T, (omega[b, 0], omega[b, 1], omega[b, 2]),
                           (dist[b, 0], dist[b, 1], dist[b, 2]), rotor)
    return out


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
    stator; ``omega`` (B, 3) body rates, rad/s; ``currents`` (B, 16) coil currents, A. The step
    is compiled by numba (``_step_rows_counted``, a loop over the rows, each with its own step
    length); the first call in a process loads it from numba's on-disk cache (or compiles it once).
    """

    def __init__(self, params: PlantParams, min_substeps: int = PHYSICS_SUBSTEPS,
                 substep_angle_rad: float = SUBSTEP_ANGLE_RAD) -> None:
        self.params = p = params
        #: The fewest RKMK4 sub-steps per step, and the largest rotation per sub-step, rad
        #: (``np.inf``: exactly ``min_substeps`` sub-steps); the defaults are the plant's rule.
        self.min_substeps, self.substep_angle_rad = int(min_substeps), float(substep_angle_rad)
        #: How many times each row of the last ``step`` evaluated the acceleration (B,): four
        #: per RKMK4 sub-step.
        self.evaluations = np.zeros(0, dtype=np.int64)
        r, motor = p.rotor, p.motor
        self.J = p.rotor.inertia_about_centre_kgm2
        self.J_inv = np.linalg.inv(self.J)
        self.stop_k, self.stop_c, self.tilt_max_rad = stop_gains(p)
        cos_cutoff = float(np.cos(np.deg2rad(motor.cutoff_deg)))
        scal = {
            "viscous": r.viscous_Nms_per_rad,
            "tau_c": r.coulomb_Nm,
            "omega_s": r.coulomb_smoothing_rad_s,
            "cos_cutoff": cos_cutoff,
            "stop_k": self.stop_k,
            "stop_c": self.stop_c,
            "tilt_max": self.tilt_max_rad,
            "cos_tilt_max": float(np.cos(self.tilt_max_rad)),
        }
        #: The arguments of the compiled kernels after the state: J, J^-1 (kg·m²), the centre of
        #: mass offset (m), m g in the stator frame (N), the coil axes (16, 3, stator frame), the
        #: magnet axes (18, 3, rotor frame), k_T s_j / (1 - cos phi_c)^2 (18,), N·m/A (the
        #: window's scale folded into the gain), and the scalars of ``_SCALARS``.
        self.consts = (
            np.ascontiguousarray(self.J, dtype=float),
            np.ascontiguousarray(self.J_inv, dtype=float),
            np.asarray(r.com_offset_m, dtype=float),
            r.mass_kg * np.array([0.0, 0.0, -r.gravity_m_s2]),
            np.ascontiguousarray(coil_axes(motor), dtype=float),
            np.ascontiguousarray(magnet_axes(), dtype=float),
            motor.k_T_Nm_per_A * magnet_polarity() / (1.0 - cos_cutoff) ** 2,
            np.array([scal[k] for k in _SCALARS], dtype=float),
        )

    def acceleration(
        self,
        q: NDArray[np.float64],
        omega: NDArray[np.float64],
        currents: NDArray[np.float64],
        disturbance: NDArray[np.float64] | None = None,
    ) -> NDArray[np.float64]:
        """omega_dot (B, 3), rad/s², of the equations in the module docstring."""
        q, omega, currents = (np.ascontiguousarray(x, dtype=float) for x in (q, omega, currents))
        d = np.zeros_like(omega) if disturbance is None else np.array(  # a writable copy: one
            np.broadcast_to(disturbance, omega.shape), dtype=float)  # compiled signature
        return _acceleration_rows(q, omega, currents, d, *self.consts)

    def step(
        self,
        q: NDArray[np.float64],
        omega: NDArray[np.float64],
        currents: NDArray[np.float64],
        h: float | NDArray[np.float64],
        disturbance: NDArray[np.float64] | None = None,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Advance by ``h`` (s; a scalar or one per rotor, (B,)) with the ``currents`` (B, 16),
        A, and the body-frame ``disturbance`` (B, 3), N·m, held: RKMK4 sub-steps, as many per
        row as ``substep_angle_rad`` asks (one for a slow rotor; ``evaluations`` counts them).
        Returns the new ``(q, omega)``; ``q`` is renormalised."""
        # Written out for the one-rotor calls of the event loop, where this preparation costs
        # as much as the step: no-ops for C-contiguous float arrays, a scalar h filled.
        q = np.ascontiguousarray(q, dtype=float)
        omega = np.ascontiguousarray(omega, dtype=float)
        currents = np.ascontiguousarray(currents, dtype=float)
        B = q.shape[0]
        # writable in both branches (a broadcast view is read-only): one compiled signature
        hb = (np.full(B, h, dtype=float) if np.ndim(h) == 0
              else np.array(np.broadcast_to(np.asarray(h, dtype=float), (B,))))
        d = np.zeros((B, 3)) if disturbance is None else np.array(  # a writable copy: one
            np.broadcast_to(disturbance, omega.shape), dtype=float)  # compiled signature
        q_new, w_new, self.evaluations = _step_rows_counted(
            q, omega, currents, hb, d, self.min_substeps, *self.consts, self.substep_angle_rad)
        return q_new, w_new
