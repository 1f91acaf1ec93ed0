"""Sub-pixel marker centres by contour extraction and circle fitting (seed 004 §4).

A refinement stage for any tracker: given an RGB frame, a marker colour and a region of interest
(the tracker's box, enlarged), it returns the centre of the circle fitted to the marker's edge.
The steps follow seed 004 §4.1–4.3:

1. **Segmentation** (§4.1, "region growth"): the colour's HSV mask (``observer.gk.hsv_gate``)
   inside the ROI, opened with a small kernel; the largest connected region is the marker.
2. **Contour** (§4.1): the region's outer boundary pixels (``cv2.findContours``). The seed uses
   Canny edges, which are integer pixels too. We move each boundary pixel to sub-pixel accuracy:
   a colour "coverage" map α = ((p − b)·(f − b)) / |f − b|² (f, b: median RGB of the marker's
   interior and of a ring just outside it; α ≈ the anti-aliased coverage of the pixel by the
   marker) is sampled bilinearly along the ray from the region's centroid through the pixel, and
   the edge is where α crosses 1/2. This assumes a locally uniform background a few pixels around
   the disc (the dark VFC plate).
3. **Burr removal** (§4.2, eq. 25): the curvature k = 1/r of the circle through three contour
   points is computed at every point; points whose k exceeds ``burr_curvature_factor`` times the
   contour's median curvature k_ref (a robust estimate of the marker's own 1/R) are burrs and
   dropped. Our addition: points with k below k_ref / ``burr_curvature_factor`` (straight or
   concave pieces, e.g. the edge of an occluder cutting the disc) are dropped too. On a pixel
   contour, three *adjacent* points are ~1 px apart and their circle is dominated by noise, so
   the three points are taken ``span`` points apart, ``span`` ≈ r₀/3 (r₀ the radius of a disc of
   the region's area; our choice: about 20° of arc).
4. **Circle fit** (§4.3, eqs. 26–28): the algebraic (Kåsa) least-squares circle
   x² + y² = 2 x_c x + 2 y_c y + (R² − x_c² − y_c²) starts a Gauss–Newton minimisation of the
   geometric error f = Σ (√((x_j − x_c)² + (y_j − y_c)²) − R)² (eq. 27). Points whose residual
   exceeds ``outlier_k`` robust standard deviations are dropped and the fit repeated (our
   choice; it removes what the curvature test misses, e.g. an occluder's straight edge).

**Bias of the circle model.** A disc in a plane tilted by θ from the image plane projects to an
ellipse (axis ratio ≈ cos θ), and the centre of that ellipse is not the projection of the disc
centre: perspective moves it by roughly f·(ρ/Z)²·tan θ (ρ the disc radius, Z its depth, f in
px). With our camera (f = 7246 sensor px, Z ≈ 0.30 m, ρ = 4 mm) that is 0 at θ = 0 and about
0.3 sensor px at the 15° tilt stop. The circle fit to the whole contour of an ellipse returns
the ellipse centre (the least-squares problem is symmetric about both axes), so this
perspective offset is the fit's bias; ``tests/test_gk.py`` and ``benchmarks/bench_gk.py``
measure it against the renderer's ground truth. It could be removed given the attitude; we do not.

Units: ROIs, centres and radii are in *image* pixels of the frame passed in (OpenCV pixel-centre
convention); ``SubpixelResult.centre_sensor_px`` converts to full-sensor pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from observer.gk import subpixel_kernels as kernels
from observer.gk.hsv_gate import (
    RED,
    YELLOW,
    Colour,
    HSVRange,
    box_sensor_to_image,
    check_rgb_image,
    colour_mask,
)
from plant.camera import image_to_sensor

_ELLIPSE3 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))


class SubpixelConfig(BaseModel):
    """Parameters of the sub-pixel centre stage. All are our choices (seed 004 gives none)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    pad_px: int = Field(3, ge=0, description="Image px added around the ROI before cropping.")
    open_kernel_px: int = Field(
        3, ge=0, description="Side of the elliptic opening kernel, image px (0: no opening); "
        "removes isolated noise pixels from the colour mask."
    )
    min_area_px: int = Field(12, ge=1, description="Smallest marker region, image px².")
    min_contrast_dn: float = Field(
        25.0, gt=0.0, description="Smallest |f − b| between marker and background colour (DN)."
    )
    edge_search_px: float = Field(
        3.0, gt=0.0, description="Half-length of the radial α profile searched around each "
        "boundary pixel, image px."
    )
    edge_step_px: float = Field(0.25, gt=0.0, le=1.0, description="Profile sampling step, px.")
    burr_span_fraction: float = Field(
        1.0 / 3.0, gt=0.0, le=2.0, description="Arc length between the three points of the "
        "curvature test, as a fraction of r₀ (seed 004 eq. 25 uses adjacent points)."
    )
    burr_curvature_factor: float = Field(
        2.5, gt=1.0, description="A point is a burr when its curvature is above this times, or "
        "below 1/this times, the contour's median curvature."
    )
    outlier_k: float = Field(
        3.0, gt=0.0, description="Geometric-fit residuals beyond this many robust sigmas "
        "(1.4826·MAD) are outliers."
    )
    outlier_floor_px: float = Field(
        0.3, ge=0.0, description="Residuals below this (image px) are never outliers."
    )
    max_iter: int = Field(20, ge=1, description="Gauss–Newton iterations per fit.")
    min_points: int = Field(12, ge=3, description="Fewest edge points for a valid fit.")
    min_arc_coverage: float = Field(
        0.4, ge=0.0, le=1.0, description="Fewest 10° sectors (fraction of 36) holding edge "
        "points, seen from the fitted centre."
    )
    max_rms_fraction: float = Field(
        0.2, gt=0.0, description="Largest RMS residual / radius for a valid fit."
    )
    consensus_tol_fraction: float = Field(
        0.1, gt=0.0, description="Inlier band of the known-radius consensus, fraction of the "
        "radius (the marker's edge points lie within about 0.5 image px of its circle)."
    )


@dataclass(frozen=True)
class SubpixelResult:
    """A fitted marker circle.

    Attributes
    ----------
    centre_image_px : (2,) fitted centre (u, v), image px of the frame (NaN when invalid).
    radius_image_px : fitted radius R, image px (NaN when invalid).
    residual_rms_image_px : RMS of the geometric residuals of the points used, image px.
    n_points : edge points used in the final fit.
    n_burrs : points removed by the curvature test (seed 004 eq. 25).
    n_outliers : points removed by the residual test.
    arc_coverage : fraction of the 36 ten-degree sectors around the centre holding points.
    valid : whether the centre can be used.
    reason : why not ("" when valid).
    """

    centre_image_px: NDArray[np.float64]
    radius_image_px: float
    residual_rms_image_px: float
    n_points: int
    n_burrs: int
    n_outliers: int
    arc_coverage: float
    valid: bool
    reason: str = ""

    @classmethod
    def invalid(cls, reason: str, n_points: int = 0) -> SubpixelResult:
        """A failed fit: NaN centre, radius and residual, no points removed, ``valid`` False and
        ``reason`` saying why, with ``n_points`` the edge points that were found."""
        return cls(np.full(2, np.nan), math.nan, math.nan, n_points, 0, 0, 0.0, False, reason)

    def centre_sensor_px(self, binning: int) -> NDArray[np.float64]:
        """The centre in full-sensor pixels, for a frame binned by ``binning``."""
        return image_to_sensor(self.centre_image_px, binning)


# --- circle fits (seed 004 §4.3) -------------------------------------------------------------
def fit_circle_algebraic(points: ArrayLike) -> tuple[NDArray[np.float64], float]:
    """Kåsa's algebraic least-squares circle through points (n, 2), n >= 3.

    Solves x² + y² = a x + b y + c in the least-squares sense (coordinates taken relative to the
    points' mean for conditioning); centre (a/2, b/2), R = √(c + x_c² + y_c²). Returns
    ``(centre (2,), R)``; NaN if the points are collinear.
    """
    cx, cy, R, _ = kernels.algebraic(_points(points))
    return np.array([cx, cy]), R


def fit_circle_geometric(
    points: ArrayLike, centre0: ArrayLike, radius0: float, max_iter: int = 20, tol: float = 1e-7
) -> tuple[NDArray[np.float64], float, NDArray[np.float64]]:
    """Geometric least-squares circle (seed 004 eq. 27) by Gauss–Newton from (centre0, radius0).

    Minimises f = Σ_j (d_j − R)², d_j = |p_j − c|; the normal equations of the linearised
    problem are the seed's eq. 28 (∂f/∂x_c = ∂f/∂y_c = 0, and ∂f/∂R = 0). Returns
    ``(centre (2,), R, residuals d_j − R (n,))``.
    """
    c0 = np.asarray(centre0, dtype=float).reshape(2)
    cx, cy, R, res = kernels.geometric(_points(points), c0[0], c0[1], float(radius0),
                                       int(max_iter), float(tol))
    return np.array([cx, cy]), R, res


def _points(points: ArrayLike) -> NDArray[np.float64]:
    """Points as a C-contiguous float64 (n, 2) array (what the kernels take)."""
    return np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 2))


def circle_of_radius(
    points: ArrayLike, radius: float, tol: float, n_pairs: int = 256, seed: int = 0
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """The circle of known ``radius`` through most of ``points`` (n, 2): random sample
    consensus (Fischler & Bolles, CACM 24 (1981) 381-395) over pairs of points, each pair giving
    the two centres at distance ``radius`` from both; a point is an inlier when its distance to
    the centre is within ``tol`` of ``radius``. Deterministic (``seed``). Returns (centre (2,),
    inlier mask (n,)); NaN centre and no inliers when no pair spans less than a diameter."""
    p = np.asarray(points, dtype=float)
    n = len(p)
    if n < 2:
        return np.full(2, np.nan), np.zeros(n, bool)
    rng = np.random.default_rng(seed)
    i = rng.integers(0, n, n_pairs)
    j = rng.integers(0, n, n_pairs)
    mid, half = 0.5 * (p[i] + p[j]), 0.5 * (p[j] - p[i])
    d2 = (half * half).sum(axis=1)
    ok = (d2 > 1e-12) & (d2 < radius * radius)
    if not ok.any():
        return np.full(2, np.nan), np.zeros(n, bool)
    mid, half, d2 = mid[ok], half[ok], d2[ok]
    normal = np.column_stack([-half[:, 1], half[:, 0]]) / np.sqrt(d2)[:, None]
    h = np.sqrt(radius * radius - d2)[:, None]
    centres = np.concatenate([mid + h * normal, mid - h * normal])
    dist = np.hypot(p[None, :, 0] - centres[:, None, 0], p[None, :, 1] - centres[:, None, 1])
    inliers = np.abs(dist - radius) <= tol
    best = int(np.argmax(inliers.sum(axis=1)))
    return centres[best], inliers[best]


def contour_curvature(points: ArrayLike, span: int, closed: bool = True) -> NDArray[np.float64]:
    """Signed curvature (1/px) at each contour point (n, 2, in contour order): seed 004 eq. 25,
    k = 1/r of the circle through points i − span, i, i + span, i.e. k = 4·area/(abc) of that
    triangle, signed by the turn direction (positive for a left turn in (u, v) coordinates).
    Wraps around when ``closed``; at the ends of an open contour the neighbours are clipped."""
    return kernels.curvature(_points(points), int(span), bool(closed))


# --- the stage ---------------------------------------------------------------------------------
def _range_of(colour: Colour | HSVRange) -> HSVRange:
    if isinstance(colour, HSVRange):
        return colour
    return {"red": RED, "yellow": YELLOW}[colour]


def _coverage(
    crop: NDArray[np.uint8], region: NDArray[np.uint8], cfg: SubpixelConfig
) -> NDArray[np.float32] | SubpixelResult:
    """The colour coverage map α = ((p − b)·(f − b)) / |f − b|² of ``crop`` (f, b: median RGB
    inside the eroded marker ``region`` and in a ring around it; seed 004 §4.2). Returns an
    invalid ``SubpixelResult`` when no background is visible or the contrast |f − b| is below
    ``min_contrast_dn``."""
    inner = cv2.erode(region, _ELLIPSE3, iterations=2)
    if cv2.countNonZero(inner) < 3:
        inner = region
    # the ring between 2 and 5 dilations (the 5 as 3 more of the 2: binary dilations compose)
    near = cv2.dilate(region, _ELLIPSE3, iterations=2)
    ring = cv2.dilate(near, _ELLIPSE3, iterations=3) - near
    if cv2.countNonZero(ring) < 3:
        return SubpixelResult.invalid("no background visible around the marker in the roi")
    fg, bg = kernels.median_rgb(crop, inner), kernels.median_rgb(crop, ring)
    crop_f = crop.astype(np.float32)
    d = fg - bg
    dd = float(d @ d)
    if math.sqrt(dd) < cfg.min_contrast_dn:
        return SubpixelResult.invalid(f"marker contrast {math.sqrt(dd):.1f} DN too low")
    return ((crop_f - bg) @ (d / dd)).astype(np.float32)


def _subpixel_edge(
    region: NDArray[np.uint8], alpha: NDArray[np.float32], cfg: SubpixelConfig
) -> NDArray[np.float64] | SubpixelResult:
    """Sub-pixel edge points (crop px) of the marker ``region``: each outer contour pixel moved
    along the ray from the region's centroid to where the coverage ``alpha`` crosses 1/2
    (seed 004 §4.2). Contour pixels on the crop's border are dropped (the region may continue
    outside it). Returns an invalid ``SubpixelResult`` when too few points remain."""
    contours, _ = cv2.findContours(region, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    contour = max(contours, key=len).reshape(-1, 2).astype(float)
    m = cv2.moments(region, binaryImage=True)
    hh, ww = region.shape
    t = np.arange(-cfg.edge_search_px, cfg.edge_search_px + 1e-9, cfg.edge_step_px)
    pts, u, sx, sy = kernels.edge_rays(contour, m["m10"] / m["m00"], m["m01"] / m["m00"],
                                       ww, hh, t)
    if len(pts) < cfg.min_points:
        return SubpixelResult.invalid("too few contour points", len(pts))
    prof = cv2.remap(alpha, sx, sy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=float("nan"))
    edge = kernels.edge_crossings(prof, t, cfg.edge_step_px, pts, u)
    if len(edge) < cfg.min_points:
        return SubpixelResult.invalid("too few sub-pixel edge points", len(edge))
    return edge


def refine_marker_centre(
    image_rgb: NDArray[np.uint8],
    colour: Colour | HSVRange,
    roi_image_px: ArrayLike,
    config: SubpixelConfig | None = None,
    radius_px: float | None = None,
) -> SubpixelResult:
    """Sub-pixel centre of the marker of ``colour`` inside ``roi_image_px`` (seed 004 §4).

    Parameters
    ----------
    image_rgb : ndarray (H, W, 3) uint8
        The frame, **RGB** channel order (see ``observer.gk.hsv_gate``).
    colour : "red", "yellow" or an ``HSVRange``
        The marker's colour class (seed 000 §3.2.1 ranges for the named ones).
    roi_image_px : array_like (4,)
        Region (x, y, w, h) in image px of this frame that contains the whole marker (a tracker's
        box enlarged by a margin); it is padded by ``config.pad_px`` and clipped to the frame.
    config : SubpixelConfig, optional
    radius_px : float, optional
        The marker's known radius, image px. Given, steps 3-4 change: instead of the burr
        test and the algebraic start, the edge points on a circle of this radius are found by
        consensus (``circle_of_radius``, tolerance ``consensus_tol_fraction`` of the radius),
        and the geometric fit runs on them. This recovers a marker whose colour region is
        merged with a same-coloured occluder (its outline is then the visible arc plus the
        occluder's), where the free fit finds the union.

    Returns
    -------
    SubpixelResult
        Centre and radius in image px, fit residual, ``valid`` and a ``reason``. Bad input
        (wrong frame, NaN ROI, no marker, low contrast, too few points) gives ``valid=False``;
        nothing raises.
    """
    cfg = config or SubpixelConfig()
    bad = check_rgb_image(image_rgb)
    if bad:
        return SubpixelResult.invalid(bad)
    try:
        hsv_range = _range_of(colour)
    except KeyError:
        return SubpixelResult.invalid(f"unknown colour {colour!r}")
    cropped = _crop(image_rgb, roi_image_px, cfg.pad_px)
    if isinstance(cropped, SubpixelResult):
        return cropped
    crop, offset = cropped

    # 1. segmentation: colour mask, opening, largest connected region
    segmented = _segment(crop, hsv_range, cfg)
    if isinstance(segmented, SubpixelResult):
        return segmented
    region, r_area = segmented

    # marker and background colours -> coverage map alpha
    alpha = _coverage(crop, region, cfg)
    if isinstance(alpha, SubpixelResult):
        return alpha

    # 2. contour, moved to the alpha = 1/2 crossing along the ray from the centroid
    edge = _subpixel_edge(region, alpha, cfg)
    if isinstance(edge, SubpixelResult):
        return edge
    fit = _fit_circle(edge, r_area, radius_px, cfg)
    if isinstance(fit, SubpixelResult):
        return fit
    return _judged_fit(*fit, offset, region.shape, cfg)


#: Why ``kernels.fit_free`` found no circle, by its status.
_FREE_FIT_FAILURES = {
    kernels.NO_CONVEX_OUTLINE: "contour has no convex outline",
    kernels.TOO_FEW_AFTER_BURRS: "too few points after burr removal",
    kernels.COLLINEAR: "degenerate contour (collinear points)",
}


def _fit_circle(
    edge: NDArray[np.float64], r_area: float, radius_px: float | None, cfg: SubpixelConfig,
) -> tuple[NDArray[np.float64], float, float, int, int, int, float] | SubpixelResult:
    """Steps 3-4: the circle through the edge points (crop px) as (centre, R, RMS residual,
    points used, points removed as burrs or off the known circle, outliers, arc coverage).
    With a known ``radius_px``: the points on a circle of that radius by consensus, then the
    robust geometric fit; otherwise burr removal (seed 004 eq. 25), the algebraic fit and the
    robust geometric fit (``kernels.fit_free``). An invalid result when too few points remain
    or they are collinear."""
    if radius_px is None:
        status, cx, cy, R, rms, n_pts, n_burrs, n_out, cover = kernels.fit_free(
            edge, r_area, cfg.burr_span_fraction, cfg.burr_curvature_factor, cfg.outlier_k,
            cfg.outlier_floor_px, cfg.min_points, cfg.max_iter)
        if status != kernels.FIT_OK:
            return SubpixelResult.invalid(_FREE_FIT_FAILURES[status], n_pts)
        return np.array([cx, cy]), R, rms, n_pts, n_burrs, n_out, cover
    c0, on_circle = circle_of_radius(edge, radius_px, cfg.consensus_tol_fraction * radius_px)
    pts, n_off = edge[on_circle], int((~on_circle).sum())
    if len(pts) < cfg.min_points:
        return SubpixelResult.invalid("too few edge points on a circle of the marker's "
                                      "radius", len(pts))
    cx, cy, R, res, pts, n_out = kernels.robust(pts, c0[0], c0[1], float(radius_px),
                                                cfg.outlier_k, cfg.outlier_floor_px,
                                                cfg.min_points, cfg.max_iter)
    return (np.array([cx, cy]), R, kernels.rms(res), len(pts), n_off, n_out,
            kernels.arc_coverage(pts, cx, cy))


def _judged_fit(
    c: NDArray[np.float64], R: float, rms: float, n_points: int, n_burrs: int, n_out: int,
    cover: float, offset: NDArray[np.float64], shape: tuple[int, ...], cfg: SubpixelConfig,
) -> SubpixelResult:
    """The fitted circle (centre ``c`` and radius ``R`` in crop px, RMS residual ``rms`` of its
    ``n_points`` points, which cover ``cover`` of the circle) as a result in image px
    (``offset`` is the crop's corner): valid unless the fit diverged, its RMS residual exceeds
    ``max_rms_fraction`` of R, its points cover less than ``min_arc_coverage`` of the circle,
    or the centre lies outside the crop of ``shape`` (rows, columns)."""
    hh, ww = shape
    reason = ""
    if not (np.all(np.isfinite(c)) and math.isfinite(R) and R > 0.0):
        reason = "circle fit did not converge"
    elif rms > cfg.max_rms_fraction * R:
        reason = f"fit residual {rms:.2f} px exceeds {cfg.max_rms_fraction} of the radius"
    elif cover < cfg.min_arc_coverage:
        reason = f"edge points cover only {cover:.2f} of the circle"
    elif not (0.0 <= c[0] <= ww - 1 and 0.0 <= c[1] <= hh - 1):
        reason = "fitted centre outside the roi"
    if reason:
        return SubpixelResult(np.full(2, np.nan), math.nan, rms, n_points, n_burrs, n_out,
                              cover, False, reason)
    return SubpixelResult(c + offset, float(R), rms, n_points, n_burrs, n_out, cover, True)


def _crop(image_rgb: NDArray[np.uint8], roi_image_px: ArrayLike,
          pad_px: int) -> tuple[NDArray[np.uint8], NDArray[np.float64]] | SubpixelResult:
    """The ROI (x, y, w, h) padded by ``pad_px`` and clipped to the frame, and its top-left
    corner (image px); an invalid result for a malformed ROI or one outside the frame."""
    try:
        x, y, w, h = (float(c) for c in np.asarray(roi_image_px, dtype=float).reshape(4))
    except (TypeError, ValueError):
        return SubpixelResult.invalid("roi must be (x, y, w, h)")
    if not all(math.isfinite(c) for c in (x, y, w, h)) or w <= 0.0 or h <= 0.0:
        return SubpixelResult.invalid("roi is not finite or has w, h <= 0")
    H, W = image_rgb.shape[:2]
    c0 = max(int(math.floor(x)) - pad_px, 0)
    r0 = max(int(math.floor(y)) - pad_px, 0)
    c1 = min(int(math.ceil(x + w)) + pad_px + 1, W)
    r1 = min(int(math.ceil(y + h)) + pad_px + 1, H)
    if c1 - c0 < 3 or r1 - r0 < 3:
        return SubpixelResult.invalid("roi lies outside the frame")
    return np.ascontiguousarray(image_rgb[r0:r1, c0:c1]), np.array([c0, r0], dtype=float)


def _segment(crop: NDArray[np.uint8], hsv_range: HSVRange,
             cfg: SubpixelConfig) -> tuple[NDArray[np.uint8], float] | SubpixelResult:
    """The largest connected region of the colour mask after an opening (a 0/1 mask of the
    crop) and the radius of a disc of its area, px; invalid if none or too small."""
    mask = colour_mask(crop, hsv_range)
    if cfg.open_kernel_px > 0:
        kern = cv2.getStructuringElement(
            cv2.MORPH_ELLIPSE, (cfg.open_kernel_px, cfg.open_kernel_px)
        )
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kern)
    n_lab, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n_lab < 2:
        return SubpixelResult.invalid("no marker-coloured region in the roi")
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    area = int(stats[k, cv2.CC_STAT_AREA])
    if area < cfg.min_area_px:
        return SubpixelResult.invalid(f"marker region too small ({area} px)")
    return (labels == k).astype(np.uint8), math.sqrt(area / math.pi)


def refine_in_box(
    image_rgb: NDArray[np.uint8],
    colour: Colour | HSVRange,
    box_sensor_px: ArrayLike,
    binning: int,
    config: SubpixelConfig | None = None,
    roi_margin: float = 0.3,
) -> tuple[NDArray[np.float64] | None, SubpixelResult]:
    """The circle-fit acceptance rule for a tracker's box (seed 004 §4).

    The fit (``refine_marker_centre``) runs in the box (x, y, w, h, full-sensor px) enlarged by
    ``roi_margin`` of its size on each side (our choice 0.3: the whole marker stays in the ROI
    when the box is off by a third of its size). Its centre is accepted when the fit is valid
    and the centre lies inside the box: a fit that wandered to another blob is not the tracked
    marker. Returns (centre in sensor px or None, the fit); a box that is not finite or has
    w, h <= 0 gives (None, an invalid fit).
    """
    box = np.asarray(box_sensor_px, dtype=float).reshape(4)
    if not np.all(np.isfinite(box)) or box[2] <= 0 or box[3] <= 0:
        return None, SubpixelResult.invalid("box not finite or has w, h <= 0")
    roi = np.r_[box[:2] - roi_margin * box[2:], box[2:] * (1.0 + 2.0 * roi_margin)]
    fit = refine_marker_centre(image_rgb, colour, box_sensor_to_image(roi, binning), config)
    if not fit.valid:
        return None, fit
    c = fit.centre_sensor_px(binning)
    return (c if np.all((c >= box[:2]) & (c <= box[:2] + box[2:])) else None), fit
