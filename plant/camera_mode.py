"""Camera modes: how the region of interest, the binning and the exposure set the frame timing,
the motion blur and the measurement noise of the bottom camera.

A global-shutter CMOS sensor (the seed's MV-CA050-12UC, Sony IMX264, 2448 × 2048, seed 000
Table 2) exposes all rows at once and then reads them out row by row. Our model:

* **Readout.** The rows of the region of interest are read at the sensor's line time
  ``t_row`` and the frame is in host memory once the last row is out and its bytes have crossed
  the link: ``t_readout = (rows + blank_rows) t_row + bytes / bandwidth`` (the transfer streams
  while the sensor reads, so only the part of the transfer that outlasts the readout adds; we
  take the larger of the two). Binning is done in the camera after the readout, so it divides
  the bytes, not the rows.
* **Frame period.** Exposure overlaps the previous frame's readout, so
  ``T_f = max(t_readout, exposure + t_min_gap)``; a requested rate slower than that is kept.
* **Noise.** The marker centre's noise (sensor px) falls with the photons collected:
  ``σ² = σ_ref² (t_ref / t_exp) + (q b)²``, shot noise against a reference exposure plus a
  quantisation floor of the binned pixel (``b`` sensor px wide, ``q`` = 1/√12 of a pixel times
  the centroid's averaging, our estimate).
* **Blur.** The marker travel during the exposure is computed by the measurement front end from
  ``exposure_s`` (``latency.frontends.MeasurementFrontEnd``); the mode only sets the exposure.
* **Region of interest** (``RegionOfInterest``): ``rows × cols`` sensor px, fixed at the sensor
  centre or re-centred each frame on the predicted marker positions (``follow``). The
  measurement front end loses the markers when one falls outside it.

Figures are the data sheet's where we know them and our estimates otherwise, each marked.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

from plant.params import CameraParams


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class SensorTiming(_Strict):
    """Readout and noise figures of the sensor and its link."""

    width_px: int = Field(2448, gt=0, description="Seed 000 Table 2 (MV-CA050-12UC).")
    height_px: int = Field(2048, gt=0, description="Seed 000 Table 2 (MV-CA050-12UC).")
    line_time_s: float = Field(
        13.45e-6,
        gt=0.0,
        description="Our estimate: the IMX264's line time, chosen so that the full 2048 rows "
        "(plus the blanking) run at the seed's 36 frames/s (seed 000 §5).",
    )
    blank_rows: int = Field(16, ge=0, description="Our estimate: vertical blanking, rows.")
    min_gap_s: float = Field(
        50e-6, ge=0.0, description="Our estimate: shortest gap between exposure end and the "
        "next exposure's start (sensor reset)."
    )
    link_bytes_per_s: float = Field(
        360e6,
        gt=0.0,
        description="Our estimate: sustained USB3 Vision throughput of the MV-CA050-12UC "
        "(USB 3.0 runs at 5 Gbit/s raw, about 400 MB/s of payload).",
    )
    bytes_per_px: float = Field(1.0, gt=0.0, description="Bayer RG8: one byte per pixel.")
    noise_ref_px: float = Field(
        0.5,
        ge=0.0,
        description="Marker-centre noise at the reference exposure, sensor px; the "
        "measurement model's default (latency.frontends.MeasurementConfig.sigma_px).",
    )
    noise_ref_exposure_s: float = Field(
        2.0e-3, gt=0.0, description="The reference exposure of noise_ref_px: the seed "
        "camera's 2 ms (plant.params.CameraParams)."
    )
    quantisation_px: float = Field(
        0.05,
        ge=0.0,
        description="Our estimate: centre noise floor per binned pixel width (a centroid over "
        "~50 pixels of a disc averages the 1/sqrt(12) pixel quantisation down to ~0.05).",
    )


class RegionOfInterest(_Strict):
    """The rows × cols (sensor px) read out, centred on the sensor or on the predicted markers.

    ``follow``: the camera re-centres the region each frame on the mean of the predicted marker
    positions (the last measurement advanced by the last inter-frame motion, the tracker's
    constant-velocity prediction); while the markers are lost it stays where it was.
    """

    rows: int = Field(ge=16, description="Rows read out, sensor px.")
    cols: int = Field(ge=16, description="Columns read out, sensor px.")
    follow: bool = Field(False, description="Re-centre on the predicted markers each frame.")

    def centre_px(
        self, sensor_px: tuple[int, int], predicted_px: ArrayLike | None = None
    ) -> NDArray[np.float64]:
        """Centre (u, v) of the region for the next frame, sensor px: the sensor's centre, or
        with ``follow`` the mean of the predicted marker centres ``predicted_px`` (2, 2) when
        there is a prediction; shifted so that the region lies on the ``sensor_px``
        (width, height) sensor.

        Mirrored in ``latency.compiled.frontend._roi_misses``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        size = np.asarray(sensor_px, dtype=float)
        centre = (size - 1.0) / 2.0
        if self.follow and predicted_px is not None:
            centre = np.asarray(predicted_px, dtype=float).mean(axis=0)
        half = 0.5 * np.minimum([self.cols, self.rows], size)
        return np.clip(centre, half - 0.5, size - 0.5 - half)

    def contains(self, points_px: ArrayLike, centre_px: ArrayLike) -> bool:
        """All ``points_px`` (n, 2; u, v sensor px) lie in the region centred on
        ``centre_px`` (a NaN point does not).

        Mirrored in ``latency.compiled.frontend._roi_misses``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        offset = np.abs(np.asarray(points_px, dtype=float) - np.asarray(centre_px, dtype=float))
        return bool(np.all(offset <= 0.5 * np.array([self.cols, self.rows])))


class CameraMode(_Strict):
    """One operating mode of the camera: region of interest, binning and exposure.

    ``rows``/``cols`` None read the whole sensor. ``frame_rate_hz`` None runs at the fastest
    rate the mode allows (``max_frame_rate_hz``); a given rate must not exceed it.
    """

    rows: int | None = Field(None, ge=16, description="ROI rows, sensor px; None: all.")
    cols: int | None = Field(None, ge=16, description="ROI columns, sensor px; None: all.")
    follow: bool = Field(False, description="ROI follows the predicted markers.")
    binning: int = Field(1, ge=1, le=4, description="Binning factor (in the camera).")
    exposure_s: float = Field(2.0e-3, gt=0.0, le=0.1, description="Exposure time, s.")
    frame_rate_hz: float | None = Field(None, gt=0.0, description="None: the mode's fastest.")
    sensor: SensorTiming = SensorTiming()

    @model_validator(mode="after")
    def _rate_possible(self) -> CameraMode:
        if self.frame_rate_hz is not None and self.frame_rate_hz > self.max_frame_rate_hz + 1e-9:
            raise ValueError(
                f"frame_rate_hz = {self.frame_rate_hz:g} exceeds the fastest rate of this mode, "
                f"{self.max_frame_rate_hz:.4g} Hz (readout {self.readout_s * 1e3:.3g} ms, "
                f"exposure {self.exposure_s * 1e3:.3g} ms)"
            )
        return self

    @property
    def size_px(self) -> tuple[int, int]:
        """(rows, cols) read out, sensor px, clipped to the sensor."""
        h, w = self.sensor.height_px, self.sensor.width_px
        return min(self.rows or h, h), min(self.cols or w, w)

    @property
    def readout_s(self) -> float:
        """Exposure end to frame in host memory, s: the larger of the sensor readout of the
        ROI's rows and its transfer over the link (module docstring)."""
        rows, cols = self.size_px
        s = self.sensor
        sensor = (rows + s.blank_rows) * s.line_time_s
        payload = math.ceil(rows / self.binning) * math.ceil(cols / self.binning) * s.bytes_per_px
        return max(sensor, payload / s.link_bytes_per_s)

    @property
    def max_frame_rate_hz(self) -> float:
        """Fastest frame rate of the mode, Hz: ``1 / max(readout, exposure + gap)``."""
        return 1.0 / max(self.readout_s, self.exposure_s + self.sensor.min_gap_s)

    @property
    def rate_hz(self) -> float:
        """The frame rate the mode runs at, Hz."""
        return self.max_frame_rate_hz if self.frame_rate_hz is None else self.frame_rate_hz

    @property
    def sigma_px(self) -> float:
        """Marker-centre noise per coordinate, sensor px (module docstring)."""
        s = self.sensor
        shot = s.noise_ref_px**2 * s.noise_ref_exposure_s / self.exposure_s
        return math.sqrt(shot + (s.quantisation_px * self.binning) ** 2)

    @property
    def roi(self) -> RegionOfInterest | None:
        """The region of interest (None when the whole sensor is read)."""
        rows, cols = self.size_px
        whole = rows >= self.sensor.height_px and cols >= self.sensor.width_px
        return None if whole else RegionOfInterest(rows=rows, cols=cols, follow=self.follow)

    def camera_params(self, base: CameraParams) -> CameraParams:
        """``base`` with this mode's frame rate and exposure (the renderers' binning is a
        simulation setting and stays ``base``'s); ``ValueError`` if ``base``'s sensor differs
        from the mode's."""
        if (base.sensor_width_px, base.sensor_height_px) != (self.sensor.width_px,
                                                              self.sensor.height_px):
            raise ValueError(
                f"camera sensor {base.sensor_width_px} x {base.sensor_height_px} px differs from "
                f"the camera mode's sensor {self.sensor.width_px} x {self.sensor.height_px} px "
                "(set sensor.width_px / height_px)"
            )
        return base.model_copy(update={"frame_rate_hz": self.rate_hz,
                                       "exposure_s": self.exposure_s})
