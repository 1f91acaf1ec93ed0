"""Centre-of-rotation constrained least-squares attitude (seed 002 §2.4, App. A).

The markers move on spheres about a fixed CoR, so the attitude is the only unknown: three
parameters, not the six of a PnP pose. We minimise the reprojection error (seed 002 eq. 12–16)

    q* = argmin_q Σ_j |uv_j^meas − π(R(q) P_j + t_cor)|²

over the modified Rodrigues parameters p of a multiplicative update ``q = q_ref ⊗ q(p)``
(``observer.cor_model``), re-centred after every accepted step so that each iteration solves
for a small p about the current estimate. Each step is a Levenberg–Marquardt step
``(JᵀJ + λ diag(JᵀJ)) Δp = Jᵀ r`` with the analytic Jacobian J (seed 002 eq. 17 is the λ = 0
Gauss–Newton step; the damping only acts when a step would increase the cost, so a warm start
converges like Gauss–Newton).

Covariance. At the solution the body-frame rotation vector is δ = 4p + O(p³), so the Jacobian
with respect to δ is ``J_δ = J_p/4`` and, for independent pixel noise of σ px per coordinate,
``Cov(δ) = σ² (J_δᵀ J_δ)⁻¹ = 16 σ² (J_pᵀ J_p)⁻¹`` (rad², body frame, ``q_true = q ⊗ exp(δ)``), the
convention of ``observer.types.SolverResult``. σ is the configured pixel noise (default 0.5 px,
our choice), or, with ``sigma_px=None``, the a-posteriori estimate ``|r|²/(m − 3)`` (seed 002
eq. 24), which is very noisy with two markers (one degree of freedom).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from observer.cor_model import CorModel
from observer.types import SolverResult


@dataclass(frozen=True)
class CorSolverConfig:
    """Settings of ``CorSolver`` (all our choices; units in the names).

    sigma_px : pixel noise σ for the covariance, px per coordinate; None = estimate it from the
        residual (needs more than 3 measurements).
    max_iterations : LM iterations before giving up ("did not converge").
    step_tol_rad : converged when the next step would rotate by less than this (rad), or when a
        step smaller than 100× this fails to lower the cost (round-off; 1e-8 rad is 2 mas, four
        orders of magnitude below the noise-induced error at 0.5 px).
    max_residual_rms_px : a solution whose RMS residual exceeds this is flagged invalid
        (mismatched markers, wrong model or a local minimum).
    max_tilt_rad : a solution tilted more than this from stator Z is flagged invalid (the far-side
        mirror solution of the ray–sphere intersection); default 45°, three times the
        mechanical stop of seed 000 §2.4.
    max_condition : JᵀJ with a larger condition number is flagged ill-conditioned.
    """

    sigma_px: float | None = 0.5
    max_iterations: int = 30
    step_tol_rad: float = 1e-8
    max_residual_rms_px: float = 5.0
    max_tilt_rad: float = float(np.deg2rad(45.0))
    max_condition: float = 1e12

    def __post_init__(self) -> None:
        if self.sigma_px is not None and not (np.isfinite(self.sigma_px) and self.sigma_px > 0):
            raise ValueError(f"sigma_px must be > 0 px or None, got {self.sigma_px!r}")
        if int(self.max_iterations) < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations!r}")
        for name in ("step_tol_rad", "max_residual_rms_px", "max_tilt_rad", "max_condition"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite positive number, got {v!r}")


def _tilt(q: NDArray[np.float64]) -> float:
    """Angle (rad) between the rotor z axis and stator Z."""
    w, x, y, _ = q
    c = 1.0 - 2.0 * (x * x + y * y)
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


@njit(cache=True)
def _qmul(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Hamilton product of two single quaternions (w, x, y, z) (compiled: the iteration uses
    it too)."""
    aw, ax, ay, az = a[0], a[1], a[2], a[3]
    bw, bx, by, bz = b[0], b[1], b[2], b[3]
    return np.array([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ])


def _axis_quat(axis: int, angle: float) -> NDArray[np.float64]:
    q = np.zeros(4)
    q[0] = np.cos(0.5 * angle)
    q[1 + axis] = np.sin(0.5 * angle)
    return q


# --- the compiled iteration ----------------------------------------------------------------
# numba-compiled (cached on disk): one frame's Levenberg–Marquardt iteration is a few hundred
# flops on 3-vectors, where numpy's per-call overhead dominated. ``intr`` is
# (fx, fy, cx, cy, k1, k2, k3); the status codes of ``_lm`` are below.
_CONVERGED, _SINGULAR, _NOT_CONVERGED = 0, 1, 2


@njit(cache=True)
def _residual_jac(q, P, uv, t_cor, intr):
    """Residual r = uv_meas − uv(q) (2n,) and J = ∂uv/∂p at p = 0 about q (2n, 3) for the
    markers P (n, 3), m, and their pixels uv (n, 2).

    The same model as ``CorModel.jacobian_mrp`` written out: with g = ∂u/∂X (a row) and
    ``∂X/∂p = −4 R(q) [P]× = −4 [R P]× R``, ``∂u/∂p = −4 (g × R P)ᵀ R``. A marker behind the
    camera makes every residual NaN."""
    fx, fy, cx, cy, k1, k2, k3 = intr[0], intr[1], intr[2], intr[3], intr[4], intr[5], intr[6]
    w, x, y, z = q[0], q[1], q[2], q[3]
    # R(q) row by row, as floats (small arrays would cost an allocation each)
    R = (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
         2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
         2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))
    n = P.shape[0]
    res = np.empty(2 * n)
    J = np.empty((2 * n, 3))
    behind = False
    for j in range(n):
        RP0 = R[0] * P[j, 0] + R[1] * P[j, 1] + R[2] * P[j, 2]
        RP1 = R[3] * P[j, 0] + R[4] * P[j, 1] + R[5] * P[j, 2]
        RP2 = R[6] * P[j, 0] + R[7] * P[j, 1] + R[8] * P[j, 2]
        X0, X1, X2 = RP0 + t_cor[0], RP1 + t_cor[1], RP2 + t_cor[2]
        behind = behind or not X2 > 0.0
        iz = 1.0 / X2
        xn, yn = X0 * iz, X1 * iz
        r2 = xn * xn + yn * yn
        s = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        ds = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3)
        res[2 * j] = uv[j, 0] - (fx * s * xn + cx)
        res[2 * j + 1] = uv[j, 1] - (fy * s * yn + cy)
        c = 2.0 * xn * yn * ds
        a11, a12 = fx * (s + 2.0 * xn * xn * ds) * iz, fx * c * iz
        a21, a22 = fy * c * iz, fy * (s + 2.0 * yn * yn * ds) * iz
        for row, g0, g1 in ((2 * j, a11, a12), (2 * j + 1, a21, a22)):
            g2 = -(g0 * xn + g1 * yn)
            e0 = g1 * RP2 - g2 * RP1  # g × RP
            e1 = g2 * RP0 - g0 * RP2
            e2 = g0 * RP1 - g1 * RP0
            for k in range(3):
                J[row, k] = -4.0 * (e0 * R[k] + e1 * R[3 + k] + e2 * R[6 + k])
    if behind:
        res[:] = np.nan
    return res, J


@njit(cache=True)
def normal_equations(J, r):
    """JᵀJ (3×3) and Jᵀr (3,) of the Jacobian J (m, 3) and residual r (m,), summed in loops
    (a BLAS call costs more than these few products)."""
    H = np.zeros((3, 3))
    g = np.zeros(3)
    for i in range(J.shape[0]):
        for a in range(3):
            g[a] += J[i, a] * r[i]
            for b in range(a, 3):
                H[a, b] += J[i, a] * J[i, b]
    for a in range(3):
        for b in range(a):
            H[a, b] = H[b, a]
    return H, g


@njit(cache=True)
def condition_number(H):
    """The 2-norm condition number of a symmetric positive semi-definite 3×3 matrix H: its
    largest over its smallest eigenvalue, inf when the smallest is not positive.

    The eigenvalues come from cyclic Jacobi rotations (Golub & Van Loan, Matrix Computations,
    4th ed., §8.5.2-8.5.3): each rotation zeroes one off-diagonal element with
    t = sgn(θ)/(|θ| + √(θ² + 1)), θ = (a_qq − a_pp)/(2 a_pq), until the off-diagonal part
    is below round-off of the diagonal. Their absolute error is of the order of ε‖H‖, as for
    the SVD that ``numpy.linalg.cond`` takes."""
    a = H.copy()
    for _ in range(60):
        off = a[0, 1] * a[0, 1] + a[0, 2] * a[0, 2] + a[1, 2] * a[1, 2]
        diag = a[0, 0] * a[0, 0] + a[1, 1] * a[1, 1] + a[2, 2] * a[2, 2]
        if not off > 1e-36 * diag:
            break
        for p, q, r in ((0, 1, 2), (0, 2, 1), (1, 2, 0)):
            if a[p, q] == 0.0:
                continue
            theta = (a[q, q] - a[p, p]) / (2.0 * a[p, q])
            t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
            c = 1.0 / np.sqrt(t * t + 1.0)
            s = t * c
            a[p, p] -= t * a[p, q]
            a[q, q] += t * a[p, q]
            a[p, q] = a[q, p] = 0.0
            arp, arq = a[r, p], a[r, q]
            a[r, p] = a[p, r] = c * arp - s * arq
            a[r, q] = a[q, r] = s * arp + c * arq
    lo = min(a[0, 0], a[1, 1], a[2, 2])
    hi = max(a[0, 0], a[1, 1], a[2, 2])
    return hi / lo if lo > 0.0 else np.inf


@njit(cache=True)
def _solve3(A, b):
    """x with A x = b for a 3×3 A (Gaussian elimination with partial pivoting); ``ok`` is False
    when a pivot is exactly zero (singular, as LAPACK's getrf reports it)."""
    M = A.copy()
    x = b.copy()
    for k in range(3):
        p = k + np.argmax(np.abs(M[k:, k]))
        if M[p, k] == 0.0:
            return x, False
        if p != k:
            for c in range(3):
                M[k, c], M[p, c] = M[p, c], M[k, c]
            x[k], x[p] = x[p], x[k]
        for r in range(k + 1, 3):
            f = M[r, k] / M[k, k]
            for c in range(k, 3):
                M[r, c] -= f * M[k, c]
            x[r] -= f * x[k]
    for k in range(2, -1, -1):
        acc = x[k]
        for c in range(k + 1, 3):
            acc -= M[k, c] * x[c]
        x[k] = acc / M[k, k]
    return x, True


@njit(cache=True)
def _lm(q, P, uv, t_cor, intr, max_iterations, step_tol):
    """The damped Gauss–Newton iteration of ``CorSolver.solve`` from the attitude q (finite
    residuals at q). Returns (q, status, iterations, cost, J at q)."""
    r, J = _residual_jac(q, P, uv, t_cor, intr)
    cost = r @ r
    lam = 1e-6
    it = 0
    for it in range(1, max_iterations + 1):
        H, g = normal_equations(J, r)
        A = H.copy()
        for k in range(3):
            A[k, k] += lam * H[k, k]
        dp, ok = _solve3(A, g)
        if not ok:
            return q, _SINGULAR, it, cost, J
        step = 4.0 * np.sqrt(dp @ dp)  # rotation angle of q(dp), rad (small dp)
        if step < step_tol:
            return q, _CONVERGED, it, cost, J  # the next step would rotate by less
        sq = dp @ dp  # q ⊗ q(dp), q(p) = ((1 − |p|²), 2p)/(1 + |p|²) (cor_model.mrp_to_quat)
        q_new = _qmul(q, np.array([1.0 - sq, 2.0 * dp[0], 2.0 * dp[1], 2.0 * dp[2]]) / (1.0 + sq))
        r_new, J_new = _residual_jac(q_new, P, uv, t_cor, intr)
        cost_new = r_new @ r_new if np.all(np.isfinite(r_new)) else np.inf
        if cost_new <= cost:
            q, r, J, cost = q_new, r_new, J_new, cost_new
            lam = max(lam / 10.0, 1e-12)
        else:
            lam *= 10.0
            if step < 100.0 * step_tol or lam > 1e8:
                return q, _CONVERGED, it, cost, J  # no step lowers the cost beyond round-off
    return q, _NOT_CONVERGED, it, cost, J


#: Why a solve is invalid after its start was accepted, by code, with the number each text
#: needs (``failure_reason``).
BEHIND_CAMERA, DEGENERATE, NOT_CONVERGED, ILL_CONDITIONED, RESIDUAL_TOO_LARGE, FAR_SIDE = range(6)


def failure_reason(code: int, value: float, config: CorSolverConfig) -> str:
    """The ``SolverResult.reason`` of an invalid solve: ``code`` one of the constants above,
    ``value`` the condition number of JᵀJ, the RMS residual (px) or the solution's tilt (rad)
    for the codes that report one."""
    if code == BEHIND_CAMERA:
        return "start attitude projects markers behind the camera"
    if code == DEGENERATE:
        return "singular normal equations (markers degenerate)"
    if code == NOT_CONVERGED:
        return f"did not converge in {config.max_iterations} iterations"
    if code == ILL_CONDITIONED:
        return f"ill-conditioned geometry (cond(JᵀJ) = {value:.3g})"
    if code == RESIDUAL_TOO_LARGE:
        return f"diverged: residual RMS {value:.3g} px > {config.max_residual_rms_px} px"
    return f"solution tilt {np.rad2deg(value):.1f}° beyond max_tilt_rad (far-side solution)"


class CorSolver:
    """CoR-constrained attitude solver (seed 002 §2.4) as an ``AttitudeSolver``.

    ``solve(marker_px, q_prev)``: ``marker_px`` is (N, 2), sensor px, rows in the order of
    ``model.markers_m``; rows with NaN or infinite entries are missing markers and are dropped.
    ``q_prev`` (w, x, y, z) warm-starts the iteration; without it (or if it is not a finite unit
    quaternion) ``coarse_guess`` supplies a cold start.
    """

    def __init__(self, model: CorModel, config: CorSolverConfig | None = None) -> None:
        self.model = model
        self.config = CorSolverConfig() if config is None else config
        intr = model.intrinsics
        self._intr = np.array([intr.fx, intr.fy, intr.cx, intr.cy, intr.k1, intr.k2, intr.k3])
        self._t_cor = np.asarray(model.t_cor_m, dtype=float)

    # -- cold start ---------------------------------------------------------------------------

    def coarse_guess(self, marker_px: NDArray[np.float64], mask: NDArray[np.bool_]) -> NDArray:
        """A cold-start attitude from the visible markers (our construction, any N ≥ 2).

        1. Turn about the camera axis: the 2-D Procrustes angle between the visible markers'
           pixels and their projections at the identity, both centred on their centroids (a turn
           about stator +Z turns the image from +u toward +v in our camera).
        2. Tilt: the centroid's pixel shift left over after that turn, scaled to metres at the
           CoR depth (Z/f), is the lateral motion of the markers' centroid, ``−r sin β (cos γ,
           sin γ)`` with r its distance from the CoR; hence β and γ.
        Good to a few degrees over the workspace; the LM iteration does the rest.
        """
        m = self.model
        meas = marker_px[mask]
        P = m.markers_m[mask]
        zero = np.zeros_like(meas)
        pred = -self._residual_jac(np.array([1.0, 0.0, 0.0, 0.0]), P, zero)[0].reshape(-1, 2)
        a = meas - meas.mean(axis=0)
        b = pred - pred.mean(axis=0)
        cross = np.sum(b[:, 0] * a[:, 1] - b[:, 1] * a[:, 0])
        dot = np.sum(b * a)
        q_spin = _axis_quat(2, float(np.arctan2(cross, dot)))
        pred_spin = -self._residual_jac(q_spin, P, zero)[0].reshape(-1, 2)
        shift = meas.mean(axis=0) - pred_spin.mean(axis=0)
        Z = m.t_cor_m[2]
        lateral = shift * Z / np.array([m.intrinsics.fx, m.intrinsics.fy])
        r = float(np.linalg.norm(P.mean(axis=0)))
        s = min(float(np.linalg.norm(lateral)) / max(r, 1e-9), np.sin(self.config.max_tilt_rad))
        beta = float(np.arcsin(s))
        gamma = float(np.arctan2(-lateral[1], -lateral[0]))
        # pure tilt toward azimuth gamma: Rz(gamma) Ry(beta) Rz(-gamma)
        q_tilt = _qmul(_axis_quat(2, gamma), _qmul(_axis_quat(1, beta), _axis_quat(2, -gamma)))
        return _qmul(q_tilt, q_spin)

    # -- one frame ----------------------------------------------------------------------------

    def _residual_jac(self, q: NDArray, P: NDArray, uv: NDArray) -> tuple[NDArray, NDArray]:
        """Residual (2n,) and Jacobian (2n, 3) at q for the markers P (n, 3) and their pixels
        uv (n, 2) (the compiled ``_residual_jac`` with this model)."""
        return _residual_jac(np.asarray(q, dtype=float), np.ascontiguousarray(P),
                             np.ascontiguousarray(uv, dtype=float), self._t_cor, self._intr)

    def solve(
        self, marker_px: NDArray[np.float64], q_prev: NDArray[np.float64] | None = None
    ) -> SolverResult:
        """Attitude from marker pixels; never raises on bad input (see the class docstring).

        Mirrored in ``latency.compiled.observer._solve``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        cfg = self.config
        try:
            uv = np.asarray(marker_px, dtype=float)
        except (TypeError, ValueError):
            return SolverResult.invalid("marker_px is not a numeric array")
        n_model = self.model.n_markers
        if uv.shape != (n_model, 2):
            return SolverResult.invalid(
                f"marker_px must have shape ({n_model}, 2) for this target, got {uv.shape}"
            )
        mask = np.all(np.isfinite(uv), axis=1)
        n_vis = int(mask.sum())
        if n_vis < 2:
            return SolverResult.invalid(
                f"{n_vis} marker(s) visible: the attitude needs at least 2 (3 unknowns)"
            )
        P = self.model.markers_m[mask]
        uv_v = uv[mask]

        q = None
        if q_prev is not None:
            qp = np.asarray(q_prev, dtype=float)
            if qp.shape == (4,) and np.all(np.isfinite(qp)) and abs(np.linalg.norm(qp) - 1) < 1e-3:
                q = qp / np.linalg.norm(qp)
        if q is None:
            q = self.coarse_guess(uv, mask)

        r, _ = self._residual_jac(q, P, uv_v)
        if not np.all(np.isfinite(r)):
            return SolverResult.invalid(failure_reason(BEHIND_CAMERA, np.nan, cfg))
        q, status, it, cost, J = _lm(q, P, np.ascontiguousarray(uv_v), self._t_cor, self._intr,
                                     int(cfg.max_iterations), float(cfg.step_tol_rad))
        if status == _SINGULAR:
            return SolverResult(
                q=np.full(4, np.nan), valid=False, iterations=it,
                reason=failure_reason(DEGENERATE, np.nan, cfg),
            )
        if status == _NOT_CONVERGED:
            return SolverResult(
                q=np.full(4, np.nan), valid=False, iterations=it,
                reason=failure_reason(NOT_CONVERGED, np.nan, cfg),
                residual_rms_px=float(np.sqrt(cost / len(r))),
            )
        q = q / np.linalg.norm(q)
        if q[0] < 0:
            q = -q
        rms = float(np.sqrt(cost / len(r)))
        H, _ = normal_equations(J, r)
        cond = float(condition_number(H))
        if not np.isfinite(cond) or cond > cfg.max_condition:
            return SolverResult(
                q=np.full(4, np.nan), valid=False, iterations=it, residual_rms_px=rms,
                reason=failure_reason(ILL_CONDITIONED, cond, cfg),
            )
        if cfg.sigma_px is None:
            dof = len(r) - 3
            sigma2 = cost / dof if dof > 0 else np.nan
        else:
            sigma2 = cfg.sigma_px**2
        cov = 16.0 * sigma2 * np.linalg.inv(H)
        if rms > cfg.max_residual_rms_px:
            return SolverResult(
                q=np.full(4, np.nan), valid=False, iterations=it, residual_rms_px=rms,
                covariance=cov,
                reason=failure_reason(RESIDUAL_TOO_LARGE, rms, cfg),
            )
        if _tilt(q) > cfg.max_tilt_rad:
            return SolverResult(
                q=np.full(4, np.nan), valid=False, iterations=it, residual_rms_px=rms,
                reason=failure_reason(FAR_SIDE, _tilt(q), cfg),
            )
        return SolverResult(q=q, covariance=cov, residual_rms_px=rms, iterations=it)
