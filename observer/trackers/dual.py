"""One independent single-object tracker per marker, run one after the other.

This is how seed 000 §4.2 runs its baselines on the two markers: the "original TransT" is two
independent TransT models (one per marker; its Table 1 latency of 31.23 ms is the pair), and KCF
and CSRT are likewise one instance per marker. ``IndependentPairTracker`` wraps any
``observer.tracking.SingleObjectTracker``: ``observer.transt.tracker.TransTTracker`` (dual
TransT), ``observer.opencv_trackers.OpenCVTracker`` (KCF, CSRT), ``NumpyKCF`` and ``K2CF``.

Per frame and marker (red first, then yellow): the tracker's box; the marker is **lost** when the
box is not finite, or the tracker's result is not ``valid``, or a box measured in this frame has
a score of at most ``lost_score`` (our choice: 0.2; OpenCV's trackers report 1 or 0, the numpy
KCF its response peak, TransT its classification confidence). A lost marker keeps the tracker's
finite box as its (flagged) position; there is no prediction and no re-detection beyond what the
tracker does itself, as in the seed's baselines. An unusable frame gives no estimate, except with
``coast_on_bad_frames`` (trackers that coast on their own prediction, ``K2CF``), which keep
predicting. With ``refine`` the centre of a tracked marker is the sub-pixel circle fit (seed 004
§4) when it is valid and inside the box.

Units: boxes and centres in results are full-sensor px; the single trackers work in image px of
the binned frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from observer.gk.drift import DriftConfig
from observer.gk.hsv_gate import box_image_to_sensor, box_sensor_to_image
from observer.gk.subpixel import SubpixelConfig
from observer.trackers import MARKERS, MarkerPairTracker, box_around
from observer.tracking import PairResult, SingleObjectTracker
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
    coast_on_bad_frames : bool
        Step the trackers on an unusable frame too (they coast on their own prediction and
        handle bad frames themselves, as ``K2CF`` does).
    drift : DriftConfig or None, optional
        Drift detection (``MarkerPairTracker``); a drifted marker's tracker is started again
        on the re-detected marker.
    """

    def __init__(
        self,
        factory: Callable[[], SingleObjectTracker],
        params: PlantParams | None = None,
        refine: bool = False,
        subpixel: SubpixelConfig | None = None,
        name: str = "independent",
        lost_score: float = 0.2,
        coast_on_bad_frames: bool = False,
        drift: DriftConfig | None = DriftConfig(),  # noqa: B008 - frozen pydantic model
    ) -> None:
        super().__init__(params, refine, subpixel, drift=drift)
        self.factory = factory
        self.name = name
        self.lost_score = float(lost_score)
        self.coast_on_bad_frames = bool(coast_on_bad_frames)
        self.trackers: list[SingleObjectTracker] = []

    def _start(self, image: NDArray[np.uint8], boxes_sensor_px: NDArray[np.float64]) -> None:
        assert self.binning is not None
        self.trackers = []
        for box in boxes_sensor_px:
            tr = self.factory()
            tr.initialize(image, box_sensor_to_image(box, self.binning))
            self.trackers.append(tr)

    def _one(
        self, image: NDArray[np.uint8], k: int
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], bool, bool, float, float, str]:
        """(centre, box, lost, measured, score, time, reason) of marker k, sensor px."""
        assert self.binning is not None
        tr = self.trackers[k].track(image)
        box_img = np.asarray(tr.box_image_px, dtype=float).reshape(-1)
        if box_img.shape != (4,) or not np.all(np.isfinite(box_img)):
            why = tr.reason or "tracker reported no box"
            return np.full(2, np.nan), np.full(4, np.nan), True, False, tr.score, \
                tr.compute_time_s, f"{MARKERS[k]}: {why}"
        box = box_image_to_sensor(box_img, self.binning)
        centre = box[:2] + 0.5 * box[2:]
        if not tr.valid:
            lost, why = True, f"{MARKERS[k]}: {tr.reason or 'tracker lost'}"
        elif tr.measured and not tr.score > self.lost_score:
            lost, why = True, f"{MARKERS[k]}: score {tr.score:.3g} <= {self.lost_score}"
        else:
            lost, why = False, ""
        measured = not lost and tr.measured
        if measured and self.refine:
            c = self._refine(image, MARKERS[k], box)
            if c is not None:
                centre = c
        return centre, box_around(centre, box[2:]), lost, measured, tr.score, \
            tr.compute_time_s, why

    def _step(self, image: NDArray[np.uint8]) -> PairResult:
        (rc, rb, rl, rm, rs, rt, rw), (yc, yb, yl, ym, ys, yt, yw) = \
            (self._one(image, k) for k in (0, 1))
        return PairResult(
            red_px=rc, yellow_px=yc, lost=rl or yl, reason="; ".join(w for w in (rw, yw) if w),
            compute_time_s=0.0, red_lost=rl, yellow_lost=yl, red_measured=rm,
            yellow_measured=ym, red_box_px=rb, yellow_box_px=yb, red_score=rs,
            yellow_score=ys, tracker_time_s=rt + yt,
        )

    def _restart_marker(self, image: NDArray[np.uint8], k: int,
                        centres_px: NDArray[np.float64]) -> None:
        """A new single-object tracker on marker ``k``'s start-size box at its centre."""
        assert self.binning is not None
        tr = self.factory()
        tr.initialize(image, box_sensor_to_image(box_around(centres_px[k], self.box_size_px[k]),
                                                 self.binning))
        self.trackers[k] = tr

    def _bad_frame(self, image: object, reason: str) -> PairResult:
        """An unusable frame: with ``coast_on_bad_frames`` the trackers are stepped so that
        their prediction keeps time (flagged, not measured); otherwise nothing is estimated."""
        if self.coast_on_bad_frames and self.trackers:
            return replace(self._step(image), red_measured=False,  # type: ignore[arg-type]
                           yellow_measured=False)
        return super()._bad_frame(image, reason)
