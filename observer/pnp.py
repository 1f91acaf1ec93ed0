"""OpenCV PnP against the CoR-constrained solver (seed 002 §3.5).

A PnP solver estimates the full 6-DOF pose ``X_c = R P + t`` of the marker target and knows
nothing of the centre of rotation; we keep its rotation and drop the translation, as the works
that seed 002 §1 criticises do. With R_cs = I (``observer.cor_model``) the camera and stator
axes coincide, so ``R(q) = R_pnp`` for object points given in the rotor frame about the CoR.
Like the seed's comparison, the PnP solvers get the exact intrinsics and marker geometry.

Errors are split as in seed 002 §3.5: the attitude error as a rotation vector in camera axes
(``observer.crb.rotvec_error_camera``), whose z component is the rotation *about boresight* and
whose x and y components are *cross-boresight*. The accuracy ratio of a method is its RMS error
divided by the CoR solver's on the same noisy pixels, per axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from observer.cor_model import CorModel, vfc_markers
from observer.cor_solver import CorSolver
from observer.crb import rotvec_error_camera
from observer.types import SolverResult
from plant import attitude
from plant.params import PlantParams

#: OpenCV flags of the PnP methods we compare. IPPE needs >= 4 coplanar points, P3P exactly 4
#: (three for the candidate poses, the fourth to choose), SQPNP >= 3; ITERATIVE is OpenCV's
#: Levenberg–Marquardt on the 6-DOF reprojection error (the maximum-likelihood pose without the
#: CoR constraint).
PNP_METHODS = {
    "IPPE": cv2.SOLVEPNP_IPPE,
    "SQPNP": cv2.SOLVEPNP_SQPNP,
    "P3P": cv2.SOLVEPNP_P3P,
    "ITERATIVE": cv2.SOLVEPNP_ITERATIVE,
}


class PnPSolver:
    """``cv2.solvePnP`` with one of ``PNP_METHODS`` as an ``AttitudeSolver`` (rotation only).

    Needs every marker of ``model`` (no missing rows); its object points are
    ``model.markers_m`` and its camera matrix and distortion those of ``model.intrinsics``.
    """

    def __init__(self, model: CorModel, method: str) -> None:
        if method not in PNP_METHODS:
            raise ValueError(f"method must be one of {sorted(PNP_METHODS)}, got {method!r}")
        if method == "P3P" and model.n_markers != 4:
            raise ValueError(f"method P3P needs exactly 4 markers, model has {model.n_markers}")
        if method == "IPPE":
            P = model.markers_m - model.markers_m.mean(axis=0)
            if model.n_markers < 4 or np.linalg.svd(P, compute_uv=False)[-1] > 1e-9:
                raise ValueError("method IPPE needs >= 4 coplanar markers")
        self.model = model
        self.method = method
        self._flag = PNP_METHODS[method]
        self._K = model.intrinsics.matrix()
        self._dist = model.intrinsics.dist_coeffs()
        self._obj = np.ascontiguousarray(model.markers_m, dtype=np.float64)

    def solve(
        self, marker_px: NDArray[np.float64], q_prev: NDArray[np.float64] | None = None
    ) -> SolverResult:
        """Attitude from all marker pixels (N, 2), sensor px; ``q_prev`` is not used."""
        uv = np.asarray(marker_px, dtype=float)
        if uv.shape != (self.model.n_markers, 2):
            return SolverResult.invalid(
                f"marker_px must have shape ({self.model.n_markers}, 2), got {uv.shape}"
            )
        if not np.all(np.isfinite(uv)):
            return SolverResult.invalid(f"{self.method} needs every marker; some are missing")
        try:
            ok, rvec, _tvec = cv2.solvePnP(
                self._obj, np.ascontiguousarray(uv), self._K, self._dist, flags=self._flag
            )
        except cv2.error as exc:
            return SolverResult.invalid(f"cv2.solvePnP({self.method}) failed: {exc}")
        if not ok or rvec is None or not np.all(np.isfinite(rvec)):
            return SolverResult.invalid(f"cv2.solvePnP({self.method}) found no pose")
        R, _ = cv2.Rodrigues(rvec)
        return SolverResult(q=attitude.from_matrix(R), iterations=0)


@dataclass(frozen=True)
class AxisErrors:
    """RMS and robust (1.4826 × median absolute) attitude errors (rad) per camera axis of one
    method over a Monte Carlo run; ``n_invalid`` solutions flagged invalid are excluded."""

    rms: NDArray[np.float64]  # (3,) x, y cross-boresight; z about boresight
    robust: NDArray[np.float64]
    n_invalid: int

    @property
    def rms_cross(self) -> float:
        """RMS over both cross-boresight axes, rad."""
        return float(np.sqrt(0.5 * (self.rms[0] ** 2 + self.rms[1] ** 2)))


def random_workspace_attitude(rng: np.random.Generator, tilt_max_rad: float) -> NDArray:
    """A random attitude: spin and yaw uniform in [0, 2π), the tilt axis uniform over the
    spherical cap of half-angle ``tilt_max_rad`` (cos β uniform)."""
    beta = float(np.arccos(rng.uniform(np.cos(tilt_max_rad), 1.0)))
    return attitude.from_zyz(rng.uniform(0.0, 2 * np.pi), beta, rng.uniform(0.0, 2 * np.pi))


def compare_pnp(
    p: PlantParams,
    n_runs: int,
    sigma_px: float,
    rng: np.random.Generator | int | None = None,
    methods: tuple[str, ...] = ("IPPE", "SQPNP", "P3P", "ITERATIVE"),
) -> dict[str, AxisErrors]:
    """Monte Carlo comparison on the 4-marker VFC (``vfc_markers(p, 4)``).

    For ``n_runs`` random workspace attitudes (tilt ≤ ``p.rotor.tilt_stop_deg``), Gaussian noise
    of ``sigma_px`` px on each pixel coordinate, every method sees the same pixels. Returns
    errors per method, with the CoR solver (cold start) under the key ``"CoR"``.
    """
    if not (np.isfinite(sigma_px) and sigma_px > 0):
        raise ValueError(f"sigma_px must be > 0 px, got {sigma_px!r}")
    if int(n_runs) < 2:
        raise ValueError(f"n_runs must be >= 2, got {n_runs!r}")
    rng = np.random.default_rng(rng)
    model = CorModel.nominal(p, markers_m=vfc_markers(p, 4))
    solvers = {"CoR": CorSolver(model)}
    solvers.update({m: PnPSolver(model, m) for m in methods})
    errs: dict[str, list] = {k: [] for k in solvers}
    invalid = dict.fromkeys(solvers, 0)
    tilt_max = np.deg2rad(p.rotor.tilt_stop_deg)
    for _ in range(int(n_runs)):
        q = random_workspace_attitude(rng, tilt_max)
        uv = model.project(q) + rng.normal(scale=sigma_px, size=(model.n_markers, 2))
        for k, s in solvers.items():
            res = s.solve(uv)
            if res.valid:
                errs[k].append(rotvec_error_camera(res.q, q))
            else:
                invalid[k] += 1
    out = {}
    for k, e in errs.items():
        e = np.array(e).reshape(-1, 3)
        out[k] = AxisErrors(
            rms=np.sqrt(np.mean(e**2, axis=0)),
            robust=1.4826 * np.median(np.abs(e - np.median(e, axis=0)), axis=0),
            n_invalid=invalid[k],
        )
    return out


def accuracy_ratios(result: dict[str, AxisErrors]) -> dict[str, dict[str, float]]:
    """Per method: RMS error ÷ the CoR solver's RMS error, about boresight ("about") and
    cross-boresight ("cross", both axes pooled); the same with robust errors ("about_robust",
    "cross_robust")."""
    ref = result["CoR"]
    out = {}
    for k, r in result.items():
        if k == "CoR":
            continue
        ref_cross_rb = np.sqrt(0.5 * (ref.robust[0] ** 2 + ref.robust[1] ** 2))
        cross_rb = np.sqrt(0.5 * (r.robust[0] ** 2 + r.robust[1] ** 2))
        out[k] = {
            "about": float(r.rms[2] / ref.rms[2]),
            "cross": float(r.rms_cross / ref.rms_cross),
            "about_robust": float(r.robust[2] / ref.robust[2]),
            "cross_robust": float(cross_rb / ref_cross_rb),
        }
    return out
