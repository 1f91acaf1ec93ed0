"""Augmentations of the TransT training crop pairs, applied when ``CropPairs`` loads them.

* ``dihedral_image`` / ``dihedral_box``: joint flips and transposition of both crops and their
  labels (the disc and the square plate are symmetric under them);
* ``hide_target``: the target removed from a search crop, a target-absent example;
* ``appearance_jitter``: a new look for a pair (texture, glare, distractors, a colour camera's
  processing chain), the changes a renderer of another kind brings.

All draws come from the ``numpy.random.Generator`` passed in, so a seeded batch is reproducible.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from plant.appearance import TRAIN_OCCLUDERS, occluder_rgb
from plant.render_analytic import jpeg_roundtrip


def dihedral_image(img: NDArray, k: int) -> NDArray:
    """Apply dihedral transform k (bit 0: flip x, bit 1: flip y, bit 2: transpose) to
    (..., H, W, C) images."""
    if k & 1:
        img = img[..., :, ::-1, :]
    if k & 2:
        img = img[..., ::-1, :, :]
    if k & 4:
        img = np.swapaxes(img, -3, -2)
    return img


def dihedral_box(box: NDArray[np.float32], k: int) -> NDArray[np.float32]:
    """The same transform on (..., 4) boxes (cx, cy, w, h) or (..., 2) points in fractions."""
    b = box.copy()
    if k & 1:
        b[..., 0] = 1.0 - b[..., 0]
    if k & 2:
        b[..., 1] = 1.0 - b[..., 1]
    if k & 4:
        b[..., [0, 1]] = b[..., [1, 0]]
        if b.shape[-1] == 4:
            b[..., [2, 3]] = b[..., [3, 2]]
    return b


def hide_target(
    search: NDArray[np.uint8], box: NDArray[np.float32], rng: np.random.Generator
) -> None:
    """In place: remove the target from a uint8 search crop (H, W, 3) whose target box is
    ``box`` (cx, cy, w, h crop fractions), so that the crop is a target-absent example.

    The region removed is the box grown 1.4-2.2 times (the disc's blur smear and its
    anti-aliased rim included). It is filled, with probabilities 0.4 / 0.4 / 0.2, by inpainting
    from its surroundings (the rotor seen without the marker), by an occluder of a training
    colour family or black (a hand, a tool, a shadow over the whole marker), or by a patch of the
    same crop taken away from the target (another part of the rotor)."""
    side = search.shape[0]
    cx, cy, w, h = (np.asarray(box, float) * side).tolist()
    grow = rng.uniform(1.4, 2.2)
    hw, hh = max(w, 2.0) * grow / 2, max(h, 2.0) * grow / 2
    c0, r0 = max(int(cx - hw), 0), max(int(cy - hh), 0)
    c1, r1 = min(int(math.ceil(cx + hw)), side), min(int(math.ceil(cy + hh)), side)
    if c1 <= c0 or r1 <= r0:
        return
    u = rng.uniform()
    if u < 0.4:
        mask = np.zeros(search.shape[:2], np.uint8)
        mask[r0:r1, c0:c1] = 255
        search[...] = cv2.inpaint(search, mask, 5, cv2.INPAINT_TELEA)
    elif u < 0.8:
        family = ("black", *TRAIN_OCCLUDERS)[int(rng.integers(len(TRAIN_OCCLUDERS) + 1))]
        colour = (0, 0, 0) if family == "black" else occluder_rgb(rng, family)
        search[r0:r1, c0:c1] = colour
    else:
        ph, pw = r1 - r0, c1 - c0
        for _ in range(20):  # a source patch that does not overlap the removed region
            sr, sc = int(rng.integers(0, side - ph + 1)), int(rng.integers(0, side - pw + 1))
            if sr + ph <= r0 or sr >= r1 or sc + pw <= c0 or sc >= c1:
                search[r0:r1, c0:c1] = search[sr:sr + ph, sc:sc + pw]
                return
        search[r0:r1, c0:c1] = np.median(search.reshape(-1, 3), axis=0).astype(np.uint8)


#: Template target box (cx, cy, w, h crop fractions): centred, half the crop's side (context
#: factor 2, ``crop.context_side``).
_TEMPLATE_BOX = np.array([0.5, 0.5, 0.5, 0.5], np.float32)
#: OpenCV demosaicing codes, per Bayer layout, for bilinear, VNG and edge-aware interpolation
#: (OpenCV names a layout by its second row, so ``BayerBG2BGR`` gives RGB order for an RGGB
#: sensor: the codes below map the layout of the top-left 2 x 2 cell to RGB output).
_DEMOSAIC_CODES = tuple(
    {cell: getattr(cv2, f"COLOR_Bayer{cell[:2]}2BGR{suffix}") for cell in ("RG", "BG", "GR", "GB")}
    for suffix in ("", "_VNG", "_EA"))
_BAYER_CELLS = {"RG": "RGGB", "BG": "BGGR", "GR": "GRBG", "GB": "GBRG"}


def _procedural_texture(rng: np.random.Generator, side: int) -> NDArray[np.float32]:
    """A (side, side) texture in about [-1, 1]: value noise, stripes, a checkerboard, thin grid
    lines or speckle, at a random scale and angle (none of the rotor's held-out families is
    drawn exactly: the checkerboard here is rotated and at crop scale)."""
    kind = int(rng.integers(5))
    yy, xx = np.mgrid[0:side, 0:side].astype(np.float32)
    ang = rng.uniform(0.0, np.pi)
    u = xx * np.cos(ang) + yy * np.sin(ang)
    v = -xx * np.sin(ang) + yy * np.cos(ang)
    period = float(np.exp(rng.uniform(np.log(3.0), np.log(40.0))))
    if kind == 0:
        n = max(2, int(side / period) + 2)
        small = rng.uniform(-1.0, 1.0, (n, n)).astype(np.float32)
        return cv2.resize(small, (side, side), interpolation=cv2.INTER_CUBIC)
    if kind == 1:
        return np.sin(2 * np.pi * u / period).astype(np.float32)
    if kind == 2:
        return np.sign(np.sin(np.pi * u / period) * np.sin(np.pi * v / period)).astype(np.float32)
    if kind == 3:
        d = np.minimum(np.abs((u % period) - period / 2), np.abs((v % period) - period / 2))
        return np.where(d > period / 2 - 1.0, -1.0, 0.0).astype(np.float32)
    return np.where(rng.uniform(size=(side, side)) < rng.uniform(0.02, 0.2), -1.0,
                    0.0).astype(np.float32)


def _ellipse_mask(side: int, box: NDArray[np.float32], grow: float) -> NDArray[np.float32]:
    """1 inside the ellipse inscribed in ``box`` (crop fractions) grown ``grow`` times, else 0."""
    yy, xx = (np.mgrid[0:side, 0:side].astype(np.float32) + 0.5) / side
    cx, cy, w, h = (float(v) for v in box)
    r = ((xx - cx) / max(w * grow / 2, 1e-3)) ** 2 + ((yy - cy) / max(h * grow / 2, 1e-3)) ** 2
    return (r <= 1.0).astype(np.float32)


def _mosaic_demosaic(lin: NDArray[np.float32], layout: str, algo: int, full_well: float,
                     read_dn: float, rng: np.random.Generator) -> NDArray[np.float32]:
    """Linear light (H, W, 3) in [0, 1] through a Bayer sensor (``layout``: top-left 2 x 2 cell),
    with shot noise (``full_well`` electrons per unit) and read noise (``read_dn`` DN at 8
    bits), 8-bit raw, OpenCV demosaicing; returns linear light again."""
    h, w = lin.shape[:2]
    cell = _BAYER_CELLS[layout]
    raw = np.empty((h, w), np.float32)
    for k, (dy, dx) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
        raw[dy::2, dx::2] = lin[dy::2, dx::2, "RGB".index(cell[k])]
    raw = np.clip(raw, 0.0, None)
    raw = raw + rng.normal(size=raw.shape).astype(np.float32) * np.sqrt(raw / full_well)
    enc = np.clip(raw, 0.0, None) ** (1 / 2.2) * 255.0
    enc += rng.normal(0.0, read_dn, enc.shape).astype(np.float32)
    bayer = np.clip(np.rint(enc), 0, 255).astype(np.uint8)
    rgb = cv2.cvtColor(bayer, _DEMOSAIC_CODES[algo][layout]).astype(np.float32) / 255.0
    return rgb**2.2


def appearance_jitter(
    template: NDArray[np.uint8], search: NDArray[np.uint8], box: NDArray[np.float32],
    rng: np.random.Generator,
) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """A new look for a crop pair (uint8 RGB crops; ``box`` the search target, cx, cy, w, h
    crop fractions): the camera and scene changes that a renderer of another kind brings,
    drawn once per pair and shared by template and search, noise and compression per crop.

    Our choices, wide on purpose: the surroundings of the targets tinted a colour of any hue
    (``_tint_surroundings``, 40 %: the analytic rotor is near grey, a real or other-rendered
    shell can be orange next to a red marker); a texture (``_procedural_texture``, contrast
    0.1-0.5) multiplied onto everything but the targets (50 %); a glossy highlight on the target
    (15 %); a disc of random colour and size, or a few thin lines, beside the target (25 %);
    the crops taken as linear light (value ^ 2.2) with a colour matrix (crosstalk ±10 %),
    white balance ±15 %, gain 0.5-1.6, saturation 0.6-1.4 and a smooth illumination field
    (a ramp and a falloff about a random centre losing up to 50 %); in 60 % a Bayer sensor
    (``_mosaic_demosaic``: random layout, bilinear, VNG or edge-aware demosaicing, full well
    200-2000, read noise 0.5-4 DN); an output gamma 1.6-2.8; Gaussian blur (sigma 0.3-1.2 px,
    25 %) and JPEG at quality 30-95 (50 %)."""
    crops = [template.astype(np.float32), search.astype(np.float32)]
    boxes = [_TEMPLATE_BOX, np.asarray(box, np.float32)]
    _tint_surroundings(crops, boxes, rng)
    _add_texture(crops, boxes, rng)
    _add_glare(crops, boxes, rng)
    _add_distractor(crops[1], boxes[1], rng)
    out = _through_a_camera(crops, rng)
    return out[0], out[1]


def _tint_surroundings(crops: list[NDArray[np.float32]], boxes: list[NDArray[np.float32]],
                       rng: np.random.Generator) -> None:
    """In place, with probability 0.4: everything but the ellipse 1.2 times each crop's target
    box multiplied by one colour (hue 0-360°, saturation 0.15-0.6, scaled to a mean gain of
    1), the same for both crops, so a near-grey rotor can become a shell of any colour,
    red and orange included."""
    u = rng.uniform
    if u() < 0.4:
        hue, sat = u(0.0, 1.0), u(0.15, 0.6)
        rgb = np.array(cv2.cvtColor(np.float32([[[360.0 * hue, sat, 1.0]]]),
                                    cv2.COLOR_HSV2RGB)[0, 0], np.float32)
        gain = rgb / rgb.mean()
        for i, (c, b) in enumerate(zip(crops, boxes, strict=True)):
            outside = 1.0 - _ellipse_mask(c.shape[0], b, 1.2)
            crops[i] = c * (1.0 + (gain - 1.0) * outside[..., None])


def _add_texture(crops: list[NDArray[np.float32]], boxes: list[NDArray[np.float32]],
                 rng: np.random.Generator) -> None:
    """In place, with probability 0.5: a procedural texture (contrast 0.1-0.5) multiplied onto
    each float crop (H, W, 3), 0-255, except inside the ellipse 1.2 times its target box."""
    u = rng.uniform
    if u() < 0.5:
        contrast = u(0.1, 0.5)
        for i, (c, b) in enumerate(zip(crops, boxes, strict=True)):
            side = c.shape[0]
            tex = _procedural_texture(np.random.default_rng(rng.integers(1 << 31)), side)
            keep = _ellipse_mask(side, b, 1.2)
            crops[i] = c * (1.0 + contrast * tex * (1.0 - keep))[..., None]


def _add_glare(crops: list[NDArray[np.float32]], boxes: list[NDArray[np.float32]],
               rng: np.random.Generator) -> None:
    """In place, with probability 0.15: a Gaussian highlight near each crop's target (centre
    within ±0.3 box sizes, sigma 8-25 % of the box size, peak 0.3-1 of full scale)."""
    u = rng.uniform
    if u() < 0.15:
        for i, (c, b) in enumerate(zip(crops, boxes, strict=True)):
            side = c.shape[0]
            yy, xx = np.mgrid[0:side, 0:side].astype(np.float32)
            cx, cy = (b[:2] + u(-0.3, 0.3, 2) * b[2:]) * side
            sig = max(float(np.mean(b[2:])) * side * u(0.08, 0.25), 0.7)
            blob = np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * sig * sig))
            crops[i] = c + 255.0 * u(0.3, 1.0) * blob[..., None]


def _add_distractor(c: NDArray[np.float32], b: NDArray[np.float32],
                    rng: np.random.Generator) -> None:
    """In place, with probability 0.25, on the search crop ``c`` with target box ``b``: a disc
    of random colour and 0.5-1.5 box sizes 1.2-3 box sizes from the target, or 1-3 thin
    lines of one random colour."""
    u = rng.uniform
    if u() < 0.25:
        side = c.shape[0]
        size = float(np.mean(b[2:])) * side
        ang = u(0.0, 2 * np.pi)
        centre = b[:2] * side + u(1.2, 3.0) * size * np.array([np.cos(ang), np.sin(ang)])
        colour = tuple(float(x) for x in u(0, 255, 3))
        if u() < 0.5:
            cv2.circle(c, tuple(int(round(x * 16)) for x in centre),
                       int(round(0.5 * size * u(0.5, 1.5) * 16)), colour, -1, cv2.LINE_AA, 4)
        else:
            for _ in range(int(rng.integers(1, 4))):
                p0, p1 = u(0, side, 2), u(0, side, 2)
                cv2.line(c, tuple(int(round(x * 16)) for x in p0),
                         tuple(int(round(x * 16)) for x in p1), colour, 1, cv2.LINE_AA, 4)


def _through_a_camera(crops: list[NDArray[np.float32]],
                      rng: np.random.Generator) -> list[NDArray[np.uint8]]:
    """The float crops (H, W, 3), 0-255, as uint8 images from one drawn camera: linear light,
    colour matrix, white balance and gain, saturation, an illumination field, a Bayer sensor
    (60 %) or read noise, an output gamma, then per crop blur (25 %) and JPEG (50 %)."""
    u = rng.uniform
    cross = rng.normal(0.0, 0.05, (3, 3)).astype(np.float32)
    np.fill_diagonal(cross, 0.0)
    cm = np.eye(3, dtype=np.float32) + cross - np.diag(cross.sum(axis=1))
    wb = u(0.85, 1.15, 3).astype(np.float32) * np.float32(u(0.5, 1.6))
    sat = np.float32(u(0.6, 1.4))
    bayer = u() < 0.6
    layout = ("RG", "BG", "GR", "GB")[int(rng.integers(4))]
    algo, full_well = int(rng.integers(3)), float(np.exp(u(np.log(200.0), np.log(2000.0))))
    read_dn, gamma = u(0.5, 4.0), u(1.6, 2.8)
    ramp, falloff = u(-0.3, 0.3, 2), u(0.0, 0.5)
    centre = u(0.2, 0.8, 2)
    out = []
    for c in crops:
        side = c.shape[0]
        lin = (np.clip(c, 0.0, 255.0) / 255.0) ** 2.2 @ cm.T * wb
        grey = lin.mean(axis=2, keepdims=True)
        lin = grey + sat * (lin - grey)
        yy, xx = (np.mgrid[0:side, 0:side].astype(np.float32) + 0.5) / side
        field = (1.0 + ramp[0] * (xx - 0.5) + ramp[1] * (yy - 0.5)) * (
            1.0 - falloff * np.clip(((xx - centre[0]) ** 2 + (yy - centre[1]) ** 2) * 2.0, 0, 1))
        lin = np.clip(lin * field[..., None], 0.0, None)
        if bayer:
            lin = _mosaic_demosaic(lin, layout, algo, full_well, read_dn, rng)
        else:
            lin = lin + rng.normal(0.0, read_dn / 255.0, lin.shape).astype(np.float32)
        enc = np.clip(lin, 0.0, 1.0) ** (1.0 / gamma) * 255.0
        if u() < 0.25:
            enc = cv2.GaussianBlur(enc, (0, 0), u(0.3, 1.2))
        img = np.clip(np.rint(enc), 0, 255).astype(np.uint8)
        out.append(jpeg_roundtrip(img, int(rng.integers(30, 96)) if u() < 0.5 else None))
    return out
