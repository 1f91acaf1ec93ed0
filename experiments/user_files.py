"""A user's own motor and camera: the motor YAML (``plant.motor_file``) and the camera YAML
(``plant.camera_file``, written by ``pmspm calibrate``) combined into one setup for ``pmspm
track`` and the scenarios."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from plant.camera_file import CameraFile
from plant.motor_file import MotorFile
from plant.params import PlantParams


@dataclass(frozen=True)
class UserSetup:
    """The plant, the camera file and the marker layout of a user's rig.

    Attributes
    ----------
    params : the plant (motor, rotor, VFC and the camera file's ``camera``).
    camera : the camera file (calibrated intrinsics when it has them).
    markers_m : (2, 3) red and yellow marker centres, rotor frame, m from the centre of rotation.
    """

    params: PlantParams = field(default_factory=PlantParams)
    camera: CameraFile = field(default_factory=CameraFile)
    markers_m: NDArray[np.float64] = field(default_factory=lambda: MotorFile().markers_m())


def load_setup(motor_yaml: Path | str | None = None,
               camera_yaml: Path | str | None = None) -> UserSetup:
    """Read the motor and camera YAML (either may be omitted: the seed's motor, the default
    camera). Raises ``ValueError`` for a missing file and pydantic's ``ValidationError``, which
    names the field and its range, for a bad value."""
    for path in (motor_yaml, camera_yaml):
        if path is not None and not Path(path).is_file():
            raise ValueError(f"no such file: {path}")
    motor = MotorFile() if motor_yaml is None else MotorFile.from_yaml(motor_yaml)
    camera = CameraFile() if camera_yaml is None else CameraFile.from_yaml(camera_yaml)
    return UserSetup(motor.plant(camera.camera), camera, motor.markers_m())
