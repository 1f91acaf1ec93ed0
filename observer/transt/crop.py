"""Square crops with context, as TransT takes them, shared by training data and the tracker.

TransT (Chen et al., CVPR 2021, §4.1; the SiamRPN-style crop of its released tracker) crops a
square around the target whose side is ``sqrt((w + p)(h + p))`` with the context
``p = (f - 1)(w + h)/2``: f = 2 for the template (the side is about twice the target's) and
f = 4 for the search region. The crop is resized to the network's input size; what lies outside
the frame is filled with the frame's mean colour.

Coordinates are image pixels with OpenCV's pixel-centre convention: integer coordinates are pixel
centres, a box (x, y, w, h) covers [x, x + w] x [y, y + h] and its centre is (x + w/2, y + h/2).
A crop of side ``s`` centred at (cx, cy) covers [cx - s/2, cx + s/2]^2; an output of S pixels
maps crop-edge coordinate e in [0, S] to u = cx - s/2 + e s/S, so a crop-normalised coordinate
b in [0, 1] (what the box head predicts) is the image coordinate ``cx - s/2 + b s``. The
resampling is bilinear at sub-pixel offsets (``cv2.warpAffine``), so no rounding of the crop
window is involved (TransT rounds it to whole pixels; our choice).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

#: ImageNet mean and std of RGB in [0, 1] (the normalisation of TransT's ResNet-50).
IMAGENET_MEAN = np.array([0.485, 0.456, 0.406], dtype=np.float32)
IMAGENET_STD = np.array([0.229, 0.224, 0.225], dtype=np.float32)


def context_side(size_wh: ArrayLike, factor: float) -> float:
    """Side (px) of TransT's context square for a target of size (w, h) px and context factor
    ``factor`` (2 for the template, 4 for the search region): sqrt((w + p)(h + p)),
    p = (factor - 1)(w + h)/2."""
    w, h = (float(v) for v in np.asarray(size_wh, dtype=float).reshape(2))
    p = (factor - 1.0) * (w + h) / 2.0
    return math.sqrt((w + p) * (h + p))


def crop_square(
    image: NDArray[np.uint8],
    centre_xy: ArrayLike,
    side_px: float,
    out_size: int,
    pad_rgb: ArrayLike | None = None,
) -> NDArray[np.uint8]:
    """Resample the square of side ``side_px`` (image px) centred at ``centre_xy`` (image px)
    to ``out_size`` x ``out_size`` pixels (bilinear); outside the frame: ``pad_rgb`` (default
    the frame's mean colour). Returns (out_size, out_size, channels) uint8."""
    cx, cy = (float(v) for v in np.asarray(centre_xy, dtype=float).reshape(2))
    a = float(side_px) / out_size
    m = np.array(
        [[a, 0.0, cx - side_px / 2.0 + 0.5 * a], [0.0, a, cy - side_px / 2.0 + 0.5 * a]],
        dtype=np.float64,
    )
    if pad_rgb is None:
        pad_rgb = image.reshape(-1, image.shape[-1]).mean(axis=0)
    pad = tuple(float(v) for v in np.asarray(pad_rgb, dtype=float).reshape(-1))
    return cv2.warpAffine(
        image,
        m,
        (out_size, out_size),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=pad,
    )


def box_to_crop(
    box_xywh: ArrayLike, centre_xy: ArrayLike, side_px: float
) -> NDArray[np.float64]:
    """A box (x, y, w, h) in image px as (cx, cy, w, h) fractions of a crop of side
    ``side_px`` centred at ``centre_xy`` (the box head's target format)."""
    x, y, w, h = np.asarray(box_xywh, dtype=float).reshape(4)
    c = np.asarray(centre_xy, dtype=float).reshape(2)
    lo = c - side_px / 2.0
    return np.array([(x + w / 2 - lo[0]) / side_px, (y + h / 2 - lo[1]) / side_px,
                     w / side_px, h / side_px])


def crop_to_box(
    cxcywh: ArrayLike, centre_xy: ArrayLike, side_px: float
) -> NDArray[np.float64]:
    """Inverse of ``box_to_crop``: crop fractions (cx, cy, w, h) -> box (x, y, w, h), image px."""
    cx, cy, w, h = np.asarray(cxcywh, dtype=float).reshape(4) * side_px
    c = np.asarray(centre_xy, dtype=float).reshape(2) - side_px / 2.0
    return np.array([c[0] + cx - w / 2, c[1] + cy - h / 2, w, h])


def _normalised_levels() -> NDArray[np.float32]:
    """(1, 256, 3) float32: ((v / 255) - mean) / std of every 8-bit level v per channel,
    computed with the float32 operations of the elementwise formula, so that looking a pixel
    up gives the same bits as computing it."""
    v = np.arange(256, dtype=np.float32)[:, None] * np.float32(1.0 / 255.0)
    return np.ascontiguousarray(((v - IMAGENET_MEAN) / IMAGENET_STD)[None])


_LEVELS = _normalised_levels()


def normalise(crops: NDArray[np.uint8]) -> NDArray[np.float32]:
    """uint8 RGB crops (..., H, W, 3) -> ImageNet-normalised float32 (..., 3, H, W):
    ((v / 255) - mean) / std per channel, looked up per 8-bit level (``cv2.LUT``) instead of
    three passes of float arithmetic over the crops."""
    c = np.ascontiguousarray(crops, dtype=np.uint8)
    f = cv2.LUT(c.reshape(1, -1, 3), _LEVELS).reshape(c.shape)
    return np.ascontiguousarray(np.moveaxis(f, -1, -3))
