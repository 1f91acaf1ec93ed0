"""The GK assistance of GK-TransT (seed 000 §3.2), behind any tracker of the main marker.

``GKAssist.step`` runs seed 000 §3.2.3's per-frame workflow on the output of whatever tracks the
red main marker (a TransT network, an OpenCV tracker, a detector, ground truth with
noise): it takes the frame and the tracker's box (or centre) and score, and returns both marker
centres with where each came from.

Per frame k:

1. **Predict** (seed 000 §3.2.1): the pixel Kalman filter's prior P̂_red(k) =
   H F X(k−1) (``observer.gk.pixel_kalman``). Before the frame, ``search_centre_sensor_px()``
   gives the same prior to a tracker that wants a search centre (the K²CF idea, seed 004 §3.2.2).
2. **Gate** (seed 000 §3.2.1): the red valid-pixel ratio inside the tracker's box
   (``observer.gk.hsv_gate``). Above 0.05 the observation is confident.
3. **Observe or stand in**: when confident, the observation z is the box centre, refined to
   sub-pixel accuracy by the circle fit (seed 004 §4, ``observer.gk.subpixel``; our addition,
   ``refine_red``) when the fit is valid and its centre lies in the box; it updates the filter.
   When not confident (or the tracker's output, or the frame, is unusable) the filter coasts and
   the prior stands in for the observation.
4. **Auxiliary point** (seed 000 §3.2.2): the yellow marker is searched around the red point and
   checked against D_exp = L·S·cos β, else P_yellow = P_red + V_rel
   (``observer.gk.aux_locator``).
5. **Scale** (seed 000 §3.2.3): when both points were measured and β < 2°, the pixel scale EMA
   S_t = 0.9 S_{t−1} + 0.1 D_det/L is updated (``observer.gk.scale``).

The midpoint of the two points is the virtual pole (seed 000 §3.2.3) that an attitude solver
takes; this module stops at the pixels.

**What the red output is.** The seed updates the filter with the tracker's observation and uses
the prediction when confidence is low; it does not say whether a confident frame reports the raw
observation or the filter's posterior. ``red_output="measurement"`` (default, our choice) reports
the observation, the more accurate choice when it is a sub-pixel circle fit (the posterior of a
constant-velocity filter lags under acceleration); ``"filtered"`` reports the posterior, better
for a jittery box centre.

**Lost.** After more than ``max_coast_frames`` consecutive frames without a confident observation
(our choice: 18 frames = 0.5 s at 36 frames/s; the seed's occlusion test covers 11 frames), when
the prediction leaves the sensor, or before the first confident observation, ``lost`` is True.
While lost the filter keeps predicting (the output is still the prediction, flagged); the next
confident observation re-initialises it.

Units: marker positions, boxes and covariances are in *full-sensor* pixels (the seed's unit);
frames are RGB (see ``observer.gk.hsv_gate``), binned by ``binning``. A tracker working on the
binned frame converts its box with ``observer.gk.hsv_gate.box_image_to_sensor``. Bad input gives
a result with a reason, never an exception.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

from observer.gk.aux_locator import AuxLocator, AuxLocatorConfig, AuxResult, AuxSource
from observer.gk.hsv_gate import (
    GateResult,
    HSVGate,
    HSVGateConfig,
    box_sensor_to_image,
    check_frame,
)
from observer.gk.pixel_kalman import PixelKalman, PixelKalmanConfig
from observer.gk.scale import PixelScaleEMA, ScaleEMAConfig, scale_from_camera
from observer.gk.subpixel import SubpixelConfig, SubpixelResult, refine_in_box
from plant.params import PlantParams

RedSource = Literal["measurement", "inferred", "prediction", "none"]


class GKConfig(BaseModel):
    """Configuration of the GK assistance. Sub-configs carry the seed's defaults.

    The gate's colour ranges are used everywhere: the auxiliary locator's yellow range and the
    sub-pixel settings of both markers are taken from ``gate.yellow`` and ``subpixel``.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    kalman: PixelKalmanConfig = PixelKalmanConfig()
    gate: HSVGateConfig = HSVGateConfig()
    aux: AuxLocatorConfig = AuxLocatorConfig()
    scale: ScaleEMAConfig = ScaleEMAConfig()
    subpixel: SubpixelConfig = SubpixelConfig()
    refine_red: bool = Field(
        True, description="Our choice: refine the red observation by the circle fit (seed 004)."
    )
    red_output: Literal["measurement", "filtered"] = Field(
        "measurement", description="Our choice: report the observation or the filter posterior "
        "in confident frames (see the module docstring)."
    )
    max_coast_frames: int = Field(
        18, ge=0, description="Our choice: frames without a confident observation before lost."
    )
    min_score: float | None = Field(
        None, description="Our choice: if set, a tracker score below it also makes the "
        "observation unreliable (the seed gates on colour only)."
    )
    refine_roi_margin: float = Field(
        0.3, ge=0.0, description="Our choice: the fit's ROI is the tracker box enlarged by this "
        "fraction of its size on each side."
    )
    centre_box_marker_radii: float = Field(
        1.0, gt=0.0, description="Our choice: half-side of the square box built around a "
        "tracker that gives only a centre, in expected marker radii (S·d/2)."
    )
    S0_px_per_m: float | None = Field(
        None, gt=0.0, description="Initial pixel scale, sensor px/m; None: from the camera "
        "model f/(p·h_c) (``observer.gk.scale``)."
    )

    @model_validator(mode="after")
    def _finite_score(self) -> GKConfig:
        if self.min_score is not None and not math.isfinite(self.min_score):
            raise ValueError("min_score must be finite or None")
        return self


@dataclass(frozen=True)
class JudgedObservation:
    """A red observation already judged by a trust rule (``observer.gk.trust``): ``step``
    then skips its own HSV gate and circle fit.

    Attributes
    ----------
    centre_sensor_px : (2,) the trusted red centre, sensor px, or None when nothing is trusted
        (the prediction stands in and the frame is not measured).
    ratio : the colour ratio reported as ``GKResult.confidence``, in [0, 1].
    refined : the centre is a circle-fit centre.
    reason : why nothing is trusted, or how the centre was obtained ("" for the network's).
    stand_in_sensor_px : with nothing trusted, where another cue puts the hidden marker (e.g.
        the VFC plate, ``observer.gk.plate``), sensor px, or None: it then stands in for the
        Kalman prediction and updates the filter with R + stand_in_sigma_px²·I2, the frame
        still not measured.
    stand_in_sigma_px : standard deviation of the stand-in beyond R, sensor px.
    yellow_stand_in_sensor_px : where the same cue puts the yellow marker, sensor px, or None:
        it replaces P_red + V_rel when the yellow marker is not measured.
    """

    centre_sensor_px: NDArray[np.float64] | None
    ratio: float
    refined: bool = False
    reason: str = ""
    stand_in_sensor_px: NDArray[np.float64] | None = None
    stand_in_sigma_px: float = 0.0
    yellow_stand_in_sensor_px: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class GKResult:
    """Both marker centres of one frame and how they were obtained.

    Attributes
    ----------
    red_px, yellow_px : (2,) centres (u, v), full-sensor px (NaN when ``*_source == "none"``).
    red_source : "measurement" (confident observation), "inferred" (a judged observation's
        stand-in, e.g. from the plate, stood in; not measured), "prediction" (the Kalman prior
        stood in) or "none".
    yellow_source : "measurement", "fallback" (P_red + V_rel), "inferred" (the judged
        observation's yellow stand-in; not measured) or "none".
    confidence : red valid-pixel ratio in the tracker's box (seed 000 §3.2.1), in [0, 1].
    confident : the red observation passed the gate (and the score threshold, if set).
    lost : no usable main-marker track (see the module docstring); ``reason`` says why.
    reason : why the frame is not a clean double measurement ("" when it is): every stage that
        fell back adds its reason, separated by "; ".
    red_predicted_px : (2,) the Kalman prior for this frame, sensor px (NaN before init).
    red_cov_px2 : (2, 2) covariance of ``red_px``, sensor px²: R for a measurement, the
        posterior for ``red_output="filtered"``, the prior for a prediction.
    red_refined : the red observation is the circle-fit centre (else the box centre).
    scale_px_per_m : pixel scale S after this frame, sensor px/m.
    scale_updated : the EMA was updated this frame.
    tracker_score : the score passed in (NaN if none).
    compute_time_s : wall-clock time of ``step``, s.
    gate, aux, red_fit : the stages' own results, for diagnostics.
    """

    red_px: NDArray[np.float64]
    yellow_px: NDArray[np.float64]
    red_source: RedSource
    yellow_source: AuxSource
    confidence: float
    confident: bool
    lost: bool
    reason: str
    red_predicted_px: NDArray[np.float64]
    red_cov_px2: NDArray[np.float64]
    red_refined: bool
    scale_px_per_m: float
    scale_updated: bool
    tracker_score: float
    compute_time_s: float
    gate: GateResult = field(repr=False)
    aux: AuxResult = field(repr=False)
    red_fit: SubpixelResult | None = field(default=None, repr=False)

    @property
    def marker_px(self) -> NDArray[np.float64]:
        """(2, 2) red then yellow centre, sensor px (the order of ``Frame.marker_px``)."""
        return np.vstack([self.red_px, self.yellow_px])

    @property
    def valid(self) -> bool:
        """Both centres are finite and the track is not lost."""
        return (not self.lost) and bool(np.all(np.isfinite(self.marker_px)))


class GKAssist:
    """Kalman prediction, HSV gate, geometric auxiliary point and scale EMA (seed 000 §3.2).

    Parameters
    ----------
    params : PlantParams, optional
        Camera (sensor size, scale S_0) and VFC (L, marker diameter); defaults if None.
    config : GKConfig, optional
        Defaults from seed 000 §3.2 and our documented choices.
    """

    def __init__(self, params: PlantParams | None = None, config: GKConfig | None = None) -> None:
        self.params = params or PlantParams()
        self.config = config or GKConfig()
        cfg = self.config
        self.kalman = PixelKalman(cfg.kalman)
        self.gate = HSVGate(cfg.gate)
        aux_cfg = cfg.aux.model_copy(update={"yellow": cfg.gate.yellow, "subpixel": cfg.subpixel})
        self.aux = AuxLocator(self.params.vfc.L_m, self.params.vfc.marker_diameter_mm / 1000.0,
                              aux_cfg)
        S0 = cfg.S0_px_per_m or scale_from_camera(self.params.camera)
        self.scale = PixelScaleEMA(self.params.vfc.L_m, S0, cfg.scale)
        self._coast = 0
        self._lost = True

    # --- state ---------------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the track, V_rel and the scale history."""
        self.kalman.reset()
        self.aux.reset()
        self.scale.reset()
        self._coast = 0
        self._lost = True

    @property
    def lost(self) -> bool:
        """The main marker's track is lost (see the module docstring)."""
        return self._lost

    def restart(self) -> None:
        """Forget the main marker's track (the next observation initialises the filter) but
        keep V_rel and the scale: after a re-detection."""
        self.kalman.reset()
        self._coast = 0
        self._lost = True

    def search_centre_sensor_px(self) -> NDArray[np.float64]:
        """The Kalman prediction of the red centre for the *next* frame, sensor px (NaN before
        the first observation): where a tracker should search."""
        return self.kalman.peek(1)

    @property
    def marker_radius_px(self) -> float:
        """Expected marker radius S·d/2, sensor px."""
        return 0.5 * self.params.vfc.marker_diameter_mm / 1000.0 * self.scale.S

    # --- the workflow --------------------------------------------------------------------------
    def _tracker_box(
        self, box_sensor_px: ArrayLike | None, centre_sensor_px: ArrayLike | None
    ) -> tuple[NDArray | None, NDArray | None, str]:
        """(box (4,), centre (2,), reason) in sensor px from the tracker's output."""
        if box_sensor_px is not None:
            try:
                box = np.asarray(box_sensor_px, dtype=float).reshape(4)
            except (TypeError, ValueError):
                return None, None, "tracker box must be (x, y, w, h)"
            if not np.all(np.isfinite(box)) or box[2] <= 0.0 or box[3] <= 0.0:
                return None, None, "tracker box not finite or has w, h <= 0"
            return box, box[:2] + 0.5 * box[2:], ""
        if centre_sensor_px is not None:
            try:
                c = np.asarray(centre_sensor_px, dtype=float).reshape(2)
            except (TypeError, ValueError):
                return None, None, "tracker centre must be (u, v)"
            if not np.all(np.isfinite(c)):
                return None, None, "tracker centre not finite"
            half = self.config.centre_box_marker_radii * self.marker_radius_px
            return np.r_[c - half, 2 * half, 2 * half], c, ""
        return None, None, "no tracker output"

    def _refine_red(
        self, image: NDArray[np.uint8], b: int, box: NDArray[np.float64],
        centre: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64], SubpixelResult | None, bool]:
        """The red observation from the tracker's box: its centre, or the circle-fit centre
        when ``refine_red`` and the fit is valid and lies in the box (observation, fit,
        refined)."""
        cfg = self.config
        if not cfg.refine_red:
            return centre, None, False
        fc, fit = refine_in_box(image, cfg.gate.red, box, b, cfg.subpixel, cfg.refine_roi_margin)
        return (fc, fit, True) if fc is not None else (centre, fit, False)

    def step(
        self,
        image: NDArray[np.uint8],
        binning: int,
        box_sensor_px: ArrayLike | None = None,
        score: float | None = None,
        centre_sensor_px: ArrayLike | None = None,
        tilt_prev_rad: float | None = None,
        judged: JudgedObservation | None = None,
    ) -> GKResult:
        """Process one frame (seed 000 §3.2.3).

        Parameters
        ----------
        image : (H, W, 3) uint8
            The frame, RGB, H × W = sensor size / ``binning``.
        binning : int
            Sensor pixels per image pixel.
        box_sensor_px : (4,), optional
            The main tracker's box (x, y, w, h) of the red marker, full-sensor px.
        score : float, optional
            The tracker's confidence score (used only with ``config.min_score``).
        centre_sensor_px : (2,), optional
            The tracker's red centre, sensor px, for trackers without a box (ignored when a box
            is given); the gate then uses a square of ``centre_box_marker_radii`` marker radii.
        tilt_prev_rad : float, optional
            Tilt β of the previous frame's attitude, rad: D_exp = L·S·cos β and the EMA's
            β < 2° condition. None: cos β = 1 and the scale stays locked.
        judged : JudgedObservation, optional
            An observation judged by a trust rule: it replaces the gate and the circle fit
            (the tracker's box and score are then ignored).

        Returns
        -------
        GKResult
        """
        t0 = time.perf_counter()
        bad_frame = check_frame(image, self.params, binning)
        b = 1 if bad_frame else int(binning)
        reasons: list[str] = [bad_frame] if bad_frame else []
        prior = self.kalman.predict()
        prior_cov = self.kalman.position_cov

        # 1-2. the tracker's observation and the HSV gate
        box, centre, why = self._tracker_box(box_sensor_px, centre_sensor_px)
        score_f = math.nan if score is None else float(score)
        gate, confident = self._gate(image, b, bad_frame, judged, box, why, score_f, reasons)

        # 3. observe, or let the prediction stand in
        red, red_cov, source, red_fit, refined = self._red_point(
            image, b, confident, judged, box, centre, prior, prior_cov, reasons)

        # 4. the auxiliary point
        aux = self._yellow_point(image, b, bad_frame, red, source, tilt_prev_rad, judged,
                                 reasons)

        # 5. the pixel scale, from a frame that measured both markers
        both = source == "measurement" and aux.source == "measurement"
        updated = both and self.scale.update(aux.D_det_px, tilt_prev_rad)[0]

        return GKResult(
            red_px=np.asarray(red, dtype=float),
            yellow_px=aux.yellow_sensor_px,
            red_source=source,
            yellow_source=aux.source,
            confidence=gate.ratio,
            confident=confident,
            lost=self._lost,
            reason="; ".join(r for r in reasons if r),
            red_predicted_px=prior,
            red_cov_px2=red_cov,
            red_refined=refined,
            scale_px_per_m=self.scale.S,
            scale_updated=updated,
            tracker_score=score_f,
            compute_time_s=time.perf_counter() - t0,
            gate=gate,
            aux=aux,
            red_fit=red_fit,
        )

    def _red_point(
        self, image: NDArray[np.uint8], b: int, confident: bool,
        judged: JudgedObservation | None, box: NDArray[np.float64] | None,
        centre: NDArray[np.float64] | None, prior: NDArray[np.float64],
        prior_cov: NDArray[np.float64], reasons: list[str],
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], RedSource, SubpixelResult | None,
               bool]:
        """Step 3 of ``step``: a confident frame observes the red centre (the trust rule's, or
        the tracker's refined by the circle fit) and updates the pixel Kalman filter; otherwise
        the prediction stands in (or the trust rule's stand-in, when it gives one). Returns the
        red centre (sensor px), its covariance (sensor px²), its source, the circle fit and
        whether the centre is the fit's; appends the reasons of a frame not observed."""
        red_fit: SubpixelResult | None = None
        refined = False
        if confident:
            if judged is not None:
                z, refined = np.asarray(judged.centre_sensor_px, dtype=float), judged.refined
            else:
                z, red_fit, refined = self._refine_red(image, b, box, centre)
            red, red_cov = self._observe(z)
            source: RedSource = "measurement"
        else:
            red, red_cov, source = self._coast_on(prior, prior_cov, reasons)
            if source == "prediction" and judged is not None \
                    and judged.stand_in_sensor_px is not None:
                red, red_cov, source = self._stand_in(judged, reasons)
        return red, red_cov, source, red_fit, refined

    def _yellow_point(
        self, image: NDArray[np.uint8], b: int, bad_frame: str, red: NDArray[np.float64],
        source: RedSource, tilt_prev_rad: float | None, judged: JudgedObservation | None,
        reasons: list[str],
    ) -> AuxResult:
        """Step 4 of ``step``: the auxiliary (yellow) point located from the red centre, or
        the trust rule's stand-in where the locator falls back; appends why it was not
        measured (when there is a red centre at all)."""
        aux = self._auxiliary(image, b, bad_frame, red, source, tilt_prev_rad)
        if aux.source == "fallback" and judged is not None \
                and judged.yellow_stand_in_sensor_px is not None:
            aux = AuxResult(np.asarray(judged.yellow_stand_in_sensor_px, dtype=float),
                            "inferred", reason=f"{aux.reason}; position inferred")
        if aux.source != "measurement" and source != "none":
            reasons.append(f"yellow: {aux.reason}")
        return aux

    def _gate(
        self, image: NDArray[np.uint8], b: int, bad_frame: str, judged: JudgedObservation | None,
        box: NDArray[np.float64] | None, why: str, score: float, reasons: list[str],
    ) -> tuple[GateResult, bool]:
        """The HSV gate of the tracker's red box (or the trust rule's judgement) and whether
        the observation is confident (the gate, then ``config.min_score``); appends the reason
        for a rejection to ``reasons``."""
        min_score = self.config.min_score
        if bad_frame:
            gate = GateResult(0.0, False, 0, bad_frame)
        elif judged is not None:
            gate = GateResult(judged.ratio, judged.centre_sensor_px is not None, 0, judged.reason)
        elif box is None:
            gate = GateResult(0.0, False, 0, why)
        else:
            gate = self.gate.ratio(image, box_sensor_to_image(box, b), "red")
        confident = gate.confident
        if confident and min_score is not None and not score >= min_score:
            confident = False
            reasons.append(f"tracker score {score} below {min_score}")
        elif not confident and not bad_frame:
            reasons.append(gate.reason)
        return gate, confident

    def _observe(self, z: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Feed a confident red centre ``z`` (sensor px) to the Kalman filter (initialising it
        after a loss); returns the red position and its covariance per ``config.red_output``."""
        if self._lost or not self.kalman.initialised:
            self.kalman.initialise(z)
        else:
            self.kalman.update(z)
        self._coast, self._lost = 0, False
        if self.config.red_output == "filtered":
            return self.kalman.position, self.kalman.position_cov
        return np.asarray(z, dtype=float), np.asarray(self.config.kalman.R, dtype=float)

    def _coast_on(
        self, prior: NDArray[np.float64], prior_cov: NDArray[np.float64], reasons: list[str],
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], RedSource]:
        """No confident observation: the Kalman prediction stands in, and the track is lost
        after ``config.max_coast_frames`` frames or once the prediction leaves the sensor;
        appends why to ``reasons``."""
        if not self.kalman.initialised:
            self._lost = True
            reasons.append("no confident main-marker observation yet")
            return np.full(2, np.nan), np.full((2, 2), np.nan), "none"
        self.kalman.coast()
        self._coast += 1
        cam = self.params.camera
        inside = (-0.5 <= prior[0] <= cam.sensor_width_px - 0.5
                  and -0.5 <= prior[1] <= cam.sensor_height_px - 0.5)
        if self._coast > self.config.max_coast_frames:
            self._lost = True
            reasons.append(f"no confident observation for {self._coast} frames "
                           f"(> {self.config.max_coast_frames})")
        elif not inside:
            self._lost = True
            reasons.append("predicted main marker left the sensor")
        elif self._lost:
            reasons.append("track lost earlier; waiting for a confident observation")
        return prior, prior_cov, "prediction"

    def _stand_in(self, judged: JudgedObservation, reasons: list[str]
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], RedSource]:
        """A coasting frame (``_coast_on`` has counted it) with a stand-in for the hidden
        marker: it updates the filter, so that its prediction follows the cue, and is reported
        as "inferred"."""
        z = np.asarray(judged.stand_in_sensor_px, dtype=float)
        var = judged.stand_in_sigma_px ** 2
        self.kalman.update(z, var)
        reasons.append(f"red position inferred ({judged.reason})" if judged.reason
                       else "red position inferred")
        return z, np.asarray(self.config.kalman.R, dtype=float) + var * np.eye(2), "inferred"

    def _auxiliary(
        self, image: NDArray[np.uint8], b: int, bad_frame: str, red: NDArray[np.float64],
        source: RedSource, tilt_prev_rad: float | None,
    ) -> AuxResult:
        """The auxiliary (yellow) point from the red position (seed 000 §3.2.3)."""
        if source == "none":
            return AuxResult(np.full(2, np.nan), "none", reason="no main-marker position")
        if bad_frame:
            return self.aux.fallback(red, "frame unusable")
        return self.aux.locate(image, b, red, self.scale.S, tilt_prev_rad,
                               red_is_measurement=(source == "measurement"))
