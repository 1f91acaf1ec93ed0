"""Compiled per-pixel kernels of the analytic renderer (``plant.render_analytic``): the camera
effects before and after the defocus blur (or, where no highlight, light map or blur makes a
pixel depend on more than its own value and noise byte, a table of both at once), the
compositing of a layer's colour, and the inset of polygon outlines.

Why compiled: a frame is 612 x 512 x 3 values, and the numpy and OpenCV version made one pass
over the frame per effect (conversion, highlights, illumination, light map, noise, gain,
clipping, rounding), each writing a new array; here each pixel is read and written once. The
kernels do the same float32 operations in the same order as that version, so frames are
identical byte for byte (tests/test_render_kernels.py compares them with the numpy and
OpenCV operations they replace).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray


@njit(cache=True)
def exposed(img: NDArray[np.uint8], highlights: NDArray[np.float32], illumination: float,
            light: NDArray[np.float32]) -> NDArray[np.float32]:
    """The frame as float32 DN, flat (H W 3,): ``img`` plus ``highlights`` (skipped when
    empty), times ``illumination`` (float32) and the ``light`` map (skipped when empty); all
    arrays flat, in the same order."""
    out = np.empty(img.size, np.float32)
    ill = np.float32(illumination)
    with_h, with_l, scale = highlights.size > 0, light.size > 0, ill != np.float32(1.0)
    for i in range(img.size):
        v = np.float32(img[i])
        if with_h:
            v = v + highlights[i]
        if scale:
            v = v * ill
        if with_l:
            v = v * light[i]
        out[i] = v
    return out


@njit(cache=True)
def _dn(v: np.float32) -> np.uint8:
    """``v`` clipped at 0, rounded half to even and saturated at 255 (``cv2.convertScaleAbs``
    of a non-negative value). Adding and removing 2^23 rounds a float32 in [0, 2^23) to an
    integer in the current rounding mode, nearest-even: the same as ``rint``, which numba
    does not vectorise."""
    big = np.float32(8388608.0)
    v = min(max(v, np.float32(0.0)), np.float32(256.0))
    return np.uint8(min((v + big) - big, np.float32(255.0)))


@njit(cache=True)
def digitised(f: NDArray[np.float32], noise_bytes: NDArray[np.uint8],
              noise_table: NDArray[np.float32], gain: float) -> NDArray[np.uint8]:
    """The sensor's 8-bit output of the float32 frame ``f`` (flat): plus the read noise
    ``noise_table[noise_bytes]`` (skipped when ``noise_bytes`` is empty), times ``gain``
    (float32; times 1 changes nothing), clipped at 0, rounded half to even and saturated at 255
    (``cv2.convertScaleAbs``)."""
    out = np.empty(f.size, np.uint8)
    g = np.float32(gain)
    if noise_bytes.size > 0:
        for i in range(f.size):
            out[i] = _dn((f[i] + noise_table[noise_bytes[i]]) * g)
    else:
        for i in range(f.size):
            out[i] = _dn(f[i] * g)
    return out


@njit(cache=True)
def digitised_levels(noise_table: NDArray[np.float32], illumination: float,
                     gain: float) -> NDArray[np.uint8]:
    """The table (256 x 256, flat) of ``digitised(exposed(v), b)`` for every frame value ``v``
    and noise byte ``b`` (index ``v * 256 + b``), for frames without highlights, light map or
    defocus: there each output byte is a function of those two bytes alone, computed here with
    the same float32 operations in the same order."""
    out = np.empty(65536, np.uint8)
    ill, g = np.float32(illumination), np.float32(gain)
    for v in range(256):
        f = np.float32(v)
        if ill != np.float32(1.0):
            f = f * ill
        for b in range(256):
            out[v * 256 + b] = _dn((f + noise_table[b]) * g)
    return out


@njit(cache=True)
def digitised_by_levels(img: NDArray[np.uint8], noise_bytes: NDArray[np.uint8],
                        levels: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """``digitised(exposed(img), noise_bytes)`` through the table of ``digitised_levels``
    (all arrays flat): one look-up per value instead of the float pass, about three times
    faster on a frame, byte for byte the same."""
    out = np.empty(img.size, np.uint8)
    for i in range(img.size):
        out[i] = levels[(np.int64(img[i]) << 8) | np.int64(noise_bytes[i])]
    return out


@njit(cache=True)
def composite(patch: NDArray[np.float32], alpha: NDArray[np.float32],
              colour: NDArray[np.float32]) -> None:
    """``patch += alpha * (colour - patch)`` in place, per pixel (H, W, 3), float32."""
    h, w, c = patch.shape
    for i in range(h):
        for j in range(w):
            a = alpha[i, j]
            for k in range(c):
                p = patch[i, j, k]
                patch[i, j, k] = p + (colour[k] - p) * a


@njit(cache=True)
def inset(polys: NDArray[np.float64], d: float) -> NDArray[np.float64]:
    """Closed polygons (k, n, 2) with every vertex moved inward by ``d`` px along the normal of
    the chord between its neighbours (inward by the sign of the polygon's area)."""
    k, n, _ = polys.shape
    out = np.empty_like(polys)
    for p in range(k):
        area2 = 0.0
        for i in range(n):
            nxt = (i + 1) % n
            area2 += polys[p, i, 0] * polys[p, nxt, 1] - polys[p, nxt, 0] * polys[p, i, 1]
        sign = 1.0 if area2 > 0.0 else (-1.0 if area2 < 0.0 else (0.0 if area2 == 0.0
                                                                   else math.nan))
        ds = d * sign
        for i in range(n):
            nxt, prv = (i + 1) % n, (i - 1) % n
            tx = polys[p, nxt, 0] - polys[p, prv, 0]
            ty = polys[p, nxt, 1] - polys[p, prv, 1]
            nx, ny = -ty, tx
            norm = max(math.sqrt(nx * nx + ny * ny), 1e-12)
            out[p, i, 0] = polys[p, i, 0] + ds * (nx / norm)
            out[p, i, 1] = polys[p, i, 1] + ds * (ny / norm)
    return out
