"""Pixel-space constant-velocity Kalman filter of the main marker (seed 000 §3.2.1).

The state is the marker centre and its velocity in the image, ``X = (u, v, u̇, v̇)ᵀ``, in
*full-sensor* pixels and sensor pixels per frame (the seed's unit; its Q and R are in these
units). One step is one frame (Δt = 1 frame), so the model of seed 000 §3.2.1 is

    X_k = F X_{k-1} + W_{k-1},    Z_k = H X_k + V_k,

    F = [[1, 0, 1, 0],          H = [[1, 0, 0, 0],
         [0, 1, 0, 1],               [0, 1, 0, 0]]
         [0, 0, 1, 0],
         [0, 0, 0, 1]]

with W ~ N(0, Q), V ~ N(0, R), defaults Q = 0.01·I4 and R = 0.1·I2 (seed 000 §3.2.1). The
observation Z_k is the centre of the main tracker's box (optionally refined to sub-pixel accuracy
by ``observer.gk.subpixel``).

The filtering itself is filterpy's ``KalmanFilter`` (predict: x = F x, P = F P Fᵀ + Q; update:
K = P Hᵀ (H P Hᵀ + R)⁻¹, x = x + K (z − H x), P = (I − K H) P (I − K H)ᵀ + K R Kᵀ). This module
adds the seed's matrices, validated configuration, the first-measurement initialisation and the
"coast" step used when the HSV gate says the observation is unreliable: then the prediction stands
in for the observation. Coasting skips the update rather than feeding the prediction back as a
measurement: the state is the same either way, but a pseudo-measurement would shrink P as if
something had been observed, and P would no longer say how stale the position is.

Frames are assumed equally spaced; a dropped frame should be covered by an extra ``predict``.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from filterpy.kalman import KalmanFilter
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, field_validator

#: The constant-velocity model of one image coordinate, state (position, velocity), Δt = 1 frame:
#: transition and observation of the position only (seed 000 §3.2.1).
F_CV_AXIS: NDArray[np.float64] = np.array([[1.0, 1.0], [0.0, 1.0]])
H_CV_AXIS: NDArray[np.float64] = np.array([[1.0, 0.0]])
#: The same model of both coordinates, state (u, v, u̇, v̇): the F and H above (seed 000 §3.2.1).
F_CV: NDArray[np.float64] = np.kron(F_CV_AXIS, np.eye(2))
H_CV: NDArray[np.float64] = np.kron(H_CV_AXIS, np.eye(2))

#: Relative tolerance of the symmetry and eigenvalue checks of Q and R.
_PSD_RTOL = 1e-9


def _as_matrix(value: object) -> list[list[float]]:
    """Accept a nested sequence or a numpy array; pydantic then checks the element types."""
    if isinstance(value, np.ndarray):
        return value.astype(float).tolist()
    return value  # type: ignore[return-value]


Matrix = Annotated[list[list[float]], BeforeValidator(_as_matrix)]


def _check_covariance(name: str, value: list[list[float]], n: int, definite: bool) -> None:
    """Raise ``ValueError`` naming ``name`` unless ``value`` is a finite, symmetric n x n matrix
    that is positive semi-definite (positive definite when ``definite``)."""
    M = np.asarray(value, dtype=float)
    if M.shape != (n, n):
        raise ValueError(f"{name} must be a {n}x{n} matrix, got shape {M.shape}")
    if not np.all(np.isfinite(M)):
        raise ValueError(f"{name} must be finite")
    scale = max(float(np.max(np.abs(M))), 1e-300)
    if not np.allclose(M, M.T, rtol=0.0, atol=_PSD_RTOL * scale):
        raise ValueError(f"{name} must be symmetric")
    lam_min = float(np.linalg.eigvalsh(0.5 * (M + M.T)).min())
    if definite and lam_min <= 0.0:
        raise ValueError(f"{name} must be positive definite (smallest eigenvalue {lam_min:.3g})")
    if lam_min < -_PSD_RTOL * scale:
        raise ValueError(
            f"{name} must be positive semi-definite (smallest eigenvalue {lam_min:.3g})"
        )


#: Our choice: the smallest measurement variance, sensor px² (sigma = 1e-6 px, a millionth of a
#: pixel; the seed's R is 0.1 px²). A centre is never known better, and below it the filter's
#: gain rounds to 1 at sensor coordinates of thousands of pixels (float64 keeps about 1e-12 px
#: of them): a variance such as 1e-300 passes "positive definite" but means nothing.
R_MIN_PX2 = 1e-12


class PixelKalmanConfig(BaseModel):
    """Noise covariances of the pixel Kalman filter, in full-sensor pixels (Δt = 1 frame).

    ``Q`` must be symmetric positive semi-definite. ``R`` must be symmetric positive *definite*:
    a pixel measurement with zero variance in some direction makes no physical sense and would
    make the innovation covariance H P Hᵀ + R singular once P has converged; every variance of
    ``R`` must be at least ``R_MIN_PX2``.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    Q: Matrix = Field(
        default_factory=lambda: (0.01 * np.eye(4)).tolist(),
        description="Process noise covariance (4x4) of (u, v, u̇, v̇) per frame, sensor px² and "
        "(sensor px/frame)². Seed 000 §3.2.1: 0.01·I4.",
    )
    R: Matrix = Field(
        default_factory=lambda: (0.1 * np.eye(2)).tolist(),
        description="Measurement noise covariance (2x2) of the observed centre, sensor px². "
        "Seed 000 §3.2.1: 0.1·I2.",
    )
    velocity_var0: float = Field(
        2500.0,
        gt=0.0,
        description="Our choice: initial variance of each velocity component, (sensor "
        "px/frame)². Large (σ = 50 px/frame, about 2 mm per frame at the VFC) so that the second "
        "measurement sets the velocity.",
    )

    @field_validator("Q")
    @classmethod
    def _q_psd(cls, v: list[list[float]]) -> list[list[float]]:
        _check_covariance("Q", v, 4, definite=False)
        return v

    @field_validator("R")
    @classmethod
    def _r_pd(cls, v: list[list[float]]) -> list[list[float]]:
        _check_covariance("R", v, 2, definite=True)
        lam_min = float(np.linalg.eigvalsh(np.asarray(v, dtype=float)).min())
        if lam_min < R_MIN_PX2:
            raise ValueError(f"R must have every variance >= {R_MIN_PX2:g} sensor px² "
                             f"(smallest eigenvalue {lam_min:.3g})")
        return v


class PixelKalman:
    """Constant-velocity Kalman filter of one marker centre in full-sensor pixels.

    Use per frame: ``predict()`` (the prior, the tracker's search centre), then either
    ``update(z)`` with a confident observation or ``coast()`` when the observation is unreliable,
    in which case the prior stands in for it (seed 000 §3.2.1). Before the first observation the
    filter is uninitialised; ``initialise(z)`` (or the first ``update``) sets
    ``X = (z, 0, 0)`` with ``P = diag(R, velocity_var0·I2)``.

    Attributes
    ----------
    kf : filterpy.kalman.KalmanFilter
        The underlying filter (``kf.x`` (4, 1), ``kf.P`` (4, 4), ``kf.K`` (4, 2), ...).
    initialised : bool
        Whether a first observation has been seen since construction or ``reset()``.

    Mirrored in ``latency.compiled.observer._pixel_kalman``; keep both in step
    (tests/test_compiled_mirror.py checks them equal).
    """

    def __init__(self, config: PixelKalmanConfig | None = None) -> None:
        self.config = config or PixelKalmanConfig()
        self.kf = KalmanFilter(dim_x=4, dim_z=2)
        self.kf.F = F_CV.copy()
        self.kf.H = H_CV.copy()
        self.kf.Q = np.asarray(self.config.Q, dtype=float)
        self.kf.R = np.asarray(self.config.R, dtype=float)
        self.initialised = False

    # --- state ---------------------------------------------------------------------------------
    @property
    def x(self) -> NDArray[np.float64]:
        """Current state (u, v, u̇, v̇), sensor px and sensor px/frame (NaN if uninitialised)."""
        return self.kf.x[:, 0].copy() if self.initialised else np.full(4, np.nan)

    @property
    def position(self) -> NDArray[np.float64]:
        """Current position (u, v), sensor px: the prior after ``predict``/``coast``, the
        posterior after ``update`` (NaN if uninitialised)."""
        return self.x[:2]

    @property
    def position_cov(self) -> NDArray[np.float64]:
        """Covariance (2, 2) of ``position``, sensor px² (NaN if uninitialised)."""
        return self.kf.P[:2, :2].copy() if self.initialised else np.full((2, 2), np.nan)

    def peek(self, n_frames: int = 1) -> NDArray[np.float64]:
        """Position (u, v), sensor px, predicted ``n_frames`` ahead of the current state
        without changing it: ``H Fⁿ X``. NaN if uninitialised."""
        if not self.initialised:
            return np.full(2, np.nan)
        return (H_CV @ np.linalg.matrix_power(F_CV, int(n_frames)) @ self.kf.x)[:, 0]

    # --- steps ---------------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the state; the next observation initialises the filter again."""
        self.kf.x = np.zeros((4, 1))
        self.kf.P = np.eye(4)
        self.initialised = False

    def initialise(self, z: ArrayLike) -> None:
        """Set X = (z, 0, 0), P = diag(R, velocity_var0·I2) from an observation z (sensor px).

        Raises ``ValueError`` if z is not a finite (2,) vector (callers in a loop check first).
        """
        z = _check_z(z)
        if z is None:
            raise ValueError("z must be a finite (2,) vector of sensor pixels")
        self.kf.x = np.array([[z[0]], [z[1]], [0.0], [0.0]])
        P = np.zeros((4, 4))
        P[:2, :2] = self.kf.R
        P[2:, 2:] = self.config.velocity_var0 * np.eye(2)
        self.kf.P = P
        self.kf.x_post, self.kf.P_post = self.kf.x.copy(), self.kf.P.copy()
        self.initialised = True

    def predict(self) -> NDArray[np.float64]:
        """Time update X⁻ = F X, P⁻ = F P Fᵀ + Q; returns the prior position (u, v), sensor px
        (NaN, and nothing done, if uninitialised)."""
        if not self.initialised:
            return np.full(2, np.nan)
        self.kf.predict()
        return self.position

    def update(self, z: ArrayLike, extra_var_px2: float = 0.0) -> bool:
        """Measurement update with the observed centre z (u, v), sensor px, whose noise is
        R + ``extra_var_px2``·I2 (sensor px²; an observation less certain than R says).

        Initialises the filter if it is not yet. Returns False and coasts (no update) if z is not
        a finite (2,) vector, so a bad observation never raises inside a tracking loop.
        """
        zz = _check_z(z)
        if zz is None:
            self.coast()
            return False
        if not self.initialised:
            self.initialise(zz)
            return True
        R = self.kf.R + float(extra_var_px2) * np.eye(2) if extra_var_px2 > 0.0 else None
        self.kf.update(zz.reshape(2, 1), R=R)
        return True

    def coast(self) -> None:
        """No observation this frame: the prior stands in (seed 000 §3.2.1). P is left at its
        prior value, so it keeps growing by Q (and F) each frame."""
        if self.initialised:
            self.kf.update(None)


def _check_z(z: ArrayLike) -> NDArray[np.float64] | None:
    """z as a finite (2,) float array, or None."""
    try:
        arr = np.asarray(z, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        return None
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        return None
    return arr
