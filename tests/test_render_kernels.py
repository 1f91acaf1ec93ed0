"""The renderer's compiled kernels give, byte for byte, what the plain numpy and OpenCV
operations they stand for give (the calibrated loss models were fitted on frames of those
operations), and the inset moves a circle's outline inward by the distance asked."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from plant import render_kernels

H, W = 37, 53


def _camera_effects_reference(img, highlights, illumination, light, defocus, raw, table, gain):
    """The camera effects as one numpy or OpenCV pass per effect."""
    f = img.astype(np.float32)
    if highlights is not None:
        f += highlights
    if illumination != 1.0:
        f *= np.float32(illumination)
    if light is not None:
        f *= light
    if defocus:
        f = cv2.GaussianBlur(f, (0, 0), defocus)
    if raw is not None:
        f += cv2.LUT(raw, table)
    if gain != 1.0:
        f *= np.float32(gain)
    np.maximum(f, 0.0, out=f)
    return cv2.convertScaleAbs(f)


@pytest.mark.parametrize(
    ("with_highlights", "illumination", "with_light", "defocus", "with_noise", "gain"),
    [(False, 1.0, False, 0.0, True, 1.0), (True, 0.35, False, 0.0, True, 2.0),
     (False, 1.0, True, 1.2, True, 1.0), (True, 1.3, True, 0.0, False, 0.7),
     (False, 1.0, False, 0.0, False, 1.0)],
)
def test_camera_effects_equal_the_numpy_and_opencv_passes(with_highlights, illumination,
                                                          with_light, defocus, with_noise,
                                                          gain):
    rng = np.random.default_rng(7)
    img = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    img[0, :5] = (255, 0, 128)  # saturation and the edges of the range
    highlights = (rng.uniform(0, 200, (H, W, 3)).astype(np.float32) if with_highlights
                  else None)
    light = rng.uniform(0.05, 2.5, (H, W, 3)).astype(np.float32) if with_light else None
    raw = rng.integers(0, 256, (H, W, 3), dtype=np.uint8) if with_noise else None
    # a table with exact halves: the rounding must be half to even, as OpenCV's
    table = np.linspace(-6.5, 6.5, 256).astype(np.float32)
    table[:4] = (-0.5, 0.5, 1.5, 2.5)
    want = _camera_effects_reference(img, highlights, illumination, light, defocus, raw,
                                     table, gain)
    none = np.empty(0, np.float32)
    f = render_kernels.exposed(img.ravel(), none if highlights is None else highlights.ravel(),
                               illumination, none if light is None else light.ravel())
    if defocus:
        f = cv2.GaussianBlur(f.reshape(img.shape), (0, 0), defocus).ravel()
    got = render_kernels.digitised(
        f, np.empty(0, np.uint8) if raw is None else raw.ravel(), table, gain
    ).reshape(img.shape)
    assert got.dtype == np.uint8
    np.testing.assert_array_equal(got, want)
    assert 0 < np.count_nonzero(got == 255) < got.size  # the cases reach saturation


def test_composite_equals_opencvs_arithmetic_on_a_view():
    rng = np.random.default_rng(3)
    roi = rng.uniform(0, 255, (H, W, 3)).astype(np.float32)
    acc = rng.uniform(0, 1, (H, W)).astype(np.float32)
    colour = np.array([201.3, 17.25, 90.0])
    box = (slice(4, 30), slice(9, 41))  # a view, as the renderer composites a sub-box
    want = roi.copy()
    patch = want[box]
    diff = cv2.subtract((*colour.tolist(), 0.0), patch)
    patch[...] = cv2.add(patch, cv2.multiply(diff, cv2.merge([acc[box]] * 3)))
    got = roi.copy()
    render_kernels.composite(got[box], acc[box], colour.astype(np.float32))
    np.testing.assert_array_equal(got, want)
    assert not np.array_equal(got, roi)


@pytest.mark.parametrize("direction", [1, -1])
def test_inset_shrinks_a_circle_by_the_distance(direction):
    ang = direction * np.linspace(0, 2 * np.pi, 400, endpoint=False)
    circle = np.stack([50 + 20 * np.cos(ang), 40 + 20 * np.sin(ang)], axis=-1)
    out = render_kernels.inset(circle[None], 0.75)[0]
    radius = np.hypot(out[:, 0] - 50, out[:, 1] - 40)
    np.testing.assert_allclose(radius, 19.25, atol=1e-9)


@pytest.mark.parametrize(("illumination", "gain"), [(1.0, 1.0), (0.45, 2.4), (1.7, 0.6)])
def test_the_table_of_levels_equals_the_numpy_and_opencv_passes(illumination, gain):
    rng = np.random.default_rng(11)
    img = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    img[0, :5] = (255, 0, 128)
    raw = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    table = np.linspace(-6.5, 6.5, 256).astype(np.float32)
    table[:4] = (-0.5, 0.5, 1.5, 2.5)  # exact halves: rounding half to even
    want = _camera_effects_reference(img, None, illumination, None, 0.0, raw, table, gain)
    levels = render_kernels.digitised_levels(table, illumination, gain)
    got = render_kernels.digitised_by_levels(img.ravel(), raw.ravel(), levels).reshape(img.shape)
    np.testing.assert_array_equal(got, want)
    assert 0 < np.count_nonzero(got == 255) < got.size
