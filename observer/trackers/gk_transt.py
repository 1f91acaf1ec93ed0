"""GK-TransT (seed 000 §3.2): one network on the main marker, guided and gated by the GK
assistance; the auxiliary marker from rigid-body geometry.

Per frame (seed 000 §3.2.3, Figure 9):

1. The GK assistance's Kalman filter predicts the red centre (``GKAssist.search_centre_sensor_px``,
   seed 000 §3.2.1). The prediction is passed to the network as its search centre: "the attention
   range is restricted by the Kalman filter" (seed 000 §4.2). Before the first observation, or with
   ``guide_search=False``, the network searches around its own previous result.
2. The network (``observer.transt.tracker.TransTTracker``, or any tracker with its API) returns a
   box and a score for the red marker.
3. ``GKAssist.step`` gates the box with the HSV valid-pixel ratio (> 0.05): a confident box updates
   the Kalman filter (its centre refined by the sub-pixel circle fit when ``refine``); otherwise the
   prediction stands in. It then finds the yellow marker around the red one and checks it against
   D_exp = L·S·cos β, else P_yellow = P_red + V_rel (seed 000 §3.2.2), and updates the scale EMA.

With ``trust`` (default ``TrustConfig()``), ``observer.gk.trust.MarkerTrust`` replaces the seed's
gate in step 3: per frame it trusts the network's box, a colour fit near the prediction, or
nothing (the prediction stands in, flagged), from the marker's own colour, the circle fit, the
Kalman innovation, the network's score and the two-marker geometry; when the track is lost or
the geometry is violated it searches the whole frame and restarts the filter
(``docs/tracking.md``). ``trust=None`` runs the seed's gate alone.

With ``plate`` (default ``PlateConfig()``, and the trust rule on), ``observer.gk.plate`` places a
hidden marker from the VFC plate's four edges. When nothing is trusted for the red marker (or
the last frame lacked a measured marker), the plate is found on the last frame with both
markers measured, which becomes its reference, and followed into this frame; the reference red
centre mapped by it stands in for the Kalman prediction (``red_source`` "inferred", not
measured; the filter is updated with it, so the prediction follows the plate), and the yellow
one replaces P_red + V_rel when the yellow marker is not measured (``yellow_source``
"inferred"). The plate is followed from frame to frame until both markers are measured again,
and believed only while a measured marker lies where it maps it when the other is inferred.
Frames with both markers measured cost nothing more: the tracker keeps a reference to the last
two such frames (not a copy), so a caller must pass each frame in its own array, not refill
one buffer in place.

After a loss (occlusion, blur) the filter keeps predicting and the network keeps searching at the
prediction, so the first frame in which the marker is visible near the prediction re-acquires it;
``GKAssist`` flags the track lost after ``max_coast_frames`` frames without a confident box. Only
one network runs per frame: that is the seed's latency argument (C_T + C_K + C_G against 2 C_T).

``start`` initialises the network on the red box and runs ``GKAssist.step`` once on the start frame
with the annotated red box, which initialises the filter, the red→yellow vector V_rel and the
scale; if the yellow marker was not found there, V_rel is taken from the two annotated boxes.

A tracker that cannot search at a given centre (OpenCV's KCF and CSRT: ``kcf_gk``, ``csrt_gk``
in ``observer.trackers.make_pair_tracker``) is run with ``guide_search=False`` and
``restart_on_prediction=True``: whenever the prediction stood in for its box, it is restarted
on a box of 3.2 expected marker radii (our choice: the marker with its rim) centred on the
prediction, so that it searches there in the next frame.

With ``steady_search_size`` (a TransT network only; off in this class, on by default for
``make_pair_tracker("gk_transt")``, ``observer.trackers.registry.STEADY_SEARCH_PX``), the
network searches only the centre of its usual search region, a crop of that many px instead of
128 at the same image scale (``TransTTracker.track``'s ``search_size``), in frames that follow
``steady_min_frames`` steady ones in a row: the red marker measured on the network's own box
(trusted as such by the trust rule) with a Kalman prediction to search at. After any other
frame (coasting, a colour fit, a re-detection, a restart) it searches the whole region until
the track has been steady that long again. The smaller crop costs less (fewer backbone pixels
and transformer tokens); right after a disturbance the network's box is less reliable in it,
hence the run of steady frames first (docs/tracking.md).

Units: sensor px in and out (``observer.trackers``); the network sees image px of the binned frame.
``tilt_hint_rad`` (None by default: cos β = 1 and the scale EMA locked) may be set by the caller
from the latest attitude estimate before each ``step``.
"""

from __future__ import annotations

from collections import deque
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from observer.gk.assist import GKAssist, GKConfig, GKResult, JudgedObservation
from observer.gk.drift import DriftConfig
from observer.gk.hsv_gate import box_image_to_sensor, box_sensor_to_image
from observer.gk.plate import PlateConfig, PlateTracker
from observer.gk.trust import MarkerTrust, TrustConfig, TrustDecision
from observer.trackers import MarkerPairTracker, box_around
from observer.tracking import PairResult, SingleObjectTracker
from plant.camera import sensor_to_image
from plant.params import PlantParams


class GKTransTPairTracker(MarkerPairTracker):
    """GK-TransT on the marker pair (see the module docstring).

    Parameters
    ----------
    tracker : SingleObjectTracker
        The red marker's tracker: ``TransTTracker.small()``; a ``NumpyKCF`` is a fast stand-in.
    params : PlantParams, optional
    gk_config : GKConfig, optional
        Seed 000 §3.2 defaults.
    refine : bool, optional
        Sub-pixel circle fit of both centres (``GKConfig.refine_red`` and ``aux.refine``); None
        keeps ``gk_config`` as given (default: both on).
    guide_search : bool
        Pass the Kalman prediction to the network as its search centre (seed 000 §3.2).
    restart_on_prediction : bool
        Restart the tracker on the prediction when it stood in (for trackers that cannot search
        at a given centre; see the module docstring).
    trust : TrustConfig or None, optional
        The per-frame trust rule and whole-frame re-detection (``observer.gk.trust``; default
        on with ``TrustConfig()``); None runs the seed's gate alone.
    plate : PlateConfig or None, optional
        The VFC plate as the hidden red marker's stand-in (``observer.gk.plate``; default on,
        used with the trust rule); None coasts on the Kalman prediction alone.
    name : str
    drift : DriftConfig or None, optional
        Drift detection (``MarkerPairTracker``): a drifted red marker restarts the network and
        the Kalman filter on the re-detected marker; a drifted yellow one resets V_rel.
    steady_search_size : int or None, optional
        The network's search crop side, px of its input, after steady frames (module
        docstring); ``tracker`` must then be a ``TransTTracker``, and the size one it accepts
        (``TransTTracker.prepare``), else ``ValueError``. None: always the full crop.
    steady_min_frames : int
        Steady frames in a row before the smaller crop is searched (>= 1).
    """

    def __init__(
        self,
        tracker: SingleObjectTracker,
        params: PlantParams | None = None,
        gk_config: GKConfig | None = None,
        refine: bool | None = True,
        guide_search: bool = True,
        restart_on_prediction: bool = False,
        trust: TrustConfig | None = TrustConfig(),  # noqa: B008 - frozen pydantic model
        plate: PlateConfig | None = PlateConfig(),  # noqa: B008 - frozen pydantic model
        name: str = "gk_transt",
        drift: DriftConfig | None = DriftConfig(),  # noqa: B008 - frozen pydantic model
        steady_search_size: int | None = None,
        steady_min_frames: int = 1,
    ) -> None:
        cfg = gk_config or GKConfig()
        if refine is not None:
            cfg = cfg.model_copy(update={
                "refine_red": bool(refine),
                "aux": cfg.aux.model_copy(update={"refine": bool(refine)}),
            })
        super().__init__(params, bool(cfg.refine_red), cfg.subpixel, drift=drift)
        self.tracker = tracker
        self.steady_search_size = steady_search_size
        if steady_min_frames < 1:
            raise ValueError(f"steady_min_frames must be >= 1, got {steady_min_frames}")
        self.steady_min_frames = steady_min_frames
        self._transt = None
        if steady_search_size is not None:
            from observer.transt.tracker import TransTTracker

            if not isinstance(tracker, TransTTracker):
                raise ValueError("steady_search_size needs a TransTTracker as tracker, got "
                                 f"{type(tracker).__name__}")
            tracker.prepare(steady_search_size)
            self._transt = tracker
        self.gk = GKAssist(self.params, cfg)
        self.guide_search = bool(guide_search)
        self.restart_on_prediction = bool(restart_on_prediction)
        self.name = name
        self.last_gk: GKResult | None = None
        self.trust = None if trust is None else MarkerTrust(self.gk, trust)
        self.last_trust: TrustDecision | None = None
        self.plate = None if plate is None or trust is None else PlateTracker(self.params, plate)
        #: The last frames with both markers measured: (frame number, image, markers (2, 2))
        self._seen: deque[tuple[int, NDArray[np.uint8], NDArray[np.float64]]] = deque(maxlen=2)
        self._frame = 0
        self._hidden_before = False
        #: Steady frames in a row up to the last one (module docstring).
        self._steady_run = 0

    def reset(self) -> None:
        """Forget the track and the GK assistance's state."""
        super().reset()
        self.gk.reset()
        self.last_gk = None
        self._steady_run = 0
        self._forget_plate()

    def _forget_plate(self) -> None:
        """Let the plate go and forget the frames kept for its next start."""
        if self.plate is not None:
            self.plate.lose()
        self._seen.clear()
        self._frame, self._hidden_before = 0, False

    def _start(self, image: NDArray[np.uint8], boxes_sensor_px: NDArray[np.float64]) -> None:
        assert self.binning is not None
        self.tracker.initialize(image, box_sensor_to_image(boxes_sensor_px[0], self.binning))
        self._steady_run = 0
        self.gk.reset()
        self.last_gk = self.gk.step(image, self.binning, box_sensor_px=boxes_sensor_px[0],
                                    tilt_prev_rad=self.tilt_hint_rad)
        centres = boxes_sensor_px[:, :2] + 0.5 * boxes_sensor_px[:, 2:]
        if self.gk.aux.V_rel is None:
            self.gk.aux.V_rel = centres[1] - centres[0]
        if self.trust is not None:
            self.trust.start(image, self.binning, boxes_sensor_px[0])
        self._forget_plate()
        if self.plate is not None:
            found = self.last_gk.marker_px
            self._seen.append((0, image, np.where(np.isfinite(found), found, centres)))

    def search_centre_image_px(self) -> NDArray[np.float64] | None:
        """The Kalman prediction of the red centre for the next frame in image px, clipped to
        the frame; None when there is none (or guidance is off)."""
        if not self.guide_search or self.binning is None or self.frame_shape is None:
            return None
        prior = self.gk.search_centre_sensor_px()
        if not np.all(np.isfinite(prior)):
            return None
        c = sensor_to_image(prior, self.binning)
        H, W = self.frame_shape[:2]
        return np.clip(c, [0.0, 0.0], [W - 1.0, H - 1.0])

    def _result(self, res: GKResult, box_sensor: NDArray | None, score: float,
                net_time_s: float) -> PairResult:
        red_measured = res.red_source == "measurement"
        red_size = box_sensor[2:] if (red_measured and box_sensor is not None) \
            else self.box_size_px[0]
        red_box = box_around(res.red_px, red_size) if np.all(np.isfinite(res.red_px)) else None
        yellow_box = box_around(res.yellow_px, self.box_size_px[1]) \
            if np.all(np.isfinite(res.yellow_px)) else None
        yellow_lost = res.lost or res.yellow_source == "none"
        return PairResult(
            red_px=res.red_px, yellow_px=res.yellow_px, lost=res.lost or yellow_lost,
            reason=res.reason, compute_time_s=0.0, red_lost=res.lost, yellow_lost=yellow_lost,
            red_measured=red_measured, yellow_measured=res.yellow_source == "measurement",
            red_box_px=red_box, yellow_box_px=yellow_box, red_score=score,
            tracker_time_s=net_time_s, red_refined=res.red_refined,
        )

    def _step(self, image: NDArray[np.uint8]) -> PairResult:
        assert self.binning is not None
        centre = self.search_centre_image_px()
        if self._transt is not None and centre is not None \
                and self._steady_run >= self.steady_min_frames:
            tr = self._transt.track(image, search_centre_image_px=centre,
                                    search_size=self.steady_search_size)
        else:
            tr = self.tracker.track(image, search_centre_image_px=centre)
        box_img = np.asarray(tr.box_image_px, dtype=float).reshape(-1)
        box = box_image_to_sensor(box_img, self.binning) \
            if box_img.shape == (4,) and np.all(np.isfinite(box_img)) else None
        score = float(tr.score) if tr.score is not None else float("nan")
        judged = None
        if self.trust is not None:
            decision = self._judge(image, box, score)
            judged, self.last_trust = decision.observation, decision
        self._frame += 1
        mapped = self._plate_markers(image, judged)
        if judged is not None and mapped is not None:
            judged = replace(judged, yellow_stand_in_sensor_px=mapped[1])
            if judged.centre_sensor_px is None:
                assert self.plate is not None
                judged = replace(judged, stand_in_sensor_px=mapped[0],
                                 stand_in_sigma_px=self.plate.config.stand_in_sigma_px,
                                 reason=f"{judged.reason}; from the plate")
        res = self.gk.step(image, self.binning, box_sensor_px=box, score=score,
                           tilt_prev_rad=self.tilt_hint_rad, judged=judged)
        self.last_gk = res
        steady = res.red_source == "measurement" and (
            self.trust is None or self.last_trust is not None
            and self.last_trust.source == "network")
        self._steady_run = self._steady_run + 1 if steady else 0
        if self.trust is not None:
            self.trust.record(res.red_source == "measurement", res.yellow_source == "measurement")
        self._plate_after(image, res, mapped)
        out = self._result(res, box, score, float(tr.compute_time_s))
        if self.restart_on_prediction and res.red_source in ("prediction", "inferred"):
            out = self._restart(image, res, out)
        return out

    def _plate_markers(self, image: NDArray[np.uint8], judged: JudgedObservation | None
                       ) -> NDArray[np.float64] | None:
        """Where the plate puts the reference red and yellow centres in this frame (2, 2),
        sensor px, when a marker is (or just was) not measured; None otherwise or without a
        plate. Starts the plate on the last frame with both markers measured when needed."""
        if self.plate is None or judged is None:
            return None
        assert self.binning is not None
        if not self.plate.tracked:
            if not (judged.centre_sensor_px is None or self._hidden_before) or not self._seen:
                return None
            k, seen_image, markers = self._seen[-1]
            before = self._seen[0][2] if len(self._seen) == 2 and self._seen[0][0] == k - 1 \
                else None
            if not self.plate.start(seen_image, self.binning, *markers, before):
                return None
        if not self.plate.update(image):
            return None
        return self.plate.locate(self.binning)

    def _plate_after(self, image: NDArray[np.uint8], res: GKResult,
                     mapped: NDArray[np.float64] | None) -> None:
        """The plate's bookkeeping after a frame: with both markers measured the frame is kept
        (a reference for the next start) and the plate let go; with one marker inferred from
        the plate, the other, measured, must lie where the plate maps it."""
        if self.plate is None:
            return
        red_measured = res.red_source == "measurement"
        yellow_measured = res.yellow_source == "measurement"
        self._hidden_before = not (red_measured and yellow_measured)
        if red_measured and yellow_measured:
            self._seen.append((self._frame, image, np.vstack([res.red_px, res.yellow_px])))
            self.plate.lose()
        elif mapped is not None and res.red_source == "inferred" and yellow_measured:
            self.plate.check(mapped[1], res.yellow_px)
        elif mapped is not None and res.yellow_source == "inferred" and red_measured:
            self.plate.check(mapped[0], res.red_px)

    def _restart(self, image: NDArray[np.uint8], res: GKResult, out: PairResult) -> PairResult:
        """Restart the tracker where the prediction puts the red marker (see the module
        docstring); a prediction the tracker refuses (e.g. outside the frame) keeps the old
        track and says so."""
        assert self.binning is not None
        r = 1.6 * self.gk.marker_radius_px
        guess = np.r_[res.red_px - r, 2 * r, 2 * r]
        try:
            self.tracker.initialize(image, box_sensor_to_image(guess, self.binning))
        except ValueError as exc:
            why = f"tracker not restarted: {exc}"
            return replace(out, reason=f"{out.reason}; {why}" if out.reason else why)
        return out

    def _judge(self, image: NDArray[np.uint8], box: NDArray[np.float64] | None,
               score: float) -> TrustDecision:
        """The trust rule's decision for this frame; a whole-frame re-detection when the track
        is lost (or untrusted for a while) and nothing is trusted, or when the geometry has been
        violated. A re-detection restarts the Kalman filter."""
        assert self.trust is not None and self.binning is not None
        decision = self.trust.judge(image, self.binning, box, score)
        if (decision.source == "prediction" and self.trust.wants_redetection()) \
                or self.trust.geometry_violated():
            found = self.trust.redetect(image, self.binning,
                                        lambda c: self._network_at(image, c))
            if found is not None:
                self.gk.restart()
                return found
        return decision

    def _network_at(self, image: NDArray[np.uint8], centre_img: NDArray[np.float64]
                    ) -> tuple[NDArray[np.float64], float]:
        """The network's box centre (image px) and score when it searches at ``centre_img``."""
        tr = self.tracker.track(image, search_centre_image_px=centre_img)
        box = np.asarray(tr.box_image_px, dtype=float).reshape(-1)
        return box[:2] + 0.5 * box[2:], float(tr.score)

    def _restart_marker(self, image: NDArray[np.uint8], k: int,
                        centres_px: NDArray[np.float64]) -> None:
        """Red: the network on the re-detected marker and the Kalman filter restarted (the
        next confident observation initialises it); yellow: V_rel from the two centres."""
        assert self.binning is not None
        if k == 0:
            box = box_around(centres_px[0], self.box_size_px[0])
            self.tracker.initialize(image, box_sensor_to_image(box, self.binning))
            self.gk.restart()
            self._steady_run = 0
        else:
            self.gk.aux.V_rel = centres_px[1] - centres_px[0]

    def _bad_frame(self, image: object, reason: str) -> PairResult:
        """An unusable frame: the network does not run; GK coasts on its prediction."""
        assert self.binning is not None
        res = self.gk.step(image, self.binning, tilt_prev_rad=self.tilt_hint_rad)  # type: ignore
        self.last_gk = res
        self._steady_run = 0
        self._frame += 1
        self._hidden_before = True
        if self.plate is not None:
            self.plate.lose()  # not followed through this frame: started again later
        return self._result(res, None, float("nan"), 0.0)
