"""Trackers of the marker pair: both marker centres per frame behind one small interface.

``MarkerPairTracker.start(frame, boxes_sensor_px)`` takes the first frame and the boxes of the red
(main) and yellow (auxiliary) markers; ``step(frame) -> PairResult`` returns both centres, the
lost flags, why, and the measured wall-clock compute time of the whole step. Implementations:

* ``GKTransTPairTracker`` (``gk_transt.py``): seed 000 §3.2, one network on the red marker guided
  by the GK assistance's Kalman prediction; the yellow marker from the geometry.
* ``IndependentPairTracker`` (``dual.py``): one single-object tracker per marker, run one after
  the other: the seed's "original TransT" (two TransT networks), OpenCV's KCF and CSRT, the numpy
  KCF and K²CF (``k2cf.py``, seed 004 §3.2).

``make_pair_tracker(name)`` builds them by name. Single-object trackers (``init(frame, box)``,
``track(frame[, search_centre]) -> (box, score)``, image px) live in ``observer.opencv_trackers``,
``kcf_numpy.py``, ``k2cf.py`` and ``observer.transt``.

Units: marker centres and boxes (x, y, w, h) in and out of this interface are *full-sensor*
pixels (the seed's unit, ``plant.scene.Frame.marker_px``); frames are RGB uint8 binned by
``binning`` (image px = ``plant.camera.sensor_to_image``). Every tracker can refine its centres
by the sub-pixel circle fit of seed 004 §4 (``observer.gk.subpixel``; option ``refine``).

Bad input: ``start`` raises ``ValueError`` for an unusable first frame or boxes; ``step`` never
raises: an unusable frame (empty, wrong dtype or shape, non-finite values in a float array,
uniform: all black or all white) or an internal failure gives a result flagged ``lost`` (or,
for GK-TransT, a flagged Kalman prediction, ``red_measured`` False) with a ``reason``.
"""

from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from observer.gk.hsv_gate import box_sensor_to_image, check_featureless, check_rgb_image
from observer.gk.subpixel import SubpixelConfig, refine_marker_centre
from plant.params import PlantParams
from plant.scene import check_binning

if TYPE_CHECKING:  # pragma: no cover
    from observer.trackers.dual import IndependentPairTracker
    from observer.trackers.gk_transt import GKTransTPairTracker
    from observer.trackers.k2cf import K2CF, K2CFConfig
    from observer.trackers.kcf_numpy import KCFConfig, NumpyKCF

__all__ = [
    "GKTransTPairTracker",
    "IndependentPairTracker",
    "K2CF",
    "K2CFConfig",
    "KCFConfig",
    "MarkerPairTracker",
    "NumpyKCF",
    "PAIR_TRACKERS",
    "PairResult",
    "make_pair_tracker",
    "refine_centre_sensor_px",
]

#: Colours of the two markers, in the order of ``Frame.marker_px`` (seed 000 §3.2.2).
MARKERS = ("red", "yellow")

#: Names accepted by ``make_pair_tracker``.
PAIR_TRACKERS = ("gk_transt", "dual_transt", "kcf", "csrt", "kcf_numpy", "k2cf")


@dataclass(frozen=True)
class PairResult:
    """Both marker centres of one frame.

    Attributes
    ----------
    red_px, yellow_px : (2,) centre (u, v) of the red (main) and yellow (auxiliary) marker,
        full-sensor px; NaN when the tracker has no estimate at all.
    lost : either marker is lost (``red_lost or yellow_lost``).
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


def box_around(centre_px: ArrayLike, size_px: ArrayLike) -> NDArray[np.float64]:
    """Box (x, y, w, h) of size ``size_px`` (w, h) centred on ``centre_px`` (same units)."""
    c = np.asarray(centre_px, dtype=float).reshape(2)
    s = np.asarray(size_px, dtype=float).reshape(2)
    return np.r_[c - 0.5 * s, s]


def refine_centre_sensor_px(
    image: NDArray[np.uint8],
    colour: str,
    box_sensor_px: ArrayLike,
    binning: int,
    config: SubpixelConfig | None = None,
    roi_margin: float = 0.3,
) -> NDArray[np.float64] | None:
    """Sub-pixel centre (sensor px) of the ``colour`` marker near a tracker's box (seed 004 §4).

    The circle fit of ``observer.gk.subpixel.refine_marker_centre`` runs in the box (x, y, w, h,
    sensor px) enlarged by ``roi_margin`` of its size on each side (0.3, the GK assistance's
    choice); its centre is accepted when the fit is valid and the centre lies inside the box
    (the same acceptance rule as ``GKAssist``). Returns None otherwise.
    """
    box = np.asarray(box_sensor_px, dtype=float).reshape(4)
    if not np.all(np.isfinite(box)) or box[2] <= 0 or box[3] <= 0:
        return None
    roi = np.r_[box[:2] - roi_margin * box[2:], box[2:] * (1.0 + 2.0 * roi_margin)]
    fit = refine_marker_centre(image, colour, box_sensor_to_image(roi, binning), config)
    if not fit.valid:
        return None
    c = fit.centre_sensor_px(binning)
    if np.all((c >= box[:2]) & (c <= box[:2] + box[2:])):
        return c
    return None


class MarkerPairTracker(ABC):
    """Base of the pair trackers: input checks, timing and the never-raise guarantee.

    Parameters
    ----------
    params : PlantParams, optional
        Camera (sensor size: frames must be sensor size / binning) and VFC geometry.
    refine : bool
        Refine the marker centres by the sub-pixel circle fit (seed 004 §4).
    subpixel : SubpixelConfig, optional
        Settings of the circle fit.

    Subclasses implement ``_start`` and ``_step`` (and may override ``_bad_frame``); the public
    ``start`` and ``step`` add the checks and the timing.
    """

    #: Short name used in tables and plots.
    name: str = "pair"

    def __init__(
        self,
        params: PlantParams | None = None,
        refine: bool = False,
        subpixel: SubpixelConfig | None = None,
    ) -> None:
        self.params = params or PlantParams()
        self.refine = bool(refine)
        self.subpixel = subpixel or SubpixelConfig()
        self.binning: int | None = None
        self.frame_shape: tuple[int, int, int] | None = None
        self.box_size_px = np.full((2, 2), np.nan)  # (w, h) per marker at start, sensor px

    # --- checks ---------------------------------------------------------------------------------
    def _infer_binning(self, image: NDArray[np.uint8]) -> int:
        cam = self.params.camera
        w = image.shape[1]
        if w == 0 or cam.sensor_width_px % w:
            raise ValueError(
                f"frame width {w} px does not divide the sensor width {cam.sensor_width_px} px; "
                "pass binning (or PlantParams of the camera that took the frames)"
            )
        return cam.sensor_width_px // w

    def expected_shape(self, binning: int) -> tuple[int, int, int]:
        """(H, W, 3) of a frame binned by ``binning``."""
        cam = self.params.camera
        return (cam.sensor_height_px // binning, cam.sensor_width_px // binning, 3)

    def check_frame(self, image: object) -> str:
        """"" if ``image`` is a usable frame for the started tracker, else why not."""
        bad = check_rgb_image(image)
        if bad:
            return bad
        if self.frame_shape is not None and image.shape != self.frame_shape:  # type: ignore
            return f"frame shape {image.shape} differs from the start frame's {self.frame_shape}"  # type: ignore
        return check_featureless(image)  # type: ignore[arg-type]

    # --- public ---------------------------------------------------------------------------------
    def start(
        self, image: NDArray[np.uint8], boxes_sensor_px: ArrayLike, binning: int | None = None
    ) -> None:
        """Start on the first frame with the marker boxes (2, 4): red then yellow (x, y, w, h),
        full-sensor px (a user's first-frame annotation or ``Frame.boxes_px``).

        ``binning`` defaults to sensor width / frame width. Raises ``ValueError`` if the frame is
        unusable (not RGB uint8, empty, all black, not sensor size / binning) or a box is not
        finite, has w or h <= 0, or has its centre outside the frame.
        """
        bad = check_rgb_image(image)
        if bad:
            raise ValueError(f"start frame: {bad}")
        b = self._infer_binning(image) if binning is None else check_binning(self.params, binning)
        if image.shape != self.expected_shape(b):
            raise ValueError(f"start frame shape {image.shape} does not match the sensor at "
                             f"binning {b}: {self.expected_shape(b)}")
        if int(image.max()) == 0:
            raise ValueError("start frame is all black: nothing to track")
        try:
            boxes = np.asarray(boxes_sensor_px, dtype=float).reshape(2, 4)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"boxes_sensor_px must be (2, 4): red, yellow (x, y, w, h): {exc}")\
                from exc
        cam = self.params.camera
        for name, box in zip(MARKERS, boxes, strict=True):
            if not np.all(np.isfinite(box)) or box[2] <= 0 or box[3] <= 0:
                raise ValueError(f"{name} box must be finite with w, h > 0, got {box}")
            c = box[:2] + 0.5 * box[2:]
            if not (-0.5 <= c[0] <= cam.sensor_width_px - 0.5
                    and -0.5 <= c[1] <= cam.sensor_height_px - 0.5):
                raise ValueError(f"{name} box centre {c} (sensor px) is outside the image")
        self.binning = b
        self.frame_shape = image.shape  # type: ignore[assignment]
        self.box_size_px = boxes[:, 2:].copy()
        self._start(image, boxes)

    def step(self, image: NDArray[np.uint8]) -> PairResult:
        """Both marker centres in the next frame (RGB, the start frame's shape). Never raises:
        bad input or an internal failure gives a ``lost`` result with a reason."""
        t0 = time.perf_counter()
        if self.binning is None:
            return PairResult.failed("tracker not started", time.perf_counter() - t0)
        bad = self.check_frame(image)
        try:
            res = self._bad_frame(image, bad) if bad else self._step(image)
        except Exception as exc:  # noqa: BLE001 - a sequence must never crash mid-way
            res = PairResult.failed(f"{type(exc).__name__} in {self.name}: {exc}")
        return _with_time(res, time.perf_counter() - t0)

    # --- for subclasses -------------------------------------------------------------------------
    @abstractmethod
    def _start(self, image: NDArray[np.uint8], boxes_sensor_px: NDArray[np.float64]) -> None:
        """Initialise on validated input (boxes (2, 4), sensor px)."""

    @abstractmethod
    def _step(self, image: NDArray[np.uint8]) -> PairResult:
        """Process a validated frame."""

    def _bad_frame(self, image: object, reason: str) -> PairResult:
        """Result for an unusable frame (default: no estimate, both lost)."""
        return PairResult.failed(f"frame unusable: {reason}")

    def _refine(self, image: NDArray[np.uint8], colour: str,
                box_sensor_px: NDArray[np.float64]) -> NDArray[np.float64] | None:
        assert self.binning is not None
        return refine_centre_sensor_px(image, colour, box_sensor_px, self.binning, self.subpixel)


def _with_time(res: PairResult, dt: float) -> PairResult:
    return replace(res, compute_time_s=dt)


def make_pair_tracker(
    name: str,
    params: PlantParams | None = None,
    refine: bool | None = None,
    transt_factory: Any = None,
    **kwargs: Any,
) -> MarkerPairTracker:
    """Build a pair tracker by name (one of ``PAIR_TRACKERS``).

    ``refine`` defaults to True for GK-TransT (the GK assistance refines its centres) and False
    for the others (the seed's baselines report the tracker's box centre). ``transt_factory``
    (a callable returning a tracker with the TransT API) defaults to
    ``observer.transt.tracker.TransTTracker.small``; pass e.g. ``NumpyKCF`` as a stand-in.
    Extra keyword arguments go to the tracker's constructor.
    """
    from observer.trackers.dual import IndependentPairTracker

    if name not in PAIR_TRACKERS:
        raise ValueError(f"unknown tracker {name!r}; choose one of {PAIR_TRACKERS}")
    if name in ("gk_transt", "dual_transt") and transt_factory is None:
        from observer.transt.tracker import TransTTracker

        transt_factory = TransTTracker.small
    if name == "gk_transt":
        from observer.trackers.gk_transt import GKTransTPairTracker

        return GKTransTPairTracker(transt_factory(), params,
                                   refine=True if refine is None else refine, **kwargs)
    r = False if refine is None else refine
    if name == "dual_transt":
        return IndependentPairTracker(transt_factory, params, refine=r, name=name, **kwargs)
    if name in ("kcf", "csrt"):
        from observer.opencv_trackers import OpenCVTracker

        return IndependentPairTracker(lambda: OpenCVTracker(name), params, refine=r, name=name,
                                      **kwargs)
    if name == "kcf_numpy":
        from observer.trackers.kcf_numpy import NumpyKCF

        return IndependentPairTracker(NumpyKCF, params, refine=r, name=name, **kwargs)
    from observer.trackers.k2cf import K2CF

    return IndependentPairTracker(K2CF, params, refine=r, name=name, **kwargs)


def __getattr__(attr: str) -> Any:
    """Lazy access to the implementations (they import this module's base classes)."""
    modules = {
        "GKTransTPairTracker": "gk_transt",
        "IndependentPairTracker": "dual",
        "K2CF": "k2cf",
        "K2CFConfig": "k2cf",
        "KCFConfig": "kcf_numpy",
        "NumpyKCF": "kcf_numpy",
    }
    if attr in modules:
        import importlib

        return getattr(importlib.import_module(f"observer.trackers.{modules[attr]}"), attr)
    raise AttributeError(f"module 'observer.trackers' has no attribute {attr!r}")
