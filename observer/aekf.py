"""Quaternion EKF and AEKF on marker pixels, with delay compensation (seed 001 §4, App. C).

State X = (p0, p1, p2, p3, omega_x, omega_y, omega_z): the attitude quaternion (rotor to stator)
extended with the body rate (rad/s). Seed 001 §4.1 propagates the quaternion alone with a known
rate; we also propagate the rate, through the rigid-body model of the plant's CasADi twin driven
by the commanded stator-frame torque (N·m), so the filter can predict across the vision delay.

* Prediction (App. C.1): X(k|k-1) = f[X(k-1|k-1)] by RK4 on the twin's dynamics, F = df/dX,
  P(k|k-1) = F P F^T + ϑ λ Q (App. C.3; plain EKF: ϑ = λ = 1). The quaternion is renormalised.
* Observation (§4.2.2): Z = the markers' pixels (sensor px) through the pinhole camera with
  OpenCV's lens distortion, H = dh/dX; missing markers (NaN rows) drop their rows.
* Update (App. C.2): K = P H^T (H P H^T + λ R)^-1, via filterpy's ``ExtendedKalmanFilter``.
* Covariance matching (App. C.3): innovation e(k) = Z - h(X(k|k-1)); C_e = mean of e e^T over
  the last N innovations; C = H P H^T + R; λ = max(1, tr C_e / tr C).
* Point observations (``update_points``, seed 001 §4.2.2 Eq. 13): any rotor-frame
  points (for example ORB features on a printed texture, ``observer.orb``) and their pixels; the
  Jacobian of the pinhole projection with distortion is CasADi's, evaluated over the points
  with ``Function.map``. Points outside a per-point chi-square gate are dropped; the trace ratio
  of App. C.3 is taken per observation component, because the number of points changes from
  frame to frame (see ``update_points``).
* Delay compensation: a measurement is fused at its exposure time; ``estimate_at(t)`` then
  predicts from there to t with the stored torque history, so a controller sees the present.

Q is given as a continuous-time intensity and scaled by each prediction's duration.
Note on λ: it is the ratio of traces, so a large predicted spread in one direction (for example
the spin about the shaft, seen only through the short marker baseline) hides excess innovation in
the others; then λ stays at 1 and the AEKF behaves as the EKF.
"""

from __future__ import annotations

import bisect
import functools
from collections import deque
from dataclasses import dataclass

import casadi as ca
import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field
from scipy.stats import chi2

from plant import attitude
from plant.camera import Camera
from plant.geometry import marker_points
from plant.params import PlantParams
from plant.twin import CasadiTwin, quat_to_matrix


def _inside_gate(e: NDArray[np.float64], HP: NDArray[np.float64], H: NDArray[np.float64],
                 var_px2: NDArray[np.float64], probability: float) -> NDArray[np.bool_]:
    """Points whose innovation 2-vector lies inside the chi-square gate (2 dof, ``probability``)
    of its own 2x2 ``H_i P H_i^T + var_i I`` (``var_px2`` per point)."""
    n = len(var_px2)
    blocks = np.einsum("nia,nja->nij", HP.reshape(n, 2, 7), H.reshape(n, 2, 7))
    blocks += np.einsum("n,ij->nij", var_px2, np.eye(2))
    e2 = e.reshape(n, 2)
    d2 = np.einsum("ni,ni->n", e2, np.linalg.solve(blocks, e2[..., None])[..., 0])
    return d2 <= chi2.ppf(probability, 2)


def _check_time(name: str, t: object) -> float:
    """``t`` as a float time (s), or ``ValueError`` naming ``name`` if it is not a finite
    real number (NaN would otherwise surface as "cannot convert float NaN to integer")."""
    if not (np.ndim(t) == 0 and np.asarray(t).dtype.kind in "iuf"):  # not bool, str, None
        raise ValueError(f"{name} must be a finite time in s, got {t!r}")
    value = float(t)
    if not np.isfinite(value):
        raise ValueError(f"{name} must be a finite time in s, got {value}")
    return value


class AEKFConfig(BaseModel):
    """Noise and adaptation settings. Intensities are per second of predicted time. A number
    that is not finite raises ``ValueError`` naming the field."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    q_quat_per_s: float = Field(
        1e-7, ge=0.0, description="Our choice: small, since the rate is in the state (seed 001, "
        "whose state has no rate, uses Q = 0.001·I4 per frame, Table 1). 1e-4 would already "
        "spread the prior over ~90 px² and hide the innovation statistics from λ."
    )
    q_omega_rad2_per_s3: float = Field(
        0.1, ge=0.0, description="Our choice: rate random walk for unmodelled torque; a "
        "starting point for the closed-loop Q/R tuning (``experiments.tuning``)."
    )
    sigma_px: float = Field(
        1.0, gt=0.0, description="Our choice: marker-centre noise, sensor px (1 sensor px is "
        "0.25 px of the 4x-binned frame)."
    )
    adaptive: bool = Field(True, description="Covariance matching on (AEKF) or off (EKF).")
    window_N: int = Field(10, ge=1, description="Our choice: sliding window of innovations.")
    theta: float = Field(0.8, gt=0.0, description="Seed 001 Table 1: scale factor ϑ = 0.8.")
    max_step_s: float = Field(2e-3, gt=0.0, description="Our choice: RK4 step in prediction.")
    gate_probability: float = Field(
        0.9999, gt=0.0, lt=1.0, description="Our choice: chi-square gate on the innovation; a "
        "measurement outside it is rejected as an outlier."
    )
    history_s: float = Field(1.0, gt=0.0, description="Torque history kept, s.")


@dataclass(frozen=True)
class UpdateResult:
    """Outcome of one measurement update."""

    accepted: bool
    reason: str = ""
    lam: float = 1.0
    nis: float = float("nan")
    n_points: int = 0  # observations used by ``update_points`` (0 for ``update``)


@functools.lru_cache(maxsize=16)
def _model_functions(p: PlantParams) -> tuple[ca.Function, ca.Function, ca.Function]:
    """The filter's CasADi functions on the plant ``p`` (``_rk4_symbolic``,
    ``_pixels_symbolic``, ``_point_symbolic``): built once per process and plant (building
    them takes about a third of a second) and shared by its filters (they hold no state)."""
    return _rk4_symbolic(p), _pixels_symbolic(p), _point_symbolic(p)


def _rk4_symbolic(p: PlantParams) -> ca.Function:
    """(x (7), T (3), h) -> (x after one RK4 step of h s with the stator-frame torque T (N·m)
    held, the quaternion renormalised; its Jacobian d x1 / d x)."""
    twin = CasadiTwin(p)
    x, T, h = ca.SX.sym("x", 7), ca.SX.sym("T", 3), ca.SX.sym("h")
    k1 = twin.f_torque(x, T)
    k2 = twin.f_torque(x + h / 2 * k1, T)
    k3 = twin.f_torque(x + h / 2 * k2, T)
    k4 = twin.f_torque(x + h * k3, T)
    x1 = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    x1 = ca.vertcat(x1[:4] / ca.norm_2(x1[:4]), x1[4:])
    return ca.Function("rk4", [x, T, h], [x1, ca.jacobian(x1, x)])


def _pixels_symbolic(p: PlantParams) -> ca.Function:
    """q (4) -> marker pixels (2N,) in sensor px, pinhole + OpenCV distortion (k1 k2 p1 p2 k3)."""
    cam = Camera.from_plant(p)
    K = cam.matrix(1)
    k1, k2, p1, p2, k3 = p.camera.dist_coeffs
    q = ca.SX.sym("q", 4)
    R = quat_to_matrix(q / ca.norm_2(q))
    out = []
    for P_j in marker_points(p.rotor, p.vfc):
        X_c = R @ ca.DM(P_j) - ca.DM(cam.center_m)
        x, y = X_c[0] / X_c[2], X_c[1] / X_c[2]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        out += [K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]]
    z = ca.vertcat(*out)
    return ca.Function("h", [q], [z, ca.jacobian(z, q)], ["q"], ["z", "H"])


def _point_symbolic(p: PlantParams) -> ca.Function:
    """(q (4), P (3)) -> (uv (2), d uv/d q (2x4)): one rotor-frame point (m) through the
    pinhole camera with OpenCV distortion (k1 k2 p1 p2 k3), sensor px (seed 001 Eq. 13)."""
    cam = Camera.from_plant(p)
    K = cam.matrix(1)
    k1, k2, p1, p2, k3 = p.camera.dist_coeffs
    q, P = ca.SX.sym("q", 4), ca.SX.sym("P", 3)
    X_c = quat_to_matrix(q / ca.norm_2(q)) @ P - ca.DM(cam.center_m)
    x, y = X_c[0] / X_c[2], X_c[1] / X_c[2]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    z = ca.vertcat(K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2])
    return ca.Function("h_point", [q, P], [z, ca.jacobian(z, q)], ["q", "P"], ["z", "H"])


class _RigidBodyEKF(ExtendedKalmanFilter):
    """filterpy's EKF with the nonlinear RK4 prediction of the rigid body."""

    def __init__(self, propagate) -> None:
        super().__init__(dim_x=7, dim_z=4)
        self._propagate = propagate

    def predict_x(self, u=0) -> None:
        T, h = u
        x, F = self._propagate(self.x, T, h)
        self.x = np.asarray(x).ravel()
        self.F = np.asarray(F)


class QuaternionAEKF:
    """Attitude and rate from marker pixels, fused at exposure time, predicted to any time.

    Parameters
    ----------
    params : PlantParams
        Rotor, camera and marker geometry (the filter's model).
    config : AEKFConfig
        Noise and adaptation; ``adaptive=False`` gives the plain EKF.
    q0 : (4,) initial attitude; ``omega0`` (3,) initial body rate, rad/s.
    P0_diag : initial covariance diagonal (quaternion components, then rate in (rad/s)^2).
    t0 : time of the initial state, s.
    """

    def __init__(
        self,
        params: PlantParams | None = None,
        config: AEKFConfig | None = None,
        q0: ArrayLike = (1.0, 0.0, 0.0, 0.0),
        omega0: ArrayLike = (0.0, 0.0, 0.0),
        P0_diag: ArrayLike = (1e-4, 1e-4, 1e-4, 1e-4, 1.0, 1.0, 1.0),
        t0: float = 0.0,
    ) -> None:
        self.params = params or PlantParams()
        self.config = config or AEKFConfig()
        self._rk4, self._h, self._h_point = _model_functions(self.params)
        self._h_point_maps: dict[int, ca.Function] = {}
        #: (sum of squared innovations, number of components) of the last N point updates.
        self._point_window: deque[tuple[float, int]] = deque(maxlen=self.config.window_N)
        self.ekf = _RigidBodyEKF(self._propagate)
        self.ekf.x = np.r_[attitude.normalize(q0, "q0"), attitude.check_finite("omega0", omega0)]
        P0 = attitude.check_finite("P0_diag", P0_diag)
        if P0.shape != (7,) or np.any(P0 <= 0):
            raise ValueError("P0_diag must be 7 positive variances")
        self.ekf.P = np.diag(P0)
        self.t = float(t0)  # time of the filter's state (last fused exposure or t0)
        self.lam = 1.0
        self._innovations: deque[NDArray[np.float64]] = deque(maxlen=self.config.window_N)
        self._torque_t: list[float] = [float(t0)]
        self._torque: list[NDArray[np.float64]] = [np.zeros(3)]

    # --- inputs ----------------------------------------------------------------------------
    def set_torque(self, t: float, torque_stator: ArrayLike) -> None:
        """Record that the stator-frame torque ``torque_stator`` (N·m) acts from time ``t``."""
        T = attitude.check_finite("torque_stator", torque_stator).reshape(3)
        if t < self._torque_t[-1]:
            raise ValueError(f"torque times must not decrease: {t} < {self._torque_t[-1]}")
        self._torque_t.append(float(t))
        self._torque.append(T)
        horizon = t - self.config.history_s
        while len(self._torque_t) > 2 and self._torque_t[1] <= min(horizon, self.t):
            self._torque_t.pop(0)
            self._torque.pop(0)

    def _torque_at(self, t: float) -> NDArray[np.float64]:
        i = bisect.bisect_right(self._torque_t, t) - 1
        return self._torque[max(i, 0)]

    # --- prediction ------------------------------------------------------------------------
    def _propagate(self, x, T, h):
        return self._rk4(x, T, h)

    def _segments(self, t0: float, t1: float):
        """(torque, duration) pieces of [t0, t1] with constant torque, each cut to max_step_s."""
        cuts = [t0] + [s for s in self._torque_t if t0 < s < t1] + [t1]
        for a, b in zip(cuts[:-1], cuts[1:], strict=True):
            n = max(1, int(np.ceil((b - a) / self.config.max_step_s - 1e-9)))
            for _ in range(n):
                yield self._torque_at(a), (b - a) / n

    def _predict_to(self, t1: float, lam: float) -> None:
        """Advance the filter's state and covariance from self.t to t1 (App. C.1, C.3)."""
        c = self.config
        scale = c.theta * lam if c.adaptive else 1.0
        for T, h in self._segments(self.t, t1):
            self.ekf.Q = scale * h * np.diag([c.q_quat_per_s] * 4 + [c.q_omega_rad2_per_s3] * 3)
            self.ekf.predict(u=(T, h))
        self.t = t1

    def estimate_at(self, t: float) -> tuple[NDArray, NDArray, NDArray]:
        """Attitude (4,), body rate (3,), rad/s, and the 3x3 body-frame rotation-vector
        covariance (rad²) predicted from the last fused measurement to time ``t`` (s), with the
        stored torque history. Does not change the filter."""
        x = self.ekf.x.copy()
        P = self.ekf.P.copy()
        c = self.config
        scale = c.theta * self.lam if c.adaptive else 1.0
        if t > self.t:
            for T, h in self._segments(self.t, t):
                x_next, F = self._rk4(x, T, h)
                x, F = np.asarray(x_next).ravel(), np.asarray(F)
                Qd = scale * h * np.diag([c.q_quat_per_s] * 4 + [c.q_omega_rad2_per_s3] * 3)
                P = F @ P @ F.T + Qd
        return x[:4].copy(), x[4:].copy(), self.attitude_covariance(x[:4], P)

    @staticmethod
    def attitude_covariance(q: NDArray, P: NDArray) -> NDArray[np.float64]:
        """Map the quaternion block of P to the body-frame rotation-vector covariance (rad²):
        delta_theta = 2 Xi(q)^T delta_q with Xi the 4x3 quaternion-product matrix."""
        w, x, y, z = q
        Xi = np.array([[-x, -y, -z], [w, -z, y], [z, w, -x], [-y, x, w]])
        G = 2.0 * Xi.T
        return G @ P[:4, :4] @ G.T

    # --- update ----------------------------------------------------------------------------
    def update(self, marker_px: ArrayLike, t_exposure: float) -> UpdateResult:
        """Fuse marker pixels (N, 2), sensor px, taken at mid-exposure ``t_exposure`` (s).

        Rows with NaN are missing markers. Returns whether the measurement was used and why
        not; a rejected measurement leaves the filter predicting. A ``t_exposure`` that is not
        a finite number is a caller error and raises ``ValueError``.
        """
        t_exposure = _check_time("t_exposure", t_exposure)
        z = np.asarray(marker_px, dtype=float).reshape(-1, 2)
        if t_exposure < self.t - 1e-12:
            return UpdateResult(False, f"stale measurement: exposure {t_exposure} s is before "
                                f"the filter's time {self.t} s")
        keep = np.all(np.isfinite(z), axis=1)
        if not keep.any():
            return UpdateResult(False, "no finite marker pixels")
        self._predict_to(float(t_exposure), self.lam)
        rows = np.repeat(keep, 2)
        zv = z[keep].ravel()
        hx, H = (np.asarray(a) for a in self._h(self.ekf.x[:4]))
        hx, H = hx.ravel()[rows], np.hstack([H[rows], np.zeros((rows.sum(), 3))])
        R = self.config.sigma_px**2 * np.eye(len(zv))
        e = zv - hx
        HPH = H @ self.ekf.P @ H.T
        lam = 1.0
        if self.config.adaptive and keep.all():
            # App. C.3: C_e over the window (this innovation included), C = H P H^T + R.
            self._innovations.append(e)
            E = np.array(self._innovations)
            C_e = E.T @ E / len(E)
            lam = max(1.0, float(np.trace(C_e) / np.trace(HPH + R)))
        nis = float(e @ np.linalg.solve(HPH + lam * R, e))
        if nis > chi2.ppf(self.config.gate_probability, len(zv)):
            return UpdateResult(
                False, f"innovation outside the chi-square gate (NIS {nis:.1f})", lam, nis
            )
        self.ekf.update(zv, lambda x: H, lambda x: hx, R=lam * R)
        self.ekf.x[:4] /= np.linalg.norm(self.ekf.x[:4])
        self.lam = lam
        return UpdateResult(True, "", lam, nis)

    def restart(
        self,
        q0: ArrayLike,
        t0: float,
        omega0: ArrayLike = (0.0, 0.0, 0.0),
        P0_diag: ArrayLike = (1e-4, 1e-4, 1e-4, 1e-4, 1.0, 1.0, 1.0),
    ) -> None:
        """Start again from attitude ``q0`` and body rate ``omega0`` (rad/s) at time ``t0``
        (s) with covariance diagonal ``P0_diag``, as a new filter would, but without
        rebuilding the CasADi functions (about 0.25 s). The torque history is cleared."""
        q0 = attitude.normalize(q0, "q0")
        w0 = attitude.check_finite("omega0", omega0).reshape(3)
        P0 = attitude.check_finite("P0_diag", P0_diag)
        if P0.shape != (7,) or np.any(P0 <= 0):
            raise ValueError("P0_diag must be 7 positive variances")
        self.ekf.x = np.r_[q0, w0]
        self.ekf.P = np.diag(P0)
        self.t = float(t0)
        self.lam = 1.0
        self._innovations.clear()
        self._point_window.clear()
        self._torque_t = [float(t0)]
        self._torque = [np.zeros(3)]

    # --- point observations ---------------------------------------------------------------------
    def project_points(
        self, points_rotor_m: ArrayLike, q: ArrayLike | None = None
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Pixels (N, 2), sensor px, of rotor-frame points (N, 3), m, at attitude ``q``
        (default the filter's) and the Jacobian (2N, 4) of the stacked (u1, v1, u2, ...) with
        respect to the quaternion (including its normalisation)."""
        P = np.asarray(points_rotor_m, dtype=float).reshape(-1, 3)
        n = len(P)
        f = self._h_point_maps.get(n)
        if f is None:
            if len(self._h_point_maps) >= 64:  # point counts vary from frame to frame
                self._h_point_maps.pop(next(iter(self._h_point_maps)))
            f = self._h_point_maps[n] = self._h_point.map(n)
        qv = self.ekf.x[:4] if q is None else np.asarray(q, dtype=float)
        z, H = f(qv, P.T)
        z = np.asarray(z).T  # (n, 2)
        H = np.asarray(H).reshape(2, n, 4).transpose(1, 0, 2).reshape(2 * n, 4)
        return z, H

    def update_points(
        self,
        points_rotor_m: ArrayLike,
        pixels_px: ArrayLike,
        t_exposure: float,
        sigma_px: ArrayLike | float | None = None,
        min_points: int = 3,
    ) -> UpdateResult:
        """Fuse the pixels (N, 2), sensor px, of rotor-frame points (N, 3), m, observed at
        mid-exposure ``t_exposure`` (s) (seed 001 §4.2.2 Eq. 13 and App. C).

        ``sigma_px`` is the per-coordinate pixel noise, one value or one per point (default
        ``config.sigma_px``). Steps, after predicting to ``t_exposure`` with the torque
        history (App. C.1, ``P = F P F^T + ϑ λ Q``):

        1. innovation ``e = z - h(X(k|k-1))`` and covariance matching (App. C.3) per
           observation component, since the number of points varies: ``c_e = Σ |e|² / Σ m``
           over the last N point updates (this one included, m = 2 N_points components each),
           ``c = tr(H P H^T + R) / m``, ``λ = max(1, c_e / c)``;
        2. each point's 2-vector is tested against its own 2x2 ``H_i P H_i^T + λ R_i`` with
           the chi-square gate (``gate_probability``, 2 dof) and dropped outside it (a
           mismatched feature);
        3. update (App. C.2) with ``λ R``: ``K = P H^T (H P H^T + λR)^-1``, computed as
           ``(I + P H^T W H)^-1 P H^T W`` with ``W = (λR)^-1`` (a 7x7 solve instead of a
           2m x 2m one), Joseph-form covariance; the quaternion is renormalised. The NIS of
           the kept innovation (with λR) is reported, not gated: outliers are removed per
           point, and a whole-frame gate would reject every frame while R is underestimated,
           which is when covariance matching has to act (measured, docs/orb.md).

        Fewer than ``min_points`` usable points, a stale time or a gated frame leave the
        filter unchanged (it keeps predicting) and say why; a non-finite ``t_exposure`` raises
        ``ValueError``.
        """
        t_exposure = _check_time("t_exposure", t_exposure)
        P_r = np.asarray(points_rotor_m, dtype=float).reshape(-1, 3)
        z = np.asarray(pixels_px, dtype=float).reshape(-1, 2)
        if len(P_r) != len(z):
            return UpdateResult(False, f"{len(P_r)} points but {len(z)} pixels")
        c = self.config
        sig = np.broadcast_to(
            np.asarray(c.sigma_px if sigma_px is None else sigma_px, dtype=float), (len(z),)
        )
        if t_exposure < self.t - 1e-12:
            return UpdateResult(
                False,
                f"stale measurement: exposure {t_exposure} s is before the filter's time "
                f"{self.t} s",
            )
        keep = np.all(np.isfinite(P_r), axis=1) & np.all(np.isfinite(z), axis=1)
        keep &= np.isfinite(sig) & (sig > 0)
        if keep.sum() < min_points:
            return UpdateResult(False, f"too few points: {int(keep.sum())} (need {min_points})")
        P_r, z, sig = P_r[keep], z[keep], sig[keep]
        self._predict_to(float(t_exposure), self.lam)
        hx, Hq = self.project_points(P_r)
        n = len(z)
        H = np.hstack([Hq, np.zeros((2 * n, 3))])
        e = (z - hx).reshape(-1)
        r = np.repeat(sig**2, 2)
        Pk = self.ekf.P
        HP = H @ Pk
        # 1. covariance matching per component (App. C.3), over all points of this frame
        lam = self._matched_lambda(e, HP, H, r) if c.adaptive else 1.0
        # 2. per-point gate with λR
        inside = _inside_gate(e, HP, H, lam * sig**2, c.gate_probability)
        if inside.sum() < min_points:
            return UpdateResult(
                False,
                f"too few points inside the gate: {int(inside.sum())} of {n} "
                f"(need {min_points})",
                lam,
                n_points=int(inside.sum()),
            )
        rows = np.repeat(inside, 2)
        H, e, r = H[rows], e[rows], r[rows]
        m = len(e)
        nis = self._fuse(H, e, lam * r)
        self.lam = lam
        return UpdateResult(True, "", lam, nis, m // 2)

    def _matched_lambda(self, e: NDArray[np.float64], HP: NDArray[np.float64],
                        H: NDArray[np.float64], r: NDArray[np.float64]) -> float:
        """Covariance matching per observation component (seed 001 App. C.3): the mean squared
        innovation over the last point updates (this one, ``e``, included) over the predicted
        ``tr(H P H^T + R) / m``, at least 1."""
        m = len(e)
        self._point_window.append((float(e @ e), m))
        sum_e2 = sum(a for a, _ in self._point_window)
        sum_m = sum(b for _, b in self._point_window)
        c_theory = (float(np.einsum("ij,ij->", HP, H)) + float(r.sum())) / m
        return max(1.0, (sum_e2 / sum_m) / c_theory)

    def _fuse(self, H: NDArray[np.float64], e: NDArray[np.float64],
              r: NDArray[np.float64]) -> float:
        """Update (seed 001 App. C.2) with the innovation ``e`` of variances ``r`` (px², the
        λ-scaled ones), Joseph form, quaternion renormalised; returns the NIS. The gain
        ``K = P H^T (H P H^T + R)^-1`` is computed as ``(I + P H^T W H)^-1 P H^T W`` with
        ``W = R^-1`` (a 7x7 solve), and ``S^-1 = W - W H (I + P H^T W H)^-1 P H^T W``."""
        Pk = self.ekf.P
        W = 1.0 / r
        HtW = H.T * W  # (7, m)
        A = np.eye(7) + Pk @ HtW @ H
        K = np.linalg.solve(A, Pk @ HtW)  # (7, m): P H^T (H P H^T + λR)^-1
        g = HtW @ e
        nis = float(e @ (W * e) - g @ np.linalg.solve(A, Pk @ g))
        I_KH = np.eye(7) - K @ H
        self.ekf.x = self.ekf.x + K @ e
        self.ekf.x[:4] /= np.linalg.norm(self.ekf.x[:4])
        P_new = I_KH @ Pk @ I_KH.T + (K * r) @ K.T
        self.ekf.P = 0.5 * (P_new + P_new.T)
        return nis

    @property
    def q(self) -> NDArray[np.float64]:
        """Attitude at the filter's time ``self.t``."""
        return self.ekf.x[:4].copy()

    @property
    def omega(self) -> NDArray[np.float64]:
        """Body rate (rad/s) at the filter's time ``self.t``."""
        return self.ekf.x[4:].copy()
