"""The attitude from ORB matches alone (seed 001 §4.2; the front end is ``observer.orb``).

``solve_attitude``: the attitude that minimises the reprojection error of the matched
rotor-frame points through the camera model (``plant.camera``: the rotor turns about its
centre, so only the three rotation parameters are free). A closed-form start
(``initial_attitude``: each viewing ray cut with the sphere on which its point must lie, then
the Kabsch rotation) and Gauss–Newton on a body-frame rotation vector with Huber weights; the
projection Jacobian comes from ``cv2.projectPoints`` (``project_with_jacobian``).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from observer.orb import normalised_rays
from observer.types import SolverResult
from plant import attitude
from plant.camera import Camera


def _kabsch(A: NDArray[np.float64], B: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation R (3x3) minimising sum |R a_i - b_i|^2 (about the origin)."""
    U, _, Vt = np.linalg.svd(B.T @ A)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def initial_attitude(
    cam: Camera, points_rotor_m: NDArray[np.float64], pixels_px: NDArray[np.float64]
) -> NDArray[np.float64] | None:
    """Closed-form attitude from points and pixels, or None if no ray meets its sphere.

    A rotation about the rotor centre O keeps each point's distance |P| to O, so the point seen
    at a pixel lies where that pixel's ray meets the sphere of radius |P| about O (the nearer
    intersection: the print faces the camera). The Kabsch rotation then maps the rotor points
    onto those stator points.
    """
    d = normalised_rays(cam, pixels_px)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    C = cam.center_m
    r2 = np.sum(points_rotor_m**2, axis=1)
    b = d @ C
    disc = b * b - (C @ C - r2)
    ok = disc >= 0.0
    if ok.sum() < 3:
        return None
    t = -b[ok] - np.sqrt(disc[ok])
    X = C + t[:, None] * d[ok]
    return attitude.from_matrix(_kabsch(points_rotor_m[ok], X))


def _skew(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Skew matrices (N, 3, 3) of vectors (N, 3)."""
    z = np.zeros(len(v))
    return np.stack(
        [
            np.stack([z, -v[:, 2], v[:, 1]], -1),
            np.stack([v[:, 2], z, -v[:, 0]], -1),
            np.stack([-v[:, 1], v[:, 0], z], -1),
        ],
        axis=-2,
    )


def project_with_jacobian(
    cam: Camera, points_rotor_m: NDArray[np.float64], q: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pixels (N, 2), sensor px, of rotor points at attitude ``q`` and their Jacobian
    (N, 2, 3) with respect to a body-frame rotation vector ``delta`` (``q ⊗ exp(delta)``).

    ``X_c = R P - C``; ``dX_c/d delta = -R [P]x``; ``d uv / d X_c`` is OpenCV's Jacobian with
    respect to the translation (``cv2.projectPoints`` at zero rotation and translation)."""
    R = attitude.to_matrix(q)
    Xc = points_rotor_m @ R.T - cam.center_m
    uv, jac = cv2.projectPoints(
        Xc.reshape(-1, 1, 3),
        np.zeros(3),
        np.zeros(3),
        cam.matrix(1),
        np.asarray(cam.params.dist_coeffs, dtype=float),
    )
    n = len(Xc)
    d_uv_dX = jac[:, 3:6].reshape(n, 2, 3)
    dX_dd = -R[None] @ _skew(points_rotor_m)
    return uv.reshape(n, 2), d_uv_dX @ dX_dd


def solve_attitude(
    cam: Camera,
    points_rotor_m: ArrayLike,
    pixels_px: ArrayLike,
    sigma_px: ArrayLike | float = 1.0,
    q_init: ArrayLike | None = None,
    max_iter: int = 20,
    huber_k: float = 2.0,
    tol_rad: float = 1e-9,
) -> SolverResult:
    """Attitude minimising the weighted reprojection error of rotor points (N, 3), m, seen at
    sensor pixels (N, 2) (seed 001 Eq. 13 solved per frame: "ORB alone").

    Gauss–Newton on a body-frame rotation vector from ``q_init`` (default the closed form of
    ``initial_attitude``), with Huber weights (threshold ``huber_k`` sigma). The covariance is
    ``s² (J^T W J)^-1`` with s² the weighted residual variance (at least 1). Never raises on bad
    input: returns an invalid result with a reason.
    """
    P = np.asarray(points_rotor_m, dtype=float).reshape(-1, 3)
    z = np.asarray(pixels_px, dtype=float).reshape(-1, 2)
    sig = np.broadcast_to(np.asarray(sigma_px, dtype=float), (len(P),))
    ok = np.all(np.isfinite(P), axis=1) & np.all(np.isfinite(z), axis=1) & (sig > 0)
    if len(P) != len(z):
        return SolverResult.invalid(f"{len(P)} points but {len(z)} pixels")
    P, z, sig = P[ok], z[ok], sig[ok]
    if len(P) < 3:
        return SolverResult.invalid(f"too few points: {len(P)} (need 3)")
    q = initial_attitude(cam, P, z) if q_init is None else attitude.normalize(q_init, "q_init")
    if q is None:
        return SolverResult.invalid("no viewing ray meets its point's sphere")
    w_sig = 1.0 / sig**2
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007
        uv, J = project_with_jacobian(cam, P, q)
        r = z - uv
        norm_r = np.linalg.norm(r, axis=1) / sig
        w = w_sig * np.where(norm_r <= huber_k, 1.0, huber_k / np.maximum(norm_r, 1e-12))
        JtW = np.einsum("nki,n->ink", J, w).reshape(3, -1)
        A = JtW @ J.reshape(-1, 3)
        delta = np.linalg.solve(A, JtW @ r.reshape(-1))
        q = attitude.multiply(q, attitude.from_rotvec(delta))
        q /= np.linalg.norm(q)
        if np.linalg.norm(delta) < tol_rad:
            break
    uv, J = project_with_jacobian(cam, P, q)
    r = z - uv
    A = np.einsum("nki,n,nkj->ij", J, w_sig, J)
    dof = max(2 * len(P) - 3, 1)
    s2 = max(1.0, float(np.sum(w_sig[:, None] * r**2) / dof))
    cov = s2 * np.linalg.inv(A)
    rms = float(np.sqrt(np.mean(np.sum(r**2, axis=1))))
    if q[0] < 0:
        q = -q
    return SolverResult(q=q, covariance=cov, valid=True, residual_rms_px=rms, iterations=it)
