"""The VFC plate as a cue for a hidden marker (GK-TransT's coasting).

The two markers sit on a square plate (``VFCParams.plate_size_mm``, 50 mm; ``plant.scene``)
fixed to the rotor, its edges along and across the red→yellow diagonal. When an occluder hides
the red marker, the yellow one fixes the plate's position but not its turn about the pole, and a
constant-velocity prediction drifts as soon as the rotor changes its motion. The plate's four
edges usually stay visible around the occluder, and their image fixes the whole plane-to-image
map. ``PlateTracker`` follows them from frame to frame:

1. **Start** on a frame with both markers measured: the plate's corners are P ± a u ± a v,
   with P the markers' midpoint, u the unit red→yellow vector, v ⟂ u and
   a = (plate side / 2) / L · |V| (L the marker spacing, V the red→yellow vector); then refined
   by the edge fit below. The markers' motion since the frame before (a similarity of the two
   points) starts the corners' velocity.
2. **Each frame**: the corners are predicted at constant velocity; along each predicted edge,
   ``samples`` lines are searched over ±``band_img_px`` along its normal for the strongest
   step of the plate's contrast sign (learned at start: dark plate, brighter rotor), and a line
   is fitted to them (Huber); the new corners are the lines' intersections. The fit is refused
   (the plate is lost until the next start) when a side has fewer than ``min_edge_points``
   points, the quadrilateral is far from a square, or a side changed by more than
   ``max_side_change`` since the last frame.
3. **Reference**: on frames where both markers are measured the tracker keeps the corners and
   both marker centres. On a frame where the red marker is not measured, ``locate`` maps the
   reference red centre by the homography from the reference corners to the current ones.
   The caller checks the mapped yellow centre against the measured one (``check``).

Positions in the API are full-sensor px; the edge search works in the binned frame's image px.
Bad input (no plate in view, a frame of another size) makes the tracker lost, never raises.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from plant.camera import image_to_sensor, sensor_to_image
from plant.params import PlantParams


class PlateConfig(BaseModel):
    """Settings of the plate's edge tracking (all our choices; see the module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    band_img_px: float = Field(12.0, gt=0.0, description="Search half-width along an edge's "
                               "normal, image px (the corners move up to ~15 px a frame on "
                               "fast development sequences; the prediction removes most).")
    samples: int = Field(24, ge=8, description="Search lines per edge.")
    min_step: float = Field(7.5, gt=0.0, description="Smallest step of the plate's contrast "
                            "sign for an edge point, grey levels per px.")
    min_edge_points: int = Field(8, ge=3, description="Fewest edge points per side.")
    min_squareness: float = Field(0.8, gt=0.0, le=1.0, description="Shortest side over the "
                                  "longest (tilt foreshortens the square by cos 15° at most).")
    max_side_change: float = Field(0.15, gt=0.0, description="Largest relative change of a "
                                   "side's length from one frame to the next.")
    yellow_tolerance_px: float = Field(12.0, gt=0.0, description="Largest distance, sensor "
                                       "px, of the measured yellow centre from the plate's "
                                       "mapping of it for the plate to be believed.")
    stand_in_sigma_px: float = Field(2.0, gt=0.0, description="Standard deviation of a red "
                                     "centre inferred from the plate beyond the Kalman "
                                     "filter's R, sensor px (errors of 0.5-2.8 px measured on "
                                     "development sequences).")


class PlateTracker:
    """Follows the VFC plate's four edges and maps the reference marker centres (module
    docstring)."""

    def __init__(self, params: PlantParams, config: PlateConfig | None = None) -> None:
        self.config = config or PlateConfig()
        vfc = params.vfc
        #: Half the plate's side over the marker spacing L (plate coordinates of the corners).
        self.half_side_over_L = 0.5 * vfc.plate_size_mm / (vfc.L_m * 1000.0)
        self.corners_img: NDArray[np.float64] | None = None
        self._previous: NDArray[np.float64] | None = None
        self._sign = 1.0
        self._reference: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None

    @property
    def tracked(self) -> bool:
        """The plate's corners are known in the current frame."""
        return self.corners_img is not None

    def lose(self) -> None:
        """Forget the plate until the next ``start``."""
        self.corners_img = self._previous = self._reference = None

    def start(self, image: NDArray[np.uint8], binning: int, red_sensor_px: ArrayLike,
              yellow_sensor_px: ArrayLike, markers_before_sensor_px: ArrayLike | None = None
              ) -> bool:
        """Find the plate from the two measured marker centres (sensor px); True if found.

        ``markers_before_sensor_px`` (2, 2), the red and yellow centres of the frame before,
        gives the plate's motion for the prediction into the next frame (the similarity that
        takes those two points to these, applied once more); without it the plate is predicted
        at rest."""
        self.lose()
        red = sensor_to_image(np.asarray(red_sensor_px, dtype=float), binning)
        yellow = sensor_to_image(np.asarray(yellow_sensor_px, dtype=float), binning)
        V = yellow - red
        norm = float(np.hypot(*V))
        if not (np.all(np.isfinite(V)) and norm > 0.0):
            return False
        u = V / norm
        v = np.array([-u[1], u[0]])
        a = self.half_side_over_L * norm
        P = 0.5 * (red + yellow)
        corners = np.array([P + a * (u + v), P + a * (u - v), P + a * (-u - v), P + a * (-u + v)])
        self._sign = _contrast_sign(image, corners, self.config)
        for _ in range(3):  # the guess is off by the tilt's foreshortening: settle the fit
            fitted = _fit_edges(image, corners, self._sign, self.config)
            if fitted is None or not _square(fitted, corners, self.config, start=True):
                return False
            corners = fitted
        self.corners_img = self._previous = corners
        if markers_before_sensor_px is not None:
            before = sensor_to_image(np.asarray(markers_before_sensor_px, dtype=float), binning)
            if np.all(np.isfinite(before)) and np.hypot(*(before[1] - before[0])) > 0.0:
                # z_now = a z_before + b on complex coordinates; the previous corners are the
                # current ones taken back by it
                zb = before[:, 0] + 1j * before[:, 1]
                zn = complex(red[0], red[1]), complex(yellow[0], yellow[1])
                a = (zn[1] - zn[0]) / (zb[1] - zb[0])
                back = (corners[:, 0] + 1j * corners[:, 1] - (zn[0] - a * zb[0])) / a
                self._previous = np.column_stack([back.real, back.imag])
        self.remember(red_sensor_px, yellow_sensor_px, binning)
        return True

    def update(self, image: NDArray[np.uint8]) -> bool:
        """Follow the plate into this frame; False (and lost) if the fit is refused."""
        if self.corners_img is None or self._previous is None:
            return False
        predicted = 2.0 * self.corners_img - self._previous
        fitted = _fit_edges(image, predicted, self._sign, self.config)
        if fitted is None or not _square(fitted, self.corners_img, self.config):
            self.lose()
            return False
        self._previous, self.corners_img = self.corners_img, fitted
        return True

    def remember(self, red_sensor_px: ArrayLike, yellow_sensor_px: ArrayLike,
                 binning: int) -> None:
        """Both markers measured in this frame: keep them with the plate's corners."""
        if self.corners_img is None:
            return
        markers = np.array([red_sensor_px, yellow_sensor_px], dtype=float)
        if np.all(np.isfinite(markers)):
            self._reference = (self.corners_img.copy(), sensor_to_image(markers, binning))

    def locate(self, binning: int) -> NDArray[np.float64] | None:
        """The reference red and yellow centres (2, 2), sensor px, mapped into this frame by the
        plate's homography; None without a plate or a reference."""
        if self.corners_img is None or self._reference is None:
            return None
        corners0, markers0 = self._reference
        H = cv2.getPerspectiveTransform(corners0.astype(np.float32),
                                        self.corners_img.astype(np.float32))
        mapped = cv2.perspectiveTransform(markers0.reshape(1, 2, 2), H)[0]
        return image_to_sensor(mapped, binning)

    def check(self, mapped_yellow_px: ArrayLike, yellow_px: ArrayLike) -> bool:
        """Whether the measured yellow centre (sensor px) lies where the plate maps it; a plate
        that fails is lost."""
        d = float(np.hypot(*(np.asarray(mapped_yellow_px) - np.asarray(yellow_px))))
        if not d <= self.config.yellow_tolerance_px:
            self.lose()
            return False
        return True


def _grey_box(image: NDArray[np.uint8], corners: NDArray[np.float64], config: PlateConfig
              ) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
    """The smoothed grey frame in the plate's bounding box grown by the search band (the rest
    of the frame is never searched), and the box's origin, image px."""
    H, W = image.shape[:2]
    grow = config.band_img_px + 3.0
    x0, y0 = (max(int(v), 0) for v in np.floor(corners.min(axis=0) - grow))
    x1, y1 = (int(v) for v in np.ceil(corners.max(axis=0) + grow))
    x1, y1 = min(max(x1, x0 + 3), W), min(max(y1, y0 + 3), H)
    crop = np.ascontiguousarray(image[y0:y1, x0:x1])
    if crop.shape[0] < 3 or crop.shape[1] < 3:
        crop = np.zeros((3, 3, 3), np.uint8)
    grey = cv2.GaussianBlur(cv2.cvtColor(crop, cv2.COLOR_RGB2GRAY).astype(np.float32), (3, 3), 0)
    return grey, np.array([x0, y0], dtype=float)


def _edge_samples(image: NDArray[np.uint8], corners: NDArray[np.float64], config: PlateConfig
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The search points (4 sides, samples, offsets, 2), image px, 1 px apart along each side's
    outward normal, and the grey level's step there (4, samples, offsets), grey levels per px:
    the difference of bilinear samples half a pixel outside and inside."""
    grey, origin = _grey_box(image, corners, config)
    offsets = np.arange(-config.band_img_px, config.band_img_px + 1e-9, 1.0)
    ends = np.r_[offsets - 0.5, offsets[-1] + 0.5]
    s = np.linspace(0.1, 0.9, config.samples)
    d = np.roll(corners, -1, axis=0) - corners  # side k runs from corner k to corner k + 1
    t = d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)[:, None]
    n = np.column_stack([-t[:, 1], t[:, 0]])
    mid = corners + 0.5 * d - corners.mean(axis=0)
    n *= np.where(np.sum(n * mid, axis=1) < 0.0, -1.0, 1.0)[:, None]  # outward
    base = corners[:, None, :] + s[None, :, None] * d[:, None, :] - origin  # (4, S, 2)
    at = base[:, :, None, :] + ends[None, None, :, None] * n[:, None, None, :]
    level = cv2.remap(grey, at[..., 0].reshape(-1, len(ends)).astype(np.float32),
                      at[..., 1].reshape(-1, len(ends)).astype(np.float32), cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_REPLICATE).reshape(4, len(s), len(ends))
    pts = base[:, :, None, :] + origin + offsets[None, None, :, None] * n[:, None, None, :]
    return pts, np.diff(level.astype(float), axis=2)


def _contrast_sign(image: NDArray[np.uint8], corners: NDArray[np.float64],
                   config: PlateConfig) -> float:
    """+1 when the plate is darker than its surroundings (the outward steps' strongest are
    positive), else -1."""
    _, g = _edge_samples(image, corners, config)
    strongest = np.take_along_axis(g, np.argmax(np.abs(g), axis=2)[..., None], axis=2)
    return 1.0 if float(np.median(strongest)) >= 0.0 else -1.0


def _fit_edges(image: NDArray[np.uint8], corners: NDArray[np.float64], sign: float,
               config: PlateConfig) -> NDArray[np.float64] | None:
    """The corners (4, 2), image px, from lines fitted to the edge points found around the
    predicted ``corners``; None when a side has too few points or two lines are parallel."""
    pts, g = _edge_samples(image, corners, config)
    g = sign * g
    j = np.clip(np.argmax(g, axis=2), 1, g.shape[2] - 2)[..., None]
    # the peak between the samples: the vertex of the parabola through the three around it
    # (the samples are 1 px apart)
    g0, g1, g2 = (np.take_along_axis(g, j + o, axis=2)[..., 0] for o in (-1, 0, 1))
    curv = g0 - 2.0 * g1 + g2
    frac = np.clip(np.where(curv < 0.0, 0.5 * (g0 - g2) / np.where(curv < 0.0, curv, -1.0),
                            0.0), -0.5, 0.5)
    p1 = np.take_along_axis(pts, j[..., None], axis=2)[:, :, 0]
    p2 = np.take_along_axis(pts, (j + 1)[..., None], axis=2)[:, :, 0]
    at = p1 + frac[..., None] * (p2 - p1)
    ok = g1 > config.min_step
    if np.any(ok.sum(axis=1) < config.min_edge_points):
        return None
    lines = []
    for k in range(4):
        vx, vy, x0, y0 = cv2.fitLine(at[k][ok[k]].astype(np.float32), cv2.DIST_HUBER, 0, 0.01,
                                     0.01).ravel()
        lines.append((np.array([x0, y0], dtype=float), np.array([vx, vy], dtype=float)))
    out = np.empty((4, 2))
    for k in range(4):
        (a, u), (b, v) = lines[k - 1], lines[k]
        det = u[0] * -v[1] + v[0] * u[1]
        if abs(det) < 1e-6:
            return None
        # a + s u = b + r v  ->  s = ((b - a) x (-v)) / (u x (-v))
        s = ((b[0] - a[0]) * -v[1] + v[0] * (b[1] - a[1])) / det
        out[k] = a + s * u
    return out if np.all(np.isfinite(out)) else None


def _square(corners: NDArray[np.float64], before: NDArray[np.float64], config: PlateConfig,
            start: bool = False) -> bool:
    """Near a square, and (except at the start) its sides close to the last frame's."""
    sides = np.hypot(*(np.roll(corners, -1, axis=0) - corners).T)
    if not (sides.min() >= config.min_squareness * sides.max() and math.isfinite(sides.sum())):
        return False
    if start:
        return True
    old = np.hypot(*(np.roll(before, -1, axis=0) - before).T)
    return bool(np.all(np.abs(sides / old - 1.0) <= config.max_side_change))
