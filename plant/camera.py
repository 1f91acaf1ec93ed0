"""The bottom camera: pinhole model, pose and the projection of rotor points.

Geometry (docs/architecture.md, "Conventions"): the camera sits on the stator Z axis below the
rotor and looks up (+Z). Its optical centre is at ``(0, 0, -(R + h_c))``, with R the rotor
radius and h_c the distance from the optical centre to the rest plane of the bottom pole (seed 000
§2.5). The OpenCV camera frame has z along the optical axis (+Z), x along image u and y along
image v; we align x with the stator X axis, so y is the stator Y axis and ``p_cam = p_stator -
C``. Looking up mirrors the scene as seen from above: a counter-clockwise rotation about +Z (X
toward Y) turns u toward v, which on screen (v down) is clockwise.

**Mounting** (``CameraParams.mount_roll_deg``, ``mount_offset_mm``; both 0 by default): a real
camera is turned about its optical axis by a roll ρ (image u lies along the stator X axis turned
by ρ about +Z) and its optical centre sits off the rotation axis by (d_u, d_v) along the image
axes. We describe it in the *camera-aligned frame*, the stator frame turned by ρ about Z: there
the optical centre is ``center_m = (d_u, d_v, -(R + h_c))`` and the camera frame is that frame
shifted to it, ``p_cam = Rz(ρ)ᵀ p_stator - center_m``. Models of the camera that write
``R(q) P - center_m`` (the attitude solver's ``CorModel.nominal``, the AEKF, ORB) therefore
estimate the attitude in the camera-aligned frame, ``q_aligned = Rz(-ρ) ⊗ q``;
``Camera.stator_attitude`` turns it back. A roll not accounted for shows as a constant yaw
offset of -ρ (at zero tilt, where yaw and spin merge, a spin offset).

Pixels follow OpenCV's convention: integer coordinates are pixel centres and the image centre of
a W x H image is ((W - 1)/2, (H - 1)/2). *Sensor* pixels are full-resolution (the seed's unit);
*image* pixels are those of a frame rendered with ``binning``:
``u_image = (u_sensor + 0.5)/binning - 0.5``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from plant import attitude
from plant.geometry import marker_points
from plant.params import CameraParams, PlantParams


def sensor_to_image(uv_sensor: ArrayLike, binning: int) -> NDArray[np.float64]:
    """Full-sensor pixel coordinates -> coordinates in a frame binned by ``binning``."""
    return (np.asarray(uv_sensor, dtype=float) + 0.5) / binning - 0.5


def image_to_sensor(uv_image: ArrayLike, binning: int) -> NDArray[np.float64]:
    """Pixel coordinates in a frame binned by ``binning`` -> full-sensor coordinates."""
    return (np.asarray(uv_image, dtype=float) + 0.5) * binning - 0.5


@dataclass(frozen=True)
class Camera:
    """Pinhole camera with OpenCV distortion, placed below the rotor looking up.

    Attributes
    ----------
    params : CameraParams
        Sensor, lens and distance.
    rotor_radius_m : float
        R: the bottom pole rests at Z = -R.
    """

    params: CameraParams
    rotor_radius_m: float

    @classmethod
    def from_plant(cls, p: PlantParams) -> Camera:
        """The camera of plant ``p``: its camera parameters and its rotor radius R, m (the
        bottom pole at Z = -R)."""
        return cls(p.camera, p.rotor.radius_m)

    @property
    def roll_rad(self) -> float:
        """The mount's roll ρ about the optical axis, rad (module docstring)."""
        return float(np.deg2rad(self.params.mount_roll_deg))

    @property
    def center_m(self) -> NDArray[np.float64]:
        """Optical centre in the camera-aligned frame (m; the stator frame when the mount has
        no roll): ``(d_u, d_v, -(R + h_c))`` with the mount's offset (module docstring)."""
        du, dv = self.params.mount_offset_mm
        return np.array([du / 1000.0, dv / 1000.0, -(self.rotor_radius_m + self.params.h_c_m)])

    @property
    def center_stator_m(self) -> NDArray[np.float64]:
        """Optical centre in the stator frame (m): ``Rz(ρ) center_m``."""
        return attitude.to_matrix(self.mount_quaternion) @ self.center_m

    @property
    def mount_quaternion(self) -> NDArray[np.float64]:
        """Rz(ρ): the camera-aligned frame in the stator frame."""
        return attitude.axis_angle([0.0, 0.0, 1.0], self.roll_rad)

    def stator_attitude(self, q_aligned: ArrayLike) -> NDArray[np.float64]:
        """An attitude estimated in the camera-aligned frame -> the stator frame:
        ``Rz(ρ) ⊗ q_aligned`` (module docstring)."""
        return attitude.multiply(self.mount_quaternion, q_aligned)

    def size(self, binning: int | None = None) -> tuple[int, int]:
        """(width, height) in pixels of a frame binned by ``binning`` (default: the params')."""
        b = self.params.binning if binning is None else binning
        return self.params.sensor_width_px // b, self.params.sensor_height_px // b

    def matrix(self, binning: int = 1) -> NDArray[np.float64]:
        """Intrinsic matrix K (px) for frames binned by ``binning`` (1 = full sensor): the
        calibrated ``params.intrinsics_px`` when set, else the nominal pinhole (f / pixel
        size, principal point at the sensor centre). Binning divides the focal lengths and
        maps the principal point as any pixel (``sensor_to_image``)."""
        c = self.params
        if c.intrinsics_px is None:
            fx = fy = c.focal_length_m / c.pixel_size_m
            cx, cy = (c.sensor_width_px - 1) / 2.0, (c.sensor_height_px - 1) / 2.0
        else:
            fx, fy, cx, cy = c.intrinsics_px
        u0, v0 = sensor_to_image((cx, cy), binning)
        return np.array([[fx / binning, 0.0, u0], [0.0, fy / binning, v0], [0.0, 0.0, 1.0]])

    def to_camera_frame(self, points_stator: ArrayLike) -> NDArray[np.float64]:
        """Stator-frame points (N, 3) in m -> camera-frame points (N, 3) in m:
        ``Rz(ρ)ᵀ p - center_m``."""
        p = np.atleast_2d(np.asarray(points_stator, dtype=float))
        if self.roll_rad != 0.0:
            p = p @ attitude.to_matrix(self.mount_quaternion)
        return p - self.center_m

    def project(self, points_stator: ArrayLike, binning: int = 1) -> NDArray[np.float64]:
        """Project stator-frame points (N, 3), m, to pixels (N, 2) of a frame binned by
        ``binning`` (1 = full-sensor pixels), with the lens distortion applied."""
        return self.project_camera_frame(self.to_camera_frame(points_stator), binning)

    def project_camera_frame(self, points_camera: ArrayLike,
                             binning: int = 1) -> NDArray[np.float64]:
        """Project camera-frame points (N, 3), m, to pixels (N, 2) as ``project``."""
        pc = np.atleast_2d(np.asarray(points_camera, dtype=float))
        if np.any(pc[:, 2] <= 0.0):
            raise ValueError("cannot project points at or behind the camera plane")
        uv, _ = cv2.projectPoints(
            pc.reshape(-1, 1, 3),
            np.zeros(3),
            np.zeros(3),
            self.matrix(binning),
            np.asarray(self.params.dist_coeffs, dtype=float),
        )
        return uv.reshape(-1, 2)


def rotor_to_stator(q: ArrayLike, points_rotor: ArrayLike) -> NDArray[np.float64]:
    """Rotor-frame points (N, 3) -> stator frame for attitude ``q`` (rotation about O)."""
    return np.atleast_2d(np.asarray(points_rotor, dtype=float)) @ attitude.to_matrix(q).T


def marker_pixels(p: PlantParams, q: ArrayLike, binning: int = 1) -> NDArray[np.float64]:
    """Ground-truth pixels (2, 2) of the red and yellow marker centres at attitude ``q``:
    the projections of the 3-D disc centres (full-sensor pixels when ``binning`` = 1).

    Mirrored in ``latency.compiled.frontend._project``; keep both in step
    (tests/test_compiled_mirror.py checks them equal)."""
    cam = Camera.from_plant(p)
    return cam.project(rotor_to_stator(q, marker_points(p.rotor, p.vfc)), binning)
