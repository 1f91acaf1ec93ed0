"""A fast analytic renderer of the bottom camera's view (for sweeps and training data), in one
file because geometry, shading, texture and compositing are one rendering pass over the same
pixel grid and share its coverage arrays.

It draws what the camera of ``plant.camera.Camera`` sees, with the same projection
(``Camera.project``, i.e. ``cv2.projectPoints`` with the lens distortion): the dark housing, the
grey rotor sphere (radius R - 1 mm, as in ``plant.mjcf``) with a mild Lambertian shading from
the ring light around the lens, the dark square VFC plate in the plane z = -R and the red and
yellow marker discs on it. The plate and discs are polygons of projected boundary points filled
with ``cv2.fillPoly`` (anti-aliased, sub-pixel coordinates); the sphere and the lighting do not
depend on the attitude and are drawn once per renderer.

Anti-aliasing: each polygon's pixel coverage is computed at ``SUPERSAMPLE`` times the resolution
(``cv2.fillPoly`` with ``LINE_AA`` and sub-pixel ``shift``) and area-averaged down, then the
colour is blended with that coverage. ``cv2.fillPoly(..., LINE_AA)`` at the frame's own
resolution would be cheaper but shifts edges by up to 1 px (more on the top edge of a shape than
on the bottom), which moves disc centroids by up to 0.2 px; supersampled, the centroid of a
drawn disc is within 0.03 px of the true one.

Camera effects, all optional and seeded: motion blur (the average of sub-exposure renders at
``plant.scene.sub_exposure_attitudes``), illumination scale, gain, Gaussian read noise, and
distractors: stationary specular highlights and a red or yellow sticker elsewhere on the rotor.

Appearance options for domain randomisation (all off by default, so the nominal scene is
unchanged): other rotor, plate and marker colours, a pattern on the rotor (blotches, stripes,
speckle, checker), uneven lighting (a linear gradient, vignetting, an off-axis light spot),
white balance, defocus blur and JPEG compression. Marker size comes from
``PlantParams.vfc.marker_diameter_mm`` (drawing and ground truth alike).

Textured variant (``AnalyticRenderOptions.texture``; off by default): the bottom plate
carries the printed pattern of ``plant.texture`` instead of the dark plate and the two markers.
Each pixel's viewing ray is intersected with the print's plane at the sub-frame's attitude (the
plane-to-image map is the homography of ``plant.texture.plane_homography`` in normalised camera
coordinates, composed with the lens undistortion when the lens is not ideal) and the texture
is sampled there: rendered at ``SUPERSAMPLE_TEXTURE`` times the resolution from a prefiltered
level of the texture and area-averaged down, so it does not alias. The print's outline is
composited with the same anti-aliased coverage as the plate, and it is shaded like the plate.
The frame's ``marker_px`` and ``boxes_px`` then describe where the markers would be (they are
not drawn); the attitude ``q`` is the ground truth.
"""

from __future__ import annotations

import functools
from statistics import NormalDist
from typing import Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from plant import attitude, render_kernels
from plant.camera import Camera
from plant.mjcf import PLATE_RGB, RED_RGB, ROTOR_RGB, YELLOW_RGB
from plant.params import PlantParams
from plant.scene import (
    Frame,
    check_binning,
    check_exposure,
    choose_n_sub,
    disc_outlines_rotor,
    ground_truth,
    plate_outline_rotor,
    sub_exposure_attitudes,
    vfc_pixel_travel,
)
from plant.texture import TextureParams, generate_texture, outline_rotor, plane_homography

#: Housing seen around the rotor (RGB in [0, 1]); our choice: nearly black, like MuJoCo's
#: empty background.
HOUSING_RGB = (0.03, 0.03, 0.035)
#: Shading of a surface whose normal makes angle theta with the direction to the camera:
#: ``SHADE_AMBIENT + (1 - SHADE_AMBIENT) * cos(theta)`` (our choice: the ring light sits next
#: to the lens, so the rotor darkens mildly toward its silhouette).
SHADE_AMBIENT = 0.55
#: OpenCV's anti-aliased fill paints about 0.6 px beyond a polygon's edges (measured: the filled
#: area of a disc is too large by 0.6 px times its perimeter). Outlines are pulled in by this
#: much at the supersampled resolution, so drawn areas match the true ones within 0.2 %.
AA_GROWTH_PX = 0.6
#: Supersampling factor of the coverage masks of the marker discs and the colour distractor
#: (our choice: disc centroids within 0.03 px) and of the plate and rotor silhouette (edges
#: within about 0.1 px, at a quarter of the cost).
SUPERSAMPLE = 4
SUPERSAMPLE_PLATE = 2
#: Supersampling factor of the textured plate (our choice: with a texture level of about one
#: texel per fine pixel, edges of the print are area-averaged over 2 x 2 samples).
SUPERSAMPLE_TEXTURE = 2
#: Fixed-point fraction bits of the polygon vertices passed to ``cv2.fillPoly`` (1/256 px).
_SHIFT = 8
#: Boundary points of the rotor silhouette.
_SILHOUETTE_POINTS = 256


def _noise_table() -> NDArray[np.float32]:
    """256 equiprobable standard-normal levels (the quantile midpoints), scaled to unit variance.

    Indexing it with uniform random bytes samples a 256-level discrete normal distribution
    (tails cut at 2.9 sigma) about ten times faster than ``Generator.standard_normal``.
    """
    nd = NormalDist()
    t = np.array([nd.inv_cdf((k + 0.5) / 256.0) for k in range(256)], dtype=np.float64)
    return (t / t.std()).astype(np.float32)


_NOISE_TABLE = _noise_table()


RotorPattern = Literal["none", "blotches", "stripes", "speckle", "checker"]


class AnalyticRenderOptions(BaseModel):
    """Camera effects and distractors of the analytic renderer. All defaults are our choice."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    noise_sigma_dn: float = Field(
        2.0,
        ge=0.0,
        description="Our choice: std of the Gaussian read noise in digital numbers "
        "(0-255 scale) before the gain; about 1 % of full scale, a machine-vision camera at "
        "low gain. Sampled from 256 equiprobable levels (tails cut at 2.9 sigma).",
    )
    gain: float = Field(
        1.0, gt=0.0, description="Our choice: sensor gain; multiplies signal and read noise."
    )
    illumination: float = Field(
        1.0, gt=0.0, description="Our choice: scale of the scene brightness (the ring light)."
    )
    motion_blur: bool = Field(
        True, description="Our choice: average sub-exposure renders when omega is given."
    )
    blur_step_px: float = Field(
        0.5,
        gt=0.0,
        description="Our choice: largest image-pixel step of a marker centre or "
        "plate corner between consecutive sub-exposure renders when n_sub is automatic.",
    )
    max_sub_frames: int = Field(
        32, ge=1, le=255, description="Our choice: cap on the automatic number of sub-frames."
    )
    n_highlights: int = Field(
        0,
        ge=0,
        le=32,
        description="Our choice: number of specular highlights (white blobs, "
        "fixed in the image like reflections of the stationary ring light).",
    )
    highlight_sigma_sensor_px: float = Field(
        24.0, gt=0.0, description="Our choice: Gaussian radius of a highlight, sensor pixels."
    )
    highlight_peak: float = Field(
        0.8,
        ge=0.0,
        le=2.0,
        description="Our choice: peak highlight brightness, fraction of "
        "full scale (before illumination and gain).",
    )
    colour_distractor: Literal["none", "red", "yellow"] = Field(
        "none",
        description="Our choice: a sticker of a marker's colour elsewhere on the rotor "
        "(35-60° from the bottom pole, azimuth drawn from the seed).",
    )
    distractor_diameter_mm: float = Field(
        8.0, gt=0.0, description="Our choice: the distractor sticker's diameter, mm."
    )
    texture: TextureParams | None = Field(
        None,
        description="A printed texture (``plant.texture``) on the bottom plate "
        "instead of the dark plate and the two markers; None (default) keeps the markers.",
    )
    # --- appearance (domain randomisation); the defaults draw the nominal scene ---------------
    rotor_rgb: tuple[float, float, float] | None = Field(
        None, description="Rotor colour, RGB in [0, 1]; None: ``plant.mjcf.ROTOR_RGB``."
    )
    plate_rgb: tuple[float, float, float] | None = Field(
        None, description="VFC plate colour, RGB in [0, 1]; None: ``plant.mjcf.PLATE_RGB``."
    )
    red_rgb: tuple[float, float, float] | None = Field(
        None, description="Main marker colour, RGB in [0, 1]; None: ``plant.mjcf.RED_RGB``."
    )
    yellow_rgb: tuple[float, float, float] | None = Field(
        None, description="Auxiliary marker colour, RGB in [0, 1]; None: ``YELLOW_RGB``."
    )
    distractor_rgb: tuple[float, float, float] | None = Field(
        None, description="Colour distractor's colour; None: the marker colour it imitates."
    )
    rotor_pattern: RotorPattern = Field(
        "none",
        description="A pattern on the rotor's surface around the plate (fixed in the image, "
        "drawn from the seed): smooth ``blotches``, ``stripes``, fine ``speckle`` or a "
        "``checker``; it multiplies the rotor colour by 1 + contrast x pattern.",
    )
    rotor_pattern_contrast: float = Field(
        0.3, ge=0.0, le=1.0, description="Amplitude of the rotor pattern (fraction of the colour)."
    )
    rotor_pattern_scale_px: float = Field(
        12.0, gt=0.0, description="Size of the pattern's features (period or blob radius), "
        "image px."
    )
    light_gradient: float = Field(
        0.0, ge=0.0, le=1.5, description="Linear illumination gradient: the brightness changes "
        "by this fraction from the frame's centre to its edge along ``light_gradient_angle_rad``."
    )
    light_gradient_angle_rad: float = Field(0.0, description="Direction of the gradient, rad.")
    vignetting: float = Field(
        0.0, ge=0.0, lt=1.0, description="Radial falloff: the brightness drops by this fraction "
        "from the centre to the frame's corners (quadratic in the radius)."
    )
    light_spot: float = Field(
        0.0, ge=0.0, le=3.0, description="An off-axis light: the brightness rises by this "
        "fraction at a spot drawn from the seed (Gaussian, ``light_spot_sigma_frac`` of the "
        "frame width)."
    )
    light_spot_sigma_frac: float = Field(0.25, gt=0.0, description="Radius of the light spot.")
    white_balance: tuple[float, float, float] = Field(
        (1.0, 1.0, 1.0), description="Per-channel gains (R, G, B) of the camera's white balance."
    )
    defocus_sigma_px: float = Field(
        0.0, ge=0.0, description="Gaussian defocus blur of the frame, image px (0: sharp)."
    )
    jpeg_quality: int | None = Field(
        None, ge=1, le=100, description="JPEG-compress each frame at this quality (None: off)."
    )


def _rgb255(rgb: tuple[float, float, float]) -> NDArray[np.float64]:
    return np.asarray(rgb, dtype=float) * 255.0


def _inset(polys: NDArray[np.float64], d: float) -> NDArray[np.float64]:
    """Move the vertices of closed polygons (k, n, 2) inward by ``d`` px along their normals."""
    return render_kernels.inset(np.ascontiguousarray(polys, dtype=float), float(d))


def polygon_coverage(
    poly_px: ArrayLike, width: int, height: int, supersample: int = SUPERSAMPLE
) -> tuple[tuple[slice, slice], NDArray[np.float32]] | None:
    """Pixel coverage of a closed polygon in a ``width`` x ``height`` image.

    ``poly_px`` (n, 2) are vertices in image pixels (OpenCV convention: integer coordinates
    are pixel centres). Returns the (rows, columns) slices of the polygon's bounding box and
    the coverage (fraction in [0, 1], float32) of each pixel in it, or None if the polygon is
    outside the image. The polygon is filled anti-aliased at ``supersample`` times the
    resolution and area-averaged down.
    """
    poly = np.asarray(poly_px, dtype=float)
    lo = np.floor(poly.min(axis=0)).astype(int) - 1
    hi = np.ceil(poly.max(axis=0)).astype(int) + 2
    x0, y0 = max(lo[0], 0), max(lo[1], 0)
    x1, y1 = min(hi[0], width), min(hi[1], height)
    if x1 <= x0 or y1 <= y0:
        return None
    ss = int(supersample)
    fine = (poly - [x0, y0] + 0.5) * ss - 0.5
    fine = _inset(fine[None], AA_GROWTH_PX)[0]
    mask = np.zeros(((y1 - y0) * ss, (x1 - x0) * ss), np.uint8)
    cv2.fillPoly(mask, [_fixed(fine)], 255, cv2.LINE_AA, _SHIFT)
    if ss > 1:
        mask = cv2.resize(mask, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
    return (slice(y0, y1), slice(x0, x1)), mask.astype(np.float32) * np.float32(1.0 / 255.0)


def jpeg_roundtrip(image: NDArray[np.uint8], quality: int | None) -> NDArray[np.uint8]:
    """``image`` (RGB uint8) JPEG-encoded at ``quality`` (1-100) and decoded, or unchanged for
    None: the blocking and ringing of a compressed video stream."""
    if quality is None:
        return image
    ok, buf = cv2.imencode(".jpg", image[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1])


def _fixed(uv: NDArray[np.float64]) -> NDArray[np.int32]:
    """Vertices as fixed-point integers with ``_SHIFT`` fraction bits for ``cv2.fillPoly``."""
    return np.round(uv * (1 << _SHIFT)).astype(np.int32)


def _pixel_rays(camera: Camera, binning: int) -> NDArray[np.float64]:
    """Unit viewing rays (H, W, 3) of the pixel centres in the camera frame."""
    width, height = camera.size(binning)
    u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    uv = np.stack([u, v], axis=-1).reshape(-1, 1, 2)
    xy = cv2.undistortPoints(
        uv, camera.matrix(binning), np.asarray(camera.params.dist_coeffs)
    ).reshape(height, width, 2)
    rays = np.concatenate([xy, np.ones((height, width, 1))], axis=-1)
    return rays / np.linalg.norm(rays, axis=-1, keepdims=True)


@functools.lru_cache(maxsize=8)
def _sphere_view(camera: Camera, binning: int) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
    """The rotor sphere as ``camera`` sees it at ``binning``: the coverage (H, W, 1) of its
    silhouette and the shading factor (H, W) of its surface. Geometry alone, so the renderers
    of a process share them (read-only arrays): computing them is about 40 ms, most of a
    renderer's construction."""
    width, height = camera.size(binning)
    r = camera.rotor_radius_m - 1e-3  # the sphere of plant.mjcf
    c = camera.to_camera_frame(np.zeros(3))[0]  # the rotor centre O, camera frame
    dist = float(np.linalg.norm(c))  # optical centre to O
    rays = _pixel_rays(camera, binning)
    b = rays @ c
    disc = np.maximum(b * b - (dist * dist - r * r), 0.0)
    t_hit = b - np.sqrt(disc)
    normal = (rays * t_hit[..., None] - c) / r
    cos = np.clip(-np.sum(normal * rays, axis=-1), 0.0, 1.0)
    shade = SHADE_AMBIENT + (1.0 - SHADE_AMBIENT) * cos
    # Silhouette: the circle where the viewing cone touches the sphere (stator frame): in
    # the plane normal to d (O toward the optical centre) at r²/dist from O.
    rho = r * np.sqrt(dist * dist - r * r) / dist
    d = camera.center_stator_m / dist
    e1 = np.cross(d, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    t = np.linspace(0.0, 2.0 * np.pi, _SILHOUETTE_POINTS, endpoint=False)
    rim = (r * r / dist) * d + rho * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)
    uv = camera.project(rim, binning)
    mask = np.zeros((height, width, 1), np.float32)
    cov = polygon_coverage(uv, width, height, SUPERSAMPLE_PLATE)
    if cov is not None:
        mask[cov[0]] = cov[1][..., None]
    mask.setflags(write=False)
    shade.setflags(write=False)
    return mask, shade


class AnalyticRenderer:
    """Render the bottom camera's view analytically.

    Parameters
    ----------
    params : PlantParams, optional
        Geometry of rotor, VFC and camera (default ``PlantParams()``).
    binning : int, optional
        Sensor pixels per image pixel (default ``params.camera.binning``); must divide both
        sensor sides.
    options : AnalyticRenderOptions, optional
        Camera effects and distractors (default: noise only, see the model).
    seed : int or numpy.random.Generator
        Seed (or generator) of the noise and of the distractor placement. The same seed and
        the same calls give identical frames.
    """

    def __init__(
        self,
        params: PlantParams | None = None,
        binning: int | None = None,
        options: AnalyticRenderOptions | None = None,
        seed: int | np.random.Generator = 0,
    ) -> None:
        self.params = params or PlantParams()
        self.binning = check_binning(self.params, binning)
        self.options = options or AnalyticRenderOptions()
        self.rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        self.camera = Camera.from_plant(self.params)
        self.width, self.height = self.camera.size(self.binning)
        self._plate = plate_outline_rotor(self.params)
        self._discs = disc_outlines_rotor(self.params)
        self.texture = None
        if self.options.texture is not None:
            if self.camera.roll_rad != 0.0:
                raise ValueError("camera.mount_roll_deg must be 0 with a texture: the textured "
                                 "plate is drawn for a camera without roll")
            self.texture = generate_texture(self.params, self.options.texture)
            self._plate = outline_rotor(self.texture)
            self._texture_level = self._choose_texture_level()
            self._undistort_fine: NDArray[np.float32] | None = None
        self._rotor_mask, self._background = self._draw_background()
        self._distractor = self._place_distractor()
        self._highlights = self._draw_highlights()
        self._light = self._lighting_map()
        self._noise_table = (self.options.noise_sigma_dn * _NOISE_TABLE).astype(np.float32)
        self._digitised_levels: NDArray[np.uint8] | None = None

    # --- static parts -----------------------------------------------------------------------
    def _draw_background(self) -> tuple[NDArray[np.float32], NDArray[np.uint8]]:
        """Coverage mask (H, W) of the rotor and the static image: housing plus shaded sphere."""
        mask, shade = _sphere_view(self.camera, self.binning)
        sphere = shade[..., None] * _rgb255(self.options.rotor_rgb or ROTOR_RGB)
        if self.options.rotor_pattern != "none":
            sphere = sphere * self._rotor_pattern()[..., None]
        img = mask * sphere + (1.0 - mask) * _rgb255(HOUSING_RGB)
        return mask[..., 0], np.clip(np.rint(img), 0, 255).astype(np.uint8)

    def _place_distractor(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """Outline (n, 3) in the rotor frame and RGB (0-255) of the colour distractor, or None."""
        o = self.options
        if o.colour_distractor == "none":
            return None
        r_s = self.params.rotor.radius_m - 1e-3
        theta = np.deg2rad(self.rng.uniform(35.0, 60.0))
        phi = self.rng.uniform(0.0, 2.0 * np.pi)
        n = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), -np.cos(theta)])
        e1 = np.cross(n, [0.0, 0.0, 1.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        t = np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False)[:, None]
        rad = o.distractor_diameter_mm / 2000.0
        outline = (r_s + 1e-4) * n + rad * (np.cos(t) * e1 + np.sin(t) * e2)
        rgb = RED_RGB if o.colour_distractor == "red" else YELLOW_RGB
        return outline, _rgb255(o.distractor_rgb or rgb)

    def _rotor_pattern(self) -> NDArray[np.float64]:
        """Multiplicative pattern (H, W) of the rotor surface, ``1 + contrast * p`` with p a
        zero-mean pattern of unit amplitude (``options.rotor_pattern``), clipped at 0.05."""
        o = self.options
        h, w, s = self.height, self.width, o.rotor_pattern_scale_px
        v, u = np.mgrid[0:h, 0:w].astype(np.float64)
        ang = self.rng.uniform(0.0, np.pi)
        along = u * np.cos(ang) + v * np.sin(ang)
        across = -u * np.sin(ang) + v * np.cos(ang)
        if o.rotor_pattern == "stripes":
            p = np.sin(2.0 * np.pi * along / s + self.rng.uniform(0.0, 2.0 * np.pi))
        elif o.rotor_pattern == "checker":
            p = np.sign(np.sin(np.pi * along / s) * np.sin(np.pi * across / s))
            p = cv2.GaussianBlur(p, (0, 0), 0.7)  # anti-aliased squares
        else:  # smooth blotches of radius s, or speckle one pixel wide
            sigma = s if o.rotor_pattern == "blotches" else 0.8
            p = cv2.GaussianBlur(self.rng.standard_normal((h, w)), (0, 0), sigma)
            p /= max(float(np.abs(p).max()), 1e-12)
        return np.maximum(1.0 + o.rotor_pattern_contrast * p, 0.05)

    def _lighting_map(self) -> NDArray[np.float32] | None:
        """Brightness factor (H, W, 3) of uneven lighting and white balance, or None if flat:
        the product of the gradient, the vignetting, the light spot and the channel gains."""
        o = self.options
        if not (o.light_gradient or o.vignetting or o.light_spot) and o.white_balance == (
            1.0, 1.0, 1.0
        ):
            return None
        h, w = self.height, self.width
        v, u = np.mgrid[0:h, 0:w].astype(np.float64)
        du, dv = u - (w - 1) / 2.0, v - (h - 1) / 2.0
        light = np.ones((h, w))
        if o.light_gradient:
            a = o.light_gradient_angle_rad
            light *= 1.0 + o.light_gradient * (du * np.cos(a) + dv * np.sin(a)) / (w / 2.0)
        if o.vignetting:
            light *= 1.0 - o.vignetting * (du * du + dv * dv) / ((w / 2.0) ** 2 + (h / 2.0) ** 2)
        if o.light_spot:
            c = self.rng.uniform([0.2 * w, 0.2 * h], [0.8 * w, 0.8 * h])
            sig = o.light_spot_sigma_frac * w
            r2 = (u - c[0]) ** 2 + (v - c[1]) ** 2
            light *= 1.0 + o.light_spot * np.exp(-r2 / (2.0 * sig * sig))
        light = np.maximum(light, 0.05)[..., None] * np.asarray(o.white_balance)
        return light.astype(np.float32)

    def _draw_highlights(self) -> NDArray[np.float32] | None:
        """Stationary specular highlights (H, W, 3) in DN at illumination 1, or None."""
        o = self.options
        if o.n_highlights == 0:
            return None
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(np.float32)
        cu, cv = (self.width - 1) / 2.0, (self.height - 1) / 2.0
        rim = float(np.hypot(*(np.argwhere(self._rotor_mask > 0.5) - [cv, cu]).T).max())
        sigma = o.highlight_sigma_sensor_px / self.binning
        acc = np.zeros((self.height, self.width), np.float32)
        for _ in range(o.n_highlights):
            rad, ang = 0.85 * rim * np.sqrt(self.rng.uniform()), self.rng.uniform(0, 2 * np.pi)
            du, dv = u - (cu + rad * np.cos(ang)), v - (cv + rad * np.sin(ang))
            acc += np.exp(-(du * du + dv * dv) / (2.0 * sigma * sigma))
        blob = 255.0 * o.highlight_peak * np.minimum(acc, 1.0) * self._rotor_mask
        return np.repeat(blob[..., None], 3, axis=2).astype(np.float32)

    # --- per frame ----------------------------------------------------------------------------
    def _shade(self, point: NDArray[np.float64], normal: NDArray[np.float64]) -> float:
        """Shading factor of a surface at ``point`` (stator frame, m) with unit ``normal``."""
        to_cam = self.camera.center_stator_m - point
        cos = max(float(normal @ to_cam / np.linalg.norm(to_cam)), 0.0)
        return SHADE_AMBIENT + (1.0 - SHADE_AMBIENT) * cos

    def _layers(self, qs: NDArray[np.float64]) -> list[tuple[NDArray, int, list]]:
        """The drawn layers in order (distractor, plate, red disc, yellow disc): each as RGB
        colour (3,), supersampling factor and its image polygon (n, 2) per sub-frame (None
        where the distractor faces away from the camera)."""
        R = attitude.to_matrix(qs)  # (n_sub, 3, 3)
        R_mid = R[len(qs) // 2]
        down = R_mid @ np.array([0.0, 0.0, -1.0])  # the plate's normal
        shade = self._shade(self.params.rotor.radius_m * down, down)
        o = self.options
        layers = [
            (self._plate, _rgb255(o.plate_rgb or PLATE_RGB) * shade, SUPERSAMPLE_PLATE),
            (self._discs[0], _rgb255(o.red_rgb or RED_RGB) * shade, SUPERSAMPLE),
            (self._discs[1], _rgb255(o.yellow_rgb or YELLOW_RGB) * shade, SUPERSAMPLE),
        ]
        if self.texture is not None:  # the print replaces plate colour and markers
            layers = [(self._plate, np.full(3, shade), SUPERSAMPLE_PLATE)]
        if self._distractor is not None:
            outline, rgb = self._distractor
            centre = R_mid @ outline.mean(axis=0)
            d_shade = self._shade(centre, centre / np.linalg.norm(centre))
            layers.insert(0, (outline, rgb * d_shade, SUPERSAMPLE))
        counts = [len(pts) for pts, _, _ in layers]
        stator = np.einsum("kij,nj->kni", R, np.vstack([pts for pts, _, _ in layers]))
        uv = self.camera.project(stator.reshape(-1, 3), self.binning).reshape(len(qs), -1, 2)
        per_layer = np.split(uv, np.cumsum(counts)[:-1], axis=1)
        out = []
        for li, ((_, colour, ss), polys) in enumerate(zip(layers, per_layer, strict=True)):
            polys = list(polys)
            if li == 0 and self._distractor is not None:
                for k in range(len(qs)):
                    centre = stator[k, : counts[0]].mean(axis=0)  # its normal is along centre
                    if centre @ (self.camera.center_stator_m - centre) <= 0.0:
                        polys[k] = None
            out.append((colour, ss, polys))
        return out

    def _draw_vfc(self, qs: NDArray[np.float64]) -> NDArray[np.uint8]:
        """Background with the plate, discs and distractor, motion-blurred over sub-frames ``qs``.

        Each layer's coverage is averaged over the sub-frames and the layers are composited
        once. That equals averaging composited sub-frames wherever a layer lies on a fully
        covered one (the discs on the plate); only where the distractor passes under the
        plate's edge is it an approximation.
        """
        img = self._background.copy()
        layers = self._layers(qs)
        textured = len(layers) - 1 if self.texture is not None else -1
        allpts = np.vstack([p for _, _, polys in layers for p in polys if p is not None])
        x0, y0 = np.maximum(np.floor(allpts.min(axis=0)).astype(int) - 2, 0)
        x1, y1 = np.ceil(allpts.max(axis=0)).astype(int) + 3
        x1, y1 = min(x1, self.width), min(y1, self.height)
        if x1 <= x0 or y1 <= y0:
            return img
        w, h = x1 - x0, y1 - y0
        roi = self._background[y0:y1, x0:x1].astype(np.float32)
        inv_n = np.float32(1.0 / len(qs))
        for li, (colour, ss, polys) in enumerate(layers):
            if li == textured:
                self._composite_texture(roi, (x0, y0), qs, polys, float(colour[0]))
                continue
            acc = np.zeros((h, w), np.float32)
            lo, hi = np.array([h, w]), np.array([0, 0])
            for poly in polys:
                cov = None if poly is None else polygon_coverage(poly - [x0, y0], w, h, ss)
                if cov is None:
                    continue
                (sy, sx), alpha = cov
                acc[sy, sx] += alpha
                lo = np.minimum(lo, [sy.start, sx.start])
                hi = np.maximum(hi, [sy.stop, sx.stop])
            if np.any(hi <= lo):
                continue
            box = (slice(lo[0], hi[0]), slice(lo[1], hi[1]))
            alpha = acc[box]
            alpha *= inv_n
            patch = roi[box]
            render_kernels.composite(patch, alpha, colour.astype(np.float32))  # in place
        img[y0:y1, x0:x1] = cv2.convertScaleAbs(roi)  # values are >= 0: rounds and saturates
        return img

    # --- textured plate ------------------------------------------------------------------------
    def _choose_texture_level(self) -> int:
        """Texels per side of the prefiltered texture level sampled when rendering: about one
        texel per supersampled pixel at the print's distance, never more than the print has."""
        cam, tex = self.camera, self.texture
        f_fine = cam.matrix(self.binning)[0, 0] * SUPERSAMPLE_TEXTURE  # fine px per rad
        distance = float(tex.z_m - cam.center_m[2])  # optical centre to the print at rest, m
        n = int(np.ceil(2.0 * tex.half_size_m / distance * f_fine))
        return int(min(tex.n, max(n, 16)))

    def _fine_to_normalised(self, origin: tuple[int, int]) -> NDArray[np.float64]:
        """3x3 matrix from the supersampled pixel grid of a region whose top-left image pixel
        is ``origin`` to normalised camera coordinates (ideal lens)."""
        ss = SUPERSAMPLE_TEXTURE
        off = 0.5 / ss - 0.5
        S = np.array(
            [[1.0 / ss, 0.0, origin[0] + off], [0.0, 1.0 / ss, origin[1] + off], [0.0, 0.0, 1.0]]
        )
        return np.linalg.inv(self.camera.matrix(self.binning)) @ S

    def _normalised_fine_grid(self) -> NDArray[np.float32]:
        """Undistorted normalised coordinates (H ss, W ss, 2) of the supersampled pixel grid of
        the whole frame (computed once, only for a distorted lens)."""
        if self._undistort_fine is None:
            ss = SUPERSAMPLE_TEXTURE
            u, v = np.meshgrid(
                (np.arange(self.width * ss) + 0.5) / ss - 0.5,
                (np.arange(self.height * ss) + 0.5) / ss - 0.5,
            )
            uv = np.stack([u, v], axis=-1).reshape(-1, 1, 2)
            xy = cv2.undistortPoints(
                uv, self.camera.matrix(self.binning), np.asarray(self.camera.params.dist_coeffs)
            )
            self._undistort_fine = xy.reshape(self.height * ss, self.width * ss, 2).astype(
                np.float32
            )
        return self._undistort_fine

    def _warp_texture(
        self, q: NDArray[np.float64], origin: tuple[int, int], size: tuple[int, int]
    ) -> NDArray[np.float32]:
        """The print as seen at attitude ``q`` over an image region (``size`` = (w, h) image
        px, top-left pixel ``origin``): RGB float32 (h, w, 3), unshaded, at image resolution."""
        ss = SUPERSAMPLE_TEXTURE
        n = self._texture_level
        tex = self.texture.resampled(n)
        G = plane_homography(self.texture, attitude.to_matrix(q), self.camera.center_m, n)
        w_f, h_f = size[0] * ss, size[1] * ss
        if not np.any(self.camera.params.dist_coeffs):
            M = G @ self._fine_to_normalised(origin)  # fine pixel -> texel
            fine = cv2.warpPerspective(
                tex,
                M,
                (w_f, h_f),
                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_REPLICATE,
            )
        else:
            xy = self._normalised_fine_grid()[
                origin[1] * ss : origin[1] * ss + h_f, origin[0] * ss : origin[0] * ss + w_f
            ]
            den = G[2, 0] * xy[..., 0] + G[2, 1] * xy[..., 1] + G[2, 2]
            mx = (G[0, 0] * xy[..., 0] + G[0, 1] * xy[..., 1] + G[0, 2]) / den
            my = (G[1, 0] * xy[..., 0] + G[1, 1] * xy[..., 1] + G[1, 2]) / den
            fine = cv2.remap(
                tex,
                mx.astype(np.float32),
                my.astype(np.float32),
                cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_REPLICATE,
            )
        out = cv2.resize(fine, size, interpolation=cv2.INTER_AREA) if ss > 1 else fine
        return out.astype(np.float32)

    def _composite_texture(
        self,
        roi: NDArray[np.float32],
        origin: tuple[int, int],
        qs: NDArray[np.float64],
        polys: list,
        shade: float,
    ) -> None:
        """Composite the print over ``roi`` (float32 RGB, top-left image pixel ``origin``) in
        place, averaged over the sub-frame attitudes ``qs`` whose outlines are ``polys``
        (image px): ``roi = roi (1 - mean coverage) + shade * mean(coverage * texture)``."""
        h, w = roi.shape[:2]
        x0, y0 = origin
        alpha_acc = np.zeros((h, w), np.float32)
        colour_acc = np.zeros((h, w, 3), np.float32)
        for q, poly in zip(qs, polys, strict=True):
            cov = polygon_coverage(poly - [x0, y0], w, h, SUPERSAMPLE_PLATE)
            if cov is None:
                continue
            (sy, sx), alpha = cov
            tex = self._warp_texture(
                q, (x0 + sx.start, y0 + sy.start), (alpha.shape[1], alpha.shape[0])
            )
            alpha_acc[sy, sx] += alpha
            colour_acc[sy, sx] += tex * alpha[..., None]
        inv_n = np.float32(1.0 / len(qs))
        alpha_acc *= inv_n
        colour_acc *= np.float32(shade) * inv_n
        roi *= (1.0 - alpha_acc)[..., None]
        roi += colour_acc

    def _camera_effects(self, img: NDArray[np.uint8]) -> NDArray[np.uint8]:
        """Highlights, illumination (and its unevenness), defocus, read noise, gain and JPEG
        compression; back to uint8 with saturation."""
        o = self.options
        # each output byte a function of its drawn byte (and noise byte) alone
        by_value = self._highlights is None and self._light is None and not o.defocus_sigma_px
        if by_value and o.noise_sigma_dn == 0.0 and o.illumination == 1.0 and o.gain == 1.0:
            return jpeg_roundtrip(img, o.jpeg_quality)
        if by_value and o.noise_sigma_dn > 0.0:
            raw = np.frombuffer(self.rng.bytes(img.size), dtype=np.uint8)
            out = render_kernels.digitised_by_levels(img.ravel(), raw, self._levels())
            return jpeg_roundtrip(out.reshape(img.shape), o.jpeg_quality)
        none = np.empty(0, np.float32)
        f = render_kernels.exposed(
            img.ravel(), none if self._highlights is None else self._highlights.ravel(),
            o.illumination, none if self._light is None else self._light.ravel())
        if o.defocus_sigma_px:
            f = cv2.GaussianBlur(f.reshape(img.shape), (0, 0), o.defocus_sigma_px).ravel()
        raw = np.empty(0, np.uint8)
        if o.noise_sigma_dn > 0.0:
            raw = np.frombuffer(self.rng.bytes(f.size), dtype=np.uint8)
        out = render_kernels.digitised(f, raw, self._noise_table, o.gain).reshape(img.shape)
        return jpeg_roundtrip(out, o.jpeg_quality)

    def _levels(self) -> NDArray[np.uint8]:
        """The table of output bytes by frame value and noise byte
        (``render_kernels.digitised_levels``), computed on first use."""
        if self._digitised_levels is None:
            o = self.options
            self._digitised_levels = render_kernels.digitised_levels(
                self._noise_table, o.illumination, o.gain)
        return self._digitised_levels

    def render(
        self,
        q: ArrayLike,
        t_exposure: float = 0.0,
        exposure_s: float | None = None,
        omega: ArrayLike | None = None,
        *,
        n_sub: int | None = None,
    ) -> Frame:
        """Render one frame.

        Parameters
        ----------
        q : array_like (4,)
            Mid-exposure attitude (w, x, y, z; rotor to stator).
        t_exposure : float
            Mid-exposure time, s (recorded in the frame).
        exposure_s : float, optional
            Exposure time, s (default ``params.camera.exposure_s``).
        omega : array_like (3,), optional
            Body-frame angular velocity, rad/s, held over the exposure (default: at rest).
        n_sub : int, optional
            Sub-exposure renders to average; default automatic from the image travel of the
            markers and plate corners (``options.blur_step_px``), 1 without motion.

        Returns
        -------
        Frame
            RGB image and full-sensor ground truth at mid-exposure.
        """
        q = attitude.normalize(q)
        t, e, w = check_exposure(self.params, t_exposure, exposure_s, omega)
        if n_sub is None:
            n = 1
            if self.options.motion_blur:
                travel = vfc_pixel_travel(self.params, q, w, e, self.binning)
                n = choose_n_sub(travel, self.options.blur_step_px, self.options.max_sub_frames)
        else:
            if isinstance(n_sub, bool) or int(n_sub) != n_sub or not 1 <= n_sub <= 255:
                raise ValueError(f"n_sub must be an integer in [1, 255], got {n_sub!r}")
            n = int(n_sub)
        qs = sub_exposure_attitudes(q, w, e, n)
        img = self._camera_effects(self._draw_vfc(qs))
        marker_px, boxes_px = ground_truth(self.params, q)
        return Frame(img, marker_px, boxes_px, q, t, e, self.binning, n)
