"""Projection of markers that rotate about a fixed centre of rotation (seed 002 §2.2–2.3).

The model (seed 002 eq. 2–11, with our symbols)::

    X_j = R_cs · R(q) · P_j + t_cor             camera-frame point of marker j (m)
    x_j = X_j / Z_j,  y_j = Y_j / Z_j            normalised image coordinates
    r²  = x_j² + y_j²
    s   = 1 + k1 r² + k2 r⁴ + k3 r⁶              radial distortion (seed 002 eq. 8–9)
    u_j = fx · s · x_j + cx,  v_j = fy · s · y_j + cy      pixel (seed 002 eq. 5–7, 10–11)

``P_j`` are the marker positions in the rotor (body) frame, measured from the centre of
rotation (CoR, the motor centre O), in m; ``q`` is the attitude (w, x, y, z), rotor → stator;
``t_cor`` is the CoR in the camera frame (m; nominally ``(0, 0, R + h_c)``); fx, fy, cx, cy are
in *sensor* pixels (the seed's unit) with OpenCV's pixel-centre convention. Skew is zero (seed
002 eq. 6) and the distortion is radial only (seed 002 eq. 8), which is OpenCV's model with
p1 = p2 = 0, so ``CorModel.nominal`` reproduces ``plant.camera.Camera.project``.

``R_cs``, the stator → camera rotation (seed 002 eq. 1 fixes its counterpart too), is the
identity in our geometry and is kept fixed: the attitude is *defined relative to the camera
axes* (camera x = image u = stator X, camera y = image v = stator Y, optical axis = stator Z).
A mounting error of the camera therefore shows up as an attitude offset, not as a parameter.

Minimal parametrisation (seed 002 eq. 14–15, "the one presented in [27]"). The seed's equations
are not legible in our copy; we use the modified Rodrigues (stereographic) parameters
``p ∈ R³``::

    q(p) = ((1 − |p|²), 2 p) / (1 + |p|²)

which is a unit quaternion for every p (no norm constraint), with ``|p| = tan(θ/4)`` for a
rotation by θ about ``p/|p|``; the inverse is ``p = q_v / (1 + q_w)``. It is used as a
*multiplicative* update about a reference attitude, ``q = q_ref ⊗ q(p)``, so p is a body-frame
perturbation, covers every rotation short of 360° and is singular only there. The rotation
vector of q(p) is ``δ = 4 arctan(|p|) · p/|p|``, hence ``δ = 4 p + O(|p|³)``: near p = 0 the
Jacobian with respect to the rotation vector is ``J_p / 4``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from plant.camera import Camera
from plant.geometry import marker_points
from plant.params import PlantParams

#: Names of the seven optical parameters, in the order of ``Intrinsics.as_array`` (seed 002 §2.5).
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "k3")


# --------------------------------------------------------------------------------------------
# Quaternion helpers without validation (the inner loops call them thousands of times).
# --------------------------------------------------------------------------------------------


def quat_matrix(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrix (..., 3, 3) of unit quaternions (..., 4), (w, x, y, z); no checks."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def quat_mul(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Hamilton product ``a ⊗ b`` (broadcasting over leading axes); no checks."""
    aw, av = a[..., :1], a[..., 1:]
    bw, bv = b[..., :1], b[..., 1:]
    return np.concatenate(
        [aw * bw - np.sum(av * bv, axis=-1, keepdims=True), aw * bv + bw * av + np.cross(av, bv)],
        axis=-1,
    )


def mrp_to_quat(p: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternion (..., 4) of modified Rodrigues parameters p (..., 3):
    ``q(p) = ((1 − |p|²), 2p)/(1 + |p|²)`` (our reading of seed 002 eq. 14–15)."""
    p = np.asarray(p, dtype=float)
    s = np.sum(p * p, axis=-1, keepdims=True)
    return np.concatenate([1.0 - s, 2.0 * p], axis=-1) / (1.0 + s)


def quat_to_mrp(q: ArrayLike) -> NDArray[np.float64]:
    """Modified Rodrigues parameters (..., 3) of unit quaternions (..., 4): ``p = q_v/(1 + q_w)``,
    taking the sign of q with ``q_w ≥ 0`` so that ``|p| ≤ 1`` (rotation angle ≤ 180°)."""
    q = np.asarray(q, dtype=float)
    q = np.where(q[..., :1] < 0.0, -q, q)
    return q[..., 1:] / (1.0 + q[..., :1])


def mrp_to_rotvec(p: ArrayLike) -> NDArray[np.float64]:
    """Rotation vector (rad) of MRP p: ``δ = 4 arctan(|p|) p/|p|`` (≈ 4p for small p)."""
    p = np.asarray(p, dtype=float)
    n = np.linalg.norm(p, axis=-1, keepdims=True)
    safe = np.where(n > 1e-12, n, 1.0)
    return np.where(n > 1e-12, 4.0 * np.arctan(n) / safe, 4.0) * p


def dquat_dmrp(p: ArrayLike) -> NDArray[np.float64]:
    """Jacobian (..., 4, 3) of q(p) with respect to p (differentiating ``mrp_to_quat``).

    With s = |p|²: ``∂q_w/∂p = −4 pᵀ/(1 + s)²`` and
    ``∂q_v/∂p = 2 I/(1 + s) − 4 p pᵀ/(1 + s)²``.
    """
    p = np.asarray(p, dtype=float)
    s = np.sum(p * p, axis=-1)[..., None, None]
    outer = p[..., :, None] * p[..., None, :]
    dw = -4.0 * p[..., None, :] / (1.0 + s) ** 2
    dv = 2.0 * np.eye(3) / (1.0 + s) - 4.0 * outer / (1.0 + s) ** 2
    return np.concatenate([dw, dv], axis=-2)


def skew(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Skew-symmetric matrices (..., 3, 3) with ``skew(a) @ b = a × b``."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(
        [np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2
    )


def drotate_dquat(q: NDArray[np.float64], P: NDArray[np.float64]) -> NDArray[np.float64]:
    """Jacobian (..., 3, 4) of ``R(q) P`` with respect to q = (w, v), for unit q.

    Differentiates ``R(q) P = P + 2w (v × P) + 2 v × (v × P)`` (which equals R(q)P on the unit
    sphere, where the chain rule through q(p) stays): ``∂/∂w = 2 v × P`` and
    ``∂/∂v = −2w [P]× + 2((v·P) I + v Pᵀ − 2 P vᵀ)`` (cf. seed 002 eq. 39).
    """
    q = np.asarray(q, dtype=float)
    P = np.asarray(P, dtype=float)
    w = q[..., 0][..., None, None]
    v = q[..., 1:]
    v, P = np.broadcast_arrays(v, P)
    d_w = 2.0 * np.cross(v, P)[..., :, None]
    vP = np.sum(v * P, axis=-1)[..., None, None]
    d_v = (
        -2.0 * w * skew(P)
        + 2.0 * vP * np.eye(3)
        + 2.0 * v[..., :, None] * P[..., None, :]
        - 4.0 * P[..., :, None] * v[..., None, :]
    )
    return np.concatenate([d_w, d_v], axis=-1)


# --------------------------------------------------------------------------------------------
# Intrinsics and the camera part of the projection
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics and radial distortion (seed 002 eq. 6, 8).

    fx, fy, cx, cy in sensor pixels; k1, k2, k3 dimensionless coefficients of r², r⁴, r⁶ in
    normalised coordinates (OpenCV's k1, k2, k3 with p1 = p2 = 0).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0

    def __post_init__(self) -> None:
        for name in INTRINSIC_NAMES:
            v = getattr(self, name)
            if not np.isfinite(v):
                raise ValueError(f"Intrinsics.{name} must be finite, got {v!r}")
        for name in ("fx", "fy"):
            if getattr(self, name) <= 0.0:
                raise ValueError(f"Intrinsics.{name} must be > 0 px, got {getattr(self, name)}")

    def as_array(self) -> NDArray[np.float64]:
        """(fx, fy, cx, cy, k1, k2, k3) as a float array."""
        return np.array([getattr(self, n) for n in INTRINSIC_NAMES], dtype=float)

    @classmethod
    def from_array(cls, a: ArrayLike) -> Intrinsics:
        """Inverse of ``as_array``."""
        a = np.asarray(a, dtype=float).reshape(7)
        return cls(*(float(x) for x in a))

    def matrix(self) -> NDArray[np.float64]:
        """The 3 × 3 intrinsic matrix K (px), zero skew."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def dist_coeffs(self) -> NDArray[np.float64]:
        """OpenCV distortion vector (k1, k2, p1, p2, k3) with p1 = p2 = 0."""
        return np.array([self.k1, self.k2, 0.0, 0.0, self.k3])


def project_camera_points(
    X: ArrayLike, intr: Intrinsics
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Pixels of camera-frame points and their derivatives (seed 002 eq. 5–11).

    Parameters
    ----------
    X : (..., 3) camera-frame points, m, with Z > 0 (points with Z ≤ 0 give NaN pixels).
    intr : the intrinsics.

    Returns
    -------
    uv : (..., 2) distorted pixels, sensor px.
    duv_dX : (..., 2, 3) derivative of the pixels with respect to X, px/m.
    duv_dintr : (..., 2, 7) derivative with respect to (fx, fy, cx, cy, k1, k2, k3).
    """
    X = np.asarray(X, dtype=float)
    Z = np.where(X[..., 2] > 0.0, X[..., 2], np.nan)
    x, y = X[..., 0] / Z, X[..., 1] / Z
    r2 = x * x + y * y
    k1, k2, k3 = intr.k1, intr.k2, intr.k3
    s = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    ds = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3)  # ds/d(r²)
    u = intr.fx * s * x + intr.cx
    v = intr.fy * s * y + intr.cy
    # d(u, v)/d(x, y)
    du_dx = intr.fx * (s + 2.0 * x * x * ds)
    du_dy = intr.fx * 2.0 * x * y * ds
    dv_dx = intr.fy * 2.0 * x * y * ds
    dv_dy = intr.fy * (s + 2.0 * y * y * ds)
    # d(x, y)/dX
    inv_z = 1.0 / Z
    zero = np.zeros_like(x)
    dx_dX = np.stack([inv_z, zero, -x * inv_z], -1)
    dy_dX = np.stack([zero, inv_z, -y * inv_z], -1)
    duv_dX = np.stack(
        [du_dx[..., None] * dx_dX + du_dy[..., None] * dy_dX,
         dv_dx[..., None] * dx_dX + dv_dy[..., None] * dy_dX],
        axis=-2,
    )
    one = np.ones_like(x)
    r4, r6 = r2 * r2, r2 * r2 * r2
    du_di = np.stack([s * x, zero, one, zero, intr.fx * x * r2, intr.fx * x * r4,
                      intr.fx * x * r6], -1)
    dv_di = np.stack([zero, s * y, zero, one, intr.fy * y * r2, intr.fy * y * r4,
                      intr.fy * y * r6], -1)
    return np.stack([u, v], -1), duv_dX, np.stack([du_di, dv_di], -2)


# --------------------------------------------------------------------------------------------
# Marker targets
# --------------------------------------------------------------------------------------------


def vfc_markers(p: PlantParams, n_markers: int = 2) -> NDArray[np.float64]:
    """Marker centres (n, 3) in the rotor frame (m) of the VFC or of its 4-marker variant.

    ``n_markers = 2``: the seed's red and yellow markers (``plant.geometry.marker_points``).
    ``n_markers = 4``: our variant with markers on all four corners of the seed's 20 mm square
    (seed 000 §3.2.2): red (−L/2, 0), yellow (+L/2, 0), then (0, −L/2) and (0, +L/2), all in the
    plate plane z = −R. It is coplanar, so OpenCV's IPPE applies, and has exactly four points,
    as OpenCV's P3P requires.
    """
    base = marker_points(p.rotor, p.vfc)
    if n_markers == 2:
        return base
    if n_markers == 4:
        h, z = 0.5 * p.vfc.L_m, -p.rotor.radius_m
        return np.vstack([base, [[0.0, -h, z], [0.0, h, z]]])
    raise ValueError(f"n_markers must be 2 or 4, got {n_markers!r}")


# --------------------------------------------------------------------------------------------
# The model
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CorModel:
    """Markers rotating about a fixed CoR seen by a camera with fixed axes (seed 002 §2.3).

    Attributes
    ----------
    intrinsics : fx, fy, cx, cy (sensor px), k1, k2, k3.
    t_cor_m : (3,) the CoR in the camera frame, m (``(0, 0, R + h_c)`` nominally).
    markers_m : (N, 3) marker positions in the rotor frame relative to the CoR, m.

    ``R_cs`` (stator → camera) is the identity and not a parameter (see the module docstring).
    """

    intrinsics: Intrinsics
    t_cor_m: NDArray[np.float64]
    markers_m: NDArray[np.float64] = field(repr=False)

    def __post_init__(self) -> None:
        t = np.asarray(self.t_cor_m, dtype=float)
        P = np.atleast_2d(np.asarray(self.markers_m, dtype=float))
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise ValueError(f"t_cor_m must be a finite 3-vector in m, got {self.t_cor_m!r}")
        if t[2] <= 0.0:
            raise ValueError(f"t_cor_m[2] (CoR depth) must be > 0 m, got {t[2]}")
        if P.ndim != 2 or P.shape[1] != 3 or P.shape[0] < 1 or not np.all(np.isfinite(P)):
            raise ValueError(f"markers_m must be a finite (N, 3) array in m, got shape {P.shape}")
        object.__setattr__(self, "t_cor_m", t)
        object.__setattr__(self, "markers_m", P)

    @classmethod
    def nominal(
        cls, p: PlantParams, markers_m: ArrayLike | None = None, n_markers: int = 2
    ) -> CorModel:
        """The model of the plant's camera and VFC with nominal (true) parameters.

        (fx, fy, cx, cy) of ``plant.camera.Camera.matrix(1)`` in sensor px (the calibrated
        ``camera.intrinsics_px`` when set, else f/pixel size and the sensor centre),
        (k1, k2, k3) from ``dist_coeffs``, and ``t_cor = -Camera.center_m = (-d_u, -d_v,
        R + h_c)`` with the camera mount's offset (0 by default). The model lives in the
        camera-aligned frame (``plant.camera``): with a mount roll the attitudes it fits are
        ``Rz(-ρ) ⊗ q``; ``Camera.stator_attitude`` turns them back.
        ``markers_m`` defaults to ``vfc_markers(p, n_markers)``.
        Raises ValueError if the plant's lens has tangential distortion, which this model lacks.
        """
        c = p.camera
        k1, k2, p1, p2, k3 = c.dist_coeffs
        if p1 != 0.0 or p2 != 0.0:
            raise ValueError(
                "camera.dist_coeffs p1, p2 must be 0: the CoR model is radial only (seed 002 eq. 8)"
            )
        K = Camera.from_plant(p).matrix(1)
        intr = Intrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2], k1, k2, k3)
        P = vfc_markers(p, n_markers) if markers_m is None else np.asarray(markers_m, float)
        return cls(intr, -Camera.from_plant(p).center_m, P)

    @property
    def n_markers(self) -> int:
        """Number of markers N in the model (rows of ``markers_m``)."""
        return int(self.markers_m.shape[0])

    def replace(self, **changes) -> CorModel:
        """A copy with some fields changed."""
        kw = {"intrinsics": self.intrinsics, "t_cor_m": self.t_cor_m, "markers_m": self.markers_m}
        kw.update(changes)
        return CorModel(**kw)

    def camera_points(self, q: ArrayLike) -> NDArray[np.float64]:
        """Camera-frame marker positions (N, 3), m, at attitude q: ``R(q) P_j + t_cor``."""
        return self.markers_m @ quat_matrix(np.asarray(q, float)).T + self.t_cor_m

    def project(self, q: ArrayLike) -> NDArray[np.float64]:
        """Marker pixels (N, 2), sensor px, at attitude q (w, x, y, z; rotor → stator)."""
        return project_camera_points(self.camera_points(q), self.intrinsics)[0]

    def project_mrp(self, p: ArrayLike, q_ref: ArrayLike) -> NDArray[np.float64]:
        """Marker pixels (N, 2) at ``q = q_ref ⊗ q(p)``."""
        return self.project(quat_mul(np.asarray(q_ref, float), mrp_to_quat(p)))

    def jacobian_mrp(
        self, p: ArrayLike, q_ref: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Pixels (N, 2) at ``q_ref ⊗ q(p)`` and their Jacobian (N, 2, 3) with respect to p.

        Chain rule (seed 002 App. A, eq. 25–40 in spirit):
        ``∂uv/∂p = ∂uv/∂X · R(q_ref) · ∂(R(q(p)) P)/∂q · ∂q/∂p``.
        At p = 0 this is ``−4 ∂uv/∂X · R(q_ref) [P]×`` (px per unit p); divide by 4 for px/rad.
        """
        p = np.asarray(p, dtype=float)
        q_ref = np.asarray(q_ref, dtype=float)
        qp = mrp_to_quat(p)
        Rref = quat_matrix(q_ref)
        Rp = quat_matrix(qp)
        X = self.markers_m @ (Rref @ Rp).T + self.t_cor_m
        uv, duv_dX, _ = project_camera_points(X, self.intrinsics)
        dRP_dp = drotate_dquat(qp, self.markers_m) @ dquat_dmrp(p)  # (N, 3, 3)
        return uv, duv_dX @ (Rref @ dRP_dp)

    def jacobian_rotvec(self, q: ArrayLike) -> NDArray[np.float64]:
        """Jacobian (2N, 3) of the pixels (u1, v1, u2, ...) with respect to a body-frame
        rotation vector δ at ``q ⊗ exp(δ)``, δ = 0; px/rad."""
        _, J = self.jacobian_mrp(np.zeros(3), q)
        return J.reshape(-1, 3) / 4.0
