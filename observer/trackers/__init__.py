"""Trackers of the marker pair: both marker centres per frame behind one small interface.

``MarkerPairTracker`` is the base of every ``observer.tracking.PairTracker``:
``start(frame, boxes_sensor_px)`` takes the first frame and the boxes of the red (main) and yellow
(auxiliary) markers; ``step(frame) -> PairResult`` returns both centres, the lost flags, why, and
the measured wall-clock compute time of the whole step. Implementations:

* ``GKTransTPairTracker`` (``gk_transt.py``): seed 000 §3.2, one network on the red marker guided
  by the GK assistance's Kalman prediction; the yellow marker from the geometry. With an OpenCV
  tracker in place of the network (``kcf_gk``, ``csrt_gk``: they cannot search at a given
  centre) the tracker is restarted on the prediction instead.
* ``IndependentPairTracker`` (``dual.py``): one single-object tracker per marker, run one after
  the other: the seed's "original TransT" (two TransT networks), OpenCV's KCF and CSRT, the numpy
  KCF and K²CF (``k2cf.py``, seed 004 §3.2).

``make_pair_tracker(name)`` builds them by name. Single-object trackers
(``observer.tracking.SingleObjectTracker``) live in ``observer.opencv_trackers``, ``kcf_numpy.py``,
``k2cf.py`` and ``observer.transt``.

Units: marker centres and boxes (x, y, w, h) in and out of this interface are *full-sensor*
pixels (the seed's unit, ``plant.scene.Frame.marker_px``); frames are RGB uint8 binned by
``binning`` (image px = ``plant.camera.sensor_to_image``). Every tracker can refine its centres
by the sub-pixel circle fit of seed 004 §4 (``observer.gk.subpixel``; option ``refine``).

Bad input: ``start`` raises ``ValueError`` for an unusable first frame or boxes; ``step`` never
raises: an unusable frame (``observer.gk.hsv_gate.check_frame``: empty, wrong dtype or shape,
featureless: all black or all white) or an internal failure gives a result flagged ``lost`` (or,
for GK-TransT, a flagged Kalman prediction, ``red_measured`` False) with a ``reason``; a bad
frame's reason starts with ``"bad frame: "`` and ``PairResult.bad_frame`` says what is wrong
with it.

Drift: every pair tracker checks its markers against the rigid geometry (D_exp = L·S·cos β,
seed 000 §3.2.2) and, when the caller sets ``residual_hint_px``, the attitude solver's residual;
a marker that fails for a few frames in a row is flagged lost and re-detected from colour, and
its tracker restarts there (``observer.gk.drift``; option ``drift``, None to switch it off).

Timing: ``compute_time_s`` of a step is read from the tracker's ``clock`` (default
``time.perf_counter``; ``make_pair_tracker(..., clock=...)`` or setting ``tracker.clock``
injects a stand-in, so that tests of the latency bookkeeping do not depend on machine load).
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from observer.gk.drift import DriftConfig, DriftMonitor
from observer.gk.hsv_gate import check_frame, check_rgb_image
from observer.gk.subpixel import SubpixelConfig, refine_in_box
from observer.trackers.registry import TRACKERS
from observer.tracking import PairResult
from plant.params import PlantParams

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
    "TRACKERS",
    "make_pair_tracker",
    "refine_centre_sensor_px",
]

#: Names accepted by ``make_pair_tracker`` (``observer.trackers.registry.TRACKERS``).
PAIR_TRACKERS = TRACKERS.names()

#: Colours of the two markers, in the order of ``Frame.marker_px`` (seed 000 §3.2.2).
MARKERS = ("red", "yellow")



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
    """Sub-pixel centre (sensor px) of the ``colour`` marker near a tracker's box (seed 004 §4),
    by the acceptance rule of ``observer.gk.subpixel.refine_in_box``; None when rejected."""
    return refine_in_box(image, colour, box_sensor_px, binning, config,  # type: ignore[arg-type]
                         roi_margin)[0]


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
    clock : callable returning seconds, default ``time.perf_counter``
        Times ``step`` (``PairResult.compute_time_s``); tests inject a stand-in so that the
        measured latency does not depend on machine load. Subclasses that do not pass it on
        keep the default; assign ``clock`` after construction (``make_pair_tracker`` does).
    drift : DriftConfig or None, optional
        Drift detection (``observer.gk.drift``; default on with ``DriftConfig()``); None
        switches it off.

    Subclasses implement ``_start`` and ``_step`` (and may override ``_restart_marker`` and
    ``_bad_frame``); the public ``start`` and ``step`` add the checks, the drift detection and
    the timing. ``tilt_hint_rad`` (the latest tilt, rad) and ``residual_hint_px`` (the attitude
    solver's RMS residual of the latest frame, sensor px) are set by the caller, None when
    unknown.
    """

    #: Short name used in tables and plots.
    name: str = "pair"

    def __init__(
        self,
        params: PlantParams | None = None,
        refine: bool = False,
        subpixel: SubpixelConfig | None = None,
        clock: Callable[[], float] = time.perf_counter,
        drift: DriftConfig | None = DriftConfig(),  # noqa: B008 - frozen pydantic model
    ) -> None:
        self.params = params or PlantParams()
        self.clock = clock
        self.refine = bool(refine)
        self.subpixel = subpixel or SubpixelConfig()
        self.binning: int | None = None
        self.frame_shape: tuple[int, int, int] | None = None
        self.box_size_px = np.full((2, 2), np.nan)  # (w, h) per marker at start, sensor px
        self.tilt_hint_rad: float | None = None
        self.residual_hint_px: float | None = None
        self.drift = None if drift is None else DriftMonitor(self.params, drift)

    @property
    def started(self) -> bool:
        """``start`` has been called since the last ``reset``."""
        return self.binning is not None

    def reset(self) -> None:
        """Forget the track: the next frame needs ``start`` again."""
        self.binning = None
        self.frame_shape = None
        self.tilt_hint_rad = None
        self.residual_hint_px = None
        if self.drift is not None:
            self.drift.reset()

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

    def check_frame(self, image: object) -> str:
        """"" if ``image`` is a usable frame for the started tracker, else why not
        (``observer.gk.hsv_gate.check_frame`` at the start frame's binning)."""
        return check_frame(image, self.params, self.binning)

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
        b = self._infer_binning(image) if binning is None else binning
        bad = check_frame(image, self.params, b)
        if bad:
            raise ValueError(f"start frame: {bad}")
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
        self.binning = int(b)
        self.frame_shape = image.shape  # type: ignore[assignment]
        self.box_size_px = boxes[:, 2:].copy()
        self._start(image, boxes)

    def step(self, image: NDArray[np.uint8]) -> PairResult:
        """Both marker centres in the next frame (RGB, the start frame's shape). Never raises:
        bad input or an internal failure gives a ``lost`` result with a reason."""
        t0 = self.clock()
        if self.binning is None:
            return PairResult.failed("tracker not started", self.clock() - t0)
        bad = self.check_frame(image)
        try:
            res = self._bad_frame(image, bad) if bad else self._step(image)
            if not bad and self.drift is not None:
                res = self._check_drift(image, res)
        except Exception as exc:  # noqa: BLE001 - a sequence must never crash mid-way
            res = PairResult.failed(f"{type(exc).__name__} in {self.name}: {exc}")
        if bad:
            # the frame problem first, once, then what the tracker made of it
            rest = [r for r in res.reason.split("; ") if r and bad not in r]
            res = replace(res, bad_frame=bad, lost=True, red_measured=False,
                          yellow_measured=False, reason="; ".join([f"bad frame: {bad}", *rest]))
        return replace(res, compute_time_s=self.clock() - t0)

    def _check_drift(self, image: NDArray[np.uint8], res: PairResult) -> PairResult:
        """Flag the markers that have drifted (``observer.gk.drift``) as lost and not measured,
        re-detect them from colour and restart their trackers there; the result then carries
        the re-detected centres (still flagged: they are measured again from the next frame)."""
        assert self.binning is not None and self.drift is not None
        concerned, why = self.drift.check(image, self.binning, res, self.tilt_hint_rad,
                                          self.residual_hint_px)
        if not concerned.any():
            return res
        self.residual_hint_px = None  # that residual belongs to the drifted track
        found = self.drift.redetect(image, self.binning, concerned, res.marker_px,
                                    self.tilt_hint_rad)
        names = " and ".join(m for m, c in zip(MARKERS, concerned, strict=True) if c)
        if found is None:
            why = f"{why}; {names} not re-detected from colour"
            centres, boxes = res.marker_px, res.boxes_px
        else:
            why = f"{why}; {names} re-detected from colour"
            centres = np.where(concerned[:, None], found, res.marker_px)
            boxes = np.vstack([box_around(centres[k], self.box_size_px[k]) for k in (0, 1)])
            for k in np.flatnonzero(concerned):
                self._restart_marker(image, int(k), centres)
        red_lost, yellow_lost = res.red_lost or concerned[0], res.yellow_lost or concerned[1]
        return replace(
            res, red_px=centres[0], yellow_px=centres[1], red_box_px=boxes[0],
            yellow_box_px=boxes[1], red_lost=bool(red_lost), yellow_lost=bool(yellow_lost),
            lost=True, red_measured=res.red_measured and not concerned[0],
            yellow_measured=res.yellow_measured and not concerned[1],
            reason="; ".join(r for r in (res.reason, why) if r))

    # --- for subclasses -------------------------------------------------------------------------
    @abstractmethod
    def _start(self, image: NDArray[np.uint8], boxes_sensor_px: NDArray[np.float64]) -> None:
        """Initialise on validated input (boxes (2, 4), sensor px)."""

    @abstractmethod
    def _step(self, image: NDArray[np.uint8]) -> PairResult:
        """Process a validated frame."""

    def _restart_marker(self, image: NDArray[np.uint8], k: int,
                        centres_px: NDArray[np.float64]) -> None:
        """Restart the tracking of marker ``k`` (0 red, 1 yellow) on this frame at
        ``centres_px[k]`` (both centres (2, 2), sensor px) after a re-detection (default:
        nothing, for a tracker that cannot restart; the drift is then flagged again)."""
        return None

    def _bad_frame(self, image: object, reason: str) -> PairResult:
        """Result for an unusable frame (default: no estimate, both lost; ``step`` adds the
        reason)."""
        return PairResult.failed("")

    def _refine(self, image: NDArray[np.uint8], colour: str,
                box_sensor_px: NDArray[np.float64]) -> NDArray[np.float64] | None:
        assert self.binning is not None
        return refine_centre_sensor_px(image, colour, box_sensor_px, self.binning, self.subpixel)


def make_pair_tracker(
    name: str,
    params: PlantParams | None = None,
    refine: bool | None = None,
    transt_factory: Any = None,
    clock: Callable[[], float] | None = None,
    **kwargs: Any,
) -> MarkerPairTracker:
    """Build a pair tracker by name (one of ``PAIR_TRACKERS``; the builders are those of
    ``observer.trackers.registry.TRACKERS``).

    ``refine`` defaults to True for the GK trackers (the GK assistance refines its centres) and
    False for the others (the seed's baselines report the tracker's box centre).
    ``transt_factory`` (a callable returning a ``SingleObjectTracker``) defaults to
    ``observer.transt.tracker.TransTTracker.small``; pass e.g. ``NumpyKCF`` as a stand-in.
    ``kcf_gk`` and ``csrt_gk`` are the GK assistance around OpenCV's KCF or CSRT, restarted on
    the Kalman prediction when it stands in. ``clock`` (default ``time.perf_counter``) times
    each ``step``. Extra keyword arguments go to the tracker's constructor.
    """
    tracker = TRACKERS.get(name).build(params, refine, transt_factory, **kwargs)
    if clock is not None:
        tracker.clock = clock
    return tracker


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
