"""Pixel scale S of the VFC: how many pixels one metre at the markers spans (seed 000 §3.2.3).

The geometric check of the auxiliary marker (seed 000 §3.2.2) expects the two markers
D_exp = L·S·cos β apart, so it needs the scale S. The seed keeps S current with an exponential
moving average of the detected distance D_det,

    S_t = 0.9·S_{t−1} + 0.1·D_det / L,                          (seed 000 §3.2.3)

executed only while both markers are validly observed and the rotor is nearly level
(β < 2°), where the foreshortening cos β is negligible; at larger tilt S_t is locked.

Units: S in *full-sensor* pixels per metre (the seed writes pixels/mm; ×1000 here), D_det in
sensor pixels, L in metres, β in radians.

**Initial value from the camera model.** At rest the VFC plate is parallel to the image plane at
depth h_c from the optical centre (``plant.camera``: the camera is at Z = −(R + h_c), the plate
at Z = −R), so a pinhole camera images a length L on it as f·L/(p·h_c) pixels, with f the focal
length and p the pixel pitch:

    S_0 = f / (p · h_c)        [sensor px/m]; 0.025 / (3.45e−6 · 0.30) = 24,155 px/m.

With lens distortion or a marker pair away from the image centre this is approximate; the EMA
then pulls S toward the measured value during the first level frames.
"""

from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict, Field

from plant.params import CameraParams


def scale_from_camera(camera: CameraParams) -> float:
    """Pixel scale S_0 = f / (p · h_c), full-sensor px per metre, of the VFC plate at rest
    (pinhole model; see the module docstring)."""
    return camera.focal_length_m / (camera.pixel_size_m * camera.h_c_m)


class ScaleEMAConfig(BaseModel):
    """Parameters of the pixel-scale EMA (seed 000 §3.2.3)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    alpha: float = Field(
        0.1, gt=0.0, le=1.0, description="Seed 000 §3.2.3: weight of the new D_det/L (0.1)."
    )
    tilt_max_deg: float = Field(
        2.0, ge=0.0, le=90.0, description="Seed 000 §3.2.3: update only while β < 2°."
    )


class PixelScaleEMA:
    """The seed's pixel-scale EMA S_t = (1 − α)·S_{t−1} + α·D_det/L, gated on β < β_max.

    Parameters
    ----------
    L_m : float
        Physical distance L between the marker centres, m (seed 000 §3.2.2: 28.28 mm).
    S0_px_per_m : float
        Initial scale, sensor px/m (``scale_from_camera`` gives the camera model's value).
    config : ScaleEMAConfig, optional
        α = 0.1 and β_max = 2° by default (seed 000 §3.2.3).

    Raises ``ValueError`` naming the argument if L_m or S0_px_per_m is not finite and > 0.
    """

    def __init__(self, L_m: float, S0_px_per_m: float, config: ScaleEMAConfig | None = None):
        for name, val in (("L_m", L_m), ("S0_px_per_m", S0_px_per_m)):
            if not (isinstance(val, (int, float)) and math.isfinite(val) and val > 0.0):
                raise ValueError(f"{name} must be a finite number > 0, got {val!r}")
        self.L_m = float(L_m)
        self.S0 = float(S0_px_per_m)
        self.S = float(S0_px_per_m)
        self.config = config or ScaleEMAConfig()
        self.n_updates = 0

    @property
    def tilt_max_rad(self) -> float:
        """The tilt β_max above which the scale stays locked, rad
        (``ScaleEMAConfig.tilt_max_deg``)."""
        return math.radians(self.config.tilt_max_deg)

    def update(self, D_det_px: float, beta_rad: float | None) -> tuple[bool, str]:
        """One EMA step with the detected distance D_det (sensor px) at tilt β (rad, from the
        previous frame). Returns ``(updated, reason)``: no update, with the reason, when β is
        unknown or ≥ β_max (S stays locked) or D_det is not a finite positive number."""
        if beta_rad is None or not math.isfinite(beta_rad):
            return False, "tilt unknown: scale locked"
        if abs(beta_rad) >= self.tilt_max_rad:
            return False, f"tilt {math.degrees(abs(beta_rad)):.2f}° >= "\
                f"{self.config.tilt_max_deg}°: scale locked"
        if not (math.isfinite(D_det_px) and D_det_px > 0.0):
            return False, "detected distance not finite and positive"
        a = self.config.alpha
        self.S = (1.0 - a) * self.S + a * D_det_px / self.L_m
        self.n_updates += 1
        return True, ""

    def reset(self) -> None:
        """Back to the initial scale."""
        self.S = self.S0
        self.n_updates = 0
