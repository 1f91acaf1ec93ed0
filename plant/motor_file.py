"""A motor description file: the rotor, the coils, the limits and the marker layout.

Layout (YAML; every block optional, missing fields keep the defaults of ``plant.params``)::

    rotor:    {radius_m, mass_kg, inertia_com_kgm2, com_offset_m, viscous_Nms_per_rad,
               coulomb_Nm, tilt_stop_deg, ...}           # plant.params.RotorParams
    motor:    {coil_latitude_deg, lower_layer_offset_deg, cutoff_deg, k_T_Nm_per_A, i_max_A,
               ...}                                      # plant.params.MotorParams
    vfc:      {leg_mm, marker_diameter_mm, plate_size_mm} # plant.params.VFCParams
    markers:                                             # optional explicit layout
      - {colour: red, offset_m: [-0.01414, 0.0, -0.065], radius_mm: 4.0}
      - {colour: yellow, offset_m: [0.01414, 0.0, -0.065], radius_mm: 4.0}

The magnets sit on the icosahedron face centres of ``plant.geometry.magnet_axes`` (seed 000
§2.1); the coil layout is set by ``motor.coil_latitude_deg`` and ``motor.lower_layer_offset_deg``.
``markers`` gives each marker's centre in the rotor frame (m, from the centre of rotation), its
colour (the trackers know ``red``, the main marker, and ``yellow``, the auxiliary one, seed 000
§3.2.2) and its radius (mm); without it the layout follows from ``vfc`` and ``rotor.radius_m``
(``plant.geometry.marker_points``). Errors name the field and its allowed range.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
import yaml
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

from plant.geometry import marker_points
from plant.params import CameraParams, MotorParams, PlantParams, RotorParams, VFCParams

Vec3 = tuple[float, float, float]


class MarkerSpec(BaseModel):
    """One marker: colour, centre in the rotor frame (m, from the CoR) and radius (mm)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    colour: Literal["red", "yellow"]
    offset_m: Vec3
    radius_mm: float = Field(gt=0.0, le=50.0, description="Disc radius, mm.")


class MotorFile(BaseModel):
    """The motor YAML (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    motor: MotorParams = MotorParams()
    rotor: RotorParams = RotorParams()
    vfc: VFCParams = VFCParams()
    markers: tuple[MarkerSpec, MarkerSpec] | None = None

    @model_validator(mode="after")
    def _markers_fit(self) -> MotorFile:
        if self.markers is None:
            return self
        if [m.colour for m in self.markers] != ["red", "yellow"]:
            raise ValueError("markers: list the red (main) marker first, then the yellow one")
        r = self.rotor.radius_m
        for i, m in enumerate(self.markers):
            d = float(np.linalg.norm(m.offset_m))
            if not 0.5 * r <= d <= 1.5 * r:
                raise ValueError(f"markers.{i}.offset_m: distance {d:.4g} m from the centre of "
                                 f"rotation must lie in [0.5, 1.5] x rotor.radius_m = "
                                 f"[{0.5 * r:.4g}, {1.5 * r:.4g}] m (a marker on the rotor)")
        if np.allclose(self.markers[0].offset_m, self.markers[1].offset_m):
            raise ValueError("markers: the two markers must not coincide")
        return self

    def markers_m(self) -> NDArray[np.float64]:
        """Marker centres (2, 3), rotor frame, m: red then yellow."""
        if self.markers is None:
            return marker_points(self.rotor, self.vfc)
        return np.array([m.offset_m for m in self.markers], dtype=float)

    def markers_follow_vfc(self, tol_m: float = 1e-6) -> bool:
        """The explicit layout (if any) is the one ``vfc`` and ``rotor.radius_m`` give
        (``plant.geometry.marker_points``, discs of ``vfc.marker_diameter_mm``) within
        ``tol_m``."""
        if self.markers is None:
            return True
        same_place = np.allclose(self.markers_m(), marker_points(self.rotor, self.vfc),
                                 atol=tol_m, rtol=0.0)
        radius = 0.5 * self.vfc.marker_diameter_mm
        return bool(same_place and all(abs(m.radius_mm - radius) <= tol_m * 1e3
                                       for m in self.markers))

    def plant(self, camera: CameraParams | None = None) -> PlantParams:
        """The plant of this motor seen by ``camera`` (default ``CameraParams()``)."""
        return PlantParams(motor=self.motor, rotor=self.rotor, vfc=self.vfc,
                           camera=camera or CameraParams())

    @classmethod
    def from_yaml(cls, path: str | Path) -> MotorFile:
        """Read a motor YAML (``ValidationError`` names the bad field)."""
        with open(path) as fh:
            return cls.model_validate(yaml.safe_load(fh) or {})
