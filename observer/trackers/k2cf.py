"""K²CF: a KCF whose detection window is placed by an adaptive Kalman predictor (seed 004 §3.2).

Per frame k (seed 004 §3.2.1-3.2.3, with T = 1 frame):

1. **Predict** (eq. 12): s⁻ = A s, P⁻ = A P Aᵀ + Q_{k-1}, constant velocity, s = (u, v, u̇, v̇) in
   image px and px/frame of the frame; no control input (B u = 0).
2. **Detect at the prediction** (eqs. 13-16): the KCF's window (``kcf_numpy.NumpyKCF``) is cut at
   H s⁻, so the target lies inside the window even when it moves fast; the response peak gives
   the shift n between the predicted and the detected position (eq. 20).
3. **Correct** (eq. 17, 24): the detected position Y = H s⁻ + n updates the filter with a constant
   R ("the imaging system is low-noise"); the KCF model is updated at Y. Seed 004 eq. 23 adds n·T
   to the velocity; the Kalman gain applied to the innovation n does this correction in the
   filter's own proportion, so we use eq. 17 alone.
4. **Adapt Q** (eqs. 18, 19, 22): Q_k = 2 δ σ² I₄ with δ = |a_k + a_{k-2} - 2 a_{k-1}| / T from the
   accelerations a_k = (Y_k - 2 Y_{k-1} + Y_{k-2}) / T² of the last detections, and
   σ² = η |2 n / T²|. Vector norms stand in for the seed's scalar absolute values. Our choices:
   η (the seed's "linear factor" is not given), Q clipped to [q_min, q_max] (with a constant
   acceleration δ = 0 would freeze the filter), and Q = q_init until five detections exist.

Occlusion (our choice, the threshold idea the seed cites from its ref. [41]): when the response
peak is below ``min_peak`` the detection is ignored, the prediction stands in (``measured`` is
False) and neither the filter nor the KCF model is updated; after ``max_coast_frames`` such frames
in a row the tracker reports ``lost`` (it keeps predicting and searching at the prediction, and the
next good peak re-acquires).

API: ``observer.tracking.SingleObjectTracker``; the result is ``valid`` unless the track is
lost and ``measured`` unless the prediction stood in. Boxes and positions are in *image* px of the
frame; the score is the KCF peak.
"""

from __future__ import annotations

import math
import time
from collections import deque

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from observer.gk.hsv_gate import check_rgb_image
from observer.gk.pixel_kalman import F_CV, H_CV
from observer.trackers.kcf_numpy import KCFConfig, NumpyKCF
from observer.tracking import TrackResult

_A, _H = F_CV, H_CV  # the constant-velocity model, T = 1 frame (seed 004 eq. 12)


class K2CFConfig(BaseModel):
    """Parameters of K²CF. Units: image px of the tracked frame, Δt = T = 1 frame."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kcf: KCFConfig = Field(
        default_factory=KCFConfig,
        description="The correlation filter; its update gate ``min_update_peak`` is replaced "
        "by ``min_peak``.",
    )
    R_px2: float = Field(
        0.25, gt=0.0, description="Our choice: measurement variance of a KCF detection, image "
        "px² (seed 004: a constant R for a low-noise imaging system)."
    )
    eta: float = Field(
        0.5, gt=0.0, description="Our choice: η of seed 004 eq. 22 (σ² = η |2n/T²|)."
    )
    q_init: float = Field(
        1.0, gt=0.0, description="Our choice: Q scale until five detections give δ."
    )
    q_min: float = Field(
        1e-2, gt=0.0, description="Our choice: floor of the adaptive Q scale (seed 000's 0.01)."
    )
    q_max: float = Field(100.0, gt=0.0, description="Our choice: ceiling of the Q scale.")
    velocity_var0: float = Field(
        100.0, gt=0.0, description="Our choice: initial velocity variance, (image px/frame)²."
    )
    min_peak: float = Field(
        0.25, ge=0.0, description="Our choice: a response peak below this is not a detection."
    )
    max_coast_frames: int = Field(
        18, ge=0, description="Our choice (as the GK assistance): coasting frames before lost."
    )


class K2CF:
    """Single-target K²CF (see the module docstring).

    Attributes
    ----------
    compute_time_s : wall-clock time of the last ``initialize``/``track``, s.
    x : (4,) state (u, v, u̇, v̇), image px and px/frame.
    P : (4, 4) state covariance.
    q_scale : current adaptive Q scale (Q = q_scale·I₄), image px².
    lost, measured, reason : status of the last ``track``.
    """

    def __init__(self, config: K2CFConfig | None = None) -> None:
        self.config = config or K2CFConfig()
        kcf_cfg = self.config.kcf.model_copy(update={"min_update_peak": self.config.min_peak})
        self.kcf = NumpyKCF(kcf_cfg)
        self.compute_time_s = 0.0
        self.x = np.full(4, np.nan)
        self.P = np.eye(4)
        self.q_scale = self.config.q_init
        self.lost = True
        self.measured = False
        self.reason = "not initialised"
        self._coast = 0
        self._detections: deque[NDArray[np.float64]] = deque(maxlen=5)

    @property
    def initialised(self) -> bool:
        """Whether ``initialize`` has been called (the inner KCF has a model)."""
        return self.kcf.initialised

    def initialize(self, frame: NDArray[np.uint8], box_image_px: ArrayLike) -> None:
        """Start on the target in ``box_image_px`` (x, y, w, h), image px; ``ValueError`` for
        an unusable frame or box (see ``NumpyKCF.initialize``)."""
        t0 = time.perf_counter()
        self.kcf.initialize(frame, box_image_px)
        c = self.kcf.centre_image_px
        cfg = self.config
        self.x = np.array([c[0], c[1], 0.0, 0.0])
        self.P = np.diag([cfg.R_px2, cfg.R_px2, cfg.velocity_var0, cfg.velocity_var0])
        self.q_scale = cfg.q_init
        self._detections.clear()
        self._detections.append(c.copy())
        self._coast = 0
        self.lost, self.measured, self.reason = False, True, ""
        self.compute_time_s = time.perf_counter() - t0

    def _adapt_q(self, n: NDArray[np.float64]) -> float:
        """Q scale 2 δ σ² from the detection history and the prediction error n (eqs. 18-22)."""
        cfg = self.config
        if len(self._detections) < 5:
            return cfg.q_init
        Y = np.array(self._detections)  # oldest first, Y[-1] = Y_k
        a = Y[2:] - 2.0 * Y[1:-1] + Y[:-2]  # a_{k-2}, a_{k-1}, a_k
        delta = float(np.linalg.norm(a[2] + a[0] - 2.0 * a[1]))
        sigma2 = cfg.eta * float(np.linalg.norm(2.0 * n))
        return float(np.clip(2.0 * delta * sigma2, cfg.q_min, cfg.q_max))

    def track(
        self, frame: NDArray[np.uint8], search_centre_image_px: ArrayLike | None = None
    ) -> TrackResult:
        """Box (x, y, w, h), image px, and score (the KCF peak) in the next frame.

        The window is placed at the Kalman prediction (or at ``search_centre_image_px`` if
        given). A frame that is not an RGB uint8 image at all (``check_rgb_image``: None, a
        list, floats, an empty array) gives a failed result with the reason and leaves the
        track as it was; a KCF peak below ``min_peak`` coasts (prediction, ``measured``
        False) with score 0.
        """
        t0 = time.perf_counter()
        bad = check_rgb_image(frame)
        if bad:
            return TrackResult.failed(bad, time.perf_counter() - t0)
        box, score = self._track(frame, search_centre_image_px)
        self.compute_time_s = time.perf_counter() - t0
        return TrackResult(box, score, not self.lost, self.reason, self.compute_time_s,
                           self.measured)

    def _track(
        self, frame: NDArray[np.uint8], search_centre: ArrayLike | None
    ) -> tuple[NDArray[np.float64], float]:
        cfg = self.config
        if not self.initialised:
            self.lost, self.measured, self.reason = True, False, "not initialised"
            return np.full(4, np.nan), 0.0
        # 1. predict (eq. 12)
        self.x = _A @ self.x
        self.P = _A @ self.P @ _A.T + self.q_scale * np.eye(4)
        prior = _H @ self.x
        centre = prior if search_centre is None else np.asarray(search_centre, float).reshape(2)
        score = 0.0
        if np.all(np.isfinite(centre)):
            # 2. detect at the prediction (eqs. 13-16)
            det = self.kcf.track(frame, centre)
            box, score = det.box_image_px, det.score if math.isfinite(det.score) else 0.0
        else:
            box = np.full(4, np.nan)
        if score >= cfg.min_peak and np.all(np.isfinite(box)):
            # 3. correct (eqs. 17, 20, 24)
            Y = box[:2] + 0.5 * box[2:]
            n = Y - prior
            S = _H @ self.P @ _H.T + cfg.R_px2 * np.eye(2)
            K = self.P @ _H.T @ np.linalg.inv(S)
            self.x = self.x + K @ n
            IKH = np.eye(4) - K @ _H
            self.P = IKH @ self.P @ IKH.T + cfg.R_px2 * K @ K.T
            self._detections.append(Y)
            # 4. adapt Q for the next step (eqs. 18-22)
            self.q_scale = self._adapt_q(n)
            self._coast = 0
            self.lost, self.measured, self.reason = False, True, ""
            pos = Y
        else:
            # occlusion: the prediction stands in; the KCF keeps its model
            self.kcf.centre_image_px = prior.copy()
            self._detections.clear()
            self._coast += 1
            self.measured = False
            why = f"KCF peak {score:.3g} < {cfg.min_peak}"
            if self._coast > cfg.max_coast_frames:
                self.lost = True
                self.reason = f"{why}; no detection for {self._coast} frames"
            else:
                self.reason = f"{why}; predicting"
            pos = prior
        size = self.kcf.size_image_px
        return np.r_[pos - 0.5 * size, size], float(score)
