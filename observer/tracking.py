"""The two tracking interfaces: a single-object tracker and a marker-pair tracker.

Every tracker in the project has one of these two shapes.

* ``SingleObjectTracker`` (pytracking style): ``initialize(frame, box_image_px)`` on the first
  frame, then ``track(frame, search_centre_image_px=None) -> TrackResult`` per frame. Boxes
  (x, y, w, h) and centres are in *image* px of the RGB uint8 frame. ``search_centre_image_px``
  asks the tracker to search around that point (GK-TransT passes the pixel Kalman prediction,
  seed 000 §3.2.1); a tracker that cannot search elsewhere ignores it. ``track`` never raises:
  bad input gives a result with ``valid`` False and a ``reason``. Implementations:
  ``observer.opencv_trackers.OpenCVTracker`` (KCF, CSRT), ``observer.trackers.kcf_numpy.NumpyKCF``,
  ``observer.trackers.k2cf.K2CF`` and ``observer.transt.tracker.TransTTracker``.
* ``PairTracker``: frame -> both marker centres (red, yellow) in *full-sensor* px with flags
  (``PairResult``). ``start(frame, boxes_sensor_px, binning)`` then ``step(frame)``. Every user
  of marker centres goes through it: the image front end of the loop
  (``latency.frontends.ImageFrontEnd``), the frame observer, the tracking benchmark and the
  reproduction. Implementations: ``observer.trackers``.

**The tracker -> attitude boundary** (``attitude_input``; docs/architecture.md): only a marker
the tracker measured in this frame (``PairResult.red_measured`` / ``yellow_measured``) reaches an
attitude back end. Any other centre (the GK Kalman prediction, the P_red + V_rel fallback, a
plate inference, a coasting tracker's guess) is passed as missing (NaN); a frame with neither
marker measured is a lost frame, through which the back end predicts (a filter) or holds (a
per-frame solver). The frame observer, the image front end of the loop and ``pmspm track`` all
apply this one rule, and their frames tables say what each attitude rests on
(``attitude_source``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray


@dataclass(frozen=True)
class TrackResult:
    """One ``SingleObjectTracker.track`` result.

    Attributes
    ----------
    box_image_px : (4,) box (x, y, w, h), image px; NaN when the tracker has no box.
    score : the tracker's confidence (its own scale: a response peak, a probability, 1/0).
    valid : the tracker's verdict that the box is on the target (not lost, not a failure).
    reason : why the result is not a clean measurement ("" when it is).
    compute_time_s : wall-clock time of the ``track`` call, s.
    measured : the box comes from this frame's image (False: the tracker's own prediction
        stood in, e.g. K²CF coasting through an occlusion).
    """

    box_image_px: NDArray[np.float64]
    score: float
    valid: bool
    reason: str = ""
    compute_time_s: float = math.nan
    measured: bool = True

    @property
    def centre_image_px(self) -> NDArray[np.float64]:
        """(2,) box centre (x + w/2, y + h/2), image px (NaN when there is no box)."""
        b = np.asarray(self.box_image_px, dtype=float)
        return b[:2] + 0.5 * b[2:]

    @classmethod
    def failed(cls, reason: str, compute_time_s: float = math.nan) -> TrackResult:
        """No box: NaN box, score 0, not valid, not measured."""
        return cls(np.full(4, np.nan), 0.0, False, reason, compute_time_s, False)


class SingleObjectTracker(Protocol):
    """A single-object tracker (see the module docstring)."""

    def initialize(self, frame: NDArray[np.uint8], box_image_px: ArrayLike) -> None:
        """Start on the object in ``box_image_px`` (x, y, w, h), image px; ``ValueError`` for
        an unusable frame or box."""
        ...

    def track(
        self, frame: NDArray[np.uint8], search_centre_image_px: ArrayLike | None = None
    ) -> TrackResult:
        """The object in the next frame; never raises."""
        ...


@dataclass(frozen=True)
class PairResult:
    """Both marker centres of one frame.

    Attributes
    ----------
    red_px, yellow_px : (2,) centre (u, v) of the red (main) and yellow (auxiliary) marker,
        full-sensor px; NaN when the tracker has no estimate at all.
    lost : either marker is lost (``red_lost or yellow_lost``), or the frame was bad.
    reason : why the frame is not a clean double measurement ("" when it is).
    compute_time_s : wall-clock time of the whole ``step``, s (``time.perf_counter``).
    red_lost, yellow_lost : the marker's track is lost; a finite centre is then a prediction or
        a guess, flagged, never a silent number.
    red_measured, yellow_measured : the centre comes from this frame's image (not a Kalman
        prediction, a geometric fallback or a held value).
    red_box_px, yellow_box_px : (4,) boxes (x, y, w, h), sensor px, centred on the reported
        centres (for the IoU metric).
    red_score, yellow_score : the single-object trackers' scores (NaN where none ran).
    tracker_time_s : time spent inside the single-object trackers (networks), s.
    red_refined : the red centre is the sub-pixel circle fit (seed 004 §4).
    bad_frame : why the frame was unusable ("" when it was usable); a bad frame is never a
        clean measurement.
    """

    red_px: NDArray[np.float64]
    yellow_px: NDArray[np.float64]
    lost: bool
    reason: str
    compute_time_s: float
    red_lost: bool = False
    yellow_lost: bool = False
    red_measured: bool = True
    yellow_measured: bool = True
    red_box_px: NDArray[np.float64] | None = None
    yellow_box_px: NDArray[np.float64] | None = None
    red_score: float = math.nan
    yellow_score: float = math.nan
    tracker_time_s: float = math.nan
    red_refined: bool = False
    bad_frame: str = ""

    @property
    def marker_px(self) -> NDArray[np.float64]:
        """(2, 2) red then yellow centre, sensor px (the order of ``Frame.marker_px``)."""
        return np.vstack([self.red_px, self.yellow_px])

    @property
    def boxes_px(self) -> NDArray[np.float64]:
        """(2, 4) red then yellow box, sensor px (NaN rows where none)."""
        rows = [np.full(4, np.nan) if b is None else np.asarray(b, float)
                for b in (self.red_box_px, self.yellow_box_px)]
        return np.vstack(rows)

    @classmethod
    def failed(cls, reason: str, compute_time_s: float = 0.0) -> PairResult:
        """A result with no estimate: NaN centres, both markers lost."""
        nan2 = np.full(2, np.nan)
        return cls(nan2, nan2.copy(), True, reason, compute_time_s, True, True, False, False)


#: What an attitude rests on (``attitude_source``), in order of trust.
ATTITUDE_SOURCES = ("both measured", "one predicted", "both predicted")


def attitude_source(red_measured: bool, yellow_measured: bool) -> str:
    """What a frame's attitude rests on: "both measured", "one predicted" (one marker was not
    measured in this frame: predicted, inferred or lost) or "both predicted" (neither was)."""
    return ATTITUDE_SOURCES[2 - int(bool(red_measured)) - int(bool(yellow_measured))]


@dataclass(frozen=True)
class AttitudeInput:
    """What the attitude back end is given for one frame (module docstring: the boundary rule).

    Attributes
    ----------
    marker_px : (2, 2) red then yellow centre, sensor px; NaN for a marker not measured.
    lost : neither marker was measured (a lost frame for the back end).
    source : ``attitude_source`` of the frame.
    """

    marker_px: NDArray[np.float64]
    lost: bool
    source: str


def attitude_input(res: PairResult) -> AttitudeInput:
    """The tracker -> attitude boundary rule (module docstring): keep the measured centres,
    replace the others by NaN; lost when neither marker was measured.

    Why not fuse a prediction as a measurement: the tracker's prediction is a pixel-space
    constant-velocity guess that knows nothing of the rotor or of the other marker; a back end
    has its own model of the motion (the AEKF's dynamics, or the last solution held), and
    fusing the guess both double-counts the past frames it was made from and hides the gap
    (a finger over the red marker: the prediction drifts 50 px and the attitude 4 deg, all
    reported as valid)."""
    measured = np.array([res.red_measured, res.yellow_measured], dtype=bool)
    z = np.where(measured[:, None], np.asarray(res.marker_px, dtype=float), np.nan)
    return AttitudeInput(z, not bool(measured.any()), attitude_source(*measured))


class PairTracker(Protocol):
    """Frame -> both marker centres (see the module docstring).

    ``tilt_hint_rad`` is the latest estimated tilt β (rad, None when unknown); trackers with a
    geometric check (D_exp = L·S·cos β, seed 000 §3.2.2) use it, the others ignore it.
    ``residual_hint_px`` is the attitude solver's RMS residual of the latest frame (sensor px,
    None or NaN when unknown); trackers with drift detection (``observer.gk.drift``) use it.
    """

    name: str
    tilt_hint_rad: float | None
    residual_hint_px: float | None

    def start(
        self, image: NDArray[np.uint8], boxes_sensor_px: ArrayLike, binning: int | None = None
    ) -> None:
        """Start on the first frame with the red and yellow boxes (2, 4), sensor px."""
        ...

    def step(self, image: NDArray[np.uint8]) -> PairResult:
        """Both marker centres in the next frame; never raises."""
        ...

    @property
    def started(self) -> bool:
        """``start`` has been called since the last ``reset``."""
        ...

    def reset(self) -> None:
        """Forget the track (the next frame needs ``start`` again)."""
        ...
