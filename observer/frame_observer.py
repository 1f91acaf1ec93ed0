"""Frames -> attitude: ``FrameObserver.update(frame, t_exposure) -> Estimate``.

Built from two replaceable parts:

* a **pair tracker** (``observer.tracking.PairTracker``, ``observer.trackers``): frame -> both
  marker centres, e.g. GK-TransT (seed 000 §3.2) or OpenCV's KCF inside the GK assistance
  (``observer.trackers.make_pair_tracker("kcf_gk")``);
* an attitude **back end** (``observer.pixel_observer``): a per-frame solver or the EKF/AEKF.

The timed loop uses the same pair tracker (``latency.frontends.ImageFrontEnd``) and the back end
separately, so that it can release the estimate after the observer's latency.

Bad frames (never a crash in the middle of a loop, never a silent wrong number): a frame that
fails ``observer.gk.hsv_gate.check_frame`` is not given to the tracker; the pair tracker's result
is ``lost`` with the problem in ``bad_frame`` and the estimate is flagged ``valid=False``,
``lost=True``, with a reason that starts with ``"bad frame: "``.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from observer.pixel_observer import PixelObserver
from observer.tracking import PairTracker
from plant import attitude
from plant.estimate import Estimate
from plant.scene import Frame


class FrameObserver:
    """``update(frame, t_exposure) -> Estimate`` from a pair tracker and a pixel back end.

    The estimate is released immediately (``t_available = t_exposure`` + the measured compute
    time); the timed loop instead releases through its latency model.

    A bad frame reaches the back end as a lost frame (it predicts or holds) and the estimate is
    flagged ``valid=False``, ``lost=True``, with a reason that starts with ``"bad frame: "``.
    The pair tracker's reasons (for example that the Kalman prediction stood in for the
    tracker) are kept in the estimate's ``reason``.
    """

    def __init__(self, locator: PairTracker, backend: PixelObserver) -> None:
        self.locator = locator
        self.backend = backend

    def reset(self, q0: ArrayLike = (1.0, 0.0, 0.0, 0.0), t0: float = 0.0) -> None:
        self.locator.reset()
        self.backend.reset(q0, t0)

    def start(self, image: NDArray[np.uint8], binning: int, boxes_sensor_px: ArrayLike) -> None:
        """Start the pair tracker on the red and yellow boxes (2, 4), sensor px."""
        self.locator.start(image, boxes_sensor_px, binning)

    def update(self, frame: Frame, t_exposure: float) -> Estimate:
        """Estimate from one ``plant.scene.Frame`` taken at mid-exposure ``t_exposure`` (s)."""
        t0 = time.perf_counter()
        loc = self.locator.step(frame.image)
        self.backend.process(loc.marker_px, t_exposure, loc.lost, loc.reason, loc.compute_time_s)
        elapsed = time.perf_counter() - t0
        est = self.backend.release(t_exposure + elapsed)
        reason = est.reason
        if loc.reason and loc.reason not in reason:
            reason = f"{loc.reason}; {reason}" if reason else loc.reason
        if loc.bad_frame:
            return replace(est, valid=False, lost=True, reason=reason)
        if reason != est.reason:
            est = replace(est, reason=reason)
        if est.valid:
            self.locator.tilt_hint_rad = attitude.tilt(est.q)
        return est
