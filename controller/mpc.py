"""Delay-aware nonlinear MPC of the rotor attitude with CasADi.

The settings are ``controller.mpc_config.MPCConfig``; the optimisation problem (the prediction,
the NLP and its solver) is ``controller.mpc_problem.MPCProblem``; this module is the controller:
the warm start, the delay compensation and the command history of one controller object.

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
The CasADi side (twins, NLP, solver, bounds: ``controller.mpc_problem.MPCProblem``) keeps no
state between solves, so controllers with the same problem settings (the fields outside
``RUNTIME_FIELDS``) and plant share one, built once per process (``shared_problem``). With
``codegen`` the SQP's Jacobian and Hessian and the prediction's RK4 chunk run as machine code
compiled once and cached on disk (``controller.codegen``); they are the same functions to
rounding (docs/controllers.md).

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

import numpy as np
from numpy.typing import ArrayLike, NDArray

from controller.base import Controller, Reference
from controller.mpc_config import RUNTIME_FIELDS, MPCConfig
from controller.mpc_problem import MPCProblem
from controller.pid import (
    RateFromAttitude,
    estimate_usable,
)
from plant import attitude
from plant.estimate import Estimate
from plant.params import PlantParams


def shared_problem(config: MPCConfig, params: PlantParams) -> MPCProblem:
    """The ``MPCProblem`` of ``config`` (its fields outside ``RUNTIME_FIELDS``) on ``params``,
    built once per process and shared (the 16 most recently used are kept)."""
    key = json.dumps([config.model_dump(mode="json", exclude=set(RUNTIME_FIELDS)),
                      params.model_dump(mode="json")], sort_keys=True)
    return _problem_of(key)


@functools.lru_cache(maxsize=16)
def _problem_of(key: str) -> MPCProblem:
    config, params = json.loads(key)
    return MPCProblem(MPCConfig.model_validate(config), PlantParams.model_validate(params))


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
