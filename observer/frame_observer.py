"""Frames -> attitude: ``FrameObserver.update(frame, t_exposure) -> Estimate``.

Built from two replaceable parts:

* a **pair tracker** (``observer.tracking.PairTracker``, ``observer.trackers``): frame -> both
  marker centres, e.g. GK-TransT (seed 000 §3.2) or OpenCV's KCF inside the GK assistance
  (``observer.trackers.make_pair_tracker("kcf_gk")``);
* an attitude **back end** (``observer.pixel_observer``): a per-frame solver or the EKF/AEKF.

The timed loop uses the same pair tracker (``latency.frontends.ImageFrontEnd``) and the back end
separately, so that it can release the estimate after the observer's latency.

Bad frames (never a crash in the middle of a loop, never a silent wrong number): a frame that
fails ``observer.gk.hsv_gate.check_frame`` is not given to the tracker; the pair tracker's result
is ``lost`` with the problem in ``bad_frame`` and the estimate is flagged ``valid=False``,
``lost=True``, with a reason that starts with ``"bad frame: "``. The back end receives only the
markers the tracker measured (``observer.tracking.attitude_input``, the boundary rule of
docs/architecture.md); a frame whose markers were not both measured makes the estimate coast:
flagged ``lost`` with a ``"coasting: "`` reason, and ``valid=False`` once the markers have not
both been measured for more than ``max_coast_s``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from observer.pixel_observer import PixelObserver
from observer.tracking import ATTITUDE_SOURCES, PairTracker, attitude_input
from plant import attitude
from plant.estimate import Estimate
from plant.scene import Frame


class FrameObserver:
    """``update(frame, t_exposure) -> Estimate`` from a pair tracker and a pixel back end.

    The estimate is released immediately (``t_available = t_exposure`` + the compute time
    measured by ``clock``); the timed loop instead releases through its latency model.

    A bad frame (one that fails ``observer.gk.hsv_gate.check_frame``, e.g. all black) reaches
    the back end as a lost frame (it predicts or holds) and the estimate is flagged
    ``valid=False``, ``lost=True``, with a reason that starts with ``"bad frame: "``. The pair
    tracker's reasons (for example that the Kalman prediction stood in for the tracker) are
    kept in the estimate's ``reason``.

    Coasting: a marker that was not measured (``PairResult.red_measured`` or
    ``yellow_measured`` False: the GK Kalman prediction or the P_red + V_rel fallback stood in,
    the track is lost, or the frame is bad) reaches the back end as missing
    (``observer.tracking.attitude_input``): with one marker left a filter fuses it and a
    per-frame solver holds its last solution; with none the frame is lost (a filter predicts
    through it with its model). Such a frame gives an estimate flagged ``lost=True`` whose
    reason says ``"coasting: ..."`` (first, or right after a bad frame's reason); once the
    markers have not both been measured for more than ``max_coast_s`` the estimate is also
    ``valid=False``, until the tracker measures both again.

    Parameters
    ----------
    locator : PairTracker
    backend : PixelObserver
    max_coast_s : float
        The longest time (s) since the last frame with both markers measured for which a
        coasting estimate is still ``valid``. Default 0.1 s (3 frames at 36 fps): on an 8°
        cone whose azimuth turns at 1 rad/s (a body rate of 8°/s) a held or predicted attitude
        drifts by up to about 0.8° in that time.
    clock : callable returning seconds, optional
        Times ``update`` (the release time). Default: the pair tracker's ``clock`` when it has
        one (``observer.trackers.MarkerPairTracker``), else ``time.perf_counter``; tests inject
        a stand-in so that the release times do not depend on machine load.
    """

    def __init__(
        self,
        locator: PairTracker,
        backend: PixelObserver,
        max_coast_s: float = 0.1,
        clock: Callable[[], float] | None = None,
    ) -> None:
        if not max_coast_s >= 0:
            raise ValueError(f"max_coast_s must be >= 0 s, got {max_coast_s}")
        self.locator = locator
        self.backend = backend
        self.clock: Callable[[], float] = clock or getattr(locator, "clock", time.perf_counter)
        self.max_coast_s = float(max_coast_s)
        self._last_measured = 0.0

    def reset(self, q0: ArrayLike = (1.0, 0.0, 0.0, 0.0), t0: float = 0.0) -> None:
        """Start from attitude ``q0`` (known: counts as measured) at time ``t0`` (s)."""
        self.locator.reset()
        self.backend.reset(q0, t0)
        self._last_measured = float(t0)

    def start(self, image: NDArray[np.uint8], binning: int, boxes_sensor_px: ArrayLike) -> None:
        """Start the pair tracker on the red and yellow boxes (2, 4), sensor px."""
        self.locator.start(image, boxes_sensor_px, binning)

    def update(self, frame: Frame, t_exposure: float) -> Estimate:
        """Estimate from one ``plant.scene.Frame`` (or any object with an ``image``) taken at
        mid-exposure ``t_exposure`` (s)."""
        t0 = self.clock()
        loc = self.locator.step(getattr(frame, "image", None))  # type: ignore[arg-type]
        # A predicted marker is not a measurement: the back end predicts (or holds) through it
        # with its own model rather than fusing the tracker's prediction as if it were measured.
        given = attitude_input(loc)
        measured = given.source == ATTITUDE_SOURCES[0]
        self.backend.process(given.marker_px, t_exposure, given.lost, loc.reason,
                             loc.compute_time_s)
        elapsed = self.clock() - t0
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
            note = (f"coasting: {given.source}, markers not both measured for {coast_s:.3f} s "
                    f"({limit} max_coast_s = {self.max_coast_s} s)")
            # A bad frame's reason stays first ("bad frame: ..."); else the coasting note is.
            parts = [reason, note] if loc.bad_frame else [note, reason]
            reason = "; ".join(r for r in parts if r)
        est = replace(est, valid=valid, lost=est.lost or not measured, reason=reason)
        if est.valid:
            self.locator.tilt_hint_rad = attitude.tilt(est.q)
        return est
