"""Every physical parameter of the motor, the rotor and the camera scene, in one place.

Each default either cites the seed it comes from or says that it is our choice and why.
SI units throughout (m, kg, s, A, N·m, rad) unless a field name says otherwise
(``*_deg``, ``*_mm``, ``*_px``). The objects are pydantic models, so a scenario file that sets
a field outside its range fails with a message that names the field.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import numpy as np
import yaml
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

Vec3 = Annotated[tuple[float, float, float], Field(description="3-vector")]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class MotorParams(_Strict):
    """Electromagnetic part: magnets, coils and the torque characteristic f(phi).

    The torque of coil i on magnet j is ``T_ij = s_j * f(phi_ij) * (c_i x r_j)/|c_i x r_j| * I_i``
    (the standard PMSpM superposition model). We use
    ``f(phi) = k_T * sin(phi) * w(cos phi)`` with the window
    ``w(x) = ((x - cos phi_c) / (1 - cos phi_c))**2`` for ``x > cos phi_c`` and 0 beyond the
    cutoff, a sine-shaped bump that is zero at phi = 0 and at the cutoff phi_c and is C1
    everywhere (our choice: smooth enough for the MPC's derivatives, cheap in CasADi).
    """

    coil_latitude_deg: float = Field(
        25.0, gt=0.0, lt=60.0, description="Our choice: the DESIGN check found 20–30° well posed."
    )
    lower_layer_offset_deg: float = Field(
        22.5,
        ge=0.0,
        lt=45.0,
        description="Our choice: azimuth offset of the lower coil layer; "
        "halves the worst condition number of K(q) (docs/plant.md).",
    )
    cutoff_deg: float = Field(40.0, gt=5.0, lt=90.0, description="Our choice: f(phi)=0 beyond it.")
    k_T_Nm_per_A: float = Field(
        0.15,
        gt=0.0,
        description="Our choice: scale of one coil-magnet pair's f(phi). With "
        "i_max = 2 A the motor delivers 0.28–0.53 N·m depending on direction "
        "(docs/plant.md, measured).",
    )
    i_max_A: float = Field(2.0, gt=0.0, description="Our choice: per-coil current limit.")
    coil_time_constant_s: float = Field(
        0.0, ge=0.0, description="Our choice: L/R of a coil; 0 = ideal current drive (no lag)."
    )


class RotorParams(_Strict):
    """Rigid-body parameters of the rotor. The seeds give only the radius."""

    radius_m: float = Field(0.065, gt=0.0, description="Seed 000 Table 2: rotor radius 65 mm.")
    mass_kg: float = Field(
        1.5, gt=0.0, description="Our choice: steel-backed shell with 18 NdFeB magnets."
    )
    inertia_com_kgm2: Vec3 = Field(
        (2.2e-3, 2.2e-3, 2.5e-3),
        description="Our choice: principal inertia about the centre of mass; between a thin "
        "shell (2/3 m r^2 = 4.2e-3) and a solid ball (2/5 m r^2 = 2.5e-3), axis slightly larger.",
    )
    com_offset_m: Vec3 = Field(
        (0.0, 0.0, 0.0),
        description="Our choice: centre of mass in the rotor frame (gravity "
        "torque when non-zero; a negative z makes a pendulum).",
    )
    viscous_Nms_per_rad: float = Field(
        2.0e-3, ge=0.0, description="Our choice: bearing + eddy-current damping."
    )
    coulomb_Nm: float = Field(3.0e-3, ge=0.0, description="Our choice: ball-bearing dry friction.")
    coulomb_smoothing_rad_s: float = Field(
        0.01,
        gt=0.0,
        description="Our choice: Coulomb friction torque is "
        "-tau_c*omega/sqrt(|omega|^2 + omega_s^2), smooth so that the MuJoCo model and the "
        "CasADi twin share one law.",
    )
    tilt_stop_deg: float = Field(15.0, gt=0.0, lt=60.0, description="Seed 000 §2.4: 0–15° tilt.")
    gravity_m_s2: float = Field(9.81, ge=0.0, description="Standard gravity along -Z.")

    @property
    def inertia_about_centre_kgm2(self) -> NDArray[np.float64]:
        """(3, 3) inertia about the fixed centre O, kg·m², rotor frame: the centre-of-mass
        inertia moved by the offset d (parallel-axis theorem),
        J_O = J_c + m (|d|² I − d dᵀ)."""
        d = np.asarray(self.com_offset_m, dtype=float)
        return np.diag(self.inertia_com_kgm2) + self.mass_kg * (d @ d * np.eye(3) - np.outer(d, d))


class CameraParams(_Strict):
    """The bottom camera. Sensor from seed 000 Table 2; lens and distance are our choice."""

    sensor_width_px: int = Field(2448, gt=0, description="Seed 000 Table 2 (MV-CA050-12UC).")
    sensor_height_px: int = Field(2048, gt=0, description="Seed 000 Table 2 (MV-CA050-12UC).")
    pixel_size_m: float = Field(3.45e-6, gt=0.0, description="Seed 000 Table 2 / datasheet.")
    focal_length_m: float = Field(
        0.025,
        gt=0.0,
        description="Our choice: a 25 mm C-mount lens; at h_c = 0.30 m the "
        "short sensor side sees ±42 mm, enough for the markers at 15° tilt (±35 mm).",
    )
    h_c_m: float = Field(
        0.30,
        gt=0.0,
        description="Our choice: optical centre to the rest plane of the bottom "
        "pole (seed 000 §2.5's h_c), 'significantly larger than R' as §2.4 requires.",
    )
    binning: int = Field(
        4,
        ge=1,
        le=16,
        description="Our choice: render at sensor/4 (612x512) for speed. "
        "Ground truth is always in full-sensor pixels.",
    )
    dist_coeffs: tuple[float, float, float, float, float] = Field(
        (0.0, 0.0, 0.0, 0.0, 0.0), description="OpenCV (k1, k2, p1, p2, k3); ideal lens default."
    )
    frame_rate_hz: float = Field(
        36.0, gt=0.0, description="Seed 000 §5: 90 frames span 2.5 s, i.e. 36 frames/s."
    )
    exposure_s: float = Field(2.0e-3, gt=0.0, description="Our choice: 2 ms with a ring LED.")
    mount_roll_deg: float = Field(
        0.0,
        ge=-180.0,
        le=180.0,
        description="Our choice: 0 (an ideal mount). The camera's roll about its optical axis: "
        "image u points along the stator X axis turned by this angle about +Z (toward +Y); "
        "``pmspm calibrate-mount`` estimates it (plant.camera).",
    )
    mount_offset_mm: tuple[float, float] = Field(
        (0.0, 0.0),
        description="Our choice: (0, 0). The optical centre's offset from the rotor's rotation "
        "axis along the image u and v directions, mm; ``pmspm calibrate-mount`` estimates it.",
    )
    intrinsics_px: tuple[float, float, float, float] | None = Field(
        None,
        description="Calibrated (fx, fy, cx, cy), full-sensor px, OpenCV pixel-centre "
        "convention (a camera file's calibration block); None: the nominal pinhole, "
        "fx = fy = focal_length_m / pixel_size_m, principal point at the sensor centre.",
    )

    @model_validator(mode="after")
    def _exposure_fits_frame(self) -> CameraParams:
        if self.exposure_s > 1.0 / self.frame_rate_hz:
            raise ValueError(
                f"exposure_s = {self.exposure_s} exceeds the frame period 1/frame_rate_hz = "
                f"{1.0 / self.frame_rate_hz:.4g} s"
            )
        return self

    @model_validator(mode="after")
    def _mount_is_finite(self) -> CameraParams:
        if not all(math.isfinite(v) for v in self.mount_offset_mm):
            raise ValueError(f"mount_offset_mm must be finite, got {self.mount_offset_mm}")
        return self

    @model_validator(mode="after")
    def _intrinsics_fit_the_sensor(self) -> CameraParams:
        if self.intrinsics_px is None:
            return self
        fx, fy, cx, cy = self.intrinsics_px
        w, h = self.sensor_width_px, self.sensor_height_px
        if fx <= 0.0 or fy <= 0.0:
            raise ValueError(f"intrinsics_px: fx = {fx:g} and fy = {fy:g} must be > 0 px")
        if not (-0.5 <= cx <= w - 0.5 and -0.5 <= cy <= h - 0.5):
            raise ValueError(
                f"intrinsics_px: principal point ({cx:g}, {cy:g}) must lie on the sensor, "
                f"u in [-0.5, {w - 0.5:g}], v in [-0.5, {h - 0.5:g}] px"
            )
        return self


class VFCParams(_Strict):
    """Visual feature component on the bottom pole (seed 000 §3.2.2, Figure 3).

    The red main and yellow auxiliary markers sit at opposite corners of a square with 20 mm legs
    (L = 28.28 mm apart), symmetric about the pole. We orient that diagonal along the rotor x axis,
    red at -x, yellow at +x, so that at rest the red→yellow vector points along +u in the image and
    the seed's spin formula reads 0 (our choice of the VFC's mounting angle).
    """

    leg_mm: float = Field(20.0, gt=0.0, description="Seed 000 §3.2.2: 20 mm legs, L = 28.28 mm.")
    marker_diameter_mm: float = Field(8.0, gt=0.0, description="Our choice: 8 mm printed discs.")
    plate_size_mm: float = Field(50.0, gt=0.0, description="Our choice: dark square plate.")

    @property
    def L_m(self) -> float:
        """Distance between the marker centres (m): the square's diagonal."""
        return self.leg_mm * 2**0.5 / 1000.0


class PlantParams(_Strict):
    """One parameter set that drives the MuJoCo model, the CasADi twin and the renderers."""

    motor: MotorParams = MotorParams()
    rotor: RotorParams = RotorParams()
    camera: CameraParams = CameraParams()
    vfc: VFCParams = VFCParams()
    physics_dt_s: float = Field(
        1.0e-3, gt=0.0, le=5e-3,
        description="Our choice: 1 kHz physics (the loop's timing needs >= 1 kHz).",
    )

    @classmethod
    def from_yaml(cls, path: str | Path) -> PlantParams:
        """Load from a YAML file; missing fields keep their defaults."""
        with open(path) as fh:
            return cls.model_validate(yaml.safe_load(fh) or {})
