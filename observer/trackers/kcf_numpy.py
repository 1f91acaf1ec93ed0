"""A kernelized correlation filter (KCF) in numpy that can search around an external centre.

OpenCV's ``TrackerKCF`` always searches around its own previous position, so it cannot take the
Kalman-predicted window of K²CF (seed 004 §3.2.2). This is the same algorithm, written from the
equations of seed 004 §3.1 (and Henriques et al., "High-speed tracking with kernelized
correlation filters", TPAMI 2015, which seed 004 builds on):

* **Training** (seed 004 eqs. 4-7, 10-11): a feature patch x of the target with context
  (``padding``), multiplied by a cosine (Hann) window; a Gaussian regression target y over the
  cyclic shifts (its peak at zero shift, width ``output_sigma_factor`` x the target size: the
  "importance" of the shifted negative samples, seed 004 eq. 10); the Gaussian kernel
  correlation k^{xx'} = exp(-(|x|² + |x'|² - 2 F⁻¹(Σ_c x̂_c* ⊙ x̂'_c)) / (σ² N)) computed with FFTs
  (eq. 11, normalised by the number of samples N as Henriques et al. do); the dual coefficients
  α̂ = ŷ / (k̂^{xx} + λ) (eq. 7).
* **Detection** (eqs. 8, 13-16): the response f(z) = F⁻¹(k̂^{xz} ⊙ α̂) over all cyclic shifts of
  the patch z cut at the *search centre*; its peak (refined to sub-pixel by a parabola through
  the neighbours, our addition) is the target's displacement from that centre.
* **Update** (eq. 9): α̂ and x̂ are blended with the learning factor ``interp_factor`` at the new
  position. Our addition: the update is skipped when the response peak is below
  ``min_update_peak``, so that an occluder is not learnt as the target.

The API is ``observer.tracking.SingleObjectTracker``, as for
``observer.transt.tracker.TransTTracker``: ``initialize(frame, box_image_px)``, ``track(frame,
search_centre_image_px=None) -> TrackResult``. So the tracker also serves as a fast stand-in for
the TransT network behind GK-TransT. Frames are RGB uint8; boxes (x, y, w, h) and centres are in
*image* pixels of the frame (OpenCV pixel-centre convention). The box keeps the initial size (the
markers barely change size: cos 15° = 0.966 at the tilt stop), so there is no scale search.

The score is the response peak: about 1 for an unchanged target at the predicted place (y has
peak 1), near 0 when nothing resembles the model. Bad frames give a failed result (NaN box,
score 0, not valid); any finite box is ``valid`` (the KCF has no verdict of its own: its users
judge the score).
"""

from __future__ import annotations

import math
import time
from typing import Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from observer.gk.hsv_gate import check_frame, check_rgb_image
from observer.tracking import TrackResult


class KCFConfig(BaseModel):
    """Parameters of the numpy KCF.

    Defaults: Henriques et al. (TPAMI 2015) for raw-pixel features (padding 1.5, λ = 1e-4,
    kernel σ = 0.2, output σ factor 0.1, interpolation 0.075); the rest is our choice.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    padding: float = Field(
        1.5, ge=0.0, le=5.0, description="Henriques et al.: window = (1 + padding) x target."
    )
    lambda_: float = Field(1e-4, gt=0.0, description="Henriques et al.: ridge λ (seed 004 eq. 4).")
    kernel_sigma: float = Field(
        0.2, gt=0.0, description="Henriques et al. (raw pixels): Gaussian kernel σ (eq. 11)."
    )
    output_sigma_factor: float = Field(
        0.1, gt=0.0, description="Henriques et al.: σ of the label y (eq. 10) as a fraction of "
        "the target size (in feature pixels)."
    )
    interp_factor: float = Field(
        0.075, ge=0.0, le=1.0, description="Henriques et al. (raw pixels): learning factor β "
        "of seed 004 eq. 9."
    )
    features: Literal["gray", "rgb"] = Field(
        "rgb", description="Our choice: raw colour pixels (3 channels, scaled to [-0.5, 0.5]); "
        "'gray' is the luminance only. The red and yellow markers differ in colour, not in "
        "brightness."
    )
    template_px: int = Field(
        64, ge=16, le=512, description="Our choice: the window's longer side is resampled to "
        "this many feature pixels (cost control; 64 keeps a 48-px marker at ~0.5 scale)."
    )
    min_update_peak: float = Field(
        0.25, ge=0.0, description="Our choice: no model update when the response peak is below "
        "this (occlusion guard)."
    )
    subpixel_peak: bool = Field(True, description="Our choice: parabolic peak interpolation.")


def _hann2d(ny: int, nx: int) -> NDArray[np.float32]:
    """Cosine (Hann) window (ny, nx) that suppresses the patch border (seed 004 §3.1.2)."""
    return np.outer(np.hanning(ny), np.hanning(nx)).astype(np.float32)


def _gaussian_label(ny: int, nx: int, sigma: float) -> NDArray[np.float32]:
    """Regression target y (ny, nx): a Gaussian of the cyclic shift, peak 1 at shift (0, 0)
    (seed 004 eq. 10, normalised to a unit peak rather than unit area)."""
    dy = np.fft.fftfreq(ny) * ny  # signed shifts 0, 1, ..., -1
    dx = np.fft.fftfreq(nx) * nx
    return np.exp(-0.5 * (dy[:, None] ** 2 + dx[None, :] ** 2) / sigma**2).astype(np.float32)


def _parabola_offset(m1: float, c: float, p1: float) -> float:
    """Sub-sample offset of the vertex of the parabola through (-1, m1), (0, c), (1, p1)."""
    den = m1 - 2.0 * c + p1
    if den >= 0.0 or not math.isfinite(den):
        return 0.0
    return float(np.clip(0.5 * (m1 - p1) / den, -0.5, 0.5))


class NumpyKCF:
    """Single-target KCF with an optional external search centre (see the module docstring).

    Attributes
    ----------
    compute_time_s : wall-clock time of the last ``initialize`` or ``track`` call, s.
    centre_image_px : (2,) current target centre, image px (NaN before ``init``).
    size_image_px : (2,) target box size (w, h), image px.
    last_peak : response peak of the last ``track`` (the score).
    last_shift_image_px : (2,) displacement of the peak from the search centre, image px.
    """

    def __init__(self, config: KCFConfig | None = None) -> None:
        self.config = config or KCFConfig()
        self.compute_time_s = 0.0
        self.centre_image_px = np.full(2, np.nan)
        self.size_image_px = np.full(2, np.nan)
        self.last_peak = 0.0
        self.last_shift_image_px = np.zeros(2)
        self._frame_shape: tuple[int, ...] | None = None
        self._alphaf: NDArray[np.complex64] | None = None
        self._xf: NDArray[np.complex64] | None = None

    @property
    def initialised(self) -> bool:
        """Whether ``initialize`` has been called (the filter's dual coefficients exist)."""
        return self._alphaf is not None

    # --- features and kernels -------------------------------------------------------------------
    def _patch(self, frame: NDArray[np.uint8], centre: NDArray[np.float64]) -> NDArray[np.float32]:
        """Feature patch (C, ny, nx) of the window around ``centre`` (image px), resampled by
        ``self._scale`` with a bilinear warp (replicated border), windowed."""
        s = self._scale
        ny, nx = self._shape
        # output pixel (j, i) <- input point centre + ((j, i) - (n - 1)/2) / s
        M = np.array([[1.0 / s, 0.0, centre[0] - (nx - 1) / 2.0 / s],
                      [0.0, 1.0 / s, centre[1] - (ny - 1) / 2.0 / s]])
        warped = cv2.warpAffine(frame, M, (nx, ny), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                borderMode=cv2.BORDER_REPLICATE)
        if self.config.features == "gray":
            feat = cv2.cvtColor(warped, cv2.COLOR_RGB2GRAY)[None].astype(np.float32)
        else:
            feat = np.moveaxis(warped, 2, 0).astype(np.float32)
        feat = feat * np.float32(1.0 / 255.0) - np.float32(0.5)
        return feat * self._window[None]

    def _kernel_f(self, xf: NDArray, zf: NDArray, xx: float, zz: float) -> NDArray:
        """FFT of the Gaussian kernel correlation k^{xz} over all cyclic shifts (eq. 11)."""
        n = self._shape[0] * self._shape[1] * xf.shape[0]
        cross = np.fft.irfft2(np.sum(np.conj(xf) * zf, axis=0), s=self._shape)
        d = np.maximum(xx + zz - 2.0 * cross, 0.0) / n
        return np.fft.rfft2(np.exp(-d / self.config.kernel_sigma**2))

    def _train(self, x: NDArray[np.float32]) -> tuple[NDArray, NDArray]:
        """(α̂, x̂) of a training patch (eq. 7)."""
        xf = np.fft.rfft2(x)
        xx = float(np.sum(x * x))
        kf = self._kernel_f(xf, xf, xx, xx)
        return self._yf / (kf + self.config.lambda_), xf

    # --- the tracker seam -----------------------------------------------------------------------
    def initialize(self, frame: NDArray[np.uint8], box_image_px: ArrayLike) -> None:
        """Start on the target in ``box_image_px`` (x, y, w, h), image px of ``frame`` (RGB).

        Raises ``ValueError`` for an unusable frame or a box that is not finite, has w or h <= 0
        or whose centre is outside the frame.
        """
        t0 = time.perf_counter()
        bad = check_rgb_image(frame)
        if bad:
            raise ValueError(bad)
        box = np.asarray(box_image_px, dtype=float).reshape(-1)
        if box.shape != (4,) or not np.all(np.isfinite(box)) or box[2] <= 0 or box[3] <= 0:
            raise ValueError(f"box_image_px must be a finite (x, y, w, h) with w, h > 0: {box}")
        centre = box[:2] + 0.5 * box[2:]
        H, W = frame.shape[:2]
        if not (-0.5 <= centre[0] <= W - 0.5 and -0.5 <= centre[1] <= H - 0.5):
            raise ValueError(f"box centre {centre} is outside the {W} x {H} frame")
        cfg = self.config
        window = box[2:] * (1.0 + cfg.padding)
        self._scale = min(1.0, cfg.template_px / float(window.max()))
        nx, ny = (max(8, 2 * int(round(0.5 * w * self._scale))) for w in window)
        self._shape = (ny, nx)
        self._window = _hann2d(ny, nx)
        sigma = cfg.output_sigma_factor * math.sqrt(float(np.prod(box[2:]))) * self._scale
        self._yf = np.fft.rfft2(_gaussian_label(ny, nx, max(sigma, 0.5)))
        self._alphaf, self._xf = self._train(self._patch(frame, centre))
        self._frame_shape = frame.shape
        self.centre_image_px = centre
        self.size_image_px = box[2:].copy()
        self.last_peak = 1.0
        self.last_shift_image_px = np.zeros(2)
        self.compute_time_s = time.perf_counter() - t0

    def response(self, frame: NDArray[np.uint8], centre_image_px: ArrayLike) -> NDArray:
        """Response map (ny, nx) of the window cut at ``centre_image_px``: entry (i, j) is the
        score of the target displaced by the cyclic shift (i, j) feature px (eq. 16)."""
        z = self._patch(frame, np.asarray(centre_image_px, dtype=float))
        zf = np.fft.rfft2(z)
        xx = self._energy(self._xf)  # |x|² of the (blended) model patch
        kzf = self._kernel_f(self._xf, zf, xx, float(np.sum(z * z)))
        return np.fft.irfft2(self._alphaf * kzf, s=self._shape)

    def _energy(self, xf: NDArray) -> float:
        """Σ x² of the real patch whose rfft2 is ``xf`` (Parseval with the half spectrum)."""
        nx = self._shape[1]
        p = np.abs(xf) ** 2
        w = np.full(p.shape[-1], 2.0)
        w[0] = 1.0
        if nx % 2 == 0:
            w[-1] = 1.0
        return float(np.sum(p * w) / (self._shape[0] * nx))

    def track(
        self, frame: NDArray[np.uint8], search_centre_image_px: ArrayLike | None = None
    ) -> TrackResult:
        """Box (x, y, w, h), image px, and score (the response peak) in ``frame``.

        ``search_centre_image_px`` (u, v) places the detection window (seed 004 §3.2.2); by
        default it is the previous position (plain KCF). A bad frame
        (``observer.gk.hsv_gate.check_frame``: not RGB uint8, a shape other than the init
        frame's, or featureless: all black or all white), a non-finite search centre or no
        ``initialize`` gives a failed result (NaN box, score 0).
        """
        t0 = time.perf_counter()
        box, peak = self._track(frame, search_centre_image_px)
        self.compute_time_s = time.perf_counter() - t0
        if not np.all(np.isfinite(box)):
            return TrackResult.failed("no box: bad frame or search centre, or not initialised",
                                      self.compute_time_s)
        return TrackResult(box, peak, True, "", self.compute_time_s)

    def _track(
        self, frame: NDArray[np.uint8], search_centre: ArrayLike | None
    ) -> tuple[NDArray[np.float64], float]:
        nan_box = np.full(4, np.nan)
        if not self.initialised or check_frame(frame, init_shape=self._frame_shape):
            self.last_peak = 0.0
            return nan_box, 0.0
        centre = self.centre_image_px if search_centre is None else \
            np.asarray(search_centre, dtype=float).reshape(-1)
        if centre.shape != (2,) or not np.all(np.isfinite(centre)):
            self.last_peak = 0.0
            return nan_box, 0.0
        resp = self.response(frame, centre)
        ny, nx = self._shape
        iy, ix = np.unravel_index(int(np.argmax(resp)), resp.shape)
        peak = float(resp[iy, ix])
        dy, dx = float(iy), float(ix)
        if self.config.subpixel_peak:
            dy += _parabola_offset(resp[(iy - 1) % ny, ix], peak, resp[(iy + 1) % ny, ix])
            dx += _parabola_offset(resp[iy, (ix - 1) % nx], peak, resp[iy, (ix + 1) % nx])
        # cyclic shift -> signed displacement
        dy = dy - ny if dy > ny / 2 else dy
        dx = dx - nx if dx > nx / 2 else dx
        shift = np.array([dx, dy]) / self._scale
        new_centre = centre + shift
        self.last_peak = peak
        self.last_shift_image_px = shift
        if not math.isfinite(peak):
            return nan_box, 0.0
        self.centre_image_px = new_centre
        cfg = self.config
        if peak >= cfg.min_update_peak and cfg.interp_factor > 0.0:
            alphaf, xf = self._train(self._patch(frame, new_centre))
            f = cfg.interp_factor
            self._alphaf = (1.0 - f) * self._alphaf + f * alphaf
            self._xf = (1.0 - f) * self._xf + f * xf
        box = np.r_[new_centre - 0.5 * self.size_image_px, self.size_image_px]
        return box, peak
