"""Delay-aware nonlinear MPC of the rotor attitude with CasADi.

One module of about 780 lines: the NLP, its solvers, the warm start and the delay compensation
share the CasADi functions (``_Problem``) and the command history of one controller object.

Model
-----
The prediction model is the plant's CasADi twin driven by torque, ``CasadiTwin.f_torque``
(plant/twin.py): quaternion kinematics ``q' = 1/2 q ⊗ (0, omega)`` and Euler's equation with the
stator-frame torque T (N·m), viscous and smooth Coulomb friction, gravity and the gyroscopic
term. We take the torque, not the 16 coil currents, as the input: 3 inputs instead of 16 and no
K(q) (16 x 18 window terms) in the prediction, and the allocator (plant/torque.py) delivers any
torque inside the motor's all-direction capacity exactly. The input constraint is therefore the
ball ``|T_k|² <= T_lim²`` with ``T_lim = margin x worst_case_capacity`` (plant/torque.py), plus
the box ``|T_k,i| <= T_lim`` that keeps every QP bounded. Inside the optimisation the twin is
built with a wider Coulomb smoothing (``model_coulomb_smoothing_rad_s``, see MPCConfig); the
delay compensation uses the plant's own law.

Optimal control problem (multiple shooting, N steps of h seconds)
-----------------------------------------------------------------
Decision variables per node: state X_k = (q_k, omega_k) (7), torque U_k (3, k < N), tilt slack
S_k >= 0 (k < N). Constraints:

* X_0 = x̂(t_0) (bounds), the delay-compensated initial state (below);
* X_{k+1} = Φ(X_k, U_k): RK4 with ``rk4_substeps`` sub-steps of ``f_torque`` over h;
* tilt: ``1 - 2 (x_k² + y_k²) + S_k >= cos(tilt_max)`` for 1 <= k < N (R33 = cos tilt), the
  slack carrying an exact L1 penalty so the constraint holds whenever it can; at k = N the
  constraint is hard (HPIPM's stage structure has no input at the last node);
* torque ball and box as above.

Cost, with the attitude error ``e_k = 2 vec(q_ref,k^-1 ⊗ q_k)`` (≈ the rotation vector for small
errors; the quaternion signs are aligned before the solve so that it stays on the short way):

    Σ_k h [ e_kᵀ Q_θ e_k + (omega_k - omega_ref,k)ᵀ Q_ω (...) + r |U_k - T_ff,k|² ]
      + Σ_i z_N,iᵀ P_i z_N,i + Σ_k (ρ1 S_k + ρ2 S_k²)

with z_N,i = (e_N,i, omega_N,i - omega_ref,N,i). The weights come from a bandwidth rule (ours):
for one axis ``J θ'' = T`` the continuous LQR with ``r = 1/T_lim²``, ``q_θ = r (J ω_n²)²`` and
``q_ω = r J² ω_n² (4ζ² - 2)`` has the closed-loop polynomial ``s² + 2ζω_n s + ω_n²`` (k1 =
sqrt(q_θ/r) = J ω_n², k2 = sqrt(q_ω/r + 2 J k1) = 2 ζ ω_n J). P_i is the discrete-time Riccati
solution of the same axis sampled with step h (scipy.linalg.solve_discrete_are), so the terminal
cost approximates the infinite-horizon cost-to-go. T_ff,k = R(q_ref)(J alpha_ref + omega_ref ×
J omega_ref) is the torque that keeps the reference moving. The error e_k is linear in q_k, so
the cost is quadratic in the decision variables.

Solver
------
Sequential quadratic programming (casadi ``sqpmethod``) with a Gauss-Newton-type Hessian: the
exact Hessian of the quadratic cost plus the (diagonal) curvature of the tilt and torque-ball
constraints, multipliers projected so the Hessian stays positive semidefinite; the curvature of
the RK4 dynamics is left out (the exact Lagrangian Hessian has 234k SX instructions and took
2.1 ms per evaluation here, the Gauss-Newton one 1.9k and 0.15 ms). The QPs go to
HPIPM, which exploits the stage structure (Riccati recursion). Warm start: the previous solution
and its multipliers shifted by the elapsed number of steps. IPOPT and SQP with qpOASES, qrqp or
OSQP are options; benchmarks/bench_controllers.py times them all (docs/controllers.md).

Delay awareness
---------------
An estimate describes the rotor at ``estimate.state_time`` (its exposure time, or its release time
for an observer that already predicts across its latency); the torque computed at ``t`` acts from
``t_0 = t + compute latency + actuation_delay_s``. With ``delay_aware=True`` the initial state is
the estimate integrated with the twin (RK4, sub-steps <= ``prediction_step_s``) from ``state_time``
to ``t_0`` under the torques this controller already sent (its own command history, each held from
its own ``t_0``; ``record_command`` lets the loop report overrides). The compute latency is
``compute_latency_s`` when set, else the median of the measured durations of the last 20 calls. With
``delay_aware=False`` the estimate is taken as the state at t.

Shared and compiled problems
----------------------------
The CasADi side (twins, NLP, solver, bounds: ``_Problem``) keeps no state between solves, so
controllers with the same problem settings (the fields outside ``RUNTIME_FIELDS``) and plant
share one, built once per process (``shared_problem``). With ``codegen`` the SQP's Jacobian and
Hessian and the prediction's RK4 chunk run as machine code compiled once and cached on disk
(``controller.codegen``); they are the same functions to rounding (docs/controllers.md).

Solve time
----------
Every call is timed with the controller's ``clock`` (``time.perf_counter`` by default):
``solve_times_s`` (the solver call) and ``compute_times_s`` (the whole call, the latency the loop
sees); ``solve_stats()`` gives the median and p95.
"""

from __future__ import annotations

import functools
import json
import time
from collections import deque
from collections.abc import Callable
from typing import Literal

import casadi as ca
import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

from controller.base import Controller, InvalidCommand, Reference
from controller.codegen import compiled
from controller.pid import (
    RateFromAttitude,
    estimate_usable,
)
from plant import attitude
from plant.estimate import Estimate
from plant.params import PlantParams
from plant.torque import worst_case_capacity
from plant.twin import CasadiTwin

Solver = Literal["sqp_hpipm", "sqp_qpoases", "sqp_qrqp", "sqp_osqp", "ipopt"]


class MPCConfig(BaseModel):
    """MPC settings; an inconsistent configuration raises ``ValueError`` naming the field."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    horizon_steps: int = Field(15, ge=2, le=200, description="Our choice: N = 15.")
    step_s: float = Field(0.01, gt=0.0, le=0.1, description="Our choice: h = 10 ms (150 ms).")
    rk4_substeps: int = Field(
        1,
        ge=1,
        le=20,
        description="Our choice: one RK4 step per interval. The smooth Coulomb law has a rate "
        "~ tau_c/(J omega_s) = 136 1/s near omega = 0 (plant/params.py); RK4 is stable for "
        "h_sub < 2.78/136 s = 20 ms, and 2 sub-steps changed the closed-loop step response "
        "by less than 0.01° while doubling the Jacobian cost (docs/controllers.md).",
    )
    bandwidth_rad_s: float = Field(
        15.0,
        gt=0.0,
        description="Our choice: ω_n = 15 rad/s (loop crossover ≈ 1.7 ω_n = 25 rad/s at ζ = 0.8). "
        "At 10 rad/s Coulomb friction left a 0.08–0.17° offset after a 5° step; at 15 rad/s "
        "0.007–0.021° (docs/controllers.md).",
    )
    damping: float = Field(
        0.8, ge=0.5**0.5, description="Our choice: ζ = 0.8 (ζ >= 1/√2 keeps q_ω >= 0)."
    )
    model_coulomb_smoothing_rad_s: float | None = Field(
        0.1,
        gt=0.0,
        description="Our choice: the prediction model inside the optimisation smooths the "
        "Coulomb law over 0.1 rad/s instead of the plant's 0.01 rad/s (plant/params.py); the "
        "friction torques differ only below ~0.3 rad/s, and resting on the tilt constraint "
        "the SQP then needs 2 iterations instead of hitting the cap of 8 (docs/controllers.md)."
        " None: the plant's law. The delay compensation always uses the plant's law.",
    )
    tilt_max_deg: float = Field(
        14.5,
        gt=0.0,
        le=15.0,
        description="Our choice: 0.5° inside the 15° stop (seed 000 §2.4), room for model and "
        "estimation error so that the rotor does not touch the stop.",
    )
    tilt_slack_l1: float = Field(1.0e3, gt=0.0, description="Our choice: exact-penalty weight ρ1.")
    tilt_slack_l2: float = Field(1.0e4, ge=0.0, description="Our choice: quadratic weight ρ2.")
    torque_limit_Nm: float | None = Field(
        None, gt=0.0, description="None: margin x the worst-direction capacity (as the PID)."
    )
    torque_limit_margin: float = Field(0.95, gt=0.0, le=1.0, description="Our choice (as PID).")
    solver: Solver = Field(
        "sqp_hpipm",
        description="Chosen by measurement (docs/controllers.md): SQP with the structure-"
        "exploiting QP solver HPIPM was the fastest of IPOPT and SQP + HPIPM/qpOASES/qrqp/OSQP.",
    )
    max_iter: int = Field(
        8,
        ge=1,
        description="Our choice: SQP iteration cap per solve. Warm-started solves take 1–3; on an "
        "active tilt constraint the Gauss-Newton SQP converges linearly (halving the residual "
        "per iteration), and 8 iterations leave < 1e-5 rad of dynamics gap. 1 is the "
        "real-time iteration: measured, 0.6x the solve time but a different closed loop near "
        "the stability boundary (docs/controllers.md).",
    )
    tol_pr: float = Field(1e-5, gt=0.0, description="Our choice: primal tolerance (gap, rad).")
    tol_du: float = Field(1e-4, gt=0.0, description="Our choice: dual tolerance (cost units).")
    hessian: Literal["gauss_newton", "exact"] = Field(
        "gauss_newton",
        description="Our choice, by measurement: the exact Lagrangian Hessian took 2.1 ms per "
        "evaluation, the Gauss-Newton one 0.15 ms (docs/controllers.md).",
    )
    codegen: bool = Field(
        True,
        description="Our choice, by measurement (docs/controllers.md): the SQP's Jacobian and "
        "Gauss-Newton Hessian compiled to machine code with the system C compiler "
        "(controller.codegen: compiled once, cached on disk; 2-3 s the first time) instead of "
        "CasADi's virtual machine, and the prediction's RK4 steps; the same functions to "
        "rounding, the solve 1.6-2.7x faster. With IPOPT only the prediction is compiled; "
        "without a C compiler nothing is.",
    )
    delay_aware: bool = Field(True, description="Predict the estimate forward (module docstring).")
    reference_preview: bool = Field(
        True,
        description="Our choice: the horizon follows the reference's future (the MPC starts "
        "moving before a step). False: the reference sampled at the call time is held over the "
        "horizon with zero rate, as a controller that cannot see ahead (a fair comparison "
        "with a PID).",
    )
    compute_latency_s: float | None = Field(
        None, ge=0.0, description="None: median of the measured call durations (last 20)."
    )
    actuation_delay_s: float = Field(
        0.0, ge=0.0, description="Our choice: 0 (ideal current drive, plant/params.py)."
    )
    prediction_step_s: float = Field(
        1.0e-3, gt=0.0, description="Our choice: 1 ms, the physics step (plant/params.py)."
    )
    invalid_command: InvalidCommand = Field(
        "hold", description="Our choice: hold the last command while the estimate is invalid "
        "(controller.base: the one invalid-estimate policy)."
    )

    @model_validator(mode="after")
    def _consistent(self) -> MPCConfig:
        if self.step_s / self.rk4_substeps > 2.78 / 136.0:
            raise ValueError(
                f"rk4_substeps = {self.rk4_substeps} is too few for step_s = {self.step_s}: "
                "sub-steps above 20 ms make RK4 unstable on the Coulomb law"
            )
        if self.bandwidth_rad_s * self.step_s > 1.0:
            raise ValueError(
                f"bandwidth_rad_s = {self.bandwidth_rad_s} is too high for step_s = {self.step_s}"
                " (need bandwidth * step <= 1 for the sampled design)"
            )
        return self


def lqr_weights(
    J: float, bandwidth_rad_s: float, damping: float, torque_limit: float
) -> tuple[float, float, float]:
    """(q_θ, q_ω, r) of the bandwidth rule (module docstring): LQR on ``J θ'' = T`` whose closed
    loop is ``s² + 2ζω_n s + ω_n²``. Units: 1/(rad²·s), 1/((rad/s)²·s), 1/(N·m)²/s."""
    r = 1.0 / torque_limit**2
    q_th = r * (J * bandwidth_rad_s**2) ** 2
    q_w = r * J**2 * bandwidth_rad_s**2 * (4.0 * damping**2 - 2.0)
    return q_th, q_w, r


def terminal_weight(J: float, h: float, q_th: float, q_w: float, r: float) -> NDArray[np.float64]:
    """Discrete Riccati solution P (2x2) for one axis ``J θ'' = T`` sampled with zero-order hold
    at step h (s), stage cost ``h (q_θ θ² + q_ω ω² + r T²)``."""
    A = np.array([[1.0, h], [0.0, 1.0]])
    B = np.array([[h * h / (2.0 * J)], [h / J]])
    return scipy.linalg.solve_discrete_are(A, B, h * np.diag([q_th, q_w]), np.array([[h * r]]))


#: MPCConfig fields that the controller reads at run time; every other field shapes the
#: optimisation problem (``_Problem``) and is part of its cache key.
RUNTIME_FIELDS = frozenset({"delay_aware", "reference_preview", "compute_latency_s",
                            "actuation_delay_s", "prediction_step_s", "invalid_command"})


class _Problem:
    """The CasADi side of the MPC for one configuration and plant: the prediction step, the NLP
    and its solver, the bounds and the layout of the decision vector. It holds no state between
    solves (the warm start and the history are the controller's), so every controller with the
    same problem settings and plant shares one (``shared_problem``): a sweep process builds it,
    and compiles or loads its derivatives, once."""

    def __init__(self, config: MPCConfig, params: PlantParams) -> None:
        self.config = cfg = config
        self.params = params
        self.twin = CasadiTwin(params)
        eps = cfg.model_coulomb_smoothing_rad_s
        if eps is None:
            self.model_twin = self.twin
        else:
            rotor = params.rotor.model_copy(update={"coulomb_smoothing_rad_s": eps})
            self.model_twin = CasadiTwin(params.model_copy(update={"rotor": rotor}))
        self.J = np.diag(params.rotor.inertia_about_centre_kgm2).copy()
        if cfg.torque_limit_Nm is not None:
            self.torque_limit = float(cfg.torque_limit_Nm)
        else:
            cap = worst_case_capacity(params.motor, params.rotor.tilt_stop_deg)
            self.torque_limit = cfg.torque_limit_margin * cap
        self.N, self.h = cfg.horizon_steps, cfg.step_s
        self._build_prediction()
        self._build_nlp()
        # Positions of X_k, U_k and S_k in the decision vector (stage order X, U, S).
        stage = np.arange(self.N)[:, None] * 11
        self.ix = np.vstack([stage + np.arange(7), 11 * self.N + np.arange(7)])
        self.iu = stage + 7 + np.arange(3)
        self.i_s = stage[:, 0] + 10

    def pack(self, X: NDArray, U: NDArray, S: NDArray) -> NDArray[np.float64]:
        """The decision vector of states X (N+1, 7), torques U (N, 3) and slacks S (N)."""
        w = np.empty(self.nw)
        w[self.ix], w[self.iu], w[self.i_s] = X, U, S
        return w

    def unpack(self, w: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        """(X, U, S) of a decision vector (inverse of ``pack``)."""
        return w[self.ix], w[self.iu], w[self.i_s]

    def bounds(self, x0: NDArray) -> dict[str, NDArray]:
        """The solver's bounds (lbx, ubx, lbg, ubg) with the first state fixed to ``x0``."""
        lbw, ubw = self.lbw.copy(), self.ubw.copy()
        lbw[:7] = ubw[:7] = x0
        return {"lbx": lbw, "ubx": ubw, "lbg": self.lbg, "ubg": self.ubg}

    # --- construction ----------------------------------------------------------------------
    def _build_prediction(self) -> None:
        x = ca.SX.sym("x", 7)
        T = ca.SX.sym("T", 3)
        hs = ca.SX.sym("h")
        f = self.twin.f_torque
        k1 = f(x, T)
        k2 = f(x + hs / 2 * k1, T)
        k3 = f(x + hs / 2 * k2, T)
        k4 = f(x + hs * k3, T)
        xn = x + hs / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        xn = ca.vertcat(xn[0:4] / ca.norm_2(xn[0:4]), xn[4:7])
        #: One RK4 step of the twin: (x (7), T (3) stator N·m, h s) -> x after h.
        self.rk4 = ca.Function("rk4", [x, T, hs], [xn])
        # The same for a chunk of steps in one call (a zero step is the identity): calling
        # casadi from Python costs ~50 µs, so a 30 ms prediction in 1 ms steps would cost more
        # than the solve.
        self.chunk = 16
        self.rk4_chunk = self.rk4.mapaccum("mpc_rk4_chunk", self.chunk)

    def _build_nlp(self) -> None:
        cfg = self.config
        Phi = self._shooting_step(cfg.step_s, cfg.rk4_substeps)
        nlp, bounds, tilt_rows, ball_rows = self._nlp_graph(Phi)
        self.lbw, self.ubw, self.lbg, self.ubg = bounds
        self.nw = int(nlp["x"].numel())
        self.ng = int(nlp["g"].numel())
        self.hess_gn = self._gauss_newton_hessian(nlp, tilt_rows, ball_rows)
        self.nlp = nlp
        #: The functions compiled to machine code (``codegen``) by role: ``rk4_chunk`` and,
        #: for the SQP, ``jac_fg`` and ``hess_lag``; empty without ``codegen`` or a compiler.
        self.compiled = self._compile(Phi) if cfg.codegen else {}
        self.rk4_chunk = self.compiled.get("rk4_chunk", self.rk4_chunk)
        self.solver = ca.nlpsol("mpc", *self._solver_spec(), nlp, self._solver_options())

    def _compile(self, Phi: ca.Function) -> dict[str, ca.Function]:
        """The prediction's ``rk4_chunk`` and, for the SQP, ``jac_fg`` (objective, its
        gradient, constraints, their Jacobian) and, with the Gauss-Newton Hessian,
        ``hess_lag``, compiled (``controller.codegen``); empty without a C compiler. The
        Jacobian is taken of a second copy of the NLP whose shooting steps are calls of one
        function (``never_inline``): its C code holds the step's derivative once instead of N
        times (0.3 MB instead of 2.6 MB of C, 2-3 s of compiling instead of 12 s) and runs as
        fast; its values equal the inlined graph's to rounding."""
        functions = {"rk4_chunk": self.rk4_chunk}
        if self.config.solver != "ipopt":
            x, T = ca.SX.sym("x", 7), ca.SX.sym("T", 3)
            step = ca.Function("mpc_phi", [x, T], [Phi(x, T)], {"never_inline": True})
            nlp = self._nlp_graph(step)[0]
            w, p, f, g = nlp["x"], nlp["p"], nlp["f"], nlp["g"]
            functions["jac_fg"] = ca.Function(
                "mpc_jac_fg", [w, p], [f, ca.gradient(f, w), g, ca.jacobian(g, w)],
                ["x", "p"], ["f", "grad_f_x", "g", "jac_g_x"])
            if self.config.hessian == "gauss_newton":
                functions["hess_lag"] = self.hess_gn
        loaded = compiled(list(functions.values()), "mpc")
        return {} if loaded is None else dict(zip(functions, loaded, strict=True))

    def weights(self) -> tuple:
        """The cost's weights: q_θ (3,), q_ω (3,), r, the terminal P_i (3 of 2 x 2) and the tilt
        slack's ρ1 and ρ2 (module docstring)."""
        cfg = self.config
        weights = [
            lqr_weights(self.J[i], cfg.bandwidth_rad_s, cfg.damping, self.torque_limit)
            for i in range(3)
        ]
        Qth = np.array([w[0] for w in weights])
        Qw = np.array([w[1] for w in weights])
        r = weights[0][2]
        P = [terminal_weight(self.J[i], cfg.step_s, *weights[i]) for i in range(3)]
        return Qth, Qw, r, P, cfg.tilt_slack_l1, cfg.tilt_slack_l2

    def _nlp_graph(
        self, Phi: ca.Function, weights: tuple | None = None
    ) -> tuple[dict, tuple[NDArray, ...], list[int], list[int]]:
        """The NLP (casadi dict x, f, g, p) with the shooting step ``Phi``, its bounds (lbw,
        ubw, lbg, ubg) and the rows of the tilt and torque-ball constraints. ``weights``
        (default ``weights()``) may be CasADi symbols of the same shapes (P_i as 2 x 2 SX):
        ``controller.mpc_machine`` makes them parameters."""
        cfg = self.config
        N, h = cfg.horizon_steps, cfg.step_s
        Qth, Qw, r, P, rho1, rho2 = self.weights() if weights is None else weights

        Xs = [ca.SX.sym(f"X{k}", 7) for k in range(N + 1)]
        Us = [ca.SX.sym(f"U{k}", 3) for k in range(N)]
        Ss = [ca.SX.sym(f"S{k}") for k in range(N)]
        p_qref = ca.SX.sym("qref", 4, N + 1)
        p_wref = ca.SX.sym("wref", 3, N + 1)
        p_tff = ca.SX.sym("tff", 3, N)

        def err(k: int) -> ca.SX:
            qr = p_qref[:, k]
            q = Xs[k][0:4]
            # vec(qr^-1 ⊗ q) = w_r v - w v_r - v_r × v
            return 2 * (qr[0] * q[1:4] - q[0] * qr[1:4] - ca.cross(qr[1:4], q[1:4]))

        cos_max = float(np.cos(np.deg2rad(cfg.tilt_max_deg)))
        J_cost = 0
        w, lbw, ubw, g, lbg, ubg = [], [], [], [], [], []
        ball_rows: list[int] = []
        tilt_rows: list[int] = []
        big = 1e3
        for k in range(N + 1):
            w.append(Xs[k])
            lbw += [-1.1] * 4 + [-big] * 3
            ubw += [1.1] * 4 + [big] * 3
            if k < N:
                w.append(Us[k])
                lbw += [-self.torque_limit] * 3
                ubw += [self.torque_limit] * 3
            if k < N:
                w.append(Ss[k])
                lbw.append(0.0)
                ubw.append(0.0 if k == 0 else ca.inf)
            e = err(k)
            dw = Xs[k][4:7] - p_wref[:, k]
            if k < N:
                dT = Us[k] - p_tff[:, k]
                J_cost += h * (ca.dot(Qth * e, e) + ca.dot(Qw * dw, dw) + r * ca.dot(dT, dT))
                # Stage constraints, in stage order (dynamics, then torque ball, then tilt).
                g.append(Phi(Xs[k], Us[k]) - Xs[k + 1])
                lbg += [0.0] * 7
                ubg += [0.0] * 7
                ball_rows.append(len(lbg))
                g.append(ca.dot(Us[k], Us[k]))
                lbg.append(-ca.inf)
                ubg.append(self.torque_limit**2)
            else:
                for i in range(3):
                    z = ca.vertcat(e[i], dw[i])
                    Pi = P[i] if isinstance(P[i], ca.SX) else ca.DM(P[i])
                    J_cost += ca.mtimes([z.T, Pi, z])
            if k >= 1:
                qk = Xs[k]
                tilt_rows.append(len(lbg))
                g.append(1 - 2 * (qk[1] ** 2 + qk[2] ** 2) + (Ss[k] if k < N else 0))
                lbg.append(cos_max)
                ubg.append(ca.inf)
            if k < N:
                J_cost += rho1 * Ss[k] + rho2 * Ss[k] ** 2

        bounds = tuple(np.array(b, dtype=float) for b in (lbw, ubw, lbg, ubg))
        pvec = ca.vertcat(ca.vec(p_qref), ca.vec(p_wref), ca.vec(p_tff))
        nlp = {"x": ca.vertcat(*w), "f": J_cost, "g": ca.vertcat(*g), "p": pvec}
        return nlp, bounds, tilt_rows, ball_rows

    def _shooting_step(self, h: float, M: int) -> ca.Function:
        """One shooting interval of ``h`` (s): ``M`` plain RK4 sub-steps of the twin's
        ``f_torque`` (no renormalisation of the quaternion: it would only add curvature)."""
        x = ca.SX.sym("x", 7)
        T = ca.SX.sym("T", 3)
        xi = x
        f, hm = self.model_twin.f_torque, h / M
        for _ in range(M):
            k1 = f(xi, T)
            k2 = f(xi + hm / 2 * k1, T)
            k3 = f(xi + hm / 2 * k2, T)
            k4 = f(xi + hm * k3, T)
            xi = xi + hm / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return ca.Function("Phi", [x, T], [xi])

    def _gauss_newton_hessian(
        self, nlp: dict, tilt_rows: list[int], ball_rows: list[int]
    ) -> ca.Function:
        """Gauss-Newton-type Hessian of the Lagrangian. The cost is quadratic in w (e_k is
        linear in q_k for a given q_ref), so its Hessian is exact. Of the constraints only the
        path constraints keep their (cheap, diagonal) curvature, with the multiplier signs
        projected so that the Hessian stays positive semidefinite (casadi: lam_g < 0 at an
        active lower bound, > 0 at an active upper bound); the curvature of the RK4 dynamics
        is left out."""
        wv, G = nlp["x"], nlp["g"]
        lam_f = ca.SX.sym("lam_f")
        lam_g = ca.SX.sym("lam_g", G.numel())
        L_path = 0
        for i in tilt_rows:
            L_path += ca.fmin(lam_g[i], 0) * G[i]
        for i in ball_rows:
            L_path += ca.fmax(lam_g[i], 0) * G[i]
        H = lam_f * ca.hessian(nlp["f"], wv)[0] + ca.hessian(L_path, wv)[0]
        if self.config.solver == "ipopt":  # IPOPT takes the upper triangle only
            H = ca.triu(H)
        return ca.Function("mpc_hess_l", [wv, nlp["p"], lam_f, lam_g], [H],
                           ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"])

    def _solver_spec(self) -> tuple[str]:
        return ("ipopt",) if self.config.solver == "ipopt" else ("sqpmethod",)

    def _solver_options(self) -> dict:
        cfg = self.config
        opts: dict = {"print_time": False, "record_time": False}
        if cfg.hessian == "gauss_newton":
            opts["hess_lag"] = self.hess_gn
        opts |= {k: f for k, f in self.compiled.items() if k in ("jac_fg", "hess_lag")}
        if cfg.solver == "ipopt":
            opts["ipopt"] = {
                "print_level": 0,
                "max_iter": cfg.max_iter * 5,
                "tol": cfg.tol_pr,
                "warm_start_init_point": "yes",
                "mu_init": 1e-3,
                "sb": "yes",
            }
            return opts
        qp = cfg.solver.removeprefix("sqp_")
        qp_opts: dict = {"error_on_fail": False}
        if qp == "hpipm":
            # Stage structure of the QP: x_k = X_k (7), u_k = (U_k, S_k) (4, none at N);
            # per stage the 7 gap rows, then the torque ball (k < N) and the tilt (k >= 1).
            N = self.N
            qp_opts.update(
                {
                    "N": N,
                    "nx": [7] * (N + 1),
                    "nu": [4] * N + [0],
                    "ng": [1] + [2] * (N - 1) + [1],
                    "hpipm": {"mode": "speed"},
                }
            )
        elif qp == "qpoases":
            qp_opts.update({"printLevel": "none", "sparse": True})
        elif qp == "osqp":
            qp_opts.update({"osqp": {"verbose": False, "eps_abs": 1e-6, "eps_rel": 1e-6}})
        elif qp == "qrqp":
            qp_opts.update({"print_iter": False, "print_header": False})
        opts.update(
            {
                "qpsol": qp,
                "qpsol_options": qp_opts,
                "max_iter": cfg.max_iter,
                "print_header": False,
                "print_iteration": False,
                "print_status": False,
                "tol_pr": cfg.tol_pr,
                "tol_du": cfg.tol_du,
                "error_on_fail": False,
            }
        )
        if cfg.hessian == "exact":
            opts["convexify_strategy"] = "regularize"
        return opts


def shared_problem(config: MPCConfig, params: PlantParams) -> _Problem:
    """The ``_Problem`` of ``config`` (its fields outside ``RUNTIME_FIELDS``) on ``params``,
    built once per process and shared (the 16 most recently used are kept)."""
    key = json.dumps([config.model_dump(mode="json", exclude=set(RUNTIME_FIELDS)),
                      params.model_dump(mode="json")], sort_keys=True)
    return _problem_of(key)


@functools.lru_cache(maxsize=16)
def _problem_of(key: str) -> _Problem:
    config, params = json.loads(key)
    return _Problem(MPCConfig.model_validate(config), PlantParams.model_validate(params))


class MPCController(Controller):
    """Nonlinear MPC behind ``command(estimate, reference, t) -> stator torque (N·m)``.

    Attributes: ``last_plan`` (states (N+1, 7) and torques (N, 3) of the last solution),
    ``last_t0`` (its start time, s), ``last_status``, ``solve_times_s``, ``compute_times_s``,
    ``unconverged`` (solves stopped by the iteration cap or reporting no success; their torque
    is still used), ``failures`` (solves with no finite solution or a solver error; the previous
    torque is held), ``invalid_count`` (invalid estimates; ``invalid_command`` applies).
    ``clock`` (default ``time.perf_counter``, s) times the calls and solves; tests inject a
    stand-in so that the timing does not depend on machine load.
    """

    def __init__(
        self,
        config: MPCConfig | None = None,
        params: PlantParams | None = None,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.config = cfg = config or MPCConfig()
        self.clock = clock
        self.params = params or PlantParams()
        self.problem = shared_problem(cfg, self.params)
        self.J, self.torque_limit = self.problem.J, self.problem.torque_limit
        self.N, self.h = self.problem.N, self.problem.h
        #: The solver (casadi nlpsol) and one RK4 step of the twin, (x (7), T (3) stator N·m,
        #: h s) -> x after h; both shared with the other controllers of the same problem.
        self.solver, self.rk4 = self.problem.solver, self.problem.rk4
        self.solve_times_s: list[float] = []
        self.compute_times_s: list[float] = []
        self.reset()

    # --- public ----------------------------------------------------------------------------
    def reset(self) -> None:
        """Clear the command history, the warm start and the rate estimator."""
        self._history: deque[tuple[float, NDArray[np.float64]]] = deque()
        self._warm: dict | None = None
        self._rate = RateFromAttitude()
        self.last_torque = np.zeros(3)
        self.last_plan: tuple[NDArray, NDArray] | None = None
        self.last_t0 = np.nan
        self.last_status = ""
        self.last_solve_time_s = 0.0
        self.last_compute_time_s = 0.0
        self.failures = 0
        self.unconverged = 0
        self.invalid_count = 0

    def solve_stats(self) -> dict[str, float]:
        """Median and 95th percentile of the solver time and of the whole call, s."""
        s, c = np.asarray(self.solve_times_s), np.asarray(self.compute_times_s)
        out = {"n": float(len(s))}
        for name, v in (("solve", s), ("command", c)):
            out[f"{name}_median_s"] = float(np.median(v)) if len(v) else np.nan
            out[f"{name}_p95_s"] = float(np.percentile(v, 95)) if len(v) else np.nan
        return out

    def expected_compute_s(self) -> float:
        """The compute latency assumed for the prediction, s."""
        if self.config.compute_latency_s is not None:
            return self.config.compute_latency_s
        recent = self.compute_times_s[-20:]
        return float(np.median(recent)) if recent else 0.0

    def command(self, estimate: Estimate, reference: Reference, t: float) -> NDArray[np.float64]:
        """Stator-frame torque (N·m) to hold from the call time ``t`` (s).

        Mirrored in ``latency.compiled.mpc._mpc`` and ``latency.compiled.mpc._mpc_keep``; keep
        both in step (tests/test_compiled_mirror.py checks them equal)."""
        t_call = self.clock()
        try:
            return self._command(estimate, reference, float(t))
        finally:
            self.last_compute_time_s = self.clock() - t_call
            self.compute_times_s.append(self.last_compute_time_s)

    def first_torque(
        self, x0: ArrayLike, reference: Reference, t0: float = 0.0
    ) -> NDArray[np.float64]:
        """The optimal first torque (stator frame, N·m) from state ``x0`` = (q, omega) at ``t0``
        (s): one cold-started solve with no delay compensation, leaving the command history,
        the warm start and the timing statistics untouched. For analysis, e.g. the linearised
        feedback law of ``latency.mpc_law``."""
        x0 = np.asarray(x0, dtype=float).reshape(7)
        x0 = np.r_[attitude.normalize(x0[:4], "x0[:4]"), attitude.check_finite("x0[4:]", x0[4:])]
        sol = self.solver(**self.problem.bounds(x0), p=self._parameters(reference, t0, x0[:4]),
                          x0=self.problem.pack(np.tile(x0, (self.N + 1, 1)),
                                               np.zeros((self.N, 3)), np.zeros(self.N)))
        _, U, _ = self.problem.unpack(np.asarray(sol["x"]).ravel())
        return U[0].copy()

    def record_command(self, t_apply: float, torque: NDArray[np.float64]) -> None:
        """Note that the stator torque ``torque`` (N·m) acts from ``t_apply`` (s) on, for the
        delay compensation. ``command`` calls it itself; a loop that overrides a command (a
        safe stop, a different hold) reports what it really sent. Commands older than the
        horizon plus 1 s before the newest are forgotten.

        Mirrored in ``latency.compiled.mpc._mpc_record``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        self._history.append((float(t_apply), np.array(torque, dtype=float).reshape(3)))
        horizon = self.N * self.h + 1.0
        while len(self._history) > 1 and self._history[1][0] < t_apply - horizon:
            self._history.popleft()

    def predict(self, x: NDArray[np.float64], t_from: float, t_to: float) -> NDArray[np.float64]:
        """Integrate the twin from state ``x`` (q, omega) at ``t_from`` to ``t_to`` (s) under the
        commands in this controller's history (zero torque before the first one).

        Mirrored in ``latency.compiled.mpc._mpc_predict``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        x = np.asarray(x, dtype=float).copy()
        if t_to <= t_from:
            return x
        hist = list(self._history)
        times = [c[0] for c in hist]
        # Segment boundaries: command start times inside (t_from, t_to).
        edges = [t_from] + [tc for tc in times if t_from < tc < t_to] + [t_to]
        dmax = self.config.prediction_step_s
        Ts, hs = [], []
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            k = int(np.searchsorted(times, a, side="right")) - 1
            T = hist[k][1] if k >= 0 else np.zeros(3)
            n = max(int(np.ceil((b - a) / dmax - 1e-9)), 1)
            Ts += [T] * n
            hs += [(b - a) / n] * n
        pad = -len(hs) % self.problem.chunk
        Ts = np.array(Ts + [np.zeros(3)] * pad).T
        hs = np.array(hs + [0.0] * pad)
        for i in range(0, len(hs), self.problem.chunk):
            sl = slice(i, i + self.problem.chunk)
            x = np.asarray(self.problem.rk4_chunk(x, Ts[:, sl], hs[sl]))[:, -1]
        return x

    # --- internals -------------------------------------------------------------------------
    def _safe(self, t: float) -> NDArray[np.float64]:
        self.invalid_count += 1
        if self.config.invalid_command == "zero":
            self.last_torque = np.zeros(3)
        self.record_command(
            t + self.expected_compute_s() + self.config.actuation_delay_s, self.last_torque
        )
        return self.last_torque.copy()

    def _initial_state(self, est: Estimate, t: float) -> tuple[NDArray[np.float64], float]:
        """The NLP's initial state (q, omega) and its time t0 (s) from an estimate at the
        call time ``t`` (s): the rate from successive attitudes when the estimate has none,
        carried to the command's start when delay-aware. Mirrored in
        ``latency.compiled.mpc._mpc_initial_state``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        q = attitude.normalize(est.q, "estimate.q")
        omega = np.asarray(est.omega, dtype=float)
        rate = self._rate.update(q, est.state_time)
        if omega.shape != (3,) or not np.all(np.isfinite(omega)):
            omega = np.where(np.isfinite(rate), rate, 0.0)
        x = np.r_[q, omega]
        if not self.config.delay_aware:
            return x, t
        t0 = t + self.expected_compute_s() + self.config.actuation_delay_s
        return self.predict(x, est.state_time, t0), t0

    def _parameters(
        self, reference: Reference, t0: float, q0: NDArray, t_call: float | None = None
    ) -> NDArray[np.float64]:
        """The NLP parameters: reference attitude and rate at the N+1 nodes from ``t0`` (s) and
        the feedforward torque of the N intervals (stator frame, N·m). Without
        ``reference_preview`` the reference at ``t_call`` (s; default ``t0``) is held.

        Mirrored in ``latency.compiled.mpc._mpc_arrays`` and
        ``latency.compiled.mpc._mpc_parameters``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        N, h, J = self.N, self.h, self.J
        if self.config.reference_preview:
            ref = reference.sample_many(t0 + h * np.arange(N + 1))
            qr = attitude.normalize(np.asarray(ref.q, dtype=float), "reference.q")
            wr = np.asarray(ref.omega, dtype=float)
            ar = np.asarray(ref.alpha, dtype=float)[:N]
        else:
            held = reference.sample(t0 if t_call is None else t_call).q
            qr = np.tile(attitude.normalize(held, "reference.q"), (N + 1, 1))
            wr, ar = np.zeros((N + 1, 3)), np.zeros((N, 3))
        # Keep the short way round: each quaternion on the side of the previous one (and q0).
        prev = q0
        for k in range(N + 1):
            if qr[k] @ prev < 0:
                qr[k] = -qr[k]
            prev = qr[k]
        tau = J * ar + np.cross(wr[:N], J * wr[:N])  # body frame of the reference
        tff = np.einsum("kij,kj->ki", attitude.to_matrix(qr[:N]), tau)
        return np.r_[qr.ravel(), wr.ravel(), tff.ravel()]

    def _initial_guess(self, x0: NDArray, t0: float) -> dict:
        """The solver's initial guess for x0 at t0 (s): the last solution shifted by the
        steps elapsed (with its multipliers when none has elapsed), or x0 held. Mirrored in
        ``latency.compiled.mpc._mpc_guess``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        N = self.N
        if self._warm is None:
            X = np.tile(x0, (N + 1, 1))
            U = np.zeros((N, 3))
            S = np.zeros(N)
            return {"x0": self.problem.pack(X, U, S)}
        X, U, S = self.problem.unpack(self._warm["w"])
        m = int(round((t0 - self._warm["t0"]) / self.h))
        m = min(max(m, 0), N)
        if m > 0:
            X = np.vstack([X[m:], np.repeat(X[-1:], m, axis=0)])
            U = np.vstack([U[m:], np.repeat(U[-1:], m, axis=0)])
            S = np.r_[S[m:], np.repeat(S[-1:], m)]
        X[0] = x0
        S[0] = 0.0
        # Keep every quaternion of the guess on x0's side of the double cover.
        flip = X[:, :4] @ x0[:4] < 0
        X[flip, :4] *= -1.0
        guess = {"x0": self.problem.pack(X, U, S)}
        if m == 0:
            guess["lam_x0"] = self._warm["lam_x"]
            guess["lam_g0"] = self._warm["lam_g"]
        return guess

    def _command(self, est: Estimate, reference: Reference, t: float) -> NDArray[np.float64]:
        if not estimate_usable(est):
            return self._safe(t)
        x0, t0 = self._initial_state(est, t)
        p = self._parameters(reference, t0, x0[:4], t)
        guess = self._initial_guess(x0, t0)
        ts = self.clock()
        try:
            sol = self.solver(**self.problem.bounds(x0), p=p, **guess)
            w = np.asarray(sol["x"]).ravel()
        except RuntimeError as err:  # a QP solver error: hold the previous torque
            sol, w = None, np.full(self.problem.nw, np.nan)
            self.last_status = f"solver error: {err}"
        self.last_solve_time_s = self.clock() - ts
        self.solve_times_s.append(self.last_solve_time_s)
        if sol is not None:
            stats = self.solver.stats()
            self.last_status = str(stats.get("return_status", ""))
            if not stats.get("success", False):
                self.unconverged += 1
        if sol is None or not np.all(np.isfinite(w)):
            self.failures += 1
            self._warm = None
        else:
            X, U, _ = self.problem.unpack(w)
            self._warm = {
                "w": w,
                "lam_x": np.asarray(sol["lam_x"]).ravel(),
                "lam_g": np.asarray(sol["lam_g"]).ravel(),
                "t0": t0,
            }
            T = U[0].copy()
            n = np.linalg.norm(T)
            if n > self.torque_limit:  # solver tolerance: never ask beyond the limit
                T *= self.torque_limit / n
            self.last_plan = (X, U)
            self.last_torque = T
        self.last_t0 = t0
        self.record_command(t0, self.last_torque)
        return self.last_torque.copy()

    @property
    def predicted_tilt_rad(self) -> NDArray[np.float64]:
        """Tilt (rad) of every node of the last plan (NaN before the first solve)."""
        if self.last_plan is None:
            return np.full(self.N + 1, np.nan)
        X = self.last_plan[0]
        qn = X[:, :4] / np.linalg.norm(X[:, :4], axis=1, keepdims=True)
        return np.array([attitude.tilt(q) for q in qn])
