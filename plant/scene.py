"""What a rendered camera frame is, and the ground truth and exposure helpers both renderers share.

``Frame`` carries the image and the ground truth of one exposure: the marker centres and their
boxes in full-sensor pixels, the mid-exposure attitude and time. The helpers here hold the
geometry the two renderers (``plant.render_analytic``, ``plant.render_mujoco``) must agree on:
the outlines of the VFC plate and marker discs in the rotor frame, the sub-exposure attitudes
of a motion-blurred frame, and the checks on binning and exposure arguments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from plant import attitude
from plant.camera import Camera, marker_pixels, rotor_to_stator
from plant.geometry import marker_points
from plant.params import PlantParams

#: Boundary points per marker disc outline (our choice: the polygon's area is within 0.2 % of
#: the circle's, its centroid is exact).
DISC_POINTS = 64
#: Boundary points per edge of the square VFC plate (curved edges under lens distortion).
PLATE_POINTS_PER_EDGE = 16


@dataclass(frozen=True)
class Frame:
    """One rendered camera frame with its ground truth.

    Attributes
    ----------
    image : ndarray (H, W, 3) uint8
        The picture, RGB channel order, H x W = sensor size / ``binning``.
    marker_px : ndarray (2, 2)
        Ground-truth centres (u, v) of the red then the yellow marker in *full-sensor* pixels:
        the projections of the 3-D disc centres at mid-exposure
        (``plant.camera.marker_pixels`` with binning 1). Use
        ``plant.camera.sensor_to_image(marker_px, binning)`` for this frame's pixels.
    boxes_px : ndarray (2, 4)
        Ground-truth boxes (x, y, w, h) of the red then the yellow disc in full-sensor pixels:
        the axis-aligned bounds of each projected disc outline at mid-exposure.
    q : ndarray (4,)
        Attitude (w, x, y, z; rotor to stator) at mid-exposure.
    t_exposure : float
        Mid-exposure time, s.
    exposure_s : float
        Exposure (shutter) time, s.
    binning : int
        Sensor pixels per image pixel along each axis.
    n_sub : int
        Number of sub-exposure renders averaged for motion blur (1 = no blur).
    """

    image: NDArray[np.uint8]
    marker_px: NDArray[np.float64]
    boxes_px: NDArray[np.float64]
    q: NDArray[np.float64]
    t_exposure: float
    exposure_s: float
    binning: int
    n_sub: int = 1


def allowed_binnings(p: PlantParams) -> list[int]:
    """The binnings (1, 2, ...) that divide both sensor sides exactly."""
    g = math.gcd(p.camera.sensor_width_px, p.camera.sensor_height_px)
    return [b for b in range(1, g + 1) if g % b == 0]  # the divisors of both = those of the gcd


def check_binning(p: PlantParams, binning: int | None) -> int:
    """Return ``binning`` (default: ``p.camera.binning``) or raise ``ValueError``.

    A binning must be a positive integer that divides both sensor sides, so that the binned
    frame has the same field of view, square pixels and principal point as the sensor.
    """
    b = p.camera.binning if binning is None else binning
    allowed = allowed_binnings(p)
    if isinstance(b, bool) or not isinstance(b, (int, np.integer)) or int(b) not in allowed:
        raise ValueError(
            f"binning must be a positive integer dividing both sensor sides "
            f"({p.camera.sensor_width_px} x {p.camera.sensor_height_px} px), one of {allowed}; "
            f"got {b!r}"
        )
    return int(b)


def check_exposure(
    p: PlantParams, t_exposure: float, exposure_s: float | None, omega: ArrayLike | None
) -> tuple[float, float, NDArray[np.float64]]:
    """Validate the exposure arguments of ``render``.

    Returns ``(t_exposure, exposure_s, omega)`` as floats / a (3,) array with the defaults filled
    in: ``exposure_s`` defaults to ``p.camera.exposure_s`` (s), ``omega`` to zero (rad/s).
    """
    t = float(attitude.check_finite("t_exposure", t_exposure))
    e = p.camera.exposure_s if exposure_s is None else exposure_s
    e = float(attitude.check_finite("exposure_s", e))
    if e < 0.0:
        raise ValueError(f"exposure_s must be >= 0 s, got {e}")
    w = np.zeros(3) if omega is None else attitude.check_finite("omega", omega)
    if w.shape != (3,):
        raise ValueError(f"omega must be a body-frame rate of shape (3,) in rad/s, got {w.shape}")
    return t, e, w


def sub_exposure_attitudes(
    q: ArrayLike, omega: ArrayLike, exposure_s: float, n_sub: int
) -> NDArray[np.float64]:
    """Attitudes (n_sub, 4) at which a motion-blurred frame is sampled.

    ``q_k = q ⊗ exp(omega · δ_k)`` with ``q`` the mid-exposure attitude (w, x, y, z; rotor to
    stator), ``omega`` the body-frame angular velocity (rad/s, held constant over the exposure)
    and ``δ_k`` (s) the midpoints of ``n_sub`` equal slices of [-exposure_s/2, +exposure_s/2]
    (the midpoint rule for a box-shaped shutter; ``n_sub = 1`` gives ``q`` itself).
    """
    q = attitude.normalize(q)
    w = attitude.check_finite("omega", omega).reshape(3)
    if int(n_sub) < 1:
        raise ValueError(f"n_sub must be >= 1, got {n_sub}")
    n = int(n_sub)
    deltas = (np.arange(n) + 0.5) / n * exposure_s - 0.5 * exposure_s
    return np.array([attitude.multiply(q, attitude.from_rotvec(w * d)) for d in deltas])


def disc_outlines_rotor(p: PlantParams, n_points: int = DISC_POINTS) -> NDArray[np.float64]:
    """Boundary points (2, n_points, 3) of the red then the yellow marker disc, rotor frame, m.

    The discs (diameter ``marker_diameter_mm``) lie in the plate plane z = -R around the
    centres of ``plant.geometry.marker_points``.
    """
    centres = marker_points(p.rotor, p.vfc)
    r = p.vfc.marker_diameter_mm / 2000.0
    t = np.linspace(0.0, 2.0 * np.pi, n_points, endpoint=False)
    ring = np.column_stack([r * np.cos(t), r * np.sin(t), np.zeros(n_points)])
    return centres[:, None, :] + ring[None, :, :]


def plate_outline_rotor(
    p: PlantParams, n_per_edge: int = PLATE_POINTS_PER_EDGE
) -> NDArray[np.float64]:
    """Boundary points (4 n_per_edge, 3) of the square VFC plate in the rotor frame, m.

    The plate (side ``plate_size_mm``) lies in the plane z = -R, centred on the bottom pole,
    edges along the rotor x and y axes; the points run around it in order.
    """
    h = p.vfc.plate_size_mm / 2000.0
    s = np.linspace(-h, h, n_per_edge, endpoint=False)
    edges = [
        np.column_stack([s, np.full_like(s, -h)]),
        np.column_stack([np.full_like(s, h), s]),
        np.column_stack([-s, np.full_like(s, h)]),
        np.column_stack([np.full_like(s, -h), -s]),
    ]
    xy = np.vstack(edges)
    return np.column_stack([xy, np.full(len(xy), -p.rotor.radius_m)])


def ground_truth(p: PlantParams, q: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Marker centres (2, 2) and boxes (2, 4) as (x, y, w, h), full-sensor pixels, at ``q``."""
    q = attitude.normalize(q)
    centres = marker_pixels(p, q, binning=1)
    cam = Camera.from_plant(p)
    outline = disc_outlines_rotor(p)
    uv = cam.project(rotor_to_stator(q, outline.reshape(-1, 3)), 1)
    uv = uv.reshape(outline.shape[:2] + (2,))
    lo, hi = uv.min(axis=1), uv.max(axis=1)
    return centres, np.column_stack([lo, hi - lo])


def vfc_pixel_travel(
    p: PlantParams,
    q: ArrayLike,
    omega: ArrayLike,
    exposure_s: float,
    binning: int,
    n_samples: int = 9,
) -> float:
    """Longest image path (pixels of a frame binned by ``binning``) that a marker centre or a
    plate corner sweeps during the exposure at body rate ``omega`` (rad/s), ``exposure_s`` (s)."""
    if exposure_s <= 0.0 or not np.any(omega):
        return 0.0
    cam = Camera.from_plant(p)
    h = p.vfc.plate_size_mm / 2000.0
    corners = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])
    pts = np.vstack(
        [marker_points(p.rotor, p.vfc), np.column_stack([corners, np.full(4, -p.rotor.radius_m)])]
    )
    qs = attitude.multiply(
        attitude.normalize(q),
        np.array(
            [
                attitude.from_rotvec(np.asarray(omega) * d)
                for d in np.linspace(-0.5 * exposure_s, 0.5 * exposure_s, n_samples)
            ]
        ),
    )
    uv = np.array([cam.project(rotor_to_stator(qk, pts), binning) for qk in qs])
    return float(np.linalg.norm(np.diff(uv, axis=0), axis=2).sum(axis=0).max())


def choose_n_sub(travel_px: float, step_px: float, max_sub: int) -> int:
    """Sub-frames needed so that consecutive sub-frames move at most ``step_px`` (image px),
    capped at ``max_sub``; 1 when the travel is below one step."""
    return int(min(max_sub, max(1, int(np.ceil(travel_px / step_px)))))
