"""A second, independent image source for evaluation only: MuJoCo with drawn looks and a sensor.

The TransT network is trained on ``plant.render_analytic`` crops
(``observer/transt/training/data.py``). Its accuracy on those renders says little about frames
from elsewhere, so this module makes frames the training never saw: the scene of ``plant.mjcf``
rendered by MuJoCo (OpenGL shading, specular highlights, textures, several coloured lights) with
materials, lights and backgrounds drawn from wide ranges (``draw_look``), then passed through a
model of a colour sensor and its processing chain (``SensorLook``): vignetting, a Bayer mosaic
with shot and read noise, OpenCV's demosaicing, colour crosstalk and white balance, a gamma
curve, a rolling shutter and JPEG compression.

**Never train on it.** ``observer/transt`` must not import this module (a test scans the
training code's imports); its seeds are the tracking benchmark's validation seeds.

Drawn per look (all ranges our choice, wide on purpose):

* rotor shell: a MuJoCo builtin texture (flat, checker or gradient, with random, edge or cross
  marks) of two random colours (value 0.15-0.9), specular 0-0.8, shininess 0-1, reflectance
  0-0.3; VFC plate: dark to mid grey (value 0.02-0.45), specular 0-1;
* markers: the project's red and yellow with hue ±6°, saturation ±15 %, value -35 %/+5 %,
  specular 0-1 (glossy stickers catch highlights);
* lights: headlight ambient 0.1-0.5 and diffuse 0.1-0.5, the ring of ``plant.mjcf`` scaled by
  0-2.5 with a colour temperature tint, one to three extra lights (directional or spot, from a
  random direction below the rotor, tinted, diffuse 0.1-0.9, specular 0-1, shadows on or
  off); the skybox a random gradient.

Sensor (``SensorLook``, drawn per look; noise per frame): exposure gain 0.4-1.6; a lens
defocus (Gaussian, sigma 0-1.2 image px); vignetting
losing 0-50 % at the frame corner about a centre off by up to 10 % of the frame; the image
taken as linear light (render value ^ 2.2), mosaicked in one of the four Bayer layouts, shot
noise (full well 200-2000 electrons per DN-equivalent unit) and read noise 0.5-6 DN at 8 bits,
demosaiced by OpenCV (bilinear, VNG or edge-aware), a colour matrix with crosstalk ±10 %,
white balance ±15 %, an output gamma 1.6-2.8; a rolling shutter reading the frame out top to
bottom in 0-25 ms; JPEG at quality 25-95 (80 % of looks) or none.

**Ground truth** (``Frame.marker_px``, ``boxes_px``) follows the rolling shutter: each marker
at the attitude of the moment its row was read (the row of its centre), by ``plant.scene``'s
projection of the 3-D discs, full-sensor px; without a rolling shutter, the mid-exposure truth
of the other renderers.

OpenGL backend: as ``plant.render_mujoco`` (``MUJOCO_GL=egl`` unless set before import).
**Exposure and readout**: a frame is rendered at K moments spread evenly over the time in
which any row is exposed (the readout plus the exposure; K from the markers' travel in that
time, one render per ``BLUR_STEP_PX``, at most ``MAX_RENDERS``); each row averages, in linear
light, the renders that fall inside its own exposure window (``_row_weights``), so motion blur
and the rolling shutter come from the same renders.
"""

from __future__ import annotations

import colorsys
import os

os.environ.setdefault("MUJOCO_GL", "egl")

import cv2  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import ArrayLike, NDArray  # noqa: E402
from pydantic import BaseModel, ConfigDict, Field  # noqa: E402

from plant import attitude  # noqa: E402
from plant.camera import sensor_to_image  # noqa: E402
from plant.mjcf import RED_RGB, YELLOW_RGB, build_mjcf  # noqa: E402
from plant.params import PlantParams  # noqa: E402
from plant.render_analytic import jpeg_roundtrip  # noqa: E402
from plant.render_mujoco import MujocoRenderer  # noqa: E402
from plant.scene import (  # noqa: E402
    Frame,
    check_exposure,
    choose_n_sub,
    ground_truth,
    vfc_pixel_travel,
)

#: OpenCV Bayer-to-RGB codes per layout (the layout names the 2 x 2 cell's top-left pair) and
#: demosaicing algorithm.
_BAYER = ("RG", "BG", "GR", "GB")
_DEMOSAIC = {
    "bilinear": {b: getattr(cv2, f"COLOR_Bayer{b}2BGR") for b in _BAYER},
    "vng": {b: getattr(cv2, f"COLOR_Bayer{b}2BGR_VNG") for b in _BAYER},
    "edge_aware": {b: getattr(cv2, f"COLOR_Bayer{b}2BGR_EA") for b in _BAYER},
}
#: Largest image-px step of the markers between the renders of one frame (exposure and
#: readout together), and the cap on those renders (our choices: each costs a MuJoCo render).
BLUR_STEP_PX = 1.5
MAX_RENDERS = 8


class SensorLook(BaseModel):
    """The camera's sensor and processing chain (drawn by ``draw_look``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    gain: float = Field(1.0, gt=0.0, description="Exposure gain on linear light.")
    defocus_px: float = Field(0.0, ge=0.0, description="Lens defocus: Gaussian sigma, image px.")
    vignetting: float = Field(0.0, ge=0.0, lt=1.0,
                              description="Fraction of light lost at the frame corner.")
    vignetting_centre: tuple[float, float] = Field(
        (0.5, 0.5), description="Centre of the vignetting, fractions of width and height.")
    bayer: str = Field("RG", description="Bayer layout: RG, BG, GR or GB.")
    demosaic: str = Field("bilinear", description="bilinear, vng or edge_aware (OpenCV).")
    full_well: float = Field(1000.0, gt=0.0,
                             description="Electrons per unit of linear light (shot noise).")
    read_noise_dn: float = Field(1.0, ge=0.0, description="Read noise, DN at 8 bits.")
    colour_matrix: tuple[tuple[float, float, float], ...] = Field(
        ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
        description="Colour matrix (rows sum to 1) applied after demosaicing.")
    white_balance: tuple[float, float, float] = Field((1.0, 1.0, 1.0),
                                                      description="Per-channel gains.")
    gamma: float = Field(2.2, gt=0.0, description="Output gamma (encoding exponent 1/gamma).")
    readout_s: float = Field(0.0, ge=0.0, description="Rolling-shutter readout time, s.")
    jpeg_quality: int | None = Field(None, ge=1, le=100, description="JPEG quality or None.")


class UnseenLook(BaseModel):
    """Scene materials and lights (MuJoCo) and the sensor of one drawn look."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    shell_texture: str = Field("flat", description="MuJoCo builtin: flat, checker, gradient.")
    shell_mark: str = Field("none", description="MuJoCo texture mark: none, random, edge, cross.")
    shell_rgb1: tuple[float, float, float] = (0.55, 0.56, 0.58)
    shell_rgb2: tuple[float, float, float] = (0.45, 0.46, 0.48)
    shell_mark_rgb: tuple[float, float, float] = (0.3, 0.3, 0.3)
    shell_texrepeat: float = Field(4.0, gt=0.0, description="Texture repeats over the shell.")
    shell_specular: float = 0.0
    shell_shininess: float = 0.5
    shell_reflectance: float = 0.0
    plate_rgb: tuple[float, float, float] = (0.08, 0.08, 0.09)
    plate_specular: float = 0.0
    red_rgb: tuple[float, float, float] = RED_RGB
    yellow_rgb: tuple[float, float, float] = YELLOW_RGB
    marker_specular: float = 0.0
    marker_shininess: float = 0.5
    head_ambient: float = 0.42
    head_diffuse: float = 0.30
    ring_scale: float = 1.0
    ring_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    extra_lights: tuple[tuple[float, ...], ...] = Field(
        (), description="Extra lights: (directional 0/1, dir x, y, z, r, g, b diffuse, "
        "specular, castshadow 0/1, cutoff deg).")
    sky_rgb1: tuple[float, float, float] = (0.2, 0.2, 0.2)
    sky_rgb2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sensor: SensorLook = SensorLook()


def _tint(rng: np.random.Generator) -> NDArray[np.float64]:
    """A light's colour: warm to cool (red/blue ratio 0.75-1.3), green 1."""
    k = float(np.exp(rng.uniform(np.log(0.75), np.log(1.3))))
    return np.array([k, 1.0, 1.0 / k]) / max(k, 1.0 / k, 1.0)


def _rand_rgb(rng: np.random.Generator, v: tuple[float, float],
              s: tuple[float, float] = (0.0, 0.6)) -> tuple[float, float, float]:
    r, g, b = colorsys.hsv_to_rgb(rng.uniform(), rng.uniform(*s), rng.uniform(*v))
    return float(r), float(g), float(b)


def _marker_shade(rgb: tuple[float, float, float], rng: np.random.Generator
                  ) -> tuple[float, float, float]:
    h, s, v = colorsys.rgb_to_hsv(*rgb)
    h = (h + rng.uniform(-6.0, 6.0) / 360.0) % 1.0
    s = float(np.clip(s * rng.uniform(0.85, 1.15), 0.0, 1.0))
    v = float(np.clip(v * rng.uniform(0.65, 1.05), 0.0, 1.0))
    r, g, b = colorsys.hsv_to_rgb(h, s, v)
    return float(r), float(g), float(b)


def draw_look(rng: np.random.Generator) -> UnseenLook:
    """A look drawn from the module docstring's ranges."""
    u = rng.uniform
    lights = []
    for _ in range(int(rng.integers(1, 4))):
        d = rng.normal(size=3)
        d[2] = abs(d[2]) + 0.5  # shining up at the rotor from below (the camera's side)
        d /= np.linalg.norm(d)
        lights.append((float(u() < 0.5), *d.tolist(), *(u(0.1, 0.9) * _tint(rng)).tolist(),
                       u(0.0, 1.0), float(u() < 0.5), u(20.0, 60.0)))
    cross = rng.normal(0.0, 0.05, size=(3, 3))
    np.fill_diagonal(cross, 0.0)
    cm = np.eye(3) + cross - np.diag(cross.sum(axis=1))
    sensor = SensorLook(
        gain=u(0.4, 1.6),
        defocus_px=u(0.0, 1.2),
        vignetting=u(0.0, 0.5),
        vignetting_centre=(u(0.4, 0.6), u(0.4, 0.6)),
        bayer=_BAYER[int(rng.integers(4))],
        demosaic=tuple(_DEMOSAIC)[int(rng.integers(3))],
        full_well=float(np.exp(u(np.log(200.0), np.log(2000.0)))),
        read_noise_dn=u(0.5, 6.0),
        colour_matrix=tuple(tuple(float(x) for x in row) for row in np.clip(cm, -0.2, 1.2)),
        white_balance=tuple(float(x) for x in u(0.85, 1.15, 3)),
        gamma=u(1.6, 2.8),
        readout_s=u(0.0, 0.025),
        jpeg_quality=int(rng.integers(25, 96)) if u() < 0.8 else None,
    )
    return UnseenLook(
        shell_texture=("flat", "checker", "gradient")[int(rng.integers(3))],
        shell_mark=("none", "random", "edge", "cross")[int(rng.integers(4))],
        shell_rgb1=_rand_rgb(rng, (0.15, 0.9)),
        shell_rgb2=_rand_rgb(rng, (0.15, 0.9)),
        shell_mark_rgb=_rand_rgb(rng, (0.0, 1.0)),
        shell_texrepeat=float(np.exp(u(np.log(1.0), np.log(30.0)))),
        shell_specular=u(0.0, 0.8),
        shell_shininess=u(0.0, 1.0),
        shell_reflectance=u(0.0, 0.3),
        plate_rgb=_rand_rgb(rng, (0.02, 0.45), (0.0, 0.4)),
        plate_specular=u(0.0, 1.0),
        red_rgb=_marker_shade(RED_RGB, rng),
        yellow_rgb=_marker_shade(YELLOW_RGB, rng),
        marker_specular=u(0.0, 1.0),
        marker_shininess=u(0.1, 1.0),
        head_ambient=u(0.1, 0.5),
        head_diffuse=u(0.1, 0.5),
        ring_scale=u(0.0, 2.5),
        ring_tint=tuple(_tint(rng).tolist()),
        extra_lights=tuple(lights),
        sky_rgb1=_rand_rgb(rng, (0.0, 0.8)),
        sky_rgb2=_rand_rgb(rng, (0.0, 0.8)),
        sensor=sensor,
    )


def _spec(params: PlantParams, look: UnseenLook) -> mujoco.MjSpec:
    """The project's MJCF with the look's materials, textures and lights."""
    spec = mujoco.MjSpec.from_string(build_mjcf(params))
    # builtin textures and the skybox
    builtin = getattr(mujoco.mjtBuiltin, f"mjBUILTIN_{look.shell_texture.upper()}")
    mark = getattr(mujoco.mjtMark, f"mjMARK_{look.shell_mark.upper()}")
    tex = spec.add_texture(name="shell_tex", type=mujoco.mjtTexture.mjTEXTURE_CUBE,
                           builtin=builtin, mark=mark, width=256, height=256)
    tex.rgb1, tex.rgb2, tex.markrgb = look.shell_rgb1, look.shell_rgb2, look.shell_mark_rgb
    tex.random = 0.05
    sky = spec.add_texture(name="sky", type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
                           builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT, width=64, height=64)
    sky.rgb1, sky.rgb2 = look.sky_rgb1, look.sky_rgb2
    mat = spec.add_material(name="shell_mat", specular=look.shell_specular,
                            shininess=look.shell_shininess, reflectance=look.shell_reflectance,
                            texrepeat=[look.shell_texrepeat] * 2)
    mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "shell_tex"
    geoms = {g.name: g for g in spec.geoms}
    geoms["shell"].material = "shell_mat"
    geoms["shell"].rgba = [1.0, 1.0, 1.0, 1.0]
    for name, rgb, spc, shin in (("vfc_plate", look.plate_rgb, look.plate_specular, 0.3),
                                 ("marker_red", look.red_rgb, look.marker_specular,
                                  look.marker_shininess),
                                 ("marker_yellow", look.yellow_rgb, look.marker_specular,
                                  look.marker_shininess)):
        spec.add_material(name=f"{name}_mat", specular=spc, shininess=shin, rgba=[*rgb, 1.0])
        geoms[name].material = f"{name}_mat"
    # lights: the headlight, the ring of plant.mjcf, extra ones
    spec.visual.headlight.ambient = [look.head_ambient] * 3
    spec.visual.headlight.diffuse = [look.head_diffuse] * 3
    for light in spec.lights:
        light.diffuse = np.asarray(light.diffuse) * look.ring_scale * np.asarray(look.ring_tint)
    for k, (directional, dx, dy, dz, r, g, b, specular, shadow, cutoff) in enumerate(
            look.extra_lights):
        d = np.array([dx, dy, dz])
        spec.worldbody.add_light(
            name=f"extra{k}", pos=-0.35 * d,
            dir=d, diffuse=[r, g, b], specular=[specular] * 3, castshadow=bool(shadow),
            type=(mujoco.mjtLightType.mjLIGHT_DIRECTIONAL if directional
                  else mujoco.mjtLightType.mjLIGHT_SPOT),
            cutoff=cutoff)
    return spec


class UnseenRenderer:
    """Frames of the bottom camera from MuJoCo in a drawn look, through a sensor model.

    Parameters
    ----------
    params : PlantParams, optional
        Geometry of rotor, VFC and camera (default ``PlantParams()``).
    look : UnseenLook
        Materials, lights and sensor (``draw_look``).
    seed : int or numpy Generator
        Sensor noise.
    binning : int, optional
        Sensor pixels per image pixel (default the camera's).

    The scene is rendered by ``plant.render_mujoco.MujocoRenderer`` (its motion blur, lens
    distortion and intrinsics) with the look's model. Holds an OpenGL context: call
    ``close()`` or use it as a context manager.
    """

    def __init__(self, params: PlantParams | None = None, look: UnseenLook | None = None,
                 seed: int | np.random.Generator = 0, binning: int | None = None) -> None:
        self.params = params or PlantParams()
        self.look = look or UnseenLook()
        self.rng = np.random.default_rng(seed)
        self._mujoco = MujocoRenderer(self.params, binning,
                                      model=_spec(self.params, self.look).compile())
        self.binning = self._mujoco.binning
        self.width, self.height = self._mujoco.width, self._mujoco.height
        s = self.look.sensor
        yy, xx = np.mgrid[0:self.height, 0:self.width].astype(np.float32)
        cx, cy = s.vignetting_centre[0] * self.width, s.vignetting_centre[1] * self.height
        r2 = ((xx - cx) ** 2 + (yy - cy) ** 2) / (0.25 * (self.width**2 + self.height**2))
        self._vignette = (1.0 - s.vignetting * np.clip(r2, 0.0, 1.5))[..., None]
        self._mosaic = self._bayer_masks(s.bayer)

    def _bayer_masks(self, layout: str) -> NDArray[np.bool_]:
        """(H, W, 3) masks of the colour each photosite sees for a Bayer ``layout``."""
        idx = {"R": 0, "G": 1, "B": 2}
        cell = {"RG": "RGGB", "BG": "BGGR", "GR": "GRBG", "GB": "GBRG"}[layout]
        m = np.zeros((self.height, self.width, 3), bool)
        for k, (dy, dx) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
            m[dy::2, dx::2, idx[cell[k]]] = True
        return m

    def _sensor(self, light: NDArray[np.float32]) -> NDArray[np.uint8]:
        """Defocus, vignetting, mosaic with noise, demosaicing, colour, gamma and JPEG on
        linear light."""
        s = self.look.sensor
        if s.defocus_px > 0:
            light = cv2.GaussianBlur(light, (0, 0), s.defocus_px)
        lin = np.clip(light * self._vignette * s.gain, 0.0, None)
        raw = lin[self._mosaic].reshape(self.height, self.width)
        raw = raw + self.rng.normal(size=raw.shape).astype(np.float32) * np.sqrt(
            raw / s.full_well)
        raw8 = np.clip(raw, 0.0, None) ** (1.0 / 2.2) * 255.0 + self.rng.normal(
            0.0, s.read_noise_dn, raw.shape).astype(np.float32)
        bayer = np.clip(np.rint(raw8), 0, 255).astype(np.uint8)
        rgb = cv2.cvtColor(bayer, _DEMOSAIC[s.demosaic][s.bayer]).astype(np.float32) / 255.0
        rgb = rgb**2.2 @ np.asarray(s.colour_matrix, np.float32).T
        rgb *= np.asarray(s.white_balance, np.float32)
        out = np.clip(rgb, 0.0, 1.0) ** (1.0 / s.gamma)
        img = np.clip(np.rint(out * 255.0), 0, 255).astype(np.uint8)
        return jpeg_roundtrip(img, s.jpeg_quality)

    def _row_time(self, row_img: float) -> float:
        """Time offset (s) from mid-frame of the readout of image row ``row_img``."""
        return (row_img / max(self.height - 1, 1) - 0.5) * self.look.sensor.readout_s

    def _row_weights(self, exposure_s: float, n: int) -> tuple[NDArray[np.float64],
                                                               NDArray[np.float32]]:
        """The ``n`` render moments (s from mid-frame) and the (H, n) weights of each row: the
        overlap of the row's exposure window with each moment's slice of the whole span,
        over the exposure (rows sum to 1; all on the middle render when nothing moves)."""
        span = self.look.sensor.readout_s + exposure_s
        if n == 1 or span == 0.0:
            return np.zeros(1), np.ones((self.height, 1), np.float32)
        edges = np.linspace(-span / 2, span / 2, n + 1)
        t_row = self._row_time(np.arange(self.height, dtype=float))[:, None]
        lo = np.maximum(edges[None, :-1], t_row - exposure_s / 2)
        hi = np.minimum(edges[None, 1:], t_row + exposure_s / 2)
        overlap = np.clip(hi - lo, 0.0, None)
        if exposure_s == 0.0:  # a sharp row: the slice that holds its moment
            overlap = ((edges[None, :-1] <= t_row) & (t_row < edges[None, 1:])).astype(float)
            overlap[:, -1] += (t_row[:, 0] >= edges[-1])
        w = overlap / overlap.sum(axis=1, keepdims=True)
        return 0.5 * (edges[:-1] + edges[1:]), w.astype(np.float32)

    def render(self, q: ArrayLike, t_exposure: float = 0.0, exposure_s: float | None = None,
               omega: ArrayLike | None = None) -> Frame:
        """Render one frame (arguments as ``plant.render_mujoco.MujocoRenderer.render``: the
        attitude at mid-frame; the body rate held over the readout and the exposure).
        ``Frame.n_sub`` is the number of renders."""
        q = attitude.normalize(q)
        t, e, w = check_exposure(self.params, t_exposure, exposure_s, omega)

        def at(dt: float) -> NDArray[np.float64]:
            return attitude.multiply(q, attitude.from_rotvec(w * dt))

        span = self.look.sensor.readout_s + e
        n = 1
        if span > 0 and np.any(w):
            travel = vfc_pixel_travel(self.params, q, w, span, self.binning)
            n = choose_n_sub(travel, BLUR_STEP_PX, MAX_RENDERS)
        moments, weights = self._row_weights(e, n)
        lin = np.zeros((self.height, self.width, 3), np.float32)
        for k, dt in enumerate(moments):
            img = self._mujoco.render(at(float(dt)), t, e, w, n_sub=1).image
            lin += weights[:, k, None, None] * (img.astype(np.float32) / 255.0) ** 2.2
        image = self._sensor(lin)
        marker, boxes = ground_truth(self.params, q)
        if self.look.sensor.readout_s > 0 and np.any(w):  # each marker when its row was read
            for m in range(2):
                for _ in range(2):
                    row = sensor_to_image(marker[m], self.binning)[1]
                    mk, bx = ground_truth(self.params, at(self._row_time(row)))
                    marker[m], boxes[m] = mk[m], bx[m]
        return Frame(np.ascontiguousarray(image), marker, boxes, q, t, e, self.binning, n)

    def close(self) -> None:
        """Free the OpenGL context (idempotent)."""
        self._mujoco.close()

    def __enter__(self) -> UnseenRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
