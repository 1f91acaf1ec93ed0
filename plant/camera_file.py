"""A camera description file: the camera's parameters and, optionally, its calibrated intrinsics.

``pmspm calibrate`` writes one; ``pmspm track`` and the scenarios read it. Layout (YAML)::

    camera:                       # plant.params.CameraParams fields (missing ones keep defaults)
      sensor_width_px: 2448
      sensor_height_px: 2048
      binning: 4
      ...
    calibration:                  # optional: what a calibration measured, full-sensor px
      fx_px: 7246.4
      fy_px: 7246.4
      cx_px: 1223.5
      cy_px: 1023.5
      std_px: [fx, fy, cx, cy]    # one standard deviation of each (OpenCV calibrateCameraExtended)
      dist_coeffs: [k1, k2, p1, p2, k3]
      dist_std: [k1, k2, p1, p2, k3]
      rms_px: 0.05                # RMS reprojection error, px of the calibration frames
      n_views: 40

The ``camera`` block gives the sensor, the timing and a nominal pinhole; the ``calibration``
block keeps what a calibration measured with its uncertainties. ``CameraFile.params`` is the
camera the plant, the renderers, the scenarios and the attitude solver (seed 002 eq. 5-11) use:
the ``camera`` block with the calibrated focal lengths, principal point
(``CameraParams.intrinsics_px``) and distortion when ``calibration`` is given. Errors name the
field and its allowed range (pydantic).
"""

from __future__ import annotations

from pathlib import Path

import yaml
from pydantic import BaseModel, ConfigDict, Field

from plant.params import CameraParams

Vec4 = tuple[float, float, float, float]
Vec5 = tuple[float, float, float, float, float]


class CalibratedIntrinsics(BaseModel):
    """Intrinsics measured by a calibration, in full-sensor pixels (OpenCV pixel-centre
    convention), with one-sigma uncertainties."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    fx_px: float = Field(gt=0.0, description="Focal length along u, sensor px.")
    fy_px: float = Field(gt=0.0, description="Focal length along v, sensor px.")
    cx_px: float = Field(description="Principal point u, sensor px.")
    cy_px: float = Field(description="Principal point v, sensor px.")
    std_px: Vec4 = Field((0.0, 0.0, 0.0, 0.0), description="1-sigma of fx, fy, cx, cy, px.")
    dist_coeffs: Vec5 = Field((0.0,) * 5, description="OpenCV (k1, k2, p1, p2, k3).")
    dist_std: Vec5 = Field((0.0,) * 5, description="1-sigma of the distortion coefficients.")
    rms_px: float = Field(0.0, ge=0.0, description="RMS reprojection error, calibration px.")
    n_views: int = Field(0, ge=0, description="Board views used.")


class CameraFile(BaseModel):
    """The camera YAML: ``camera`` (``CameraParams``) and optional ``calibration``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    camera: CameraParams = CameraParams()
    calibration: CalibratedIntrinsics | None = None

    @property
    def params(self) -> CameraParams:
        """The camera as used everywhere: ``camera`` with ``calibration``'s (fx, fy, cx, cy)
        as ``intrinsics_px`` and its distortion, when a calibration is given (validated: the
        principal point must lie on the sensor)."""
        cal = self.calibration
        if cal is None:
            return self.camera
        return CameraParams.model_validate(self.camera.model_dump() | {
            "intrinsics_px": (cal.fx_px, cal.fy_px, cal.cx_px, cal.cy_px),
            "dist_coeffs": cal.dist_coeffs})

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of the frames, px: the sensor binned by ``camera.binning``."""
        c = self.camera
        return c.sensor_width_px // c.binning, c.sensor_height_px // c.binning

    @classmethod
    def from_yaml(cls, path: str | Path) -> CameraFile:
        """Read a camera YAML (``ValidationError`` names the bad field)."""
        with open(path) as fh:
            return cls.model_validate(yaml.safe_load(fh) or {})

    def save(self, path: str | Path) -> Path:
        """Write the YAML; returns the path."""
        out = Path(path)
        out.parent.mkdir(parents=True, exist_ok=True)
        data = self.model_dump(mode="json", exclude_none=True)
        out.write_text(yaml.safe_dump(data, sort_keys=False))
        return out
