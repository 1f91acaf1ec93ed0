"""Intrinsic calibration of the bottom camera from rendered checkerboard views.

A planar checkerboard is placed in front of the camera at about the distance of the VFC plane
(h_c), at random tilts, in-plane rotations and offsets, and drawn with the camera model of
``plant.camera.Camera`` (lens distortion included) as anti-aliased polygons (the supersampled
coverage of ``plant.render_analytic.polygon_coverage``). Its inner corners
are found with ``cv2.findChessboardCorners`` and refined with ``cv2.cornerSubPix``;
``cv2.calibrateCamera`` then recovers K and the distortion. Comparing the result with
``Camera.matrix(binning)`` checks the projection chain end to end; the per-view detections carry
the true corner pixels for the detector's own error.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from plant import attitude
from plant.camera import Camera
from plant.params import PlantParams
from plant.render_analytic import polygon_coverage
from plant.scene import check_binning

#: Inner corners (columns, rows) of the board: our choice. The 13 x 10 squares span 65 x 50 mm
#: (75 x 60 mm with the white border), about three quarters of the 101 x 85 mm field of view at
#: h_c = 0.30 m. A board that reaches into the image corners, where the radial distortion is
#: largest, pins the distortion centre (= the principal point) much better than a small one.
#: With k1 = -0.3, OpenCV's classic 9 x 6 board and 30 views (the earlier default) left cx, cy
#: off by up to 1.9 % over 20 seeds; ``benchmarks/bench_plant.py`` measures both that and the
#: defaults here (``calib_*`` in ``benchmarks/RESULTS.md``; docs/plant.md quotes them).
PATTERN = (12, 9)
#: Side of one square, mm: our choice (about 30 image px at the default 4x binning).
SQUARE_MM = 5.0
#: Board tilts (rad) drawn uniformly from this range: our choice; tilted views make the focal
#: length observable.
TILT_RANGE_RAD = (np.deg2rad(15.0), np.deg2rad(40.0))
#: Default number of views: our choice. The principal point of this narrow lens (19° x 16°) is
#: weakly determined, and with a distorted lens its error from the detector's corner noise
#: (a few hundredths of a pixel) falls only slowly with the number of views: 80 views keep
#: cx, cy within 1 % with margin over seeds (``bench_plant``), as a motorised board would
#: collect.
N_VIEWS = 80
#: ``cv2.calibrateCamera`` flags: estimate fx, fy, cx, cy, k1 and k2 (our choice). With this
#: narrow lens k3 and the tangential terms are poorly identifiable (they trade against the
#: principal point), so they are fixed at zero; pass ``flags=0`` to fit all five terms
#: (``bench_plant`` reports that case too).
DEFAULT_FLAGS = cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
#: Grey levels (0-255) of the background, the board's white squares and border, the black squares.
_BACKGROUND, _WHITE, _BLACK = 90.0, 230.0, 25.0
_POINTS_PER_EDGE = 8


@dataclass(frozen=True)
class BoardView:
    """One rendered checkerboard view and its detection.

    Attributes
    ----------
    rvec, tvec : ndarray (3,)
        True board pose in the camera frame (Rodrigues vector in rad, translation in m):
        ``p_camera = R(rvec) @ p_board + tvec``.
    found : bool
        Whether all inner corners were detected.
    corners_px : ndarray (N, 2)
        Refined detected corners in image pixels (of the binned frame), in the order of
        ``truth_px`` (the detector's order may start from the opposite corner; it is turned
        around here for comparison). NaN when not found.
    truth_px : ndarray (N, 2)
        Projections of the true inner corners, image pixels.
    """

    rvec: NDArray[np.float64]
    tvec: NDArray[np.float64]
    found: bool
    corners_px: NDArray[np.float64]
    truth_px: NDArray[np.float64]


@dataclass(frozen=True)
class CalibrationResult:
    """Intrinsics recovered by ``cv2.calibrateCamera`` from rendered views.

    Attributes
    ----------
    K : ndarray (3, 3)
        Recovered intrinsic matrix, pixels of the frame binned by ``binning``.
    dist : ndarray (5,)
        Recovered distortion (k1, k2, p1, p2, k3).
    rms_px : float
        RMS reprojection error over all used views, pixels.
    K_true : ndarray (3, 3)
        ``Camera.matrix(binning)``, the truth the renders were made with.
    image_size : (int, int)
        (width, height) in pixels.
    binning : int
        Sensor pixels per image pixel.
    views : list of BoardView
        Every rendered view with its detection (views with ``found = False`` were not used).
    """

    K: NDArray[np.float64]
    dist: NDArray[np.float64]
    rms_px: float
    K_true: NDArray[np.float64]
    image_size: tuple[int, int]
    binning: int
    views: list[BoardView]

    @property
    def n_used(self) -> int:
        """Number of views whose corners were found and used."""
        return sum(v.found for v in self.views)

    def relative_errors(self) -> dict[str, float]:
        """Relative errors of fx, fy, cx, cy against ``K_true`` (dimensionless)."""
        idx = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}
        return {k: float(self.K[i] / self.K_true[i] - 1.0) for k, i in idx.items()}


def board_points(pattern: tuple[int, int] = PATTERN, square_mm: float = SQUARE_MM) -> NDArray:
    """Inner corners (N, 3) in the board frame, m, row by row (x fastest), centred on the board."""
    cols, rows = pattern
    s = square_mm / 1000.0
    x, y = np.meshgrid(
        (np.arange(cols) - (cols - 1) / 2.0) * s, (np.arange(rows) - (rows - 1) / 2.0) * s
    )
    return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])


def _square_polygons(pattern: tuple[int, int], square_mm: float) -> tuple[NDArray, NDArray]:
    """Board-frame outlines (m) of the white board with a one-square border (n, 3) and of the
    black squares (k, n, 3), each edge sampled so that distortion can bend it."""
    cols, rows = pattern
    s = square_mm / 1000.0
    t = np.linspace(0.0, 1.0, _POINTS_PER_EDGE, endpoint=False)

    def rect(x0: float, y0: float, x1: float, y1: float) -> NDArray:
        edges = [
            np.column_stack([x0 + (x1 - x0) * t, np.full_like(t, y0)]),
            np.column_stack([np.full_like(t, x1), y0 + (y1 - y0) * t]),
            np.column_stack([x1 - (x1 - x0) * t, np.full_like(t, y1)]),
            np.column_stack([np.full_like(t, x0), y1 - (y1 - y0) * t]),
        ]
        xy = np.vstack(edges)
        return np.column_stack([xy, np.zeros(len(xy))])

    # Squares span (cols + 1) x (rows + 1); the white border adds one square on each side.
    hx, hy = (cols + 1) / 2.0 * s, (rows + 1) / 2.0 * s
    board = rect(-hx - s, -hy - s, hx + s, hy + s)
    black = [
        rect(-hx + i * s, -hy + j * s, -hx + (i + 1) * s, -hy + (j + 1) * s)
        for j in range(rows + 1)
        for i in range(cols + 1)
        if (i + j) % 2 == 0
    ]
    return board, np.array(black)


def _project(cam: Camera, pts_cam: NDArray, binning: int) -> NDArray[np.float64]:
    """Camera-frame points (..., 3), m -> image pixels (..., 2) via
    ``Camera.project_camera_frame``."""
    flat = pts_cam.reshape(-1, 3)
    return cam.project_camera_frame(flat, binning).reshape(pts_cam.shape[:-1] + (2,))


def render_checkerboard(
    params: PlantParams,
    rvec: NDArray[np.float64],
    tvec: NDArray[np.float64],
    binning: int | None = None,
    pattern: tuple[int, int] = PATTERN,
    square_mm: float = SQUARE_MM,
) -> NDArray[np.uint8]:
    """Grey image (H, W) of the checkerboard at pose (``rvec`` rad, ``tvec`` m) in the camera
    frame, seen by the bottom camera (anti-aliased polygons, lens distortion included).

    The board is white with a one-square border, on a mid-grey background."""
    b = check_binning(params, binning)
    cam = Camera.from_plant(params)
    w, h = cam.size(b)
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=float))
    board, black = _square_polygons(pattern, square_mm)
    img = np.full((h, w), _BACKGROUND, np.float32)
    for poly, level in [(board, _WHITE)] + [(sq, _BLACK) for sq in black]:
        cov = polygon_coverage(_project(cam, poly @ R.T + tvec, b), w, h)
        if cov is not None:
            sl, alpha = cov
            img[sl] += alpha * (np.float32(level) - img[sl])
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def random_board_poses(
    params: PlantParams,
    n_views: int,
    rng: np.random.Generator,
    binning: int,
    pattern: tuple[int, int] = PATTERN,
    square_mm: float = SQUARE_MM,
) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """``n_views`` board poses (rvec rad, tvec m) in the camera frame with the whole board
    (border included) inside the image: centre near the VFC plane distance h_c (±5 %), tilt in
    ``TILT_RANGE_RAD`` about a random in-plane axis, random in-plane rotation and offset.
    Raises ``ValueError`` if the board does not fit the view."""
    cam = Camera.from_plant(params)
    w, h = cam.size(binning)
    board, _ = _square_polygons(pattern, square_mm)
    margin = 4.0
    # Quick rejection: a board larger than the view at the nearest distance never fits.
    px_m = binning * params.camera.pixel_size_m / params.camera.focal_length_m * params.camera.h_c_m
    field = sorted([w * px_m * 1.05, h * px_m * 1.05])
    extent = sorted([(n + 3) * square_mm / 1000.0 for n in pattern])
    if extent[0] > field[0] or extent[1] > field[1]:
        raise ValueError(
            f"a board of {pattern} inner corners x {square_mm} mm squares (with its border "
            f"{extent[1] * 1000:.0f} x {extent[0] * 1000:.0f} mm) does not fit the "
            f"{field[1] * 1000:.0f} x {field[0] * 1000:.0f} mm view; use smaller squares"
        )
    poses: list[tuple[NDArray, NDArray]] = []
    for _ in range(200 * n_views):
        if len(poses) == n_views:
            break
        phi = rng.uniform(0.0, 2.0 * np.pi)
        tilt = rng.uniform(*TILT_RANGE_RAD)
        q = attitude.multiply(
            attitude.axis_angle([np.cos(phi), np.sin(phi), 0.0], tilt),
            attitude.axis_angle([0.0, 0.0, 1.0], rng.uniform(0.0, 2.0 * np.pi)),
        )
        R = attitude.to_matrix(q)
        z = params.camera.h_c_m * rng.uniform(0.95, 1.05)
        # Offset within the field of view at that distance.
        half_w = 0.5 * w * binning * params.camera.pixel_size_m / params.camera.focal_length_m * z
        half_h = 0.5 * h * binning * params.camera.pixel_size_m / params.camera.focal_length_m * z
        t = np.array([rng.uniform(-0.5, 0.5) * half_w, rng.uniform(-0.5, 0.5) * half_h, z])
        uv = _project(cam, board @ R.T + t, binning)
        inside = uv.min() >= margin and np.all(uv.max(axis=0) <= [w - 1 - margin, h - 1 - margin])
        if inside:
            rvec, _ = cv2.Rodrigues(R)
            poses.append((rvec.ravel(), t))
    if len(poses) < n_views:
        raise ValueError(
            f"could not place {n_views} boards of {pattern} x {square_mm} mm inside the "
            f"{w} x {h} px view; use smaller squares"
        )
    return poses


def detect_corners(
    image: NDArray[np.uint8], pattern: tuple[int, int] = PATTERN
) -> NDArray[np.float64] | None:
    """Inner corners (N, 2) of a checkerboard in a grey image, pixels, refined to sub-pixel
    accuracy, in the detector's order; None if the board was not found."""
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(image, pattern, flags=flags)
    if not found:
        return None
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
    corners = cv2.cornerSubPix(image, corners, (5, 5), (-1, -1), criteria)
    return corners.reshape(-1, 2).astype(float)


def calibrate_from_renders(
    params: PlantParams | None = None,
    n_views: int = N_VIEWS,
    seed: int | np.random.Generator = 0,
    binning: int | None = None,
    pattern: tuple[int, int] = PATTERN,
    square_mm: float = SQUARE_MM,
    flags: int = DEFAULT_FLAGS,
) -> CalibrationResult:
    """Render ``n_views`` checkerboard views, detect their corners and calibrate.

    Parameters
    ----------
    params : PlantParams, optional
        Camera model to render with (default ``PlantParams()``).
    n_views : int
        Number of board views (at least 3); default ``N_VIEWS`` (80, our choice: see there).
    seed : int or numpy.random.Generator
        Source of the board poses.
    binning : int, optional
        Frame binning (default ``params.camera.binning``).
    pattern, square_mm : (int, int), float
        Inner corners (columns, rows) and square side (mm) of the board.
    flags : int
        ``cv2.calibrateCamera`` flags (default ``DEFAULT_FLAGS``: free fx, fy, cx, cy, k1, k2;
        pass 0 for all five distortion coefficients).

    Returns
    -------
    CalibrationResult
    """
    params = params or PlantParams()
    if n_views < 3:
        raise ValueError(f"n_views must be >= 3 for a calibration, got {n_views}")
    b = check_binning(params, binning)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    cam = Camera.from_plant(params)
    size = cam.size(b)
    obj = board_points(pattern, square_mm)
    views, obj_list, img_list = [], [], []
    for rvec, tvec in random_board_poses(params, n_views, rng, b, pattern, square_mm):
        img = render_checkerboard(params, rvec, tvec, b, pattern, square_mm)
        R, _ = cv2.Rodrigues(rvec)
        truth = _project(cam, obj @ R.T + tvec, b)
        corners = detect_corners(img, pattern)
        if corners is None:
            views.append(BoardView(rvec, tvec, False, np.full_like(truth, np.nan), truth))
            continue
        # The board looks the same turned by 180°, so the detector may list the corners from
        # the opposite end; calibrateCamera does not care (it is a rigid motion of the board).
        obj_list.append(obj.astype(np.float32))
        img_list.append(corners.astype(np.float32).reshape(-1, 1, 2))
        if np.linalg.norm(corners[0] - truth[-1]) < np.linalg.norm(corners[0] - truth[0]):
            corners = corners[::-1]
        views.append(BoardView(rvec, tvec, True, corners, truth))
    if len(obj_list) < 3:
        raise RuntimeError(f"only {len(obj_list)} of {n_views} boards were detected")
    rms, K, dist, _, _ = cv2.calibrateCamera(obj_list, img_list, size, None, None, flags=flags)
    return CalibrationResult(
        K=np.asarray(K, dtype=float),
        dist=np.asarray(dist, dtype=float).ravel()[:5],
        rms_px=float(rms),
        K_true=cam.matrix(b),
        image_size=size,
        binning=b,
        views=views,
    )
