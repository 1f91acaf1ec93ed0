"""Front ends of the timed loop: from the rotor's true motion to measured marker pixels.

* ``MeasurementFrontEnd`` (measurement-model mode): the true marker pixels at mid-exposure plus
  Gaussian noise, frame dropouts and outliers. Fast, for sweeps.
* ``ImageFrontEnd`` (image-in-the-loop mode): a rendered frame (with motion blur over the
  exposure) and a pair tracker (``observer.tracking.PairTracker``: e.g. GK-TransT, or OpenCV's
  KCF inside the GK assistance of seed 000 §3.2) for both centres. Its compute time is measured.
  With a region of interest the tracker sees only the region's pixels, placed as the
  measurement model places it.
* ``OrbFrontEnd`` (image-in-the-loop, rotor without markers): a rendered frame of the textured
  rotor and the ORB matches of ``observer.orb``; its ``Capture.orb`` carries the
  ``OrbMeasurement`` for ``observer.orb_observer.OrbObserver`` (no marker truth: NaN).
  ``orb_reference`` renders the reference view it matches against. A scenario selects it with
  an ORB observer kind (``latency.scenario``: ``observer.kind: orb_aekf``, image mode).

Both return a ``Capture`` in full-sensor pixels, with the truth beside the measurement so that the
loop can flag tracking loss by the seed's 20 px criterion (seed 000 §4.2).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any, Literal, Protocol

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

from latency.loss_model import (
    BASELINE_SCENE,
    CALIBRATABLE,
    LossModel,
    blur_travel_px,
    load_loss_model,
    prediction_offset_px,
)
from observer.orb import OrbConfig, OrbMeasurement, OrbReference
from observer.trackers import make_pair_tracker
from observer.tracking import PairTracker, attitude_input
from plant.camera import marker_pixels, sensor_to_image
from plant.camera_mode import RegionOfInterest
from plant.params import PlantParams
from plant.registry import Registry
from plant.texture import TextureParams


@dataclass(frozen=True)
class Capture:
    """One frame's measurement.

    Attributes
    ----------
    marker_px : (2, 2) measured marker centres, sensor px (red, yellow); NaN when there is none
        (lost, or a rotor without markers).
    true_px : (2, 2) true marker centres, sensor px (NaN without marker truth).
    lost : the front end lost the markers (or the features) in this frame.
    reason : why the frame is not a clean measurement ("" when it is).
    compute_time_s : the front end's measured compute time, s.
    orb : the ORB matches of a textured rotor (``OrbFrontEnd``), None for marker front ends.
    red_measured, yellow_measured : the pair tracker's own flags (``PairResult``): the centre
        was measured in this frame, not predicted; None for a front end without a tracker
        (the measurement model: every finite centre is a measurement).
    """

    marker_px: NDArray[np.float64]
    true_px: NDArray[np.float64]
    lost: bool = False
    reason: str = ""
    compute_time_s: float = 0.0
    orb: OrbMeasurement | None = None
    red_measured: bool | None = None
    yellow_measured: bool | None = None

    @property
    def measured(self) -> NDArray[np.bool_]:
        """(2,) red, yellow: measured in this frame (the flag unless None, and a finite
        centre)."""
        flags = np.array([f is None or f for f in (self.red_measured, self.yellow_measured)])
        return flags & np.all(np.isfinite(self.marker_px), axis=1)

    @property
    def measurement(self) -> NDArray[np.float64] | OrbMeasurement:
        """What the observer fuses: the ORB matches if any, else the measured marker centres
        (NaN for a marker the tracker did not measure: the boundary rule of
        ``observer.tracking.attitude_input``)."""
        if self.orb is not None:
            return self.orb
        return np.where(self.measured[:, None], self.marker_px, np.nan)


class FrontEnd(Protocol):
    """Rotor motion -> one frame's measurement (see the module docstring)."""

    def reset(self) -> None:
        """Forget the tracking state (a new run)."""
        ...

    def capture(
        self, q: NDArray[np.float64], omega: NDArray[np.float64], t_exposure: float
    ) -> Capture:
        """The measurement of a frame exposed at ``t_exposure`` (s, mid-exposure) while the
        rotor is at attitude ``q`` with body rate ``omega`` (rad/s)."""
        ...

    def tilt_hint(self, tilt_rad: float) -> None:
        """The latest estimated tilt β (rad), for front ends with a geometric check; the
        others ignore it."""
        ...


#: Why a front end loses a frame (``Capture.reason``).
LOST_DROPOUT = "dropout (measurement model)"
LOST_OUTSIDE_WINDOW = "marker left the search window"
LOST_OUTSIDE_ROI = "marker outside the region of interest"
LOST_BLUR = "motion blur beyond the tracker's limit"
LOST_CALIBRATED = "lost by the tracker's calibrated loss model"


class SearchWindowLoss(BaseModel):
    """The hand-set search-window loss model, the same for every tracker (our construction, so
    that loss depends on the delay, the frame drops and the reference's aggressiveness): the
    tracker searches a window of radius ``search_radius_px`` around its expected marker
    position (the last measurement, advanced by the last inter-frame motion when
    ``predictive_search``, as the GK Kalman prediction does); a marker outside the window is
    lost until a re-detection ``reacquire_after_frames`` processed frames later. A marker
    smeared over more than ``blur_limit_px`` during the exposure is lost for that frame.
    ``CalibratedLoss`` replaces it with a tracker's own, measured behaviour."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["search_window"] = "search_window"
    search_radius_px: float | None = Field(
        None,
        gt=0.0,
        description="Tracker search window radius, sensor px; None: never lost "
        "by motion. A KCF-like window of 2.5 marker diameters is about 240 sensor px.",
    )
    predictive_search: bool = Field(True, description="Centre the window on a CV prediction.")
    reacquire_after_frames: int = Field(
        5, ge=1, description="Our choice: processed frames until a re-detection finds it."
    )
    blur_limit_px: float | None = Field(
        None,
        gt=0.0,
        description="Marker travel during the exposure beyond which the frame is "
        "lost, sensor px; None: blur never loses it.",
    )


class CalibratedLoss(BaseModel):
    """A tracker's own loss behaviour, calibrated on its image-in-the-loop runs
    (``latency.loss_model``; written by ``pmspm calibrate-loss --tracker NAME``). The file is
    loaded when the settings are validated, so a missing, stale or foreign file is an error
    before any run."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["calibrated"] = "calibrated"
    tracker: str = Field(description=f"One of {', '.join(CALIBRATABLE)}.")
    noise: Literal["calibrated", "sigma_px"] = Field(
        "calibrated", description="Centre noise of tracked frames: the tracker's calibrated "
        "spread, or the measurement model's sigma_px.")
    scene: str = Field(BASELINE_SCENE, description="The scene appearance of the calibration "
                       "(its file lists them: nominal, dim, highlights, distractor_red, "
                       "uneven_light; experiments.loss_calibration.APPEARANCES).")

    @model_validator(mode="after")
    def _file_loads(self) -> CalibratedLoss:
        load_loss_model(self.tracker, scene=self.scene)
        return self

    @property
    def model(self) -> LossModel:
        """The loaded calibration, in this scene."""
        return load_loss_model(self.tracker, scene=self.scene)


LossSpec = Annotated[SearchWindowLoss | CalibratedLoss, Field(discriminator="kind")]
#: Keys of ``SearchWindowLoss`` that older settings gave at the top level.
_WINDOW_KEYS = ("search_radius_px", "predictive_search", "reacquire_after_frames",
                "blur_limit_px")


class MeasurementConfig(BaseModel):
    """Noise and loss model of the measurement front end, sensor px.

    Tracking loss comes from ``loss``: the hand-set search window (``SearchWindowLoss``, the
    default) or a tracker's calibrated model (``CalibratedLoss``). The search window's keys
    given at the top level (the older form) are moved into ``loss`` with a
    ``DeprecationWarning``.

    With a region of interest ``roi`` (``plant.camera_mode.RegionOfInterest``) only those rows
    and columns are read: a marker outside them is lost for the frame (the motion outran the
    region). The region sits at the sensor centre, or with ``roi.follow`` on the mean of the
    predicted marker positions (the same constant-velocity prediction), which stays put while
    the markers are lost; it is shifted to lie on the sensor.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    sigma_px: float = Field(
        0.5,
        ge=0.0,
        description="Our choice: per-coordinate noise; the GK sub-pixel stage "
        "measured 0.15 px median, 0.3 px p95 on rendered frames (benchmarks/RESULTS.md).",
    )
    dropout_prob: float = Field(0.0, ge=0.0, le=1.0, description="Frames with no markers.")
    outlier_prob: float = Field(0.0, ge=0.0, le=1.0, description="Frames with a jumped centre.")
    outlier_px: float = Field(60.0, ge=0.0, description="Size of an outlier jump, sensor px.")
    loss: LossSpec = Field(
        default_factory=SearchWindowLoss,
        description="Tracking loss: {kind: search_window, ...} (hand-set, the same for every "
        "tracker) or {kind: calibrated, tracker: NAME} (the tracker's own, measured).",
    )
    roi: RegionOfInterest | None = Field(
        None, description="Region of interest read out; None: the whole sensor."
    )

    @model_validator(mode="before")
    @classmethod
    def _window_keys_into_loss(cls, data):
        """The older form: search-window keys at the top level."""
        if isinstance(data, dict) and any(k in data for k in _WINDOW_KEYS):
            if "loss" in data:
                raise ValueError(f"give the search window's keys ({', '.join(_WINDOW_KEYS)}) "
                                 "inside loss, not beside it")
            warnings.warn("measurement.search_radius_px and its siblings moved into "
                          "measurement.loss: {kind: search_window, ...}", DeprecationWarning,
                          stacklevel=2)
            data = dict(data)
            data["loss"] = {"kind": "search_window",
                            **{k: data.pop(k) for k in _WINDOW_KEYS if k in data}}
        return data

    @property
    def window(self) -> SearchWindowLoss | None:
        """The search-window loss model, None with a calibrated one."""
        return self.loss if isinstance(self.loss, SearchWindowLoss) else None

    @property
    def predictive(self) -> bool:
        """Whether the front end's prediction advances by the last motion (always with a
        calibrated model: it was calibrated so)."""
        return self.window is None or self.window.predictive_search

    @property
    def noise_sigma_px(self) -> float:
        """Per-coordinate noise of a tracked frame, sensor px."""
        loss = self.loss
        if isinstance(loss, CalibratedLoss) and loss.noise == "calibrated":
            return loss.model.noise_sigma_px
        return self.sigma_px


class MarkerPrediction:
    """The trackers' constant-velocity prediction of the two marker centres, sensor px: the
    last measurement advanced by the last inter-frame motion per processed frame (the GK
    Kalman prediction's role, seed 000 §3.2.1), or the last measurement alone without
    ``use_motion``. It places the search window and a following region of interest."""

    def __init__(self, use_motion: bool = True) -> None:
        self.use_motion = use_motion
        self.reset()

    def reset(self) -> None:
        """No measurement yet."""
        self._last: NDArray[np.float64] | None = None
        self._motion = np.zeros((2, 2))
        self._frames_since = 0  # processed frames since the last measurement

    def frame(self) -> None:
        """A frame is processed (measured or not)."""
        self._frames_since += 1

    def measured(self, z: NDArray[np.float64]) -> None:
        """The frame just counted measured the centres ``z`` (2, 2)."""
        if self._last is not None:
            self._motion = (z - self._last) / self._frames_since
        self._last, self._frames_since = np.array(z, dtype=float), 0

    @property
    def predicted_px(self) -> NDArray[np.float64] | None:
        """(2, 2) predicted centres for the next frame, sensor px; None before the first
        measurement."""
        if self._last is None:
            return None
        return self._last + (self._motion if self.use_motion else 0.0)


def _sensor_px(params: PlantParams) -> tuple[int, int]:
    return params.camera.sensor_width_px, params.camera.sensor_height_px


class MeasurementFrontEnd:
    """True marker pixels plus noise, dropout, outliers and motion-induced tracking loss
    (measurement-model mode; see ``MeasurementConfig``)."""

    def __init__(
        self, params: PlantParams, config: MeasurementConfig, rng: np.random.Generator
    ) -> None:
        self.params, self.config, self.rng = params, config, rng
        self._prediction = MarkerPrediction(config.predictive)
        self._calibrated = config.loss.model if isinstance(config.loss, CalibratedLoss) else None
        self._sigma_px = config.noise_sigma_px
        self.reset()

    def reset(self) -> None:
        """Forget the tracker's state (last position, motion, loss count)."""
        self._prediction.reset()
        self._lost_frames = 0

    def tilt_hint(self, tilt_rad: float) -> None:
        """No geometric check: ignored."""

    def roi_centre_px(self, roi: RegionOfInterest) -> NDArray[np.float64]:
        """Centre (u, v) of the region of interest for the next frame, sensor px
        (``RegionOfInterest.centre_px`` on the predicted markers)."""
        return roi.centre_px(_sensor_px(self.params), self._prediction.predicted_px)

    def capture(
        self, q: NDArray[np.float64], omega: NDArray[np.float64], t_exposure: float
    ) -> Capture:
        """The measurement of a frame exposed at ``t_exposure`` (s) at attitude ``q`` and
        body rate ``omega`` (rad/s): the true marker pixels, lost or plus noise
        (``MeasurementConfig``). Mirrored in ``latency.compiled.frontend._capture``; keep
        both in step (tests/test_compiled_mirror.py checks them equal)."""
        c = self.config
        truth = marker_pixels(self.params, q)
        nothing = np.full((2, 2), np.nan)
        if self.rng.random() < c.dropout_prob:
            return Capture(nothing, truth, True, LOST_DROPOUT)
        predicted = self._prediction.predicted_px
        self._prediction.frame()
        if c.roi is not None and not c.roi.contains(truth, self.roi_centre_px(c.roi)):
            self._lost_frames += 1
            return Capture(nothing, truth, True, LOST_OUTSIDE_ROI)
        w = c.window
        if self._calibrated is not None:
            p = self._calibrated.p_lost(prediction_offset_px(truth, predicted),
                                        blur_travel_px(self.params, q, omega), self._lost_frames)
            if self.rng.random() < p:
                self._lost_frames += 1
                return Capture(nothing, truth, True, LOST_CALIBRATED)
        elif (
            w is not None
            and w.search_radius_px is not None
            and predicted is not None
            and self._lost_frames < w.reacquire_after_frames  # else: re-detected this frame
        ):
            if prediction_offset_px(truth, predicted) > w.search_radius_px:
                self._lost_frames += 1
                return Capture(nothing, truth, True, LOST_OUTSIDE_WINDOW)
        if w is not None and w.blur_limit_px is not None \
                and blur_travel_px(self.params, q, omega) > w.blur_limit_px:
            return Capture(nothing, truth, True, LOST_BLUR)
        z = truth + self.rng.normal(scale=self._sigma_px, size=(2, 2))
        if self.rng.random() < c.outlier_prob:
            angle = self.rng.uniform(0, 2 * np.pi)
            z[self.rng.integers(2)] += c.outlier_px * np.array([np.cos(angle), np.sin(angle)])
        self._prediction.measured(z)
        self._lost_frames = 0
        return Capture(z, truth)


class ImageFrontEnd:
    """Render a frame (with motion blur), then locate both markers with a pair tracker.

    Parameters
    ----------
    params : PlantParams
    renderer : object with ``render(q, t_exposure, omega=...) -> plant.scene.Frame``
        (``AnalyticRenderer`` or ``MujocoRenderer``).
    locator : PairTracker, optional
        Default: OpenCV KCF inside the GK assistance (``make_pair_tracker("kcf_gk")``).
    roi : RegionOfInterest, optional
        The region read out (None: the whole sensor). The camera delivers only those rows and
        columns: the frame is blanked (zero) outside the region, placed as the measurement
        model places it (``RegionOfInterest.centre_px``: the sensor centre, or with ``follow``
        the constant-velocity prediction of this front end's own measurements,
        ``MarkerPrediction``), so the tracker sees only the region, in the sensor's
        coordinates. A marker the tracker loses there, or reports outside the region (a
        centre no pixel of this frame can have measured), is lost for the frame
        (``LOST_OUTSIDE_ROI``). The prediction takes only centres the tracker measured in the image,
        so a following region stays put while the tracker coasts or has lost the markers.

    The tracker starts on the true boxes of the first frame, as a user's first-frame annotation
    would, and that frame's measurement is the annotation (the boxes' centres), as in the
    tracking benchmark (``experiments.tracking_bench.run_trackers``): the loop and the benchmark
    run the same tracker on the same frames. ``tilt_hint`` (called by the loop with the latest
    estimate) feeds the GK geometry.
    """

    def __init__(self, params: PlantParams, renderer, locator: PairTracker | None = None,
                 roi: RegionOfInterest | None = None) -> None:
        self.params = params
        self.renderer = renderer
        self.locator = locator or make_pair_tracker("kcf_gk", params)
        self.roi = roi
        self._prediction = MarkerPrediction()
        #: Centre (u, v) of the region of the last frame captured, sensor px (None: whole sensor).
        self.last_roi_centre_px: NDArray[np.float64] | None = None

    def reset(self) -> None:
        """Forget the tracker's and the prediction's state (a new run)."""
        self.locator.reset()
        self._prediction.reset()
        self.last_roi_centre_px = None

    def tilt_hint(self, tilt_rad: float) -> None:
        """The latest estimated tilt β, rad, for the GK geometric check."""
        self.locator.tilt_hint_rad = tilt_rad

    def _read_out(self, frame) -> NDArray[np.uint8]:
        """The frame's image as the camera delivers it: blanked outside the region of
        interest (binned pixels whose centre lies outside it), placed for this frame."""
        if self.roi is None:
            return frame.image
        centre = self.roi.centre_px(_sensor_px(self.params), self._prediction.predicted_px)
        self.last_roi_centre_px = centre
        half = 0.5 * np.array([self.roi.cols, self.roi.rows])
        lo = np.ceil(sensor_to_image(centre - half, frame.binning)).astype(int)
        hi = np.floor(sensor_to_image(centre + half, frame.binning)).astype(int)
        image = np.zeros_like(frame.image)
        window = (slice(max(lo[1], 0), hi[1] + 1), slice(max(lo[0], 0), hi[0] + 1))
        image[window] = frame.image[window]
        return image

    def capture(
        self, q: NDArray[np.float64], omega: NDArray[np.float64], t_exposure: float
    ) -> Capture:
        """Render the frame, read out the region of interest and track both markers
        (``FrontEnd.capture``)."""
        frame = self.renderer.render(q, t_exposure=t_exposure, omega=omega)
        image = self._read_out(frame)
        self._prediction.frame()
        if not self.locator.started:
            boxes = np.asarray(frame.boxes_px, dtype=float)
            centres = boxes[:, :2] + 0.5 * boxes[:, 2:]
            if self._outside_roi(centres):  # nothing to annotate yet
                return Capture(np.full((2, 2), np.nan), frame.marker_px, True, LOST_OUTSIDE_ROI,
                               red_measured=False, yellow_measured=False)
            self.locator.start(image, frame.boxes_px, frame.binning)
            self._prediction.measured(centres)
            return Capture(centres, frame.marker_px, red_measured=True, yellow_measured=True)
        loc = self.locator.step(image)
        if self._outside_roi(loc.marker_px):
            return Capture(np.full((2, 2), np.nan), frame.marker_px, True, LOST_OUTSIDE_ROI,
                           loc.compute_time_s, red_measured=False, yellow_measured=False)
        if not loc.lost and loc.red_measured and loc.yellow_measured:
            self._prediction.measured(loc.marker_px)  # not a coasting tracker's prediction
        # the boundary rule (observer.tracking.attitude_input): no marker measured, a lost frame
        lost = loc.lost or attitude_input(loc).lost
        return Capture(loc.marker_px, frame.marker_px, lost, loc.reason, loc.compute_time_s,
                       red_measured=loc.red_measured, yellow_measured=loc.yellow_measured)

    def _outside_roi(self, centres_px: NDArray[np.float64]) -> bool:
        """Finite centres (2, 2), sensor px, not all inside this frame's region of interest."""
        return (self.roi is not None and bool(np.all(np.isfinite(centres_px)))
                and not self.roi.contains(centres_px, self.last_roi_centre_px))


class OrbFrontEnd:
    """Render the textured rotor and match ORB features against the observer's reference view.

    Parameters
    ----------
    renderer : a renderer built with a texture (``AnalyticRenderOptions(texture=...)``).
    observer : ``observer.orb_observer.OrbObserver`` whose ``measure(frame)`` is used; the loop
        passes the measurement back to the same observer's ``process``.
    """

    def __init__(self, renderer, observer) -> None:
        self.renderer = renderer
        self.observer = observer

    def reset(self) -> None:
        """Nothing to reset: the reference view is fixed."""

    def tilt_hint(self, tilt_rad: float) -> None:
        """No geometric check: ignored."""

    def capture(
        self, q: NDArray[np.float64], omega: NDArray[np.float64], t_exposure: float
    ) -> Capture:
        """Render the frame and match its ORB features (``Capture.orb``; no marker
        centres)."""
        frame = self.renderer.render(q, t_exposure=t_exposure, omega=omega)
        m = self.observer.measure(frame)
        nan = np.full((2, 2), np.nan)
        return Capture(nan, nan.copy(), not m.valid, m.reason, m.compute_time_s, orb=m)



def orb_reference(
    params: PlantParams,
    renderer,
    texture: TextureParams,
    q_ref=(1.0, 0.0, 0.0, 0.0),
    config: OrbConfig | None = None,
) -> OrbReference:
    """The ORB reference view of the textured rotor: one frame rendered by ``renderer`` (built
    with ``texture``) at the known attitude ``q_ref``, at rest, captured by
    ``OrbReference.capture`` with the print's size from ``texture`` (m inside; ``size_mm`` at
    the edge, default the VFC plate's 50 mm)."""
    size_mm = texture.size_mm if texture.size_mm is not None else params.vfc.plate_size_mm
    frame = renderer.render(q_ref)
    return OrbReference.capture(
        frame.image, frame.binning, params, q_ref, print_half_size_m=size_mm / 2000.0,
        config=config,
    )


def _measurement(s: Any, renderer: Any, observer: Any, clock: Callable[[], float]) -> FrontEnd:
    """``MeasurementFrontEnd`` with the scenario's noise and loss, its own random stream."""
    return MeasurementFrontEnd(s.plant, s.measurement, np.random.default_rng([s.seed, 1]))


def _image(s: Any, renderer: Any, observer: Any, clock: Callable[[], float]) -> FrontEnd:
    """``ImageFrontEnd`` with the scenario's tracker (``observer.trackers.TRACKERS``) timed by
    ``clock``, reading the region of interest ``measurement.roi``."""
    tracker = make_pair_tracker(s.tracker, s.plant, clock=clock)
    return ImageFrontEnd(s.plant, renderer, tracker, roi=s.measurement.roi)


def _orb(s: Any, renderer: Any, observer: Any, clock: Callable[[], float]) -> FrontEnd:
    """``OrbFrontEnd`` feeding the ORB observer its frames."""
    return OrbFrontEnd(renderer, observer)


FRONT_ENDS = Registry(
    "front_end",
    "what the loop measures each frame: modelled marker centres, or rendered images through a "
    "tracker or ORB",
    "(scenario, renderer, observer, clock) -> FrontEnd",
    "mode: measurement | image (image with an ORB observer: orb); options under measurement",
)
FRONT_ENDS.register("measurement", "the measurement model: true marker centres plus noise, "
                    "dropouts, outliers and a loss model (mode: measurement)", _measurement,
                    MeasurementConfig, prefix="measurement.")
FRONT_ENDS.register("image", "rendered frames through a marker-pair tracker (mode: image, "
                    "marker observers)", _image)
FRONT_ENDS.register("orb", "rendered frames of the textured rotor matched by ORB (mode: "
                    "image, ORB observers)", _orb)


def _loss(spec: SearchWindowLoss | CalibratedLoss) -> SearchWindowLoss | LossModel:
    """The search window's settings (the front end applies them), or the loaded calibration."""
    return spec.model if isinstance(spec, CalibratedLoss) else spec


LOSS_MODELS = Registry(
    "loss",
    "when the measurement model loses a marker (measurement.loss)",
    "(spec) -> SearchWindowLoss | LossModel",
    "measurement: {loss: {kind: NAME, ...}}",
)
LOSS_MODELS.register("search_window", "the hand-set search window, the same for every tracker "
                     "(our construction)", _loss, SearchWindowLoss)
LOSS_MODELS.register("calibrated", "a tracker's own loss, calibrated on its image-in-the-loop "
                     "runs (pmspm calibrate-loss)", _loss, CalibratedLoss)
