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
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from observer.gk.assist import GKAssist, GKResult
from observer.gk.hsv_gate import box_image_to_sensor, box_sensor_to_image
from observer.opencv_trackers import OpenCVTracker
from observer.pixel_observer import PixelObserver
from plant import attitude
from plant.estimate import Estimate
from plant.params import PlantParams


@dataclass(frozen=True)
class Located:
    """Both marker centres (2, 2), sensor px (red, yellow), with the GK result and the measured
    wall-clock time of tracker + GK (s)."""

    marker_px: NDArray[np.float64]
    lost: bool
    reason: str
    compute_time_s: float
    gk: GKResult


class MarkerLocator:
    """Tracker on the red marker + GK assistance for both centres.

    Parameters
    ----------
    params : PlantParams
    tracker : object with ``init(frame, box)`` and ``track(frame) -> (box, score)`` (image px);
        default OpenCV KCF.
    gk : GKAssist, optional

    ``start(frame, box_sensor_px)`` initialises the tracker on the red marker (a user's first-frame
    annotation). When the GK assistance had to stand in for the tracker, the tracker is restarted
    on the Kalman prediction. ``tilt_hint_rad`` (the latest estimated tilt) feeds the geometric
    check D_exp = L·S·cos β.
    """

    def __init__(self, params: PlantParams, tracker=None, gk: GKAssist | None = None) -> None:
        self.params = params
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

    def locate(self, image: NDArray[np.uint8], binning: int) -> Located:
        """Both marker centres in this frame (RGB, binned by ``binning``)."""
        t0 = time.perf_counter()
        if not self.started:
            raise RuntimeError("start() the locator on the red marker's box first")
        box_img, score = self.tracker.track(image)
        box = box_image_to_sensor(box_img, binning) if np.all(np.isfinite(box_img)) else None
        res = self.gk.step(
            image, binning, box_sensor_px=box, score=score, tilt_prev_rad=self.tilt_hint_rad
        )
        if res.red_source != "measurement" and np.all(np.isfinite(res.red_px)):
            # Restart the tracker where the Kalman prediction puts the red marker.
            r = 1.6 * self.gk.marker_radius_px
            guess = np.r_[res.red_px - r, 2 * r, 2 * r]
            self.tracker.init(image, box_sensor_to_image(guess, binning))
        return Located(res.marker_px, res.lost, res.reason, time.perf_counter() - t0, res)


class FrameObserver:
    """``update(frame, t_exposure) -> Estimate`` from a locator and a pixel back end.

    The estimate is released immediately (``t_available = t_exposure`` + the measured compute
    time); the timed loop instead releases through its latency model.
    """

    def __init__(self, locator: MarkerLocator, backend: PixelObserver) -> None:
        self.locator = locator
        self.backend = backend

    def reset(self, q0: ArrayLike = (1.0, 0.0, 0.0, 0.0), t0: float = 0.0) -> None:
        self.locator.reset()
        self.backend.reset(q0, t0)

    def start(self, image: NDArray[np.uint8], binning: int, box_sensor_px: ArrayLike) -> None:
        """Initialise the tracker on the red marker's box, sensor px."""
        self.locator.start(image, binning, box_sensor_px)

    def update(self, frame, t_exposure: float) -> Estimate:
        """Estimate from one ``plant.scene.Frame`` (or any object with ``image`` and
        ``binning``) taken at mid-exposure ``t_exposure`` (s)."""
        t0 = time.perf_counter()
        loc = self.locator.locate(frame.image, frame.binning)
        self.backend.process(loc.marker_px, t_exposure, loc.lost, loc.reason, loc.compute_time_s)
        elapsed = time.perf_counter() - t0
        est = self.backend.release(t_exposure + elapsed)
        if est.valid:
            self.locator.tilt_hint_rad = attitude.tilt(est.q)
        return est
