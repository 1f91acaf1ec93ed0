"""Calibrate a camera from chessboard views in a folder or a video (``pmspm calibrate``).

Each frame's inner chessboard corners are found and refined to sub-pixel accuracy
(``plant.calibration.detect_corners``); ``cv2.calibrateCameraExtended`` then estimates the
intrinsics and the distortion with one-sigma uncertainties of each parameter and the RMS
reprojection error per view. By default fx, fy, cx, cy, k1 and k2 are free and k3 and the
tangential terms fixed at zero (``plant.calibration.DEFAULT_FLAGS``: with a narrow lens the others
trade against the principal point). The result is a camera YAML (``plant.camera_file``) in
full-sensor pixels for frames binned by ``binning``, and a report with the coverage of the
views over the image and the residuals.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from experiments.sources import UserInputError, open_source
from plant.calibration import DEFAULT_FLAGS, board_points, detect_corners
from plant.camera import image_to_sensor
from plant.camera_file import CalibratedIntrinsics, CameraFile
from plant.params import CameraParams

#: Names of the parameters ``calibrateCameraExtended`` reports uncertainties for, in its order.
INTRINSIC_STD_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


@dataclass(frozen=True)
class CameraCalibration:
    """A calibration from real or rendered views.

    Attributes
    ----------
    camera : the camera file to write (sensor px; ``calibration`` block filled in).
    K_image : (3, 3) intrinsic matrix in px of the calibration frames.
    dist : (5,) distortion (k1, k2, p1, p2, k3).
    std : parameter name -> one-sigma uncertainty (px of the frames for fx .. cy).
    rms_px : RMS reprojection error over all views, px of the frames.
    per_view_rms_px : (n_views,) RMS reprojection error of each used view.
    corners_px : detected corners (n_views, N, 2), px of the frames.
    residuals_px : detected minus reprojected corners (n_views, N, 2), px.
    used : names of the frames whose board was found; ``skipped`` the others.
    """

    camera: CameraFile
    K_image: NDArray[np.float64]
    dist: NDArray[np.float64]
    std: dict[str, float]
    rms_px: float
    per_view_rms_px: NDArray[np.float64]
    corners_px: NDArray[np.float64]
    residuals_px: NDArray[np.float64]
    used: list[str]
    skipped: list[str]

    def summary_lines(self) -> list[str]:
        """The parameters with their uncertainties, for the terminal and the report."""
        K = self.K_image
        vals = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2],
                **dict(zip(("k1", "k2", "p1", "p2", "k3"), self.dist, strict=True))}
        lines = [f"views used: {len(self.used)} (board not found in {len(self.skipped)})",
                 f"RMS reprojection error: {self.rms_px:.4f} px"]
        lines += [f"{k}: {vals[k]:.6g} ± {self.std[k]:.2g}" for k in INTRINSIC_STD_NAMES]
        return lines


def calibrate_frames(
    frames: list[tuple[str, NDArray[np.uint8]]],
    pattern: tuple[int, int],
    square_mm: float,
    camera: CameraParams | None = None,
    flags: int = DEFAULT_FLAGS,
) -> CameraCalibration:
    """Calibrate from named grey or BGR frames of a chessboard with ``pattern`` inner corners
    (columns, rows) and squares of ``square_mm`` mm.

    ``camera`` supplies what the images cannot: pixel size, binning (sensor px per frame px),
    h_c and frame rate (default ``CameraParams()`` fields); the sensor size becomes frame size x
    binning and the focal length mean(fx, fy) x binning x pixel size. Raises ``UserInputError``
    when fewer than 3 boards are found or the frames differ in size.
    """
    base = camera or CameraParams()
    if not frames:
        raise UserInputError("no frames to calibrate from")
    size = frames[0][1].shape[1::-1]
    obj = board_points(pattern, square_mm).astype(np.float32)
    used, skipped, corners = [], [], []
    for name, img in frames:
        if img.shape[1::-1] != size:
            raise UserInputError(f"{name}: {img.shape[1]} x {img.shape[0]} px, the first "
                                  f"frame is {size[0]} x {size[1]} px")
        grey = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        c = detect_corners(grey, pattern)
        (used if c is not None else skipped).append(name)
        if c is not None:
            corners.append(c.astype(np.float32))
    if len(corners) < 3:
        raise UserInputError(f"a {pattern[0]} x {pattern[1]} chessboard was found in "
                              f"{len(corners)} of {len(frames)} frames; at least 3 are needed")
    img_pts = [c.reshape(-1, 1, 2) for c in corners]
    rms, K, dist, rvecs, tvecs, std_int, _, per_view = cv2.calibrateCameraExtended(
        [obj] * len(corners), img_pts, size, None, None, flags=flags)
    dist = np.asarray(dist, dtype=float).ravel()[:5]
    std = dict(zip(INTRINSIC_STD_NAMES, np.asarray(std_int, float).ravel()[:9], strict=True))
    residuals = np.array([
        c - cv2.projectPoints(obj, r, t, K, dist)[0].reshape(-1, 2)
        for c, r, t in zip(corners, rvecs, tvecs, strict=True)])
    b = base.binning
    cx_s, cy_s = image_to_sensor([K[0, 2], K[1, 2]], b)
    cal = CalibratedIntrinsics(
        fx_px=float(K[0, 0] * b), fy_px=float(K[1, 1] * b), cx_px=float(cx_s),
        cy_px=float(cy_s), std_px=tuple(float(std[k] * b) for k in ("fx", "fy", "cx", "cy")),
        dist_coeffs=tuple(float(v) for v in dist),
        dist_std=tuple(float(std[k]) for k in ("k1", "k2", "p1", "p2", "k3")),
        rms_px=float(rms), n_views=len(corners))
    cam = base.model_copy(update={
        "sensor_width_px": int(size[0] * b), "sensor_height_px": int(size[1] * b),
        "focal_length_m": 0.5 * (cal.fx_px + cal.fy_px) * base.pixel_size_m,
        "dist_coeffs": cal.dist_coeffs})
    return CameraCalibration(CameraFile(camera=CameraParams.model_validate(cam.model_dump()),
                                        calibration=cal),
                             np.asarray(K, float), dist, std, float(rms),
                             np.asarray(per_view, float).ravel(), np.array(corners), residuals,
                             used, skipped)


def read_frames(spec: str, step: int = 1) -> list[tuple[str, NDArray[np.uint8]]]:
    """Every ``step``-th frame of a folder of images or a video file, named by index."""
    if step < 1:
        raise UserInputError(f"step must be >= 1, got {step}")
    source = open_source(spec)
    if source.kind == "live":
        raise UserInputError(f"{spec}: calibrate reads a folder or a video file, not a camera")
    frames = []
    k = 0
    while True:
        ok, img = source.capture.read()
        if not ok or img is None:
            break
        if k % step == 0:
            frames.append((f"frame {k}", img))
        k += 1
    source.capture.release()
    if not frames:
        raise UserInputError(f"{spec}: no frame could be read (empty or unreadable)")
    return frames


def write_report(cal: CameraCalibration, out_dir: Path | str, source: str) -> Path:
    """``camera.yaml``, ``coverage.png``, ``residuals.png`` and ``report.md`` in ``out_dir``."""
    from matplotlib.figure import Figure

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cal.camera.save(out / "camera.yaml")
    c = cal.camera.camera
    w, h = c.sensor_width_px // c.binning, c.sensor_height_px // c.binning
    fig = Figure(figsize=(6, 6 * h / w))
    ax = fig.subplots()
    for pts in cal.corners_px:
        hull = cv2.convexHull(pts.astype(np.float32)).reshape(-1, 2)
        ax.fill(hull[:, 0], hull[:, 1], alpha=0.08, color="C0")
        ax.plot(pts[:, 0], pts[:, 1], ".", ms=1, color="C0")
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_aspect("equal")
    ax.set_title(f"coverage: {len(cal.corners_px)} views (corners and board outlines)")
    fig.tight_layout()
    fig.savefig(out / "coverage.png", dpi=100)
    fig = Figure(figsize=(10, 4))
    a1, a2 = fig.subplots(1, 2)
    res = cal.residuals_px.reshape(-1, 2)
    a1.plot(res[:, 0], res[:, 1], ".", ms=2)
    a1.set_aspect("equal")
    a1.set_xlabel("residual u, px")
    a1.set_ylabel("residual v, px")
    a1.set_title("corner residuals (detected - reprojected)")
    a2.bar(np.arange(len(cal.per_view_rms_px)), cal.per_view_rms_px)
    a2.set_xlabel("view")
    a2.set_ylabel("RMS reprojection error, px")
    fig.tight_layout()
    fig.savefig(out / "residuals.png", dpi=100)
    lines = [f"# Camera calibration: {source}", "", *[f"- {s}" for s in cal.summary_lines()],
             "", "Intrinsics in px of the calibration frames (± one sigma, OpenCV "
             "calibrateCameraExtended); `camera.yaml` holds them in full-sensor px.", "",
             "![coverage](coverage.png)", "", "![residuals](residuals.png)", ""]
    if cal.skipped:
        lines += ["Board not found in: " + ", ".join(cal.skipped), ""]
    (out / "report.md").write_text("\n".join(lines))
    return out / "camera.yaml"
