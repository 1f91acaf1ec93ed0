"""One independent single-object tracker per marker, run one after the other.

This is how seed 000 §4.2 runs its baselines on the two markers: the "original TransT" is two
independent TransT models (one per marker; its Table 1 latency of 31.23 ms is the pair), and KCF
and CSRT are likewise one instance per marker. ``IndependentPairTracker`` wraps any tracker with
the seam's API (``init(frame, box_image_px)``, ``track(frame) -> (box_image_px, score)``,
``compute_time_s``): ``observer.transt.tracker.TransTTracker`` (dual TransT),
``observer.opencv_trackers.OpenCVTracker`` (KCF, CSRT), ``NumpyKCF`` and ``K2CF``.

Per frame and marker (red first, then yellow): the tracker's box; the marker is **lost** when the
box is not finite, or the score is at most ``lost_score`` (our choice: 0.2; OpenCV's trackers
report 1 or 0, the numpy KCF its response peak, TransT its classification confidence), or the
tracker itself says so (an attribute ``lost``, as ``K2CF`` has). A lost marker keeps the
tracker's finite box as its (flagged) position; there is no prediction and no re-detection beyond
what the tracker does itself, as in the seed's baselines. An unusable frame gives no estimate,
except for trackers that coast on their own prediction (``K2CF``), which keep predicting. With
``refine`` the centre of a tracked marker is the sub-pixel circle fit (seed 004 §4) when it is
valid and inside the box.

Units: boxes and centres in results are full-sensor px; the single trackers work in image px of
the binned frame.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from observer.gk.hsv_gate import box_image_to_sensor, box_sensor_to_image
from observer.gk.subpixel import SubpixelConfig
from observer.trackers import MARKERS, MarkerPairTracker, PairResult, box_around
from plant.params import PlantParams


class IndependentPairTracker(MarkerPairTracker):
    """Two independent single-object trackers, red then yellow (see the module docstring).

    Parameters
    ----------
    factory : callable returning a new single-object tracker (called once per marker).
    params : PlantParams, optional
    refine : bool
        Sub-pixel circle-fit centres (seed 004 §4).
    subpixel : SubpixelConfig, optional
    name : str
        Name in tables ("dual_transt", "kcf", "csrt", ...).
    lost_score : float
        A score at or below this flags the marker lost (our choice 0.2).
    """

    def __init__(
        self,
        factory: Callable[[], Any],
        params: PlantParams | None = None,
        refine: bool = False,
        subpixel: SubpixelConfig | None = None,
        name: str = "independent",
        lost_score: float = 0.2,
    ) -> None:
        super().__init__(params, refine, subpixel)
        self.factory = factory
        self.name = name
        self.lost_score = float(lost_score)
        self.trackers: list[Any] = []

    def _start(self, image: NDArray[np.uint8], boxes_sensor_px: NDArray[np.float64]) -> None:
        assert self.binning is not None
        self.trackers = []
        for box in boxes_sensor_px:
            tr = self.factory()
            tr.init(image, box_sensor_to_image(box, self.binning))
            self.trackers.append(tr)

    def _one(
        self, image: NDArray[np.uint8], k: int
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], bool, float, float, str]:
        """(centre, box, lost, score, time, reason) of marker k, sensor px."""
        assert self.binning is not None
        tr = self.trackers[k]
        box_img, score = tr.track(image)
        dt = float(getattr(tr, "compute_time_s", math.nan))
        score = float(score) if score is not None else math.nan
        box_img = np.asarray(box_img, dtype=float).reshape(-1)
        if box_img.shape != (4,) or not np.all(np.isfinite(box_img)):
            return np.full(2, np.nan), np.full(4, np.nan), True, score, dt, \
                f"{MARKERS[k]}: tracker reported no box"
        box = box_image_to_sensor(box_img, self.binning)
        centre = box[:2] + 0.5 * box[2:]
        own_lost = getattr(tr, "lost", None)
        if own_lost is not None:
            lost = bool(own_lost)
            why = f"{MARKERS[k]}: {getattr(tr, 'reason', '') or 'tracker lost'}" if lost else ""
        else:
            lost = not score > self.lost_score
            why = f"{MARKERS[k]}: score {score:.3g} <= {self.lost_score}" if lost else ""
        measured = not lost and bool(getattr(tr, "measured", True))
        if measured and self.refine:
            c = self._refine(image, MARKERS[k], box)
            if c is not None:
                centre = c
        return centre, box_around(centre, box[2:]), lost, score, dt, why

    def _step(self, image: NDArray[np.uint8]) -> PairResult:
        (rc, rb, rl, rs, rt, rw), (yc, yb, yl, ys, yt, yw) = (self._one(image, k) for k in (0, 1))
        measured = [not rl and bool(getattr(self.trackers[0], "measured", True)),
                    not yl and bool(getattr(self.trackers[1], "measured", True))]
        return PairResult(
            red_px=rc, yellow_px=yc, lost=rl or yl, reason="; ".join(w for w in (rw, yw) if w),
            compute_time_s=0.0, red_lost=rl, yellow_lost=yl, red_measured=measured[0],
            yellow_measured=measured[1], red_box_px=rb, yellow_box_px=yb, red_score=rs,
            yellow_score=ys, tracker_time_s=rt + yt,
        )

    def _bad_frame(self, image: object, reason: str) -> PairResult:
        """An unusable frame. Trackers that coast on their own prediction (those with a ``lost``
        attribute, e.g. ``K2CF``, which handle bad frames themselves) are stepped so that their
        prediction keeps time, and report it flagged; otherwise nothing is estimated."""
        if self.trackers and all(getattr(tr, "lost", None) is not None for tr in self.trackers):
            res = self._step(image)  # type: ignore[arg-type]
            return replace(res, reason="; ".join(r for r in (f"frame unusable: {reason}",
                                                            res.reason) if r),
                           red_measured=False, yellow_measured=False)
        return super()._bad_frame(image, reason)

