"""A procedural printed texture for the rotor's bottom plate (seed 001 §4.2.1).

Seed 001 estimates attitude from ORB feature matches on a textured scene. Our variant of the
rotor replaces the two VFC markers by a print on the bottom plate that is rich in corners:
random rectangles (axis-aligned and rotated), polygons, ellipses and small checker fragments in
random grey levels and colours, drawn from a seed. The pattern has no repetition, so every ORB
descriptor has a unique match.

The texture is a function of rotor-surface coordinates, shared by both renderers:

* the print covers the square ``|x|, |y| <= h`` (h = half the side, m) of the plane ``z = -R``
  in the rotor frame (the plane of the VFC plate, tangent to the rotor at the bottom pole);
* the texel in column ``i`` and row ``j`` of ``Texture.image`` is centred on the rotor point
  ``x = -h + (i + 1/2) s``, ``y = -h + (j + 1/2) s`` with ``s = 2 h / n`` the texel size; in
  continuous coordinates (OpenCV convention, integer = texel centre)
  ``(u, v) = ((x + h)/s - 1/2, (y + h)/s - 1/2)``.

At rest the camera's u axis is the stator (= rotor) X axis and v is Y (``plant.camera``), so the
camera sees the texture upright and unmirrored.

All lengths are SI (m) unless a name says ``_mm``; the image is RGB uint8.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from plant.params import PlantParams

#: Fixed-point fraction bits of the vertices handed to ``cv2.fillPoly`` (1/16 texel).
_SHIFT = 4


class TextureParams(BaseModel):
    """How the printed pattern is generated. All defaults are our choice."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    seed: int = Field(0, ge=0, description="Seed of the pattern: same seed, same texture.")
    size_mm: float | None = Field(
        None,
        gt=0.0,
        description="Side of the printed square, mm; None: the VFC plate's "
        "``plate_size_mm`` (50 mm), so the print covers the plate that carried the markers.",
    )
    texels_per_mm: float = Field(
        20.0,
        gt=0.0,
        le=100.0,
        description="Our choice: 0.05 mm texels, finer than a full-sensor pixel's "
        "footprint on the plate (0.041 mm at h_c = 0.30 m is about the same), so the print is "
        "sharp at every binning.",
    )
    n_rectangles: int = Field(
        140, ge=0, description="Our choice: rectangles (half of them rotated)."
    )
    n_polygons: int = Field(40, ge=0, description="Our choice: random triangles/quadrilaterals.")
    n_ellipses: int = Field(40, ge=0, description="Our choice: blobs (ellipses).")
    n_checkers: int = Field(14, ge=0, description="Our choice: rotated checker fragments.")
    min_feature_mm: float = Field(
        1.2,
        gt=0.0,
        description="Our choice: smallest shape side, mm; 7 pixels of the 4x-binned frame "
        "(0.166 mm/px at the plate), enough for ORB's FAST ring of radius 3 px.",
    )
    max_feature_mm: float = Field(8.0, gt=0.0, description="Our choice: largest shape side, mm.")
    background_grey: int = Field(
        70, ge=0, le=255, description="Our choice: dark grey ground (8-bit), like the VFC plate."
    )


@dataclass(frozen=True, eq=False)
class Texture:
    """A generated print and its placement on the rotor.

    Attributes
    ----------
    image : ndarray (n, n, 3) uint8
        RGB texels; column index along rotor +x, row index along rotor +y.
    half_size_m : float
        h: the print covers ``|x|, |y| <= h`` in the rotor frame, m.
    z_m : float
        The plane of the print in the rotor frame, m (``-R``).
    """

    image: NDArray[np.uint8]
    half_size_m: float
    z_m: float

    @property
    def n(self) -> int:
        """Texels per side."""
        return int(self.image.shape[0])

    @property
    def texel_m(self) -> float:
        """Side of one texel, m."""
        return 2.0 * self.half_size_m / self.n

    def to_texel(self, xy_m: ArrayLike, n: int | None = None) -> NDArray[np.float64]:
        """Rotor-frame (x, y), m, (N, 2) -> continuous texel coordinates (N, 2) of an image with
        ``n`` texels per side (default ``self.n``), OpenCV convention."""
        s = 2.0 * self.half_size_m / (self.n if n is None else n)
        return (np.asarray(xy_m, dtype=float) + self.half_size_m) / s - 0.5

    def to_rotor(self, uv_texel: ArrayLike, n: int | None = None) -> NDArray[np.float64]:
        """Continuous texel coordinates (N, 2) of an image with ``n`` texels per side (default
        ``self.n``) -> rotor-frame points (N, 3), m, on the plane ``z = -R``."""
        s = 2.0 * self.half_size_m / (self.n if n is None else n)
        uv = np.atleast_2d(np.asarray(uv_texel, dtype=float))
        xy = (uv + 0.5) * s - self.half_size_m
        return np.column_stack([xy, np.full(len(xy), self.z_m)])

    def texel_to_rotor_matrix(self, n: int | None = None) -> NDArray[np.float64]:
        """3x3 matrix A with ``(x, y, 1) = A (u, v, 1)``: texel coordinates of an ``n``-texel
        image -> rotor-frame plane coordinates, m."""
        s = 2.0 * self.half_size_m / (self.n if n is None else n)
        off = 0.5 * s - self.half_size_m
        return np.array([[s, 0.0, off], [0.0, s, off], [0.0, 0.0, 1.0]])

    def contains(self, xy_m: ArrayLike, margin_m: float = 0.0) -> NDArray[np.bool_]:
        """Whether rotor-frame (x, y) points (N, 2) lie on the print, ``margin_m`` inside it."""
        xy = np.atleast_2d(np.asarray(xy_m, dtype=float))
        return np.all(np.abs(xy) <= self.half_size_m - margin_m, axis=1)

    def resampled(self, n: int) -> NDArray[np.uint8]:
        """The image area-averaged (or, when enlarging, linearly interpolated) to ``n`` texels
        per side: the prefiltered level a renderer samples so that it does not alias."""
        return _resampled(self, int(n))


@lru_cache(maxsize=16)
def _resampled(texture: Texture, n: int) -> NDArray[np.uint8]:
    if n == texture.n:
        return texture.image
    interp = cv2.INTER_AREA if n < texture.n else cv2.INTER_LINEAR
    return cv2.resize(texture.image, (n, n), interpolation=interp)


def _colour(rng: np.random.Generator, background: int) -> tuple[int, int, int]:
    """A random RGB colour at least 50 grey levels from the background (contrast for FAST)."""
    while True:
        if rng.uniform() < 0.5:  # grey level
            g = int(rng.integers(0, 256))
            rgb = (g, g, g)
        else:
            rgb = tuple(int(c) for c in rng.integers(0, 256, size=3))
        luma = 0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2]
        if abs(luma - background) >= 50:
            return rgb  # type: ignore[return-value]


def _poly(img: NDArray[np.uint8], pts: NDArray[np.float64], rgb: tuple[int, int, int]) -> None:
    cv2.fillPoly(img, [np.round(pts * (1 << _SHIFT)).astype(np.int32)], rgb, cv2.LINE_AA, _SHIFT)


def _rotated_rect(centre, w, h, angle) -> NDArray[np.float64]:
    c, s = np.cos(angle), np.sin(angle)
    corners = np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) / 2.0
    return centre + corners @ np.array([[c, s], [-s, c]])


def generate_texture(p: PlantParams, tp: TextureParams | None = None) -> Texture:
    """Draw the print for plant ``p`` from ``tp`` (default ``TextureParams()``).

    Same parameters, same texels (the drawing is seeded and OpenCV's rasteriser is
    deterministic). Shapes are drawn in sequence, later ones over earlier ones, with
    anti-aliased edges; the print has a thin light frame so that its outline against the dark
    housing is also textured.
    """
    tp = tp or TextureParams()
    size_m = (tp.size_mm if tp.size_mm is not None else p.vfc.plate_size_mm) / 1000.0
    n = max(16, int(round(size_m * 1000.0 * tp.texels_per_mm)))
    px_per_mm = n / (size_m * 1000.0)
    lo_px, hi_px = tp.min_feature_mm * px_per_mm, tp.max_feature_mm * px_per_mm
    if hi_px < lo_px:
        raise ValueError("max_feature_mm must not be smaller than min_feature_mm")
    rng = np.random.default_rng(tp.seed)
    bg = tp.background_grey
    img = np.full((n, n, 3), bg, np.uint8)

    def centre() -> NDArray[np.float64]:
        return rng.uniform(0.0, n - 1.0, size=2)

    def side() -> float:
        return float(np.exp(rng.uniform(np.log(lo_px), np.log(hi_px))))

    # Shapes of each kind are interleaved in a random order so no kind always lies on top.
    kinds = (
        ["rect"] * tp.n_rectangles
        + ["poly"] * tp.n_polygons
        + ["ellipse"] * tp.n_ellipses
        + ["checker"] * tp.n_checkers
    )
    for kind in rng.permutation(np.array(kinds, dtype=object)) if kinds else []:
        rgb = _colour(rng, bg)
        if kind == "rect":
            angle = 0.0 if rng.uniform() < 0.5 else rng.uniform(0.0, np.pi)
            _poly(img, _rotated_rect(centre(), side(), side(), angle), rgb)
        elif kind == "poly":
            k = int(rng.integers(3, 5))
            ang = np.sort(rng.uniform(0.0, 2.0 * np.pi, size=k))
            rad = rng.uniform(0.5, 1.0, size=k) * side() / 2.0
            _poly(img, centre() + np.column_stack([np.cos(ang), np.sin(ang)]) * rad[:, None], rgb)
        elif kind == "ellipse":
            c = np.round(centre()).astype(int)
            axes = (max(1, int(side() / 2)), max(1, int(side() / 2)))
            cv2.ellipse(
                img, tuple(c), axes, float(rng.uniform(0, 180)), 0, 360, rgb, -1, cv2.LINE_AA
            )
        else:  # checker fragment: 2-4 x 2-4 cells of two colours, rotated
            cells = rng.integers(2, 5, size=2)
            cell = max(lo_px, side() / 2.5)
            angle = rng.uniform(0.0, np.pi)
            other = _colour(rng, bg)
            c0 = centre()
            for a in range(cells[0]):
                for b in range(cells[1]):
                    offset = (np.array([a, b]) - (cells - 1) / 2.0) * cell
                    cs, sn = np.cos(angle), np.sin(angle)
                    centre_ab = c0 + offset @ np.array([[cs, sn], [-sn, cs]])
                    colour = rgb if (a + b) % 2 == 0 else other
                    _poly(img, _rotated_rect(centre_ab, cell, cell, angle), colour)
    frame = max(1, int(round(0.4 * px_per_mm)))  # a 0.4 mm light border
    cv2.rectangle(img, (0, 0), (n - 1, n - 1), (200, 200, 200), frame)
    img.setflags(write=False)
    return Texture(img, 0.5 * size_m, -p.rotor.radius_m)


def encode_png(texture: Texture) -> bytes:
    """The texture as PNG bytes (RGB order on disk), e.g. for a MuJoCo texture asset."""
    ok, buf = cv2.imencode(".png", cv2.cvtColor(texture.image, cv2.COLOR_RGB2BGR))
    if not ok:  # pragma: no cover - OpenCV always encodes a uint8 RGB image
        raise RuntimeError("PNG encoding of the texture failed")
    return buf.tobytes()


def outline_rotor(texture: Texture, n_per_edge: int = 16) -> NDArray[np.float64]:
    """Boundary points (4 n_per_edge, 3) of the printed square in the rotor frame, m, in order
    around it (the textured variant's plate outline)."""
    h = texture.half_size_m
    s = np.linspace(-h, h, n_per_edge, endpoint=False)
    xy = np.vstack(
        [
            np.column_stack([s, np.full_like(s, -h)]),
            np.column_stack([np.full_like(s, h), s]),
            np.column_stack([-s, np.full_like(s, h)]),
            np.column_stack([np.full_like(s, -h), -s]),
        ]
    )
    return np.column_stack([xy, np.full(len(xy), texture.z_m)])


def plane_homography(
    texture: Texture, R: ArrayLike, camera_centre_m: ArrayLike, n: int | None = None
) -> NDArray[np.float64]:
    """3x3 homography G from normalised (undistorted) camera coordinates ``(x/z, y/z, 1)`` to
    continuous texel coordinates of an ``n``-texel level of the print, at rotor attitude
    rotation ``R`` (rotor to stator) with the camera's optical centre at ``camera_centre_m``
    (stator frame, m; the camera axes are the stator axes, ``plant.camera``).

    A rotor point (x, y, -R) on the print is at ``M (x, y, 1)`` in the camera frame with
    ``M = [R e_x, R e_y, R (0, 0, z_print) - C]``, so ``G = A^-1 M^-1`` with A of
    ``Texture.texel_to_rotor_matrix``.
    """
    Rm = np.asarray(R, dtype=float)
    M = np.column_stack([Rm[:, 0], Rm[:, 1], Rm[:, 2] * texture.z_m - np.asarray(camera_centre_m)])
    return np.linalg.inv(texture.texel_to_rotor_matrix(n)) @ np.linalg.inv(M)
