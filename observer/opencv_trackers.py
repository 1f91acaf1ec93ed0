"""OpenCV's KCF and CSRT trackers (opencv-contrib) behind the tracker seam of DESIGN.md.

``init(frame, box)`` and ``track(frame) -> (box, score)``: frames are RGB uint8 (as our renderers
produce them; converted to OpenCV's BGR inside), boxes are (x, y, w, h) in *image* pixels of the
frame. The score is 1.0 when OpenCV reports success and 0.0 when it reports a failure (then the
box is NaN); these trackers have no calibrated confidence. Seed 000 §4 uses both as baselines.
"""

from __future__ import annotations

import time
from typing import Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

TrackerKind = Literal["kcf", "csrt"]


class OpenCVTracker:
    """KCF (``kind="kcf"``) or CSRT (``kind="csrt"``) single-object tracker.

    Attributes
    ----------
    compute_time_s : wall-clock time of the last ``init`` or ``track`` call, s.
    """

    def __init__(self, kind: TrackerKind = "kcf") -> None:
        if kind not in ("kcf", "csrt"):
            raise ValueError(f"kind must be 'kcf' or 'csrt', got {kind!r}")
        self.kind = kind
        self._tracker: cv2.Tracker | None = None
        self.compute_time_s = 0.0

    def _create(self) -> cv2.Tracker:
        return cv2.TrackerKCF.create() if self.kind == "kcf" else cv2.TrackerCSRT.create()

    def init(self, frame: NDArray[np.uint8], box_image_px: ArrayLike) -> None:
        """Start tracking the object in ``box_image_px`` (x, y, w, h), image px."""
        box = np.asarray(box_image_px, dtype=float)
        if box.shape != (4,) or not np.all(np.isfinite(box)) or box[2] <= 0 or box[3] <= 0:
            raise ValueError(f"box_image_px must be a finite (x, y, w, h) with w, h > 0: {box}")
        t0 = time.perf_counter()
        self._tracker = self._create()
        x, y, w, h = (int(round(v)) for v in box)
        self._tracker.init(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR), (x, y, max(w, 1), max(h, 1)))
        self.compute_time_s = time.perf_counter() - t0

    def track(self, frame: NDArray[np.uint8]) -> tuple[NDArray[np.float64], float]:
        """Box (x, y, w, h) in image px and score for the next frame; NaN box and score 0.0
        when the tracker reports a failure or was never initialised."""
        if self._tracker is None:
            return np.full(4, np.nan), 0.0
        t0 = time.perf_counter()
        ok, box = self._tracker.update(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        self.compute_time_s = time.perf_counter() - t0
        if not ok:
            return np.full(4, np.nan), 0.0
        return np.asarray(box, dtype=float), 1.0
