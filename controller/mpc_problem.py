"""The optimisation problem of the attitude MPC (``controller.mpc``): the prediction step, the
NLP over the horizon and its solver, the bounds and the decision vector's layout
(``MPCProblem``), and the stage and terminal weights from the bandwidth and damping
(``lqr_weights``, ``terminal_weight``). Model, cost and solver are described in
``controller.mpc``'s module docstring."""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from controller.codegen import compiled
from controller.mpc_config import MPCConfig
from plant.params import PlantParams
from plant.torque import worst_case_capacity
from plant.twin import CasadiTwin


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


class MPCProblem:
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
            functions["jac_fg"] = self.jac_fg_function(Phi)
            if self.config.hessian == "gauss_newton":
                functions["hess_lag"] = self.hess_gn
        loaded = compiled(list(functions.values()), "mpc")
        return {} if loaded is None else dict(zip(functions, loaded, strict=True))

    def jac_fg_function(self, Phi: ca.Function | None = None) -> ca.Function:
        """The SQP's derivatives as one function ``mpc_jac_fg`` (x, p) -> (f, grad_f_x, g,
        jac_g_x): the objective, its gradient, the constraints and their Jacobian, over the
        NLP whose shooting steps are calls of one step function ``Phi`` (default: this
        problem's, ``never_inline``; ``_compile`` says why). Every SQP iteration evaluates it
        once, at its iterate."""
        if Phi is None:
            Phi = self._shooting_step(self.config.step_s, self.config.rk4_substeps)
        x, T = ca.SX.sym("x", 7), ca.SX.sym("T", 3)
        step = ca.Function("mpc_phi", [x, T], [Phi(x, T)], {"never_inline": True})
        nlp = self._nlp_graph(step)[0]
        w, p, f, g = nlp["x"], nlp["p"], nlp["f"], nlp["g"]
        return ca.Function("mpc_jac_fg", [w, p], [f, ca.gradient(f, w), g, ca.jacobian(g, w)],
                           ["x", "p"], ["f", "grad_f_x", "g", "jac_g_x"])

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
