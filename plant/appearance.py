"""Appearance families of the analytic renderer's scene, for domain randomisation.

A tracker trained on one look of the rotor does not hold on another (a textured or unevenly lit
rotor, other marker shades, a finger over a marker). This module draws scene appearances from
named *families*, so training data can cover some families and evaluation can use families the
training never saw:

* rotor patterns (``AnalyticRenderOptions.rotor_pattern``): ``none``, ``blotches``,
  ``stripes``, ``speckle``, ``checker``;
* lighting: ``flat``, ``gradient`` (a linear brightness ramp), ``vignetting``, ``spot`` (an
  off-axis light making one region up to 2.5x brighter);
* occluder colours (``OCCLUDER_HSV``): ``dark``, ``grey``, ``white``, ``skin``, ``red_brown``,
  ``blue``, ``green``, ``purple``.

Within a family the draws vary the rotor, plate and marker colours (marker hue ±8°, saturation
and value ±15 %, all inside the seed's HSV gates of 000 §3.2.1 after shading), white balance
(±10 % per channel), specular highlights (0-4), a red or yellow distractor sticker of another
shade and size, read noise, and the marker diameter (6.5-9.5 mm, via ``PlantParams``). All
ranges are our choice.
"""

from __future__ import annotations

import colorsys
from typing import Literal

import numpy as np

from plant.mjcf import RED_RGB, YELLOW_RGB
from plant.params import PlantParams
from plant.render_analytic import AnalyticRenderOptions, RotorPattern

Lighting = Literal["flat", "gradient", "vignetting", "spot"]
OccluderFamily = Literal["dark", "grey", "white", "skin", "red_brown", "blue", "green", "purple"]

PATTERNS: tuple[RotorPattern, ...] = ("none", "blotches", "stripes", "speckle", "checker")
LIGHTINGS: tuple[Lighting, ...] = ("flat", "gradient", "vignetting", "spot")
#: HSV ranges (hue in degrees, saturation and value in [0, 1]) of the occluder families; skin
#: spans light to dark complexions, red-brown is a dark red object (wood, leather, a sleeve).
OCCLUDER_HSV: dict[OccluderFamily, tuple[tuple[float, float], ...]] = {
    "dark": ((0.0, 360.0), (0.0, 0.2), (0.0, 0.15)),
    "grey": ((0.0, 360.0), (0.0, 0.1), (0.2, 0.8)),
    "white": ((0.0, 360.0), (0.0, 0.08), (0.85, 1.0)),
    "skin": ((5.0, 30.0), (0.25, 0.6), (0.35, 0.95)),
    "red_brown": ((355.0, 375.0), (0.55, 0.9), (0.3, 0.6)),
    "blue": ((200.0, 240.0), (0.4, 0.9), (0.3, 0.9)),
    "green": ((90.0, 150.0), (0.4, 0.9), (0.3, 0.9)),
    "purple": ((265.0, 320.0), (0.35, 0.85), (0.3, 0.85)),
}
OCCLUDER_FAMILIES: tuple[OccluderFamily, ...] = tuple(OCCLUDER_HSV)
#: Appearance families never used for training, kept for evaluation (chosen before training):
#: a checkerboard rotor pattern, an off-axis light spot, purple occluders.
HELD_OUT_PATTERN = "checker"
HELD_OUT_LIGHTING = "spot"
HELD_OUT_OCCLUDER = "purple"
TRAIN_PATTERNS = tuple(p for p in PATTERNS if p != HELD_OUT_PATTERN)
TRAIN_LIGHTINGS = tuple(x for x in LIGHTINGS if x != HELD_OUT_LIGHTING)
TRAIN_OCCLUDERS = tuple(f for f in OCCLUDER_FAMILIES if f != HELD_OUT_OCCLUDER)


def occluder_rgb(rng: np.random.Generator, family: OccluderFamily) -> tuple[int, int, int]:
    """An occluder colour (RGB uint8 values) drawn from ``family``'s HSV ranges."""
    (h0, h1), (s0, s1), (v0, v1) = OCCLUDER_HSV[family]
    h = (rng.uniform(h0, h1) % 360.0) / 360.0
    r, g, b = colorsys.hsv_to_rgb(h, rng.uniform(s0, s1), rng.uniform(v0, v1))
    return int(round(255 * r)), int(round(255 * g)), int(round(255 * b))


def _shade_of(rgb: tuple[float, float, float], rng: np.random.Generator) -> tuple[float, ...]:
    """``rgb`` with its hue moved by up to ±8° and saturation and value scaled by ±15 %."""
    h, s, v = colorsys.rgb_to_hsv(*rgb)
    h = (h + rng.uniform(-8.0, 8.0) / 360.0) % 1.0
    s = float(np.clip(s * rng.uniform(0.85, 1.15), 0.0, 1.0))
    v = float(np.clip(v * rng.uniform(0.85, 1.05), 0.0, 1.0))
    return tuple(float(c) for c in colorsys.hsv_to_rgb(h, s, v))


def random_params(rng: np.random.Generator, base: PlantParams | None = None) -> PlantParams:
    """``base`` (default ``PlantParams()``) with a marker diameter drawn in 6.5-9.5 mm."""
    p = base or PlantParams()
    vfc = p.vfc.model_copy(update={"marker_diameter_mm": float(rng.uniform(6.5, 9.5))})
    return p.model_copy(update={"vfc": vfc})


def random_options(
    rng: np.random.Generator,
    patterns: tuple[RotorPattern, ...] = PATTERNS,
    lightings: tuple[Lighting, ...] = LIGHTINGS,
    **fixed: object,
) -> AnalyticRenderOptions:
    """Renderer options of a random appearance from the given pattern and lighting families.

    ``fixed`` overrides any option (e.g. ``noise_sigma_dn=0.0``, ``max_sub_frames=32``).
    """
    grey = rng.uniform(0.3, 0.8)
    tint = rng.uniform(0.9, 1.1, 3)
    lighting = lightings[int(rng.integers(len(lightings)))]
    opts: dict[str, object] = {
        "rotor_rgb": tuple(float(c) for c in np.clip(grey * tint, 0.0, 1.0)),
        "plate_rgb": tuple(float(c) for c in rng.uniform(0.03, 0.2) * rng.uniform(0.85, 1.15, 3)),
        "red_rgb": _shade_of(RED_RGB, rng),
        "yellow_rgb": _shade_of(YELLOW_RGB, rng),
        "rotor_pattern": patterns[int(rng.integers(len(patterns)))],
        "rotor_pattern_contrast": float(rng.uniform(0.1, 0.5)),
        "rotor_pattern_scale_px": float(np.exp(rng.uniform(np.log(3.0), np.log(25.0)))),
        "white_balance": tuple(float(c) for c in rng.uniform(0.9, 1.1, 3)),
        "n_highlights": int(rng.integers(0, 5)),
        "highlight_peak": float(rng.uniform(0.3, 1.0)),
        "noise_sigma_dn": float(rng.uniform(0.0, 4.0)),
    }
    distractor = ("none", "red", "yellow")[int(rng.integers(3))]
    if distractor != "none":
        base = RED_RGB if distractor == "red" else YELLOW_RGB
        opts |= {
            "colour_distractor": distractor,
            "distractor_rgb": _shade_of(base, rng),
            "distractor_diameter_mm": float(rng.uniform(5.0, 12.0)),
        }
    if lighting == "gradient":
        opts |= {"light_gradient": float(rng.uniform(0.2, 0.6)),
                 "light_gradient_angle_rad": float(rng.uniform(0.0, 2.0 * np.pi))}
    elif lighting == "vignetting":
        opts["vignetting"] = float(rng.uniform(0.2, 0.6))
    elif lighting == "spot":
        opts |= {"light_spot": float(rng.uniform(0.6, 1.5)),
                 "light_spot_sigma_frac": float(rng.uniform(0.1, 0.3))}
    opts.update(fixed)
    return AnalyticRenderOptions(**opts)


def heldout_options(seed: int, family: str) -> tuple[PlantParams, AnalyticRenderOptions]:
    """Plant parameters and renderer options of a scene from a held-out appearance family
    (``"pattern"``: the held-out rotor pattern under training lighting; ``"lighting"``: the
    held-out lighting on a training pattern), drawn from ``seed``."""
    rng = np.random.default_rng([seed, 4243])
    if family == "pattern":
        pats, lights = (HELD_OUT_PATTERN,), TRAIN_LIGHTINGS
    elif family == "lighting":
        pats, lights = TRAIN_PATTERNS, (HELD_OUT_LIGHTING,)
    else:
        raise ValueError(f"family must be 'pattern' or 'lighting', got {family!r}")
    return random_params(rng), random_options(rng, pats, lights, noise_sigma_dn=2.0)
