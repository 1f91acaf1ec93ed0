"""Geometric localisation of the auxiliary (yellow) marker from the main (red) one (seed 000
§3.2.2).

Seed 000 §3.2.2 replaces a second tracker by geometry. The two markers are a rigid pair
L = 28.28 mm apart, so around the main point P_red:

1. **Candidates**: within a search radius around P_red, the yellow HSV mask (seed 000 §3.2.1
   ranges) is cleaned by morphological opening and closing; each connected region large enough to
   be the marker is a candidate.
2. **Distance check**: a candidate at pixel distance D_det from P_red is valid when
   E = |D_det − D_exp| / D_exp < 0.3, with D_exp = L·S·cos β (S the pixel scale, β the tilt
   from the previous frame; ``observer.gk.scale``).
3. **Fallback**: if no candidate passes, P_yellow = P_red + V_rel, with V_rel the red→yellow
   vector of the last frame in which both markers were measured ("high-confidence frame").

Our choices where the seed says "a predefined dynamic radius" and "the candidate": the search
radius is (1 + E_max)·L·S + 1.5 marker radii (anything farther fails the distance check anyway;
the margin keeps a marker at the edge whole), so it scales with S. Among the candidates that pass
the check, the one nearest to P_red + V_rel is taken (the smallest E while there is no V_rel
yet). Its centre is then refined by the sub-pixel circle fit (``observer.gk.subpixel``, seed 004
§4), falling back to the region's centroid when the fit is invalid.

**Predicted window (our speed-up, same answer).** The search square is most of the frame
(2.6 L·S wide), and segmenting it costs more than the rest of the GK assistance. With V_rel
known, the candidates are first segmented in a small square around P_red + V_rel (half-width
``window_marker_radii`` marker radii), with the same search disc drawn into it. The window's
answer is used only when it must equal the full search's: the yellow mask has no pixel within
the morphology kernels' reach of the window's border (so every region seen is whole and is
cleaned as in the full crop, and every region outside lies wholly outside), and the chosen
candidate is no farther from P_red + V_rel than the half-width (so no region outside can be
nearer). Otherwise the full search runs. ``n_candidates`` counts the regions of the search
actually used; ``tests/test_gk.py`` checks the two give the same result.

Units: marker positions in and out are *full-sensor* pixels; the frame is RGB and binned by
``binning`` (image px internally). S in sensor px/m, L and the marker diameter in m, β in rad.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from observer.gk.hsv_gate import YELLOW, HSVRange, check_rgb_image, colour_mask
from observer.gk.subpixel import SubpixelConfig, SubpixelResult, refine_marker_centre
from plant.camera import image_to_sensor, sensor_to_image

AuxSource = Literal["measurement", "fallback", "inferred", "none"]


class AuxLocatorConfig(BaseModel):
    """Parameters of the auxiliary-marker locator."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    E_max: float = Field(
        0.3, gt=0.0, lt=1.0, description="Seed 000 §3.2.2: accept when E < 0.3."
    )
    radius_margin_marker_radii: float = Field(
        1.5, ge=0.0, description="Our choice: search radius = (1 + E_max)·L·S + this many "
        "marker radii."
    )
    yellow: HSVRange = Field(YELLOW, description="Seed 000 §3.2.1: H∈[15,40], S,V∈[50,255].")
    open_kernel_px: int = Field(
        3, ge=0, description="Our choice: elliptic opening kernel, image px (0: none)."
    )
    close_kernel_px: int = Field(
        3, ge=0, description="Our choice: elliptic closing kernel, image px (0: none)."
    )
    min_area_fraction: float = Field(
        0.2, gt=0.0, le=1.0, description="Our choice: smallest candidate region as a fraction "
        "of the expected marker disc area π·(S·d/2)²."
    )
    window_marker_radii: float = Field(
        3.0, ge=0.0, description="Our choice: half-width of the predicted window around "
        "P_red + V_rel, marker radii (0: always the full search; module docstring)."
    )
    refine: bool = Field(True, description="Our choice: refine the centre by the circle fit.")
    roi_margin_fraction: float = Field(
        0.3, ge=0.0, description="Our choice: the fit's ROI is the candidate's bounding box "
        "enlarged by this fraction of its size on each side."
    )
    subpixel: SubpixelConfig = SubpixelConfig()


@dataclass(frozen=True)
class AuxResult:
    """Where the auxiliary marker is, and how it was found.

    Attributes
    ----------
    yellow_sensor_px : (2,) centre (u, v), full-sensor px; NaN when ``source == "none"``.
    source : "measurement" (a candidate passed E < E_max), "fallback" (P_red + V_rel),
        "inferred" (not measured; another cue's position, e.g. the VFC plate's, given to
        ``GKAssist.step``) or "none" (no measurement and no V_rel yet, or no usable P_red).
    D_det_px, D_exp_px, E : detected and expected distance (sensor px) and relative error of the
        chosen candidate (NaN when there is none).
    n_candidates : yellow regions found within the search radius.
    refined : the centre comes from the circle fit (else the region centroid, or the fallback).
    reason : why the result is a fallback or none ("" for a measurement).
    fit : the circle fit, when one was attempted.
    """

    yellow_sensor_px: NDArray[np.float64]
    source: AuxSource
    D_det_px: float = math.nan
    D_exp_px: float = math.nan
    E: float = math.nan
    n_candidates: int = 0
    refined: bool = False
    reason: str = ""
    fit: SubpixelResult | None = field(default=None, repr=False)


class AuxLocator:
    """Seed 000 §3.2.2's cooperative localisation of the yellow marker around the red one.

    Parameters
    ----------
    L_m : float
        Distance between the marker centres, m (seed 000 §3.2.2: 28.28 mm).
    marker_diameter_m : float
        Diameter of a marker disc, m (sets the candidate size and search margin).
    config : AuxLocatorConfig, optional

    Raises ``ValueError`` naming the argument if L_m or marker_diameter_m is not finite and > 0.

    Attributes
    ----------
    V_rel : (2,) or None
        Red→yellow vector (sensor px) of the last frame in which both were measured.
    """

    def __init__(self, L_m: float, marker_diameter_m: float,
                 config: AuxLocatorConfig | None = None) -> None:
        for name, val in (("L_m", L_m), ("marker_diameter_m", marker_diameter_m)):
            if not (isinstance(val, (int, float)) and math.isfinite(val) and val > 0.0):
                raise ValueError(f"{name} must be a finite number > 0, got {val!r}")
        self.L_m = float(L_m)
        self.d_m = float(marker_diameter_m)
        self.config = config or AuxLocatorConfig()
        self.V_rel: NDArray[np.float64] | None = None

    def reset(self) -> None:
        """Forget V_rel."""
        self.V_rel = None

    def search_radius_px(self, S_px_per_m: float) -> float:
        """Search radius around P_red, sensor px."""
        c = self.config
        return (1.0 + c.E_max) * self.L_m * S_px_per_m + \
            c.radius_margin_marker_radii * 0.5 * self.d_m * S_px_per_m

    def _candidates(self, image_rgb, centre_img, half, red_img, r_search, r_marker,
                    whole_only: bool = False):
        """Yellow regions in the square of half-width ``half`` (image px) around
        ``centre_img``, inside the search disc of radius ``r_search`` around ``red_img``:
        (centroids, bounding rects, crop column, crop row), crop coordinates; None if the square
        is outside the frame or, with ``whole_only``, if the cleaned mask comes within the
        kernels' reach of a border of the square that is not the frame's."""
        cfg = self.config
        H, W = image_rgb.shape[:2]
        c0 = max(int(math.floor(centre_img[0] - half)), 0)
        r0 = max(int(math.floor(centre_img[1] - half)), 0)
        c1 = min(int(math.ceil(centre_img[0] + half)) + 1, W)
        r1 = min(int(math.ceil(centre_img[1] + half)) + 1, H)
        if c1 - c0 < 2 or r1 - r0 < 2:
            return None
        crop = np.ascontiguousarray(image_rgb[r0:r1, c0:c1])
        mask = colour_mask(crop, cfg.yellow)
        disc = np.zeros_like(mask)
        shift = 4
        centre_fx = tuple(int(round(v * (1 << shift))) for v in (red_img[0] - c0, red_img[1] - r0))
        cv2.circle(disc, centre_fx, int(round(r_search * (1 << shift))), 255, -1, cv2.LINE_8,
                   shift)
        mask &= disc
        if whole_only:
            # No yellow pixel within reach of a cut border: then every region of the full
            # search either lies inside this square, beyond the morphology's reach of its
            # border (cleaned identically), or wholly outside it (the kernels cannot bridge
            # the empty band).
            m = cfg.open_kernel_px + cfg.close_kernel_px + 1
            edges = [mask[:m] if r0 > 0 else None, mask[-m:] if r1 < H else None,
                     mask[:, :m] if c0 > 0 else None, mask[:, -m:] if c1 < W else None]
            if any(e is not None and e.any() for e in edges):
                return None
        for op, ksz in ((cv2.MORPH_OPEN, cfg.open_kernel_px), (cv2.MORPH_CLOSE,
                                                               cfg.close_kernel_px)):
            if ksz > 0:
                kern = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (ksz, ksz))
                mask = cv2.morphologyEx(mask, op, kern)
        # Candidates: outer contours of the cleaned mask (much cheaper than labelling the whole
        # search square); area and centroid from the contour polygon's moments.
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        min_area = cfg.min_area_fraction * math.pi * r_marker * r_marker
        cents, rects = [], []
        for cnt in contours:
            mom = cv2.moments(cnt)
            if mom["m00"] >= min_area:
                cents.append((mom["m10"] / mom["m00"], mom["m01"] / mom["m00"]))
                rects.append(cv2.boundingRect(cnt))
        return cents, rects, c0, r0

    def _score(self, found, b: int, red, D_exp: float):
        """(centres sensor px (n, 2), E (n,), indices passing E < E_max, their scores): the
        score is the distance to P_red + V_rel (sensor px), or E while there is no V_rel."""
        cents, _, c0, r0 = found
        c_sensor = image_to_sensor(np.asarray(cents) + [c0, r0], b)
        E = np.abs(np.hypot(*(c_sensor - red).T) - D_exp) / D_exp
        ok = np.flatnonzero(E < self.config.E_max)
        if self.V_rel is not None:
            score = np.hypot(*(c_sensor[ok] - (red + self.V_rel)).T)
        else:
            score = E[ok]
        return c_sensor, E, ok, score

    def fallback(self, red_sensor_px: ArrayLike, reason: str) -> AuxResult:
        """P_yellow = P_red + V_rel (seed 000 §3.2.2), or ``source="none"`` without V_rel."""
        red = np.asarray(red_sensor_px, dtype=float).reshape(-1)
        if self.V_rel is None or red.shape != (2,) or not np.all(np.isfinite(red)):
            why = "no V_rel from a previous good frame" if self.V_rel is None else \
                "main marker position not finite"
            return AuxResult(np.full(2, np.nan), "none", reason=f"{reason}; {why}")
        return AuxResult(red + self.V_rel, "fallback", reason=reason)

    def _search(
        self, image_rgb: NDArray[np.uint8], b: int, red: NDArray[np.float64], D_exp: float,
        r_search: float, r_marker: float,
    ) -> tuple[tuple | None, tuple | None]:
        """The yellow candidates around P_red ``red`` (sensor px) in a frame binned by ``b``:
        first in the window of ``window_marker_radii`` marker radii about the last good
        P_red + V_rel (kept only when a candidate there passes the distance check and lies
        nearer than the window's half-width), else in the whole search radius ``r_search``
        (image px). Returns the candidates (``_candidates``; None when the region is outside
        the frame) and, for the window, their scores (``_score``), else None."""
        cfg = self.config
        red_img = sensor_to_image(red, b)
        found, scored = None, None
        if self.V_rel is not None and cfg.window_marker_radii > 0.0:
            rho = cfg.window_marker_radii * r_marker
            found = self._candidates(image_rgb, sensor_to_image(red + self.V_rel, b), rho,
                                     red_img, r_search, r_marker, whole_only=True)
            if found is not None and found[0]:
                scored = self._score(found, b, red, D_exp)
                ok, score = scored[2], scored[3]
                # a nearer region outside the window would be farther than its half-width
                if len(ok) == 0 or score.min() > rho * b:
                    found = scored = None
            else:
                found = None
        if found is None:
            found = self._candidates(image_rgb, red_img, r_search, red_img, r_search, r_marker)
        return found, scored

    def _refine(
        self, image_rgb: NDArray[np.uint8], b: int, yellow: NDArray[np.float64],
        rect: NDArray, c0: int, r0: int, r_marker: float,
    ) -> tuple[NDArray[np.float64], bool, SubpixelResult | None]:
        """With ``config.refine``: the circle-fit centre (sensor px) of the chosen candidate,
        whose bounding rectangle ``rect`` (x, y, w, h, image px of the search region at column
        ``c0``, row ``r0``) grown by ``roi_margin_fraction`` is the fit's region, used when the
        fit is valid and within a marker radius ``r_marker`` (image px) of the candidate's
        centroid ``yellow``. Returns the centre, whether it is the fit's, and the fit."""
        cfg = self.config
        if not cfg.refine:
            return yellow, False, None
        x, y, w, h = (float(v) for v in rect)
        m = cfg.roi_margin_fraction
        roi = (x + c0 - m * w, y + r0 - m * h, w * (1 + 2 * m), h * (1 + 2 * m))
        fit = refine_marker_centre(image_rgb, cfg.yellow, roi, cfg.subpixel)
        if fit.valid:
            fc = fit.centre_sensor_px(b)
            if np.hypot(*(fc - yellow)) < r_marker * b:
                return fc, True, fit
        return yellow, False, fit

    def locate(
        self,
        image_rgb: NDArray[np.uint8],
        binning: int,
        red_sensor_px: ArrayLike,
        S_px_per_m: float,
        beta_prev_rad: float | None = None,
        red_is_measurement: bool = True,
    ) -> AuxResult:
        """Find the yellow marker around P_red in one frame (seed 000 §3.2.2).

        Parameters
        ----------
        image_rgb : (H, W, 3) uint8 RGB frame, binned by ``binning``.
        binning : sensor pixels per image pixel.
        red_sensor_px : (2,) P_red, full-sensor px.
        S_px_per_m : pixel scale S, sensor px/m (``observer.gk.scale``).
        beta_prev_rad : tilt β of the previous frame, rad (None: 0, i.e. cos β = 1; at the 15°
            stop that overestimates D_exp by 3.5 %, well inside E_max).
        red_is_measurement : P_red was measured this frame (not a Kalman prediction); only then
            does a measured yellow marker renew V_rel.

        Returns
        -------
        AuxResult
            Never raises on bad frames or positions: those give a fallback or ``none``.
        """
        bad = check_rgb_image(image_rgb)
        if bad:
            return self.fallback(red_sensor_px, bad)
        red = np.asarray(red_sensor_px, dtype=float).reshape(-1)
        if red.shape != (2,) or not np.all(np.isfinite(red)):
            return AuxResult(np.full(2, np.nan), "none", reason="main marker position not finite")
        if not (math.isfinite(S_px_per_m) and S_px_per_m > 0.0):
            return self.fallback(red, f"pixel scale S = {S_px_per_m} not usable")
        cfg = self.config
        b = int(binning)
        beta = 0.0 if beta_prev_rad is None or not math.isfinite(beta_prev_rad) else beta_prev_rad
        D_exp = self.L_m * S_px_per_m * math.cos(beta)
        r_search = self.search_radius_px(S_px_per_m) / b
        r_marker = 0.5 * self.d_m * S_px_per_m / b
        found, scored = self._search(image_rgb, b, red, D_exp, r_search, r_marker)
        if found is None:
            return self.fallback(red, "search region outside the frame")
        cents, rects, c0, r0 = found
        if not cents:
            fb = self.fallback(red, "no yellow candidate within the search radius")
            return replace(fb, D_exp_px=D_exp)
        c_sensor, E, ok, score = scored or self._score(found, b, red, D_exp)
        if len(ok) == 0:
            fb = self.fallback(
                red, f"no candidate passes the distance check (best E = {E.min():.2f})"
            )
            return replace(fb, n_candidates=len(cents), E=float(E.min()), D_exp_px=D_exp)
        i = int(ok[np.argmin(score)])
        yellow = c_sensor[i]
        yellow, refined, fit = self._refine(image_rgb, b, yellow, rects[i], c0, r0, r_marker)
        D_det = float(np.hypot(*(yellow - red)))
        E_det = abs(D_det - D_exp) / D_exp
        if E_det >= cfg.E_max:
            fb = self.fallback(red, f"refined candidate fails the distance check (E = {E_det:.2f})")
            return replace(fb, n_candidates=len(cents), E=E_det, D_exp_px=D_exp, fit=fit)
        if red_is_measurement:
            self.V_rel = yellow - red
        return AuxResult(yellow, "measurement", D_det, D_exp, E_det, len(cents), refined, "", fit)
