"""A user's own motor and camera: the motor YAML (``plant.motor_file``) and the camera YAML
(``plant.camera_file``, written by ``pmspm calibrate``) combined into one setup for ``pmspm
track`` and the scenarios."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from plant.camera_file import CameraFile
from plant.motor_file import MotorFile
from plant.params import PlantParams


@dataclass(frozen=True)
class UserSetup:
    """The plant, the camera file and the marker layout of a user's rig.

    Attributes
    ----------
    params : the plant (motor, rotor, VFC and the camera file's camera with its calibrated
        intrinsics, ``CameraFile.params``).
    camera : the camera file (calibrated intrinsics when it has them).
    markers_m : (2, 3) red and yellow marker centres, rotor frame, m from the centre of rotation.
    motor : the motor file.
    """

    params: PlantParams = field(default_factory=PlantParams)
    camera: CameraFile = field(default_factory=CameraFile)
    markers_m: NDArray[np.float64] = field(default_factory=lambda: MotorFile().markers_m())
    motor: MotorFile = field(default_factory=MotorFile)


def load_setup(motor_yaml: Path | str | None = None,
               camera_yaml: Path | str | None = None) -> UserSetup:
    """Read the motor and camera YAML (either may be omitted: the seed's motor, the default
    camera). Raises ``ValueError`` for a missing file or a bad value, naming the file, the
    field and its allowed range."""
    motor = MotorFile() if motor_yaml is None else _read(MotorFile, motor_yaml)
    camera = CameraFile() if camera_yaml is None else _read(CameraFile, camera_yaml)
    try:
        camera_params = camera.params
    except ValidationError as exc:
        raise ValueError(f"{camera_yaml}: calibration: "
                         f"{exc.errors()[0]['msg'].removeprefix('Value error, ')}") from exc
    return UserSetup(motor.plant(camera_params), camera, motor.markers_m(), motor)


def _read(model: type[MotorFile] | type[CameraFile], path: Path | str) -> MotorFile | CameraFile:
    """Read a YAML file into ``model``; ``ValueError`` naming the file, the field and the
    allowed range."""
    if not Path(path).is_file():
        raise ValueError(f"no such file: {path}")
    try:
        return model.from_yaml(path)
    except ValidationError as exc:
        fields = "; ".join(f"{'.'.join(str(p) for p in e['loc']) or '(top level)'}: {e['msg']}"
                           for e in exc.errors())
        raise ValueError(f"{path}: {fields}") from exc


def plant_from_files(data: dict) -> dict:
    """A scenario mapping with ``motor_file`` and/or ``camera_file`` (paths of the YAML files
    above) turned into one with the ``plant`` they describe. Scenarios draw the markers from
    ``vfc``, so a motor file whose explicit ``markers`` layout differs from that (possible for
    ``pmspm track``) is refused rather than silently ignored."""
    files = {k: data[k] for k in ("motor_file", "camera_file") if k in data}
    if not files:
        return data
    if "plant" in data:
        raise ValueError("give either plant or motor_file / camera_file, not both")
    setup = load_setup(files.get("motor_file"), files.get("camera_file"))
    if not setup.motor.markers_follow_vfc():
        raise ValueError(f"{files['motor_file']}: markers: scenarios render the markers from "
                         "vfc (leg_mm, marker_diameter_mm) and rotor.radius_m; this layout "
                         "differs from theirs (it is for pmspm track only)")
    rest = {k: v for k, v in data.items() if k not in files}
    return {**rest, "plant": setup.params}
