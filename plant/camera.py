"""The bottom camera: pinhole model, pose and the projection of rotor points.

Geometry (docs/architecture.md, "Conventions"): the camera sits on the stator Z axis below the
rotor and looks up (+Z). Its optical centre is at ``(0, 0, -(R + h_c))``, with R the rotor
radius and h_c the distance from the optical centre to the rest plane of the bottom pole (seed 000
§2.5). The OpenCV camera frame has z along the optical axis (+Z), x along image u and y along
image v; we align x with the stator X axis, so y is the stator Y axis and ``p_cam = p_stator -
C``. Looking up mirrors the scene as seen from above: a counter-clockwise rotation about +Z (X
toward Y) turns u toward v, which on screen (v down) is clockwise.

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
        return cls(p.camera, p.rotor.radius_m)

    @property
    def center_m(self) -> NDArray[np.float64]:
        """Optical centre in the stator frame (m)."""
        return np.array([0.0, 0.0, -(self.rotor_radius_m + self.params.h_c_m)])

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
        """Stator-frame points (N, 3) in m -> camera-frame points (N, 3) in m."""
        return np.atleast_2d(np.asarray(points_stator, dtype=float)) - self.center_m

    def project(self, points_stator: ArrayLike, binning: int = 1) -> NDArray[np.float64]:
        """Project stator-frame points (N, 3), m, to pixels (N, 2) of a frame binned by
        ``binning`` (1 = full-sensor pixels), with the lens distortion applied."""
        pc = self.to_camera_frame(points_stator)
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
    the projections of the 3-D disc centres (full-sensor pixels when ``binning`` = 1)."""
    cam = Camera.from_plant(p)
    return cam.project(rotor_to_stator(q, marker_points(p.rotor, p.vfc)), binning)
