"""Frames -> attitude: the observer of DESIGN.md, ``update(frame, t_exposure) -> Estimate``.

Built from replaceable parts:

* a **tracker** of the red main marker (``init(frame, box)``, ``track(frame) -> (box, score)``
  in image px): OpenCV KCF or CSRT today, GK-TransT when the network lands;
* the **GK assistance** (seed 000 §3.2, ``observer.gk``): Kalman prediction, HSV gate, geometric
  auxiliary point, scale EMA, sub-pixel centres;
* an attitude **back end** (``observer.pixel_observer``): a per-frame solver or the EKF/AEKF.

``MarkerLocator`` is the first two (frame -> both marker centres); ``FrameObserver`` adds the back
end. The timed loop uses the locator and the back end separately so that it can release the
estimate after the observer's latency.

Bad frames (DESIGN.md: never a crash in the middle of a loop, never a silent wrong number): a
frame that is not (H, W, 3) uint8 RGB, is empty (``observer.gk.hsv_gate.check_rgb_image``), or
does not have the sensor's size at its binning is not given to the tracker. ``locate`` returns
``lost=True`` with the problem in ``reason`` and ``bad_frame``; ``FrameObserver.update`` returns
an estimate with ``valid=False``, ``lost=True`` and a reason that starts with ``"bad frame: "``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from observer.gk.assist import GKAssist, GKResult
from observer.gk.hsv_gate import box_image_to_sensor, box_sensor_to_image, check_rgb_image
from observer.opencv_trackers import OpenCVTracker
from observer.pixel_observer import PixelObserver
from plant import attitude
from plant.estimate import Estimate
from plant.params import PlantParams
from plant.scene import check_binning


@dataclass(frozen=True)
class Located:
    """Both marker centres (2, 2), sensor px (red, yellow), with the GK result and the measured
    wall-clock time of tracker + GK (s). ``bad_frame`` is why the frame was unusable ("" when it
    was usable); a bad frame is always ``lost``."""

    marker_px: NDArray[np.float64]
    lost: bool
    reason: str
    compute_time_s: float
    gk: GKResult
    bad_frame: str = ""


class MarkerLocator:
    """Tracker on the red marker + GK assistance for both centres.

    Parameters
    ----------
    params : PlantParams
    tracker : object with ``init(frame, box)`` and ``track(frame) -> (box, score)`` (image px);
        default OpenCV KCF.
    gk : GKAssist, optional
    clock : callable returning seconds, default ``time.perf_counter``
        Times ``locate`` (``compute_time_s``); tests inject a stand-in so that the latency does
        not depend on machine load.

    ``start(frame, box_sensor_px)`` initialises the tracker on the red marker (a user's first-frame
    annotation). When the GK assistance had to stand in for the tracker, the tracker is restarted
    on the Kalman prediction. ``tilt_hint_rad`` (the latest estimated tilt) feeds the geometric
    check D_exp = L·S·cos β.
    """

    def __init__(
        self,
        params: PlantParams,
        tracker=None,
        gk: GKAssist | None = None,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.params = params
        self.clock = clock
        self.tracker = tracker or OpenCVTracker("kcf")
        self.gk = gk or GKAssist(params)
        self.tilt_hint_rad: float | None = None
        self.started = False

    def reset(self) -> None:
        self.gk.reset()
        self.started = False
        self.tilt_hint_rad = None

    def start(self, image: NDArray[np.uint8], binning: int, box_sensor_px: ArrayLike) -> None:
        """Initialise the tracker on the red marker's box (x, y, w, h), sensor px."""
        self.tracker.init(image, box_sensor_to_image(box_sensor_px, binning))
        self.started = True

    def check_frame(self, image: object, binning: object) -> str:
        """"" if ``image`` is a usable frame at ``binning``, else why not: it must be RGB uint8
        (H, W, 3), non-empty (``check_rgb_image``), and H × W = sensor size / ``binning``.
        Never raises."""
        bad = check_rgb_image(image)
        if bad:
            return bad
        try:
            b = check_binning(self.params, binning)  # type: ignore[arg-type]
        except (TypeError, ValueError) as exc:
            return f"bad binning: {exc}"
        cam = self.params.camera
        expected = (cam.sensor_height_px // b, cam.sensor_width_px // b, 3)
        if image.shape != expected:  # type: ignore[union-attr]
            return (f"frame shape {image.shape} does not match the sensor at binning {b}: "  # type: ignore[union-attr]
                    f"expected {expected}")
        return ""

    def locate(self, image: NDArray[np.uint8], binning: int) -> Located:
        """Both marker centres in this frame (RGB, binned by ``binning``).

        A bad frame (``check_frame``) is not shown to the tracker; the GK assistance predicts
        through it and the result is ``lost`` with the problem in ``reason`` and ``bad_frame``.
        """
        t0 = self.clock()
        if not self.started:
            raise RuntimeError("start() the locator on the red marker's box first")
        bad = self.check_frame(image, binning)
        box, score = None, 0.0
        if not bad:
            box_img, score = self.tracker.track(image)
            box = box_image_to_sensor(box_img, binning) if np.all(np.isfinite(box_img)) else None
        res = self.gk.step(
            image, binning, box_sensor_px=box, score=score, tilt_prev_rad=self.tilt_hint_rad
        )
        reason = res.reason
        if bad:
            # GK names the frame problem too (in its gate's reason): say it once, first.
            rest = [r for r in res.reason.split("; ") if r and r not in (bad, res.gate.reason)]
            reason = "; ".join([f"bad frame: {bad}", *rest])
        elif res.red_source != "measurement" and np.all(np.isfinite(res.red_px)):
            # Restart the tracker where the Kalman prediction puts the red marker.
            r = 1.6 * self.gk.marker_radius_px
            guess = np.r_[res.red_px - r, 2 * r, 2 * r]
            try:
                self.tracker.init(image, box_sensor_to_image(guess, binning))
            except ValueError as exc:  # e.g. the prediction left the frame: keep the old track
                reason = f"{reason}; tracker not restarted: {exc}" if reason else \
                    f"tracker not restarted: {exc}"
        return Located(res.marker_px, res.lost or bool(bad), reason,
                       self.clock() - t0, res, bad)


class FrameObserver:
    """``update(frame, t_exposure) -> Estimate`` from a locator and a pixel back end.

    The estimate is released immediately (``t_available = t_exposure`` + the compute time
    measured by the locator's ``clock``); the timed loop instead releases through its latency
    model.

    A bad frame (``MarkerLocator.check_frame``) reaches the back end as a lost frame (it
    predicts or holds) and the estimate is flagged ``valid=False``, ``lost=True``, with a reason
    that starts with ``"bad frame: "``. The locator's reasons (for example that the Kalman
    prediction stood in for the tracker) are kept in the estimate's ``reason``.

    Coasting: a frame whose red marker was not measured (the GK Kalman prediction stood in, the
    track is lost, or the frame is bad) reaches the back end as a lost frame (a filter predicts
    through it with its model, a per-frame solver holds its last solution) and gives an
    estimate flagged ``lost=True`` with a reason that starts with ``"coasting: "``; once no
    marker has been measured for more than ``max_coast_s`` the estimate is also
    ``valid=False``, until the tracker measures the marker again.

    Parameters
    ----------
    locator : MarkerLocator
    backend : PixelObserver
    max_coast_s : float
        The longest time (s) since the last measured marker for which a coasting estimate is
        still ``valid``. Default 0.1 s (3 frames at 36 fps): on an 8° cone whose azimuth turns
        at 1 rad/s (a body rate of 8°/s) a held or predicted attitude drifts by up to about
        0.8° in that time.
    """

    def __init__(
        self, locator: MarkerLocator, backend: PixelObserver, max_coast_s: float = 0.1
    ) -> None:
        if not max_coast_s >= 0:
            raise ValueError(f"max_coast_s must be >= 0 s, got {max_coast_s}")
        self.locator = locator
        self.backend = backend
        self.max_coast_s = float(max_coast_s)
        self._last_measured = 0.0

    def reset(self, q0: ArrayLike = (1.0, 0.0, 0.0, 0.0), t0: float = 0.0) -> None:
        """Start from attitude ``q0`` (known: counts as measured) at time ``t0`` (s)."""
        self.locator.reset()
        self.backend.reset(q0, t0)
        self._last_measured = float(t0)

    def start(self, image: NDArray[np.uint8], binning: int, box_sensor_px: ArrayLike) -> None:
        """Initialise the tracker on the red marker's box, sensor px."""
        self.locator.start(image, binning, box_sensor_px)

    def update(self, frame, t_exposure: float) -> Estimate:
        """Estimate from one ``plant.scene.Frame`` (or any object with ``image`` and
        ``binning``) taken at mid-exposure ``t_exposure`` (s)."""
        t0 = self.locator.clock()
        image = getattr(frame, "image", None)
        binning = getattr(frame, "binning", None)
        loc = self.locator.locate(image, binning)  # type: ignore[arg-type]
        # A predicted marker is not a measurement: the back end predicts (or holds) through it
        # with its own model rather than fusing the GK prediction as if it were measured.
        measured = not loc.lost and loc.gk.red_source == "measurement"
        self.backend.process(loc.marker_px, t_exposure, not measured, loc.reason,
                             loc.compute_time_s)
        elapsed = self.locator.clock() - t0
        est = self.backend.release(t_exposure + elapsed)
        reason = est.reason
        if loc.reason and loc.reason not in reason:
            reason = f"{loc.reason}; {reason}" if reason else loc.reason
        if measured:
            self._last_measured = float(t_exposure)
        coast_s = float(t_exposure) - self._last_measured
        valid = est.valid and not loc.bad_frame and coast_s <= self.max_coast_s
        if not measured:
            limit = "over" if coast_s > self.max_coast_s else "within"
            note = (f"coasting: no marker measured for {coast_s:.3f} s ({limit} max_coast_s = "
                    f"{self.max_coast_s} s)")
            # A bad frame's reason stays first ("bad frame: ..."); else the coasting note is.
            parts = [reason, note] if loc.bad_frame else [note, reason]
            reason = "; ".join(r for r in parts if r)
        est = replace(est, valid=valid, lost=est.lost or not measured, reason=reason)
        if est.valid:
            self.locator.tilt_hint_rad = attitude.tilt(est.q)
        return est
