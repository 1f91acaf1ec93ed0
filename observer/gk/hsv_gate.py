"""HSV colour gate: how much of a tracker's box is marker-coloured (seed 000 §3.2.1).

The seed judges an observation by the proportion of valid pixels inside the box the tracker
returns: pixels whose HSV values fall in the marker's ranges, in OpenCV's 8-bit HSV convention
(H in [0, 180), S and V in [0, 255]):

* red main marker: H ∈ [0, 10] ∪ [170, 180], S ∈ [50, 255], V ∈ [50, 255];
* yellow auxiliary marker: H ∈ [15, 40], S ∈ [50, 255], V ∈ [50, 255].

A proportion above 0.05 makes the observation valid ("confident"); below it the Kalman
prediction stands in (``observer.gk.pixel_kalman``).

**Channel order.** Frames in this toolkit (``plant.scene.Frame.image``, both renderers) are RGB,
so the conversion here is ``cv2.COLOR_RGB2HSV``. Frames read with ``cv2.imread`` or
``cv2.VideoCapture`` are BGR: convert them first with ``cv2.cvtColor(img, cv2.COLOR_BGR2RGB)``.
Feeding a BGR frame would swap red and blue and the red gate would see nothing.

Boxes here are (x, y, w, h) in *image* pixels of the frame passed in (OpenCV's pixel-centre
convention: the box covers the continuous rectangle [x, x + w] × [y, y + h]); the pixels counted
are those whose centres lie inside it, clipped to the frame. ``observer.gk.assist`` converts the
tracker's full-sensor boxes with ``box_sensor_to_image``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

from plant.params import PlantParams
from plant.scene import check_binning

Colour = Literal["red", "yellow"]

#: OpenCV's 8-bit hue range is [0, 180) (degrees / 2); 180 is allowed as an inclusive bound.
_H_MAX = 180
_SV_MAX = 255

#: A frame or region whose values span at most this many DN is featureless (all black, all
#: white or blank): nothing to track (our choice; ``check_frame`` applies it to whole frames,
#: the TransT tracker to its search region).
UNIFORM_PTP_DN = 2


class HSVRange(BaseModel):
    """A colour class in OpenCV 8-bit HSV: a union of hue intervals, one S and one V interval.

    All bounds are inclusive, H in [0, 180], S and V in [0, 255].
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    hue: tuple[tuple[int, int], ...] = Field(min_length=1, description="(lo, hi) hue intervals.")
    sat: tuple[int, int] = Field((50, 255), description="(lo, hi) saturation.")
    val: tuple[int, int] = Field((50, 255), description="(lo, hi) value.")

    @model_validator(mode="after")
    def _check_bounds(self) -> HSVRange:
        for i, (lo, hi) in enumerate(self.hue):
            if not 0 <= lo <= hi <= _H_MAX:
                raise ValueError(
                    f"hue[{i}] = ({lo}, {hi}) must satisfy 0 <= lo <= hi <= {_H_MAX} "
                    "(OpenCV 8-bit hue)"
                )
        for name, (lo, hi) in (("sat", self.sat), ("val", self.val)):
            if not 0 <= lo <= hi <= _SV_MAX:
                raise ValueError(f"{name} = ({lo}, {hi}) must satisfy 0 <= lo <= hi <= 255")
        return self

    def mask(self, hsv: NDArray[np.uint8]) -> NDArray[np.uint8]:
        """Binary mask (255 = in range) of an 8-bit HSV image (H, W, 3)."""
        out = None
        for lo, hi in self.hue:
            m = cv2.inRange(hsv, (lo, self.sat[0], self.val[0]), (hi, self.sat[1], self.val[1]))
            out = m if out is None else cv2.bitwise_or(out, m)
        return out


#: Seed 000 §3.2.1: red main marker.
RED = HSVRange(hue=((0, 10), (170, 180)), sat=(50, 255), val=(50, 255))
#: Seed 000 §3.2.1: yellow auxiliary marker.
YELLOW = HSVRange(hue=((15, 40),), sat=(50, 255), val=(50, 255))


class HSVGateConfig(BaseModel):
    """Colour ranges and threshold of the confidence gate (seed 000 §3.2.1)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    red: HSVRange = Field(RED, description="Seed 000 §3.2.1: H∈[0,10]∪[170,180], S,V∈[50,255].")
    yellow: HSVRange = Field(YELLOW, description="Seed 000 §3.2.1: H∈[15,40], S,V∈[50,255].")
    min_ratio: float = Field(
        0.05,
        ge=0.0,
        lt=1.0,
        description="Seed 000 §3.2.1: the observation is valid when the valid-pixel ratio "
        "exceeds this.",
    )

    def range_of(self, colour: Colour) -> HSVRange:
        """The HSV range of the gate for ``colour`` (``"red"`` or ``"yellow"``); ``ValueError``
        naming ``colour`` for any other value."""
        if colour == "red":
            return self.red
        if colour == "yellow":
            return self.yellow
        raise ValueError(f"colour must be 'red' or 'yellow', got {colour!r}")


@dataclass(frozen=True)
class GateResult:
    """Outcome of the gate for one box.

    Attributes
    ----------
    ratio : fraction of the box's pixels inside the colour's HSV ranges, in [0, 1]
        (0 when the box is unusable).
    confident : ``ratio > min_ratio`` (seed 000 §3.2.1).
    n_pixels : number of pixels counted (the box clipped to the frame).
    reason : why the observation is not confident ("" when it is).
    """

    ratio: float
    confident: bool
    n_pixels: int
    reason: str = ""


def check_rgb_image(image: object) -> str:
    """Return "" if ``image`` is a usable RGB frame (H, W, 3) uint8 with H, W > 0, else the
    reason why not. Never raises."""
    if not isinstance(image, np.ndarray):
        return f"frame is not a numpy array (got {type(image).__name__})"
    if image.ndim != 3 or image.shape[2] != 3:
        return f"frame must have shape (H, W, 3), got {image.shape}"
    if image.shape[0] == 0 or image.shape[1] == 0:
        return f"frame is empty (shape {image.shape})"
    if image.dtype != np.uint8:
        return f"frame must be uint8 RGB, got dtype {image.dtype}"
    return ""


def check_frame(
    image: object,
    params: PlantParams | None = None,
    binning: object = None,
    *,
    init_shape: tuple[int, ...] | None = None,
) -> str:
    """"" if ``image`` is a usable frame, else why not. Never raises.

    The one frame check of the trackers and the GK assistance, in this order:

    * RGB uint8 (H, W, 3), non-empty (``check_rgb_image``);
    * with ``params``: of the sensor's size at a valid ``binning``
      (``plant.scene.check_binning``), for the pair trackers and the GK assistance, which know
      the camera;
    * with ``init_shape``: the shape of the frame the tracker was initialised on, for the
      single-object trackers, which keep their track in that frame's pixels;
    * not featureless: values spanning more than ``UNIFORM_PTP_DN`` DN. An all-black, all-white
      or blank frame shows nothing to track, and a correlation tracker scores it as a perfect
      match (OpenCV's KCF reports success on a black frame), so every tracker refuses it.
    """
    bad = check_rgb_image(image)
    if bad:
        return bad
    img: NDArray[np.uint8] = image  # type: ignore[assignment]
    if params is not None:
        try:
            b = check_binning(params, binning)  # type: ignore[arg-type]
        except (TypeError, ValueError) as exc:
            return f"bad binning: {exc}"
        cam = params.camera
        expected = (cam.sensor_height_px // b, cam.sensor_width_px // b, 3)
        if img.shape != expected:
            return (f"frame shape {img.shape} does not match the sensor at binning {b}: "
                    f"expected {expected}")
    if init_shape is not None and img.shape != tuple(init_shape):
        return f"frame shape {img.shape} differs from the init frame's {tuple(init_shape)}"
    rows = np.ascontiguousarray(img).reshape(img.shape[0], -1)
    # A featureless frame is uniform in every row: a middle row whose values already span more
    # than UNIFORM_PTP_DN settles it without reading the whole frame (same verdict).
    lo, hi, _, _ = cv2.minMaxLoc(rows[img.shape[0] // 2])
    if hi - lo <= UNIFORM_PTP_DN:
        lo, hi, _, _ = cv2.minMaxLoc(rows)
    if hi - lo <= UNIFORM_PTP_DN:
        return f"frame is uniform (values {lo:.0f}-{hi:.0f} DN: all black, all white or blank)"
    return ""


def box_pixels(box_image_px: ArrayLike, width: int, height: int) -> tuple[slice, slice] | None:
    """Rows and columns of the pixels whose centres lie in the box (x, y, w, h), image px,
    clipped to a ``width`` x ``height`` frame; None if the box is not finite, has w or h <= 0,
    or contains no pixel centre of the frame."""
    try:
        x, y, w, h = (float(c) for c in np.asarray(box_image_px, dtype=float).reshape(4))
    except (TypeError, ValueError):
        return None
    if not all(math.isfinite(c) for c in (x, y, w, h)) or w <= 0.0 or h <= 0.0:
        return None
    c0, c1 = max(math.ceil(x), 0), min(math.floor(x + w), width - 1)
    r0, r1 = max(math.ceil(y), 0), min(math.floor(y + h), height - 1)
    if c1 < c0 or r1 < r0:
        return None
    return slice(r0, r1 + 1), slice(c0, c1 + 1)


def box_sensor_to_image(box_sensor_px: ArrayLike, binning: int) -> NDArray[np.float64]:
    """A box (x, y, w, h) in full-sensor pixels -> the same box in image pixels of a frame
    binned by ``binning``: corners map like points (``plant.camera.sensor_to_image``,
    ``u_image = (u_sensor + 0.5)/binning − 0.5``), sizes divide by ``binning``."""
    b = np.asarray(box_sensor_px, dtype=float).reshape(4)
    return np.array([(b[0] + 0.5) / binning - 0.5, (b[1] + 0.5) / binning - 0.5,
                     b[2] / binning, b[3] / binning])


def box_image_to_sensor(box_image_px: ArrayLike, binning: int) -> NDArray[np.float64]:
    """Inverse of ``box_sensor_to_image``: image-pixel box of a binned frame -> sensor px."""
    b = np.asarray(box_image_px, dtype=float).reshape(4)
    return np.array([(b[0] + 0.5) * binning - 0.5, (b[1] + 0.5) * binning - 0.5,
                     b[2] * binning, b[3] * binning])


def colour_mask(image_rgb: NDArray[np.uint8], hsv_range: HSVRange) -> NDArray[np.uint8]:
    """Binary mask (255 = in range) of an RGB image (or crop) for one colour class."""
    return hsv_range.mask(cv2.cvtColor(image_rgb, cv2.COLOR_RGB2HSV))


class HSVGate:
    """The seed's confidence gate (seed 000 §3.2.1): valid-pixel ratio inside a box.

    Parameters
    ----------
    config : HSVGateConfig, optional
        Colour ranges and the ratio threshold (defaults from the seed).
    """

    def __init__(self, config: HSVGateConfig | None = None) -> None:
        self.config = config or HSVGateConfig()

    def ratio(self, image_rgb: NDArray[np.uint8], box_image_px: ArrayLike,
              colour: Colour = "red") -> GateResult:
        """Valid-pixel ratio of ``colour`` in the box (x, y, w, h), image px of ``image_rgb``
        (an RGB frame, see the module docstring). Bad frames or boxes give ``ratio = 0``,
        ``confident = False`` and a reason; nothing raises."""
        bad = check_rgb_image(image_rgb)
        if bad:
            return GateResult(0.0, False, 0, bad)
        h, w = image_rgb.shape[:2]
        sl = box_pixels(box_image_px, w, h)
        if sl is None:
            return GateResult(0.0, False, 0, "box is not finite, empty or outside the frame")
        crop = np.ascontiguousarray(image_rgb[sl])
        mask = colour_mask(crop, self.config.range_of(colour))
        n = int(mask.size)
        r = float(cv2.countNonZero(mask)) / n
        ok = r > self.config.min_ratio
        reason = "" if ok else (
            f"{colour} valid-pixel ratio {r:.3f} <= {self.config.min_ratio} in the box"
        )
        return GateResult(r, ok, n, reason)
