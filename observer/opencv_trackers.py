"""OpenCV's KCF and CSRT trackers (opencv-contrib) behind the tracker seam of DESIGN.md.

``init(frame, box)`` and ``track(frame) -> (box, score)``: frames are RGB uint8 (as our renderers
produce them; converted to OpenCV's BGR inside), boxes are (x, y, w, h) in *image* pixels of the
frame. The score is 1.0 when OpenCV reports success and 0.0 when it reports a failure (then the
box is NaN); these trackers have no calibrated confidence. Seed 000 §4 uses both as baselines.

Bad input: ``init`` raises ``ValueError`` for an unusable frame (see
``observer.gk.hsv_gate.check_rgb_image``: not (H, W, 3) uint8, or empty) or box. ``track`` never
raises: an unusable frame, a frame whose shape differs from the init frame's, a featureless
frame (all black or all white, ``check_featureless``: OpenCV's KCF reports success on it), no
``init`` or an OpenCV error give a NaN box, score 0.0 and the reason in ``reason``.
"""

from __future__ import annotations

import time
from typing import Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from observer.gk.hsv_gate import check_featureless, check_rgb_image

TrackerKind = Literal["kcf", "csrt"]


class OpenCVTracker:
    """KCF (``kind="kcf"``) or CSRT (``kind="csrt"``) single-object tracker.

    Attributes
    ----------
    compute_time_s : wall-clock time of the last ``init`` or ``track`` call, s.
    reason : why the last ``track`` gave no box ("" when it gave one or OpenCV merely reported
        a tracking failure, which is the tracker's own verdict, not bad input).
    """

    def __init__(self, kind: TrackerKind = "kcf") -> None:
        if kind not in ("kcf", "csrt"):
            raise ValueError(f"kind must be 'kcf' or 'csrt', got {kind!r}")
        self.kind = kind
        self._tracker: cv2.Tracker | None = None
        self._frame_shape: tuple[int, ...] | None = None
        self.compute_time_s = 0.0
        self.reason = ""

    def _create(self) -> cv2.Tracker:
        return cv2.TrackerKCF.create() if self.kind == "kcf" else cv2.TrackerCSRT.create()

    def init(self, frame: NDArray[np.uint8], box_image_px: ArrayLike) -> None:
        """Start tracking the object in ``box_image_px`` (x, y, w, h), image px of ``frame``
        (RGB uint8). Raises ``ValueError`` for an unusable frame or box, or if OpenCV refuses
        them."""
        bad = check_rgb_image(frame)
        if bad:
            raise ValueError(f"init frame: {bad}")
        box = np.asarray(box_image_px, dtype=float).reshape(-1)
        if box.shape != (4,) or not np.all(np.isfinite(box)) or box[2] <= 0 or box[3] <= 0:
            raise ValueError(f"box_image_px must be a finite (x, y, w, h) with w, h > 0: {box}")
        t0 = time.perf_counter()
        tracker = self._create()
        x, y, w, h = (int(round(v)) for v in box)
        try:
            tracker.init(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR), (x, y, max(w, 1), max(h, 1)))
        except cv2.error as exc:
            raise ValueError(f"OpenCV {self.kind.upper()} refused the init frame/box {box}: "
                             f"{exc}") from exc
        self._tracker = tracker
        self._frame_shape = frame.shape
        self.reason = ""
        self.compute_time_s = time.perf_counter() - t0

    def track(self, frame: NDArray[np.uint8]) -> tuple[NDArray[np.float64], float]:
        """Box (x, y, w, h) in image px and score for the next frame; NaN box and score 0.0
        when the tracker reports a failure, was never initialised or the frame is unusable
        (``reason`` then says why)."""
        nan_box = np.full(4, np.nan)
        if self._tracker is None:
            self.reason = "tracker not initialised"
            return nan_box, 0.0
        bad = check_rgb_image(frame)
        if not bad and frame.shape != self._frame_shape:
            bad = f"frame shape {frame.shape} differs from the init frame's {self._frame_shape}"
        bad = bad or check_featureless(frame)
        if bad:
            self.reason = bad
            return nan_box, 0.0
        t0 = time.perf_counter()
        try:
            ok, box = self._tracker.update(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        except cv2.error as exc:  # should not happen after the checks above; never crash a loop
            self.reason = f"OpenCV {self.kind.upper()} error: {exc}"
            return nan_box, 0.0
        finally:
            self.compute_time_s = time.perf_counter() - t0
        self.reason = ""
        if not ok:
            return nan_box, 0.0
        return np.asarray(box, dtype=float), 1.0
