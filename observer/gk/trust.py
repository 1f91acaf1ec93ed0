"""Per-frame trust rule and whole-frame re-detection of the main marker (GK-TransT).

The seed's gate (000 §3.2.1) accepts a tracker box when more than 5 % of its pixels fall in the
red HSV range. A confidently wrong network passes it on anything reddish: a finger or a
red-brown object over the marker, a red sticker, the marker's own rim beside a glare. One such
box feeds a wrong position and velocity into the Kalman filter, and nothing searches beyond
the predicted window afterwards. ``MarkerTrust`` decides per frame what to believe, from what the
system knows:

* **colour** (the HSV gate, tightened): the marker's own hue and saturation, measured on the
  start frame, define a narrow range (hue ± ``hue_tolerance``, saturation ≥
  ``saturation_fraction`` of the marker's); skin, highlights and most occluders fall outside it;
* **shape** (the circle fit, seed 004 §4): the fit on that colour must be valid (its RMS
  residual and arc coverage within ``SubpixelConfig``'s limits) with a radius within
  ``radius_tolerance`` of the marker's radius at start (times the scale's change). When the
  free fit fails, the fit is repeated with the marker's radius known (the edge points on a
  circle of that radius found by consensus): a marker merged with a same-coloured occluder
  (a red-brown finger) is still measured on its visible arc, with the same validity and
  radius checks. Without a valid fit nothing is measured: a blob centroid would be wrong for
  a marker merged with a same-coloured occluder or mostly hidden;
* **innovation** (the Kalman filter, seed 000 §3.2.1): the observation must lie within
  ``gate_marker_radii`` marker radii of the prediction;
* **the network's score map**: a box whose target probability is below ``min_score`` is not
  used;
* **geometry** (seed 000 §3.2.2): the yellow marker at D_exp = L·S·cos β from the red one.

**The rule, per frame.** (1) The network's box, if its score passes, is measured as above in
its own region; if that passes colour, shape and innovation, the network is trusted. (2)
Otherwise the marker-coloured blobs in a window around the prediction are measured; the one
nearest the prediction that passes is trusted (``source`` "colour"). (3) Otherwise nothing is
measured: the Kalman prediction stands in and the frame is flagged (``red_measured`` False).

**Re-detection.** When the track is lost (``GKAssist``'s coasting limit, or
``redetect_after_frames`` frames in a row without a trusted observation) or the geometry is
violated (``geometry_frames`` frames in a row in which the red marker was measured but no
yellow marker sat at D_exp from it), the whole frame is searched: every marker-coloured blob of
about the marker's size is measured, kept only if a yellow marker lies at D_exp from it (the
auxiliary locator, without touching its V_rel) and ranked by whether the network, searching
there, agrees (its box centre within one marker radius, score ≥ ``min_score``), then by the
distance error E. The best candidate restarts the Kalman filter (``GKAssist.restart``).

All positions are full-sensor px unless a name says ``_img`` (image px of the binned frame).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from observer.gk.assist import GKAssist, JudgedObservation
from observer.gk.hsv_gate import HSVRange, colour_mask
from observer.gk.subpixel import SubpixelConfig, refine_marker_centre
from plant.camera import image_to_sensor, sensor_to_image

TrustSource = Literal["network", "colour", "redetected", "prediction"]


class TrustConfig(BaseModel):
    """Thresholds of the trust rule (all our choices; see the module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    hue_tolerance: int = Field(8, ge=1, le=45, description="Marker hue ± this, OpenCV units "
                               "(degrees / 2).")
    saturation_fraction: float = Field(0.7, gt=0.0, le=1.0, description="Smallest saturation, "
                                       "as a fraction of the marker's at start.")
    min_value: int = Field(50, ge=0, le=255, description="Smallest HSV value (the seed's).")
    radius_tolerance: float = Field(0.2, gt=0.0, description="Largest |R_fit / R_start - 1|.")
    min_blob_fraction: float = Field(0.25, gt=0.0, description="Smallest colour blob searched "
                                     "(fraction of the marker disc's area; a partly hidden "
                                     "marker still counts).")
    max_blob_fraction: float = Field(3.0, gt=1.0, description="Largest colour blob searched "
                                     "(fraction of the disc area; a smeared marker).")
    gate_marker_radii: float = Field(2.0, gt=0.0, description="Largest distance of an "
                                     "observation from the Kalman prediction, marker radii.")
    min_score: float = Field(0.1, ge=0.0, le=1.0, description="Smallest network target "
                             "probability for its box to be used.")
    redetect_after_frames: int = Field(3, ge=1, description="Frames in a row without a trusted "
                                       "observation before the whole frame is searched.")
    geometry_frames: int = Field(4, ge=1, description="Frames in a row with the red marker "
                                 "measured but no yellow marker at D_exp before the whole "
                                 "frame is searched.")
    max_candidates: int = Field(4, ge=1, description="Blobs checked in a whole-frame search "
                                "(the closest to the marker's area first).")


@dataclass(frozen=True)
class Measurement:
    """A marker centre measured in a region: the circle-fit centre ``centre_img`` (2,), image
    px, or None and why."""

    centre_img: NDArray[np.float64] | None
    reason: str = ""


@dataclass(frozen=True)
class TrustDecision:
    """What the trust rule believed in one frame.

    Attributes
    ----------
    source : "network", "colour", "redetected" or "prediction" (nothing trusted).
    observation : the judged observation handed to ``GKAssist.step``.
    reasons : why the network (and the colour search) were not trusted ("" if trusted).
    """

    source: TrustSource
    observation: JudgedObservation
    reasons: str


def marker_range(image_rgb: NDArray[np.uint8], box_img: ArrayLike, seed_range: HSVRange,
                 config: TrustConfig) -> HSVRange | None:
    """The marker's own colour range from the start frame: median hue and saturation of the
    ``seed_range`` pixels in the inner half of ``box_img`` (x, y, w, h), widened by the
    config's tolerances; None if fewer than 10 such pixels."""
    x, y, w, h = np.asarray(box_img, dtype=float)
    H, W = image_rgb.shape[:2]
    c0, r0 = max(int(x + 0.25 * w), 0), max(int(y + 0.25 * h), 0)
    c1, r1 = min(int(math.ceil(x + 0.75 * w)), W), min(int(math.ceil(y + 0.75 * h)), H)
    if c1 <= c0 or r1 <= r0:
        return None
    crop = np.ascontiguousarray(image_rgb[r0:r1, c0:c1])
    hsv = cv2.cvtColor(crop, cv2.COLOR_RGB2HSV).reshape(-1, 3)
    sel = hsv[seed_range.mask(hsv.reshape(-1, 1, 3)).reshape(-1) > 0]
    if len(sel) < 10:
        return None
    hue = sel[:, 0].astype(float)
    ang = np.angle(np.mean(np.exp(2j * np.pi * hue / 180.0)))  # circular mean (red wraps)
    h_ref = int(round((ang * 180.0 / (2 * np.pi)) % 180.0))
    sat = int(round(config.saturation_fraction * float(np.median(sel[:, 1]))))
    sat = max(sat, seed_range.sat[0])
    lo, hi, t = h_ref - config.hue_tolerance, h_ref + config.hue_tolerance, 180
    hues = ((lo, hi),) if 0 <= lo and hi <= t else \
        ((0, hi % t), (lo % t, t)) if lo < 0 or hi > t else ((lo, hi),)
    return HSVRange(hue=hues, sat=(sat, 255), val=(config.min_value, 255))


def measure_marker(image_rgb: NDArray[np.uint8], roi_img: ArrayLike, colour: HSVRange,
                   radius_img: float, config: TrustConfig,
                   subpixel: SubpixelConfig) -> Measurement:
    """Centre of the marker of ``colour`` in ``roi_img`` (x, y, w, h): the circle fit if it is
    valid and its radius within tolerance of ``radius_img``, else None with the reason. A blob
    centroid is never used: a marker merged with a same-coloured occluder, or mostly hidden,
    would give a wrong centre."""
    reasons = []
    for known, label in ((None, "circle"), (radius_img, "known-radius circle")):
        fit = refine_marker_centre(image_rgb, colour, roi_img, subpixel, radius_px=known)
        if not fit.valid:
            reasons.append(f"{label} fit invalid: {fit.reason}")
            continue
        ratio = fit.radius_image_px / radius_img
        if abs(ratio - 1.0) <= config.radius_tolerance:
            return Measurement(fit.centre_image_px)
        reasons.append(f"{label} radius {ratio:.2f} x the marker's")
    return Measurement(None, "; ".join(reasons))


def colour_blobs(image_rgb: NDArray[np.uint8], colour: HSVRange, radius_img: float,
                 config: TrustConfig, window_img: ArrayLike | None = None
                 ) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Blobs of ``colour`` of a plausible marker area (``min_blob_fraction`` to
    ``max_blob_fraction`` of the disc) in ``window_img`` (x, y, w, h; None: the whole frame):
    (centroid, region (x, y, w, h)) in image px, sorted by how close their area is to the
    disc's."""
    H, W = image_rgb.shape[:2]
    c0, r0, c1, r1 = 0, 0, W, H
    if window_img is not None:
        x, y, w, h = np.asarray(window_img, dtype=float)
        c0, r0 = max(int(math.floor(x)), 0), max(int(math.floor(y)), 0)
        c1, r1 = min(int(math.ceil(x + w)) + 1, W), min(int(math.ceil(y + h)) + 1, H)
        if c1 - c0 < 2 or r1 - r0 < 2:
            return []
    mask = colour_mask(np.ascontiguousarray(image_rgb[r0:r1, c0:c1]), colour)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN,
                            cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3)))
    n, _, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
    disc = math.pi * radius_img * radius_img
    out = []
    for i in range(1, n):
        frac = stats[i, cv2.CC_STAT_AREA] / disc
        if config.min_blob_fraction <= frac <= config.max_blob_fraction:
            bx, by, bw, bh = stats[i, :4].astype(float)
            out.append((abs(math.log(frac)), cents[i] + [c0, r0],
                        np.array([bx + c0, by + r0, bw, bh])))
    out.sort(key=lambda t: t[0])
    return [(c, r) for _, c, r in out]


class MarkerTrust:
    """The trust rule and the re-detection for one GK-TransT track (module docstring).

    Parameters
    ----------
    gk : GKAssist
        The track's GK assistance (its Kalman prior, scale, auxiliary locator).
    config : TrustConfig, optional
    subpixel : SubpixelConfig, optional
        Settings of the circle fit (default: the GK assistance's).
    """

    def __init__(self, gk: GKAssist, config: TrustConfig | None = None,
                 subpixel: SubpixelConfig | None = None) -> None:
        self.gk = gk
        self.config = config or TrustConfig()
        self.subpixel = subpixel or gk.config.subpixel
        self.colour: HSVRange = gk.config.gate.red
        self.radius_sensor_px = math.nan
        self.scale_start = math.nan
        self._untrusted = 0
        self._no_geometry = 0

    # --- state ---------------------------------------------------------------------------------
    def start(self, image_rgb: NDArray[np.uint8], binning: int, box_sensor_px: ArrayLike) -> None:
        """Learn the marker's colour and radius from the start frame and its red box."""
        box = np.asarray(box_sensor_px, dtype=float)
        b = int(binning)
        box_img = np.r_[sensor_to_image(box[:2], b), box[2:] / b]
        self.colour = marker_range(image_rgb, box_img, self.gk.config.gate.red, self.config) \
            or self.gk.config.gate.red
        fit = refine_marker_centre(image_rgb, self.colour, box_img, self.subpixel)
        r_box = 0.25 * float(box[2] + box[3])
        self.radius_sensor_px = fit.radius_image_px * b if fit.valid else r_box
        self.scale_start = self.gk.scale.S
        self._untrusted = 0
        self._no_geometry = 0

    def radius_img(self, binning: int) -> float:
        """The marker's radius now (start radius times the scale's change), image px."""
        return self.radius_sensor_px * self.gk.scale.S / self.scale_start / binning

    def wants_redetection(self) -> bool:
        """The track is lost, has had no trusted observation for a while, or its geometry has
        been violated for a while."""
        c = self.config
        return self.gk.lost or self._untrusted >= c.redetect_after_frames or \
            self.geometry_violated()

    def geometry_violated(self) -> bool:
        """The red marker has been measured for ``geometry_frames`` frames in a row without a
        yellow marker at D_exp from it."""
        return self._no_geometry >= self.config.geometry_frames

    def record(self, red_measured: bool, yellow_measured: bool) -> None:
        """Count the frame's outcome (after ``GKAssist.step``): untrusted frames in a row and
        measured-red frames without the yellow marker at D_exp in a row."""
        self._untrusted = 0 if red_measured else self._untrusted + 1
        self._no_geometry = self._no_geometry + 1 if red_measured and not yellow_measured else 0

    # --- the rule ------------------------------------------------------------------------------
    def _accept(self, m: Measurement, prior: NDArray[np.float64], b: int, gate_px: float
                ) -> tuple[NDArray[np.float64] | None, str]:
        if m.centre_img is None:
            return None, m.reason
        z = image_to_sensor(m.centre_img, b)
        if np.all(np.isfinite(prior)):
            d = float(np.hypot(*(z - prior)))
            if d > gate_px:
                return None, f"{d:.0f} px from the prediction (gate {gate_px:.0f} px)"
        return z, ""

    def judge(self, image_rgb: NDArray[np.uint8], binning: int,
              box_sensor_px: NDArray[np.float64] | None, score: float) -> TrustDecision:
        """Decide this frame's red observation from the network's box and score (before
        ``GKAssist.step``, whose prior is ``gk.search_centre_sensor_px()``).

        The network's box (if its score passes) is measured first, then the marker-coloured
        blobs in a window around the prediction, nearest the disc's area first; the first that
        passes wins."""
        c, b = self.config, int(binning)
        prior = self.gk.search_centre_sensor_px()
        r_img = self.radius_img(b)
        gate_px = c.gate_marker_radii * r_img * b
        reasons: list[str] = []
        if box_sensor_px is None:
            reasons.append("network: no box")
        elif not score >= c.min_score:
            reasons.append(f"network: score {score:.2f} < {c.min_score}")
        else:
            centre = sensor_to_image(box_sensor_px[:2] + 0.5 * box_sensor_px[2:], b)
            half = np.minimum(0.5 * box_sensor_px[2:] / b * 1.3, 2.5 * r_img)
            m = measure_marker(image_rgb, np.r_[centre - half, 2 * half], self.colour, r_img, c,
                               self.subpixel)
            z, why = self._accept(m, prior, b, gate_px)
            if z is not None:
                return TrustDecision("network", JudgedObservation(z, 1.0, True), "")
            reasons.append(f"network: {why}")
        if np.all(np.isfinite(prior)):
            p_img = sensor_to_image(prior, b)
            half = gate_px / b + 2.0 * r_img
            window = np.r_[p_img - half, 2 * half, 2 * half]
            for _, region in colour_blobs(image_rgb, self.colour, r_img, c, window):
                m = measure_marker(image_rgb, _grow(region, r_img), self.colour, r_img, c,
                                   self.subpixel)
                z, _ = self._accept(m, prior, b, gate_px)
                if z is not None:
                    why_net = "; ".join(reasons)
                    return TrustDecision("colour", JudgedObservation(
                        z, 1.0, True, f"colour fit (not the network: {why_net})"), why_net)
        reasons.append("no trusted marker near the prediction")
        why = "; ".join(reasons)
        return TrustDecision("prediction", JudgedObservation(None, 0.0, False, why), why)

    def redetect(self, image_rgb: NDArray[np.uint8], binning: int, network_check
                 ) -> TrustDecision | None:
        """Search the whole frame (module docstring). ``network_check(centre_img)`` runs the
        network searching at a candidate and returns its box centre (image px) and score.
        Returns a decision with source "redetected", or None if no candidate passes."""
        c, b = self.config, int(binning)
        self._no_geometry = 0  # searched: wait for the geometry to fail again before the next
        r_img = self.radius_img(b)
        found = []
        for _, region in colour_blobs(image_rgb, self.colour, r_img, c)[: c.max_candidates]:
            m = measure_marker(image_rgb, _grow(region, r_img), self.colour, r_img, c,
                               self.subpixel)
            if m.centre_img is None:
                continue
            z = image_to_sensor(m.centre_img, b)
            aux = self.gk.aux.locate(image_rgb, b, z, self.gk.scale.S, None,
                                     red_is_measurement=False)
            if aux.source != "measurement":
                continue
            net_c, score = network_check(m.centre_img)
            agrees = bool(np.all(np.isfinite(net_c)) and score >= c.min_score
                          and np.hypot(*(np.asarray(net_c) - m.centre_img)) <= r_img)
            found.append((not agrees, aux.E, z))
        if not found:
            return None
        found.sort(key=lambda t: (t[0], t[1]))
        disagree, E, z = found[0]
        how = "network disagrees" if disagree else "network agrees"
        return TrustDecision("redetected", JudgedObservation(
            z, 1.0, True, f"re-detected in the whole frame (E = {E:.2f}, {how})"), "")


def _grow(region: NDArray[np.float64], r_img: float) -> NDArray[np.float64]:
    """A blob's bounding box grown by half a marker radius on each side (the fit's ROI)."""
    m = 0.5 * r_img
    return np.r_[region[:2] - m, region[2:] + 2 * m]
