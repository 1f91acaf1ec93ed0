"""The rotor's rigid-body dynamics, driven by coil currents through K(q), in a MuJoCo model.

Equations (body frame, about the fixed centre O), shared with the CasADi twin
(``plant.twin``) and the batched engine (``latency.batched``):

    q_dot = 1/2 q ⊗ (0, omega)
    J_O omega_dot = R^T K(q) I + d x (R^T m g) - b omega - tau_c omega/sqrt(|omega|^2 + omega_s^2)
                    - omega x J_O omega + R^T T_stop

with J_O the inertia about O (parallel-axis from the centre-of-mass inertia and offset d) and
T_stop the tilt stop's contact torque. A fourth-order Runge-Kutta-Munthe-Kaas step on the
rotation group with every torque, K(q) I included, evaluated at each stage
(one sub-step per physics step for a slow rotor, more for a fast one:
``plant.rigid_body.SUBSTEP_ANGLE_RAD``) integrates them: ``plant.rigid_body``'s
compiled step, the same code for this one rotor as for the batched engine's many. The coil
currents follow their commands through an optional first-order lag (L/R), exact at the step
start, and are held over the step. MuJoCo holds the model of the scene, the state, the clock
and the sensors: its natively delayed attitude sensor records the state at the start of each
step.
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from plant import attitude
from plant.mjcf import build_mjcf
from plant.params import PlantParams
from plant.rigid_body import RigidBody, tilt_stop_contact
from plant.torque import N_COILS, Allocation, TorqueMap, allocate


def _is_real_scalar(x: object) -> bool:
    """A real number (Python or numpy scalar, or a 0-d array), not a bool or a string."""
    return np.ndim(x) == 0 and np.asarray(x).dtype.kind in "iuf"


def _check_dt(dt: object, h: float) -> float:
    """``dt`` (s) as a float, or ``ValueError`` naming it unless it is a finite positive
    multiple of the physics step ``h`` (s)."""
    if not _is_real_scalar(dt):
        raise ValueError(f"dt must be a positive multiple of physics_dt_s = {h} s, "
                         f"got {dt!r}")
    value = float(dt)
    if not np.isfinite(value):
        raise ValueError(f"dt must be a finite positive multiple of physics_dt_s = {h} s, "
                         f"got {value}")
    return value


class MujocoPlant:
    """The PMSpM rotor simulated by MuJoCo.

    State: attitude ``q`` (w, x, y, z; rotor to stator), body-frame angular velocity ``omega``
    (rad/s) and the actual coil currents (A). ``step(currents, dt)`` holds the commanded currents
    over ``dt`` seconds (a whole number of physics steps of ``params.physics_dt_s``).
    ``sensor_delay_s`` adds MuJoCo's natively delayed attitude sensor (``delayed_q``).
    """

    def __init__(
        self,
        params: PlantParams | None = None,
        q0: ArrayLike = (1.0, 0.0, 0.0, 0.0),
        omega0: ArrayLike = (0.0, 0.0, 0.0),
        sensor_delay_s: float | None = None,
    ) -> None:
        self.params = params or PlantParams()
        self.model = mujoco.MjModel.from_xml_string(build_mjcf(self.params, sensor_delay_s))
        self.data = mujoco.MjData(self.model)
        self.body = RigidBody(self.params)
        self._native_sensor = sensor_delay_s is not None
        self.torque_map = TorqueMap(self.params.motor)
        self.currents = np.zeros(N_COILS)
        #: Optional disturbance: called with each physics step's length h (s), returns a
        #: body-frame torque (N·m) held over that step (e.g. white noise of variance q/h).
        self.disturbance: Callable[[float], NDArray[np.float64]] | None = None
        self.reset(q0, omega0)

    # --- state -------------------------------------------------------------------------------
    def reset(self, q0: ArrayLike = (1.0, 0.0, 0.0, 0.0), omega0: ArrayLike = (0.0, 0.0, 0.0)):
        """Set the attitude, body rate (rad/s) and zero the coil currents and time."""
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = attitude.normalize(q0, "q0")
        self.data.qvel[:] = attitude.check_finite("omega0", omega0).reshape(3)
        self.currents = np.zeros(N_COILS)
        mujoco.mj_forward(self.model, self.data)

    def set_state(self, q: ArrayLike, omega: ArrayLike, currents: ArrayLike,
                  time_s: float) -> None:
        """Put the rotor at attitude ``q`` (unit, w x y z), body rate ``omega`` (rad/s), coil
        currents ``currents`` (16,), A, and time ``time_s`` (s): the state that another
        integrator of this plant's physics reached (the compiled physics step that the event
        loop uses between events). No MuJoCo step is taken, so the delayed sensor is not updated:
        for plants built without ``sensor_delay_s``."""
        if self._native_sensor:
            raise ValueError("set_state would leave the delayed sensor behind: this plant has "
                             "sensor_delay_s, advance it with advance()")
        self.data.qpos[:] = q
        self.data.qvel[:] = omega
        self.currents = np.array(currents, dtype=float)
        self.data.time = float(time_s)

    @property
    def q(self) -> NDArray[np.float64]:
        """Attitude quaternion (w, x, y, z), rotor to stator."""
        return self.data.qpos.copy()

    @property
    def omega(self) -> NDArray[np.float64]:
        """Angular velocity in the rotor (body) frame, rad/s."""
        return self.data.qvel.copy()

    def delayed_q(self) -> NDArray[np.float64]:
        """The ``rotor_quat_delayed`` sensor. MuJoCo evaluates sensors before integrating, so
        after a step to time t it reports the attitude at t - dt - sensor_delay_s."""
        sid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SENSOR, "rotor_quat_delayed")
        if sid < 0:
            raise ValueError("this plant was built without sensor_delay_s")
        adr = self.model.sensor_adr[sid]
        return self.data.sensordata[adr : adr + 4].copy()

    @property
    def time(self) -> float:
        """Simulated time, s."""
        return float(self.data.time)

    # --- electromagnetics --------------------------------------------------------------------
    def allocate(
        self, torque: ArrayLike, q: ArrayLike | None = None, i_max: float | None = None
    ) -> Allocation:
        """Coil currents for a stator-frame torque, the issue's ``allocate(torque, q, i_max)``.

        Parameters
        ----------
        torque : array_like (3,)
            Requested torque on the rotor, stator frame, N·m.
        q : array_like (4,), optional
            Attitude (w, x, y, z) at which K(q) is evaluated; default the plant's current one.
        i_max : float, optional
            Per-coil current limit, A; default the motor's ``params.motor.i_max_A``. A smaller
            value (a derated drive, a thermal limit) binds earlier; a larger one is refused,
            since ``step`` would reject the currents.

        Returns
        -------
        Allocation
            ``(currents (16,) A, saturated, delivered (3,) N·m)``: least-norm currents within
            ``±i_max``, or, when the limit binds, the largest part of the request in the same
            direction (``plant.torque.allocate``).
        """
        limit = self.params.motor.i_max_A
        if i_max is None:
            i_max = limit
        elif isinstance(i_max, bool) or not (
            isinstance(i_max, (int, float, np.integer, np.floating)) and 0.0 < i_max <= limit
        ):  # NaN fails the comparison too
            raise ValueError(f"i_max must be a current in (0, {limit}] A (the motor's limit), "
                             f"got {i_max!r}")
        K = self.torque_map(self.q if q is None else q)
        return allocate(torque, K, float(i_max))

    # --- time --------------------------------------------------------------------------------
    def step(self, currents: ArrayLike, dt: float) -> None:
        """Advance ``dt`` seconds with the coil-current command ``currents`` (16,), A, held.

        Commands beyond ``±i_max`` are a caller error (use ``allocate``) and raise
        ``ValueError``, as do non-finite values and a ``dt`` that is not a positive multiple of
        the physics step (NaN and infinity included).
        """
        cmd = self._check_currents(currents)
        h = self.params.physics_dt_s
        dt = _check_dt(dt, h)
        n = round(dt / h)
        if n < 1 or abs(n * h - dt) > 1e-9 * max(1.0, dt):
            raise ValueError(f"dt = {dt} s must be a positive multiple of physics_dt_s = {h} s")
        self._integrate(cmd, [h] * n)

    def simulate(
        self, currents: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Step once per row of ``currents`` (N, 16), A, each held for one physics step, from
        the present state; returns the attitudes (N+1, 4) and body rates (N+1, 3), rad/s, the
        present state first (the shape of ``CasadiTwin.simulate``, for comparisons)."""
        U = attitude.check_finite("currents", currents)
        if U.ndim != 2 or U.shape[1] != N_COILS:
            raise ValueError(f"currents must have shape (N, {N_COILS}), got {U.shape}")
        qs, ws = [self.q], [self.omega]
        for u in U:
            self.step(u, self.params.physics_dt_s)
            qs.append(self.q)
            ws.append(self.omega)
        return np.array(qs), np.array(ws)

    def advance(self, currents: ArrayLike, dt: float) -> None:
        """Like ``step`` but for any ``dt`` > 0 (s): whole physics steps, then one shorter
        step for the remainder, so that events of a timed loop fall on their exact times."""
        cmd = self._check_currents(currents)
        if not _is_real_scalar(dt):
            raise ValueError(f"dt must be a finite time >= 0 in s, got {dt!r}")
        dt = float(dt)
        if not (np.isfinite(dt) and dt >= 0):
            raise ValueError(f"dt must be a finite time >= 0 in s, got {dt}")
        h = self.params.physics_dt_s
        n = int(np.floor(dt / h + 1e-9))
        rest = dt - n * h
        self._integrate(cmd, [h] * n + ([rest] if rest > 1e-12 else []))

    def _check_currents(self, currents: ArrayLike) -> NDArray[np.float64]:
        cmd = attitude.check_finite("currents", currents).reshape(-1)
        if cmd.shape != (N_COILS,):
            raise ValueError(f"currents must have {N_COILS} entries, got shape {cmd.shape}")
        i_max = self.params.motor.i_max_A
        if np.max(np.abs(cmd)) > i_max * (1 + 1e-9):
            raise ValueError(f"currents exceed the limit ±{i_max} A: max |I| = {np.abs(cmd).max()}")
        return cmd

    def _integrate(self, cmd: NDArray[np.float64], steps: list[float]) -> None:
        tau_L = self.params.motor.coil_time_constant_s
        h0 = self.model.opt.timestep
        q, w = self.data.qpos[None].copy(), self.data.qvel[None].copy()
        for h in steps:
            decay = np.exp(-h / tau_L) if tau_L > 0 else 0.0
            self.currents = cmd + (self.currents - cmd) * decay  # exact first-order lag
            dist = None if self.disturbance is None else np.reshape(self.disturbance(h), (1, 3))
            q, w = self.body.step(q, w, self.currents[None], h, dist)
            if self._native_sensor:  # MuJoCo's step records the sensors at the step start
                self.model.opt.timestep = h
                mujoco.mj_step(self.model, self.data)
            else:
                self.data.time += h
            self.data.qpos[:], self.data.qvel[:] = q[0], w[0]
        self.model.opt.timestep = h0

    def tilt_stop_active(self) -> bool:
        """True when the rotor is in contact with the tilt stop (beyond its limit)."""
        return bool(tilt_stop_contact(self.data.qpos[None], self.params)[0])
