"""OpenCV's KCF and CSRT trackers (opencv-contrib) as ``observer.tracking.SingleObjectTracker``.

``initialize(frame, box)`` and ``track(frame) -> TrackResult``: frames are RGB uint8 (as our
renderers produce them; converted to OpenCV's BGR inside), boxes are (x, y, w, h) in *image*
pixels of the frame. The score is 1.0 when OpenCV reports success and 0.0 when it reports a
failure (then the box is NaN and the result not valid); these trackers have no calibrated
confidence. They search around their previous box only: a ``search_centre_image_px`` is ignored
(``observer.trackers.gk_transt`` restarts them on the prediction instead). Seed 000 §4 uses both
as baselines.

Bad input: ``initialize`` raises ``ValueError`` for an unusable frame (see
``observer.gk.hsv_gate.check_rgb_image``: not (H, W, 3) uint8, or empty) or box. ``track`` never
raises: an unusable frame, a frame whose shape differs from the init frame's, a featureless
frame (all black or all white: OpenCV's KCF reports success on it; the frame check is
``observer.gk.hsv_gate.check_frame``), no ``initialize`` or an OpenCV error give a failed
result with the reason.
"""

from __future__ import annotations

import time
from typing import Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from observer.gk.hsv_gate import check_frame, check_rgb_image
from observer.tracking import TrackResult

TrackerKind = Literal["kcf", "csrt"]


class OpenCVTracker:
    """KCF (``kind="kcf"``) or CSRT (``kind="csrt"``) single-object tracker."""

    def __init__(self, kind: TrackerKind = "kcf") -> None:
        if kind not in ("kcf", "csrt"):
            raise ValueError(f"kind must be 'kcf' or 'csrt', got {kind!r}")
        self.kind = kind
        self._tracker: cv2.Tracker | None = None
        self._frame_shape: tuple[int, ...] | None = None

    def _create(self) -> cv2.Tracker:
        return cv2.TrackerKCF.create() if self.kind == "kcf" else cv2.TrackerCSRT.create()

    def initialize(self, frame: NDArray[np.uint8], box_image_px: ArrayLike) -> None:
        """Start tracking the object in ``box_image_px`` (x, y, w, h), image px of ``frame``
        (RGB uint8). Raises ``ValueError`` for an unusable frame or box, or if OpenCV refuses
        them."""
        bad = check_rgb_image(frame)
        if bad:
            raise ValueError(f"init frame: {bad}")
        box = np.asarray(box_image_px, dtype=float).reshape(-1)
        if box.shape != (4,) or not np.all(np.isfinite(box)) or box[2] <= 0 or box[3] <= 0:
            raise ValueError(f"box_image_px must be a finite (x, y, w, h) with w, h > 0: {box}")
        tracker = self._create()
        x, y, w, h = (int(round(v)) for v in box)
        try:
            tracker.init(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR), (x, y, max(w, 1), max(h, 1)))
        except cv2.error as exc:
            raise ValueError(f"OpenCV {self.kind.upper()} refused the init frame/box {box}: "
                             f"{exc}") from exc
        self._tracker = tracker
        self._frame_shape = frame.shape

    def track(
        self, frame: NDArray[np.uint8], search_centre_image_px: ArrayLike | None = None
    ) -> TrackResult:
        """Box (x, y, w, h) in image px and score for the next frame (``search_centre_image_px``
        is ignored: see the module docstring). Never raises."""
        t0 = time.perf_counter()
        if self._tracker is None:
            return TrackResult.failed("tracker not initialised", time.perf_counter() - t0)
        bad = check_frame(frame, init_shape=self._frame_shape)
        if bad:
            return TrackResult.failed(bad, time.perf_counter() - t0)
        try:
            ok, box = self._tracker.update(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        except cv2.error as exc:  # should not happen after the checks above; never crash a loop
            return TrackResult.failed(f"OpenCV {self.kind.upper()} error: {exc}",
                                      time.perf_counter() - t0)
        if not ok:
            return TrackResult.failed(f"OpenCV {self.kind.upper()} reported a tracking failure",
                                      time.perf_counter() - t0)
        return TrackResult(np.asarray(box, dtype=float), 1.0, True, "", time.perf_counter() - t0)
