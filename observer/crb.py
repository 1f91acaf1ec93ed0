"""Cramér–Rao bound of the attitude from marker pixels with Gaussian pixel noise.

For pixels ``uv = π(q) + n``, n ~ N(0, σ² I) per coordinate, and the attitude perturbed as
``q ⊗ exp(δ)`` (δ the body-frame rotation vector, rad), the Fisher information is
``Jᵀ J / σ²`` with J = ∂uv/∂δ at the true attitude (``CorModel.jacobian_rotvec``), so any
unbiased estimator has ``Cov(δ) ⪰ σ² (Jᵀ J)⁻¹``. The intrinsics, CoR and marker positions are
taken as known (the attitude solver's setting; seed 002 §2.4).

Three ways to report the bound, each named for what it is:

* ``crb_body``: δ in the rotor (body) frame — the convention of ``SolverResult.covariance``.
* ``crb_camera``: the same error expressed in the camera frame (= stator frame here, R_cs = I),
  ``δ_c = R(q) δ``. Its z component is the rotation *about boresight*, x and y are
  *cross-boresight* (seed 002 §3.5's split).
* ``crb_zyz``: the seed's spin α, tilt β and yaw γ (``plant.attitude``, Z-Y-Z), through the
  Jacobian of the angles with respect to δ (``zyz_jacobian``). This map is singular at β = 0
  (only α + γ is defined there), so per-angle bounds on α and γ grow like 1/sin β; use them away
  from β = 0 (our tests use β ≥ 2°).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from observer.cor_model import CorModel, quat_matrix
from plant import attitude


def fisher_information(model: CorModel, q: ArrayLike, sigma_px: float) -> NDArray[np.float64]:
    """Fisher information (3, 3), rad⁻², of the body rotation vector δ at attitude q, for σ px of
    independent Gaussian noise on every pixel coordinate of every marker of ``model``."""
    if not (np.isfinite(sigma_px) and sigma_px > 0):
        raise ValueError(f"sigma_px must be > 0 px, got {sigma_px!r}")
    J = model.jacobian_rotvec(np.asarray(q, dtype=float))
    return J.T @ J / sigma_px**2


def crb_body(model: CorModel, q: ArrayLike, sigma_px: float) -> NDArray[np.float64]:
    """CRB (3, 3), rad², of the body-frame rotation-vector error: ``σ² (JᵀJ)⁻¹``."""
    return np.linalg.inv(fisher_information(model, q, sigma_px))


def crb_camera(model: CorModel, q: ArrayLike, sigma_px: float) -> NDArray[np.float64]:
    """CRB (3, 3), rad², of the error rotation vector in camera (= stator) axes:
    ``R(q) C_body R(q)ᵀ``; index 2 is about boresight, 0 and 1 cross-boresight."""
    R = quat_matrix(np.asarray(q, dtype=float))
    return R @ crb_body(model, q, sigma_px) @ R.T


def zyz_jacobian(q: ArrayLike) -> NDArray[np.float64]:
    """∂(α, β, γ)/∂δ (3, 3) at q, δ the body-frame rotation vector of ``q ⊗ exp(δ)``.

    With ``R = Rz(γ) Ry(β) Rz(α)`` the stator-frame angular velocity is
    ``ω_s = α̇ Rz(γ)Ry(β) e_z + β̇ Rz(γ) e_y + γ̇ e_z = E (α̇, β̇, γ̇)``, with the columns of E
    ``(sβ cγ, sβ sγ, cβ)``, ``(−sγ, cγ, 0)``, ``(0, 0, 1)``; and ``ω_s = R ω_body``. Hence
    ``∂(α, β, γ)/∂δ = E⁻¹ R``. E is singular at sin β = 0 (raises ValueError there).
    """
    q = attitude.normalize(q)
    _, beta, gamma = attitude.to_zyz(q)
    sb, cb, sg, cg = np.sin(beta), np.cos(beta), np.sin(gamma), np.cos(gamma)
    if abs(sb) < 1e-9:
        raise ValueError("zyz_jacobian is singular at tilt beta = 0 (only alpha + gamma defined)")
    E = np.array([[sb * cg, -sg, 0.0], [sb * sg, cg, 0.0], [cb, 0.0, 1.0]])
    return np.linalg.solve(E, quat_matrix(q))


def crb_zyz(model: CorModel, q: ArrayLike, sigma_px: float) -> NDArray[np.float64]:
    """CRB (3, 3), rad², of (spin α, tilt β, yaw γ): ``A C_body Aᵀ`` with A = ``zyz_jacobian``.
    Valid for β away from 0 (linearisation of a singular chart)."""
    A = zyz_jacobian(q)
    return A @ crb_body(model, q, sigma_px) @ A.T


def rotvec_error_camera(q_est: ArrayLike, q_true: ArrayLike) -> NDArray[np.float64]:
    """Attitude error as a rotation vector in camera (= stator) axes, rad:
    ``log(q_est ⊗ q_true⁻¹)``; z = about boresight, x, y = cross-boresight."""
    d = attitude.multiply(np.asarray(q_est, float), attitude.conjugate(np.asarray(q_true, float)))
    return attitude.to_rotvec(d / np.linalg.norm(d))


def zyz_error(q_est: ArrayLike, q_true: ArrayLike) -> NDArray[np.float64]:
    """Per-angle error (α̂ − α, β̂ − β, γ̂ − γ), rad, with α and γ differences wrapped to
    (−π, π]. Meaningful away from β = 0."""
    a = np.array(attitude.to_zyz(q_est))
    b = np.array(attitude.to_zyz(q_true))
    e = a - b
    e[0], e[2] = attitude.wrap_angle(e[0]), attitude.wrap_angle(e[2])
    return e
