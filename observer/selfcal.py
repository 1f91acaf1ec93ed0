"""Batch self-calibration of the CoR camera model from frames at unknown attitudes
(seed 002 §2.5, App. B).

Unknowns: the seven optical parameters (fx, fy, cx, cy, k1, k2, k3), the CoR in the camera frame
``t_cor`` (3), the marker positions ``P_j`` in the rotor frame (3N, less the gauge), and one
attitude per frame (3M, modified Rodrigues parameters about a per-frame reference, as in
``observer.cor_model``). Measurements: the 2 pixel coordinates of every visible marker in every
frame. The cost is the sum of squared reprojection errors (seed 002 eq. 18–19), minimised by
Levenberg–Marquardt on the analytic Jacobian (seed 002 eq. 20, App. B). The Jacobian is sparse:
a frame's residuals depend on the shared parameters and on that frame's three attitude
parameters only, so each step eliminates the 3 × 3 attitude blocks with a Schur complement and
solves a small system in the shared parameters (``SelfCalProblem.jacobian_sparse`` assembles
the full sparse matrix for checks).

Gauge. The reprojections do not change if the rotor frame is rotated (``P_j → G P_j``,
``q_i → q_i ⊗ G⁻¹``: 3 freedoms) or if the whole scene is scaled about the optical centre
(``P_j → s P_j``, ``t_cor → s t_cor``: 1 freedom; a single camera sees no absolute size). We fix
these four explicitly by holding the in-plate coordinates (x, y) of the first two markers (red
and yellow) at their printed values: they fix the body x axis (red → yellow, so spin 0 keeps
the seed's meaning), the zero of the rotation about x and y together with the depths left free,
and the scale through the printed distance L (seed 000 §3.2.2). Their z coordinates (the plate's
distance from the CoR, i.e. R) stay free. With only the seed's two markers, 4 measurements per
frame against 3 attitude unknowns leave one equation per frame for the 12 shared unknowns: the
problem is formally determined for enough frames but so badly conditioned that it is useless in
practice (``predicted_sigma``: fx to tens of percent, t_cor to centimetres; docs/solvers.md), so
``self_calibrate`` requires at least 3 markers and we use the six-marker ``SELFCAL_OFFSETS_MM``
target.

Uncertainties (seed 002 eq. 22–24): ``C = σ̂² (JᵀJ)⁻¹`` with ``σ̂² = |r|²/(m − n)``; for the shared
parameters this is σ̂² times the inverse of the Schur complement, so the attitude unknowns are
accounted for.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray

from observer.cor_model import (
    INTRINSIC_NAMES,
    CorModel,
    Intrinsics,
    dquat_dmrp,
    drotate_dquat,
    mrp_to_quat,
    project_camera_points,
    quat_matrix,
    quat_mul,
)
from observer.cor_solver import CorSolver, CorSolverConfig
from plant.params import PlantParams

#: Our self-calibration target: in-plate (x, y) offsets (mm) from the bottom pole on the VFC plate.
#: The seed's red and yellow markers first (the diagonal of the 20 mm square, L = 28.28 mm), then
#: four more at the corners of a 36 mm square (8 mm discs stay on the 50 mm plate). Our choice.
SELFCAL_OFFSETS_MM = (
    (-14.142135623730951, 0.0),
    (14.142135623730951, 0.0),
    (18.0, 18.0),
    (-18.0, 18.0),
    (-18.0, -18.0),
    (18.0, -18.0),
)
#: Marker coordinates fixed by the gauge: (marker index, axis index) — red x, y and yellow x, y.
DEFAULT_GAUGE = ((0, 0), (0, 1), (1, 0), (1, 1))
_AXES = "xyz"


def selfcal_markers(p: PlantParams, offsets_mm: ArrayLike = SELFCAL_OFFSETS_MM) -> NDArray:
    """Marker positions (N, 3), m, rotor frame, of a multi-marker VFC at z = −R."""
    xy = np.asarray(offsets_mm, dtype=float) / 1000.0
    return np.column_stack([xy, np.full(len(xy), -p.rotor.radius_m)])


@dataclass(frozen=True)
class SelfCalResult:
    """Outcome of ``self_calibrate``.

    Attributes
    ----------
    model : the calibrated ``CorModel`` (intrinsics, t_cor, markers).
    q : (M, 4) per-frame attitudes (w, x, y, z).
    names : names of the shared parameters, e.g. "fx", "t_cor_z", "P3_y".
    values : (n,) their estimates (px, dimensionless, m as the name implies).
    covariance : (n, n) their covariance ``σ̂² S⁻¹`` (units² accordingly).
    sigma : name → 1σ uncertainty.
    attitude_covariance : (M, 3, 3) body rotation-vector covariance of each frame, rad².
    sigma_px : a-posteriori pixel noise σ̂ (seed 002 eq. 24), px.
    residual_rms_px : RMS reprojection residual, px.
    iterations, converged, reason : solver status ("" when converged).
    """

    model: CorModel
    q: NDArray[np.float64]
    names: tuple[str, ...]
    values: NDArray[np.float64]
    covariance: NDArray[np.float64]
    sigma: dict[str, float]
    attitude_covariance: NDArray[np.float64]
    sigma_px: float
    residual_rms_px: float
    iterations: int
    converged: bool
    reason: str = ""


@dataclass
class SelfCalProblem:
    """The least-squares problem of one calibration batch (see the module docstring).

    marker_px : (M, N, 2) measured pixels, NaN rows = not seen.
    model0 : initial guess; its markers' gauge coordinates are held fixed.
    q_ref : (M, 4) reference attitudes; frame i's attitude is ``q_ref[i] ⊗ q(p_i)``.
    gauge : fixed (marker, axis) coordinates.
    fixed_intrinsics : names from ``INTRINSIC_NAMES`` to hold at model0's values.
    """

    marker_px: NDArray[np.float64]
    model0: CorModel
    q_ref: NDArray[np.float64]
    gauge: tuple[tuple[int, int], ...] = DEFAULT_GAUGE
    fixed_intrinsics: tuple[str, ...] = ()
    _free_intr: NDArray[np.int64] = field(init=False, repr=False)
    _free_P: NDArray[np.bool_] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        uv = np.asarray(self.marker_px, dtype=float)
        M, N = self.q_ref.shape[0], self.model0.n_markers
        if uv.shape != (M, N, 2):
            raise ValueError(f"marker_px must have shape (M={M}, N={N}, 2), got {uv.shape}")
        if N < 2:
            raise ValueError(f"model0.markers_m has {N} marker(s): need at least 2")
        for name in self.fixed_intrinsics:
            if name not in INTRINSIC_NAMES:
                raise ValueError(f"fixed_intrinsics: unknown name {name!r}")
        free_P = np.ones((N, 3), dtype=bool)
        for j, a in self.gauge:
            if not (0 <= j < N and 0 <= a < 3):
                raise ValueError(f"gauge entry {(j, a)} out of range for {N} markers")
            free_P[j, a] = False
        self.marker_px = uv
        self._free_intr = np.array(
            [k for k, n in enumerate(INTRINSIC_NAMES) if n not in self.fixed_intrinsics], int
        )
        self._free_P = free_P
        self.mask = np.all(np.isfinite(uv), axis=2)
        n_meas = 2 * int(self.mask.sum())
        if n_meas <= self.n_params:
            raise ValueError(
                f"marker_px has {n_meas} finite measurements for {self.n_params} unknowns: "
                "need more frames or markers"
            )

    # -- parameter vector ---------------------------------------------------------------------

    @property
    def n_shared(self) -> int:
        """Number of parameters shared by all frames: the free intrinsics, the centre of rotation
        (3) and the free marker coordinates."""
        return len(self._free_intr) + 3 + int(self._free_P.sum())

    @property
    def n_params(self) -> int:
        """Length of the parameter vector: the shared parameters and a rotation vector (3) per
        frame."""
        return self.n_shared + 3 * self.q_ref.shape[0]

    def names(self) -> tuple[str, ...]:
        """Names of the shared parameters in vector order."""
        out = [INTRINSIC_NAMES[k] for k in self._free_intr] + ["t_cor_x", "t_cor_y", "t_cor_z"]
        for j, a in zip(*np.nonzero(self._free_P), strict=True):
            out.append(f"P{j}_{_AXES[a]}")
        return tuple(out)

    def x0(self) -> NDArray[np.float64]:
        """Initial parameter vector: model0's shared values, zero attitude updates."""
        m = self.model0
        return np.concatenate([
            m.intrinsics.as_array()[self._free_intr], m.t_cor_m, m.markers_m[self._free_P],
            np.zeros(3 * self.q_ref.shape[0]),
        ])

    def unpack(self, x: NDArray[np.float64]) -> tuple[Intrinsics, NDArray, NDArray, NDArray]:
        """x → (intrinsics, t_cor (3,), markers (N, 3), MRP (M, 3))."""
        nI = len(self._free_intr)
        ia = self.model0.intrinsics.as_array()
        ia[self._free_intr] = x[:nI]
        t = x[nI:nI + 3]
        P = self.model0.markers_m.copy()
        nP = int(self._free_P.sum())
        P[self._free_P] = x[nI + 3:nI + 3 + nP]
        p = x[self.n_shared:].reshape(-1, 3)
        return Intrinsics.from_array(ia), t, P, p

    # -- residuals and analytic Jacobian blocks -----------------------------------------------

    def blocks(self, x: NDArray[np.float64]):
        """Residuals and Jacobian blocks at x.

        Returns (r, Jg, Jf, frame): r (K, 2) = predicted − measured pixels of the K visible
        observations; Jg (K, 2, n_shared) their derivatives with respect to the shared
        parameters; Jf (K, 2, 3) with respect to their frame's MRP; frame (K,) frame indices.
        """
        intr, t, P, p = self.unpack(x)
        q = quat_mul(self.q_ref, mrp_to_quat(p))
        Rref = quat_matrix(self.q_ref)  # (M, 3, 3)
        R = quat_matrix(q)
        fi, mj = np.nonzero(self.mask)
        X = np.einsum("kab,kb->ka", R[fi], P[mj]) + t
        uv, duv_dX, duv_dI = project_camera_points(X, intr)
        r = uv - self.marker_px[fi, mj]
        K = len(fi)
        # shared: intrinsics, t_cor, free marker coordinates
        nI = len(self._free_intr)
        Jg = np.zeros((K, 2, self.n_shared))
        Jg[:, :, :nI] = duv_dI[:, :, self._free_intr]
        Jg[:, :, nI:nI + 3] = duv_dX
        duv_dP = duv_dX @ R[fi]  # (K, 2, 3)
        col = np.full(self._free_P.shape, -1)
        col[self._free_P] = nI + 3 + np.arange(int(self._free_P.sum()))
        for a in range(3):
            ok = col[mj, a] >= 0
            Jg[np.nonzero(ok)[0], :, col[mj[ok], a]] = duv_dP[ok, :, a]
        # frame attitude: ∂X/∂p = R_ref ∂(R(q(p)) P)/∂q ∂q/∂p
        dRP_dp = drotate_dquat(mrp_to_quat(p)[fi], P[mj]) @ dquat_dmrp(p)[fi]
        Jf = duv_dX @ (Rref[fi] @ dRP_dp)
        return r, Jg, Jf, fi

    def jacobian_sparse(self, x: NDArray[np.float64]) -> sp.csr_matrix:
        """The full Jacobian (2K, n_params) of the stacked residuals as a sparse matrix."""
        _, Jg, Jf, fi = self.blocks(x)
        K, ns = len(fi), self.n_shared
        rows_g = np.repeat(np.arange(2 * K), ns)
        cols_g = np.tile(np.arange(ns), 2 * K)
        rows_f = np.repeat(np.arange(2 * K), 3)
        cols_f = (ns + 3 * np.repeat(fi, 2)[:, None] + np.arange(3)).reshape(-1)
        data = np.concatenate([Jg.reshape(-1), Jf.reshape(-1)])
        rows = np.concatenate([rows_g, rows_f])
        cols = np.concatenate([cols_g, cols_f])
        return sp.csr_matrix((data, (rows, cols)), shape=(2 * K, self.n_params))

    def residuals(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Stacked residuals (2K,), predicted − measured, px."""
        return self.blocks(x)[0].reshape(-1)

    def normal_equations(self, x: NDArray[np.float64]):
        """(cost, A, B, D, gg, gf): ``JᵀJ = [[A, B], [Bᵀ, blockdiag(D)]]`` and ``Jᵀr = (gg, gf)``
        with B (M, n_shared, 3), D (M, 3, 3), gf (M, 3)."""
        r, Jg, Jf, fi = self.blocks(x)
        M, ns = self.q_ref.shape[0], self.n_shared
        A = np.einsum("kag,kah->gh", Jg, Jg)
        gg = np.einsum("kag,ka->g", Jg, r)
        B = np.zeros((M, ns, 3))
        np.add.at(B, fi, np.einsum("kag,kah->kgh", Jg, Jf))
        D = np.zeros((M, 3, 3))
        np.add.at(D, fi, np.einsum("kag,kah->kgh", Jf, Jf))
        gf = np.zeros((M, 3))
        np.add.at(gf, fi, np.einsum("kag,ka->kg", Jf, r))
        return float(np.sum(r * r)), A, B, D, gg, gf


def _schur_solve(A, B, D, gg, gf, lam):
    """Solve ``(H + λ diag H) δ = −g`` by eliminating the frame blocks; returns (δg, δf)."""
    Ad = A + lam * np.diag(np.diag(A))
    Dd = D + lam * np.einsum("mii->mi", D)[:, :, None] * np.eye(3)
    Dinv = np.linalg.inv(Dd)
    BDinv = B @ Dinv  # (M, ns, 3)
    S = Ad - np.einsum("mgi,mhi->gh", BDinv, B)
    rhs = -gg + np.einsum("mgi,mi->g", BDinv, gf)
    s = np.sqrt(np.maximum(np.diag(S), 1e-300))
    dg = np.linalg.solve(S / np.outer(s, s), rhs / s) / s
    df = -np.einsum("mij,mj->mi", Dinv, gf + np.einsum("mgi,g->mi", B, dg))
    return dg, df


def _shared_and_frame_covariance(A, B, D, sigma2):
    """σ² times the shared block S⁻¹ of (JᵀJ)⁻¹ (S the Schur complement) and the per-frame
    3 × 3 blocks ``σ² (D⁻¹ + D⁻¹ Bᵀ S⁻¹ B D⁻¹)``."""
    Dinv = np.linalg.inv(D)
    BDinv = B @ Dinv
    S = A - np.einsum("mgi,mhi->gh", BDinv, B)
    s = np.sqrt(np.diag(S))
    S_inv = np.linalg.inv(S / np.outer(s, s)) / np.outer(s, s)
    cov_f = sigma2 * (Dinv + np.einsum("mgi,gh,mhj->mij", BDinv, S_inv, BDinv))
    return sigma2 * S_inv, cov_f


def predicted_sigma(problem: SelfCalProblem, x: ArrayLike, sigma_px: float) -> dict[str, float]:
    """1σ of the shared parameters (name → value) predicted by the linearisation at x for σ px of
    pixel noise: the square roots of the diagonal of ``σ² S⁻¹``. Evaluated at the true
    parameters it is the Cramér–Rao bound of the calibration; it shows how well a target
    and a set of attitudes determine each parameter before any data are taken."""
    _, A, B, D, _, _ = problem.normal_equations(np.asarray(x, dtype=float))
    cov, _ = _shared_and_frame_covariance(A, B, D, sigma_px**2)
    return {n: float(np.sqrt(cov[k, k])) for k, n in enumerate(problem.names())}


def initial_attitudes(marker_px: ArrayLike, model0: CorModel) -> NDArray[np.float64]:
    """Per-frame starting attitudes (M, 4) from ``CorSolver`` with the initial model (the seed
    uses P3P with the initial camera parameters, §2.6); the residual and tilt gates are opened
    because the initial model is wrong by design. A frame that still fails gets the solver's
    coarse guess."""
    cfg = CorSolverConfig(max_residual_rms_px=1e9, max_tilt_rad=float(np.pi / 2))
    solver = CorSolver(model0, cfg)
    out = []
    for uv in np.asarray(marker_px, dtype=float):
        res = solver.solve(uv)
        if res.valid:
            out.append(res.q)
        else:
            mask = np.all(np.isfinite(uv), axis=1)
            out.append(solver.coarse_guess(uv, mask) if mask.sum() >= 2 else np.r_[1.0, 0, 0, 0])
    return np.array(out)


def self_calibrate(
    marker_px: ArrayLike,
    model0: CorModel,
    q0: ArrayLike | None = None,
    gauge: tuple[tuple[int, int], ...] = DEFAULT_GAUGE,
    fixed_intrinsics: tuple[str, ...] = (),
    max_iterations: int = 100,
    rel_tol: float = 1e-12,
) -> SelfCalResult:
    """Estimate the intrinsics, the CoR, the marker positions and the attitudes (seed 002 §2.5).

    Parameters
    ----------
    marker_px : (M, N, 2) marker pixels, sensor px, NaN where a marker was not seen.
    model0 : initial guess (manual measurements and the lens data sheet, seed 002 §2.6); its
        marker coordinates named in ``gauge`` are held fixed.
    q0 : (M, 4) initial attitudes; default ``initial_attitudes(marker_px, model0)``.
    gauge : fixed (marker, axis) coordinates, default red and yellow in-plate (x, y).
    fixed_intrinsics : intrinsic names to hold at model0's values.
    max_iterations, rel_tol : LM stops when an accepted step lowers the cost by less than
        ``rel_tol`` relative, or after ``max_iterations`` (then ``converged`` is False).

    Raises ValueError for inconsistent shapes, fewer than 3 markers or too few measurements.
    """
    if model0.n_markers < 3:
        raise ValueError(
            f"model0.markers_m has {model0.n_markers} markers: self-calibration needs >= 3 (with "
            "the seed's 2 the geometry is practically unidentifiable; use selfcal_markers)"
        )
    uv = np.asarray(marker_px, dtype=float)
    q_ref = initial_attitudes(uv, model0) if q0 is None else np.asarray(q0, dtype=float)
    if q_ref.ndim != 2 or q_ref.shape[1] != 4:
        raise ValueError(f"q0 must have shape (M, 4), got {q_ref.shape}")
    prob = SelfCalProblem(uv, model0, q_ref, tuple(gauge), tuple(fixed_intrinsics))
    ns = prob.n_shared
    x, cost, (A, B, D), it, converged = _levenberg_marquardt(prob, max_iterations, rel_tol)
    reason = "" if converged else f"did not converge in {max_iterations} iterations"
    # covariance (seed 002 eq. 22-24) from the undamped normal equations
    m_meas = 2 * int(prob.mask.sum())
    sigma2 = cost / (m_meas - prob.n_params)
    cov, cov_f = _shared_and_frame_covariance(A, B, D, sigma2)
    intr, t, P, p = prob.unpack(x)
    q = quat_mul(q_ref, mrp_to_quat(p))
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(q[:, :1] < 0, -q, q)
    # p is not 0 at the solution (q_ref is the start): map Cov(p) to the body rotation vector
    Jp = np.array([_drotvec_dmrp(pi) for pi in p])
    cov_body = Jp @ cov_f @ np.transpose(Jp, (0, 2, 1))
    names = prob.names()
    values = x[:ns]
    return SelfCalResult(
        model=CorModel(intr, t, P), q=q, names=names, values=values, covariance=cov,
        sigma={n: float(np.sqrt(cov[k, k])) for k, n in enumerate(names)},
        attitude_covariance=cov_body, sigma_px=float(np.sqrt(sigma2)),
        residual_rms_px=float(np.sqrt(cost / m_meas)), iterations=it, converged=converged,
        reason=reason,
    )


def _levenberg_marquardt(
    prob: SelfCalProblem, max_iterations: int, rel_tol: float,
) -> tuple[NDArray[np.float64], float, tuple[NDArray, NDArray, NDArray], int, bool]:
    """Levenberg-Marquardt on ``prob`` from its start ``x0``, each step solved by the Schur
    complement of the per-frame blocks (``_schur_solve``): a step is tried with the damping
    raised tenfold (at most 20 times) until it lowers the cost; it stops when no step does (a
    minimum), when an accepted step lowers the cost by less than ``rel_tol`` relative, or
    after ``max_iterations``. Returns the parameters, the cost (sum of squared residuals,
    px²), the undamped normal-equation blocks (A, B, D) at the parameters, the iterations
    and whether it converged."""
    x = prob.x0()
    cost, A, B, D, gg, gf = prob.normal_equations(x)
    lam, converged, it = 1e-3, False, 0
    for it in range(1, max_iterations + 1):  # noqa: B007
        accepted = False
        for _ in range(20):
            try:
                dg, df = _schur_solve(A, B, D, gg, gf, lam)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            x_new = x + np.concatenate([dg, df.reshape(-1)])
            r_new = prob.residuals(x_new)
            cost_new = float(r_new @ r_new) if np.all(np.isfinite(r_new)) else np.inf
            if cost_new < cost:
                accepted = True
                break
            lam *= 10.0
        if not accepted:
            converged = True  # no damped step lowers the cost: at a minimum
            break
        decrease = (cost - cost_new) / cost
        x = x_new
        cost, A, B, D, gg, gf = prob.normal_equations(x)
        lam = max(lam / 10.0, 1e-12)
        if decrease < rel_tol:
            converged = True
            break
    return x, cost, (A, B, D), it, converged


def _drotvec_dmrp(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """∂δ/∂p (3, 3) of the body-frame perturbation δ at ``q_ref ⊗ q(p)`` for a change of p:
    ``q(p + dp) = q(p) ⊗ exp(dδ)`` with ``dδ = 2 (q(p)⁻¹ ⊗ ∂q/∂p dp)_v``."""
    q = mrp_to_quat(p)
    dq = dquat_dmrp(p)  # (4, 3)
    qc = q * np.array([1.0, -1.0, -1.0, -1.0])
    cols = [2.0 * quat_mul(qc, dq[:, k])[1:] for k in range(3)]
    return np.column_stack(cols)
