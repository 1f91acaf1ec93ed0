"""The camera's mounting from a recording (``pmspm calibrate-mount``): its roll about the optical
axis and the optical centre's offset from the rotation axis (``plant.camera``, "Mounting").

The recording is tracked by ``pmspm track`` (``experiments.track.run_track``) and only frames with
both markers measured are used. Two kinds of recording:

* **at rest at known attitudes** (``known``: a CSV with columns ``first_frame, last_frame,
  spin_deg, tilt_deg, yaw_deg``, the Z-Y-Z angles of ``plant.attitude`` of each resting
  stretch): the roll ρ and the offset (d_u, d_v) are fitted by least squares to the marker
  centres, whose model is the attitude solver's (``CorModel.nominal`` of the camera with that
  mount) at the known attitude turned into the camera-aligned frame, ``Rz(-ρ) ⊗ q``. Needs at
  least ``MIN_POSES`` attitudes at least ``MIN_POSE_SEPARATION_DEG`` apart.
* **spinning at zero tilt** (no ``known``): both markers run on circles about the image of the
  rotation axis; one circle fit with a shared centre gives that point, hence the offset
  (d_u, d_v) = -(x_n, y_n)·Z, with (x_n, y_n) the centre's normalised (undistorted) image
  coordinates and Z the markers' depth below the optical centre. A spin about the axis cannot
  show the roll (it only adds to the spin angle): the roll is kept from the camera file and
  reported as not identified. Needs the markers to sweep ``MIN_ARC_DEG`` about the centre.

Uncertainties are one standard deviation from the fit: σ² (Jᵀ J)⁻¹ with σ² the residual
variance (sum of squares over the degrees of freedom). Outputs in the run folder: the camera file
with the estimated mount (``camera.yaml``), ``mount_report.md`` and the tracking run in
``track/``. Bad input raises ``UserInputError``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from experiments.sources import Source, UserInputError
from experiments.track import run_track
from observer.cor_model import CorModel
from observer.tracking import ATTITUDE_SOURCES, PairTracker
from plant import attitude
from plant.camera import Camera
from plant.camera_file import CameraFile
from plant.params import PlantParams
from plant.user_files import UserSetup

#: Known-attitude mode: distinct resting attitudes needed, and how far apart (geodesic, deg) two
#: must be to count as distinct (our choice: two poses make the fit redundant beyond one
#: attitude's four numbers; 5° moves the markers by about 20 sensor px).
MIN_POSES = 2
MIN_POSE_SEPARATION_DEG = 5.0
#: Spin mode: the smallest arc (deg) the markers must sweep about the fitted centre (our choice:
#: below a quarter turn the circle's centre is poorly conditioned).
MIN_ARC_DEG = 90.0
KNOWN_COLUMNS = ("first_frame", "last_frame", "spin_deg", "tilt_deg", "yaw_deg")


@dataclass
class MountEstimate:
    """The estimated mount.

    Attributes
    ----------
    roll_deg, roll_std_deg : the roll about the optical axis and its 1-sigma (NaN std when not
        identified: kept from the camera file).
    offset_mm, offset_std_mm : (d_u, d_v) along the image axes and their 1-sigma, mm.
    mode : "known attitudes" or "spin at zero tilt".
    frames_used : frames with both markers measured that entered the fit.
    rms_px : RMS residual of the fit, sensor px.
    notes : what the user should know (e.g. the roll was not identified).
    """

    roll_deg: float
    roll_std_deg: float
    offset_mm: NDArray[np.float64]
    offset_std_mm: NDArray[np.float64]
    mode: str
    frames_used: int
    rms_px: float
    notes: list[str] = field(default_factory=list)

    @property
    def roll_identified(self) -> bool:
        """Whether the fit identified the roll (its standard deviation is finite)."""
        return math.isfinite(self.roll_std_deg)

    def camera_file(self, base: CameraFile) -> CameraFile:
        """``base`` with this mount."""
        cam = base.camera.model_copy(update={
            "mount_roll_deg": float(self.roll_deg),
            "mount_offset_mm": (float(self.offset_mm[0]), float(self.offset_mm[1]))})
        return base.model_copy(update={"camera": cam})

    def summary_lines(self) -> list[str]:
        """The estimate as lines of text: frames and fit RMS (sensor px), roll (deg) and offset (mm)
        with their standard deviations, then the fit's notes."""
        roll = (f"roll {self.roll_deg:.3f} ± {self.roll_std_deg:.3f} deg" if self.roll_identified
                else f"roll {self.roll_deg:.3f} deg (not identified: kept from the camera file)")
        return [f"mount from {self.frames_used} frames ({self.mode}), fit RMS "
                f"{self.rms_px:.2f} sensor px", roll,
                f"offset d_u {self.offset_mm[0]:.3f} ± {self.offset_std_mm[0]:.3f} mm, "
                f"d_v {self.offset_mm[1]:.3f} ± {self.offset_std_mm[1]:.3f} mm", *self.notes]


def read_known_attitudes(path: Path | str) -> pd.DataFrame:
    """The known-attitudes CSV (module docstring); ``UserInputError`` naming the problem."""
    try:
        table = pd.read_csv(path)
    except (OSError, ValueError) as exc:
        raise UserInputError(f"{path}: cannot read the known attitudes ({exc})") from exc
    missing = [c for c in KNOWN_COLUMNS if c not in table.columns]
    if missing:
        raise UserInputError(f"{path}: needs the columns {', '.join(KNOWN_COLUMNS)}; missing "
                              f"{', '.join(missing)}")
    values = table[list(KNOWN_COLUMNS)].to_numpy(float)
    if not np.all(np.isfinite(values)):
        raise UserInputError(f"{path}: every value must be a finite number")
    if np.any(values[:, 1] < values[:, 0]) or np.any(values[:, 0] < 0):
        raise UserInputError(f"{path}: each row needs 0 <= first_frame <= last_frame")
    return table


def known_attitudes_per_frame(table: pd.DataFrame) -> dict[int, NDArray[np.float64]]:
    """Frame index -> the known attitude (quaternion) of the known-attitudes table."""
    out = {}
    for row in table.itertuples():
        q = attitude.from_zyz(*np.deg2rad([row.spin_deg, row.tilt_deg, row.yaw_deg]))
        for k in range(int(row.first_frame), int(row.last_frame) + 1):
            out[k] = q
    return out


def _with_mount(params: PlantParams, roll_deg: float, offset_mm: ArrayLike) -> PlantParams:
    cam = params.camera.model_copy(update={"mount_roll_deg": float(roll_deg),
                                           "mount_offset_mm": tuple(map(float, offset_mm))})
    return params.model_copy(update={"camera": cam})


def _covariance(jac: NDArray[np.float64], residuals: NDArray[np.float64]) -> NDArray[np.float64]:
    """σ² (Jᵀ J)⁻¹ with σ² = the residuals' sum of squares over the degrees of freedom."""
    dof = max(len(residuals) - jac.shape[1], 1)
    sigma2 = float(residuals @ residuals) / dof
    return sigma2 * np.linalg.pinv(jac.T @ jac)


def estimate_from_known(centres_px: NDArray[np.float64], q_known: NDArray[np.float64],
                        params: PlantParams, markers_m: NDArray[np.float64]) -> MountEstimate:
    """Roll and offset from marker centres (N, 2, 2), sensor px, at known attitudes (N, 4)
    (module docstring). ``UserInputError`` when the attitudes are too few or too alike."""
    q_known = np.asarray(q_known, dtype=float)
    poses: list[NDArray[np.float64]] = []
    for q in q_known:
        if all(np.rad2deg(attitude.geodesic_angle(q, p)) >= MIN_POSE_SEPARATION_DEG
               for p in poses):
            poses.append(q)
    if len(poses) < MIN_POSES:
        raise UserInputError(
            f"the frames with both markers measured show {len(poses)} distinct known "
            f"attitude(s): rest the rotor at {MIN_POSES} or more known attitudes at least "
            f"{MIN_POSE_SEPARATION_DEG:g} deg apart (e.g. tilted 5 deg toward +X, then toward "
            "+Y), or record it spinning at zero tilt through at least "
            f"{MIN_ARC_DEG:g} deg without --known")
    z = centres_px.reshape(len(centres_px), -1)

    def residuals(x: NDArray[np.float64]) -> NDArray[np.float64]:
        p = _with_mount(params, x[0], x[1:])
        model = CorModel.nominal(p, markers_m=markers_m)
        turn = attitude.conjugate(Camera.from_plant(p).mount_quaternion)
        pred = np.array([model.project(attitude.multiply(turn, q)).reshape(-1)
                         for q in q_known])
        return (pred - z).reshape(-1)

    x0 = np.array([params.camera.mount_roll_deg, *params.camera.mount_offset_mm])
    fit = least_squares(residuals, x0)
    std = np.sqrt(np.diag(_covariance(fit.jac, fit.fun)))
    rms = float(np.sqrt(np.mean(fit.fun ** 2)))
    return MountEstimate(float(fit.x[0]), float(std[0]), fit.x[1:].copy(), std[1:].copy(),
                         "known attitudes", len(centres_px), rms)


def estimate_from_spin(centres_px: NDArray[np.float64], params: PlantParams,
                       markers_m: NDArray[np.float64]) -> MountEstimate:
    """Offset from marker centres (N, 2, 2), sensor px, of the rotor spinning at zero tilt
    (module docstring); the roll is kept from ``params``. ``UserInputError`` when the markers
    swept less than ``MIN_ARC_DEG``."""
    c = np.asarray(centres_px, dtype=float)
    guess = c.reshape(-1, 2).mean(axis=0)
    radii0 = np.linalg.norm(c - guess, axis=2).mean(axis=0)

    def residuals(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return (np.linalg.norm(c - x[:2], axis=2) - x[2:]).reshape(-1)

    fit = least_squares(residuals, np.r_[guess, radii0])
    centre = fit.x[:2]
    angles = np.sort(np.arctan2(*(c[:, 0] - centre).T[::-1]))
    gaps = np.diff(np.r_[angles, angles[0] + 2 * np.pi])
    arc_deg = float(np.rad2deg(2 * np.pi - gaps.max())) if len(angles) > 1 else 0.0
    if arc_deg < MIN_ARC_DEG:
        raise UserInputError(
            f"the markers turned through {arc_deg:.0f} deg about the rotation axis: record the "
            f"rotor spinning at zero tilt through at least {MIN_ARC_DEG:g} deg (a full turn is "
            "best), or rest it at known attitudes (--known)")
    cov = _covariance(fit.jac, fit.fun)[:2, :2]
    cam = Camera.from_plant(params)
    K = cam.matrix(1)
    dist = np.asarray(params.camera.dist_coeffs, dtype=float)
    xn = cv2.undistortPoints(centre.reshape(1, 1, 2), K, dist).reshape(2)
    # the markers' depth below the optical centre at zero tilt (the centre at -(R + h_c))
    depth_m = float(np.mean(markers_m[:, 2]) + params.rotor.radius_m + params.camera.h_c_m)
    scale = depth_m / np.array([K[0, 0], K[1, 1]])  # m per px near the centre (d xn / d u = 1/f)
    offset_mm = -xn * depth_m * 1000.0
    std_mm = np.sqrt(np.diag(cov)) * scale * 1000.0
    rms = float(np.sqrt(np.mean(fit.fun ** 2)))
    note = ("roll not identified: a spin about the rotation axis cannot show it (rest the "
            "rotor at known attitudes, --known, to estimate it)")
    return MountEstimate(params.camera.mount_roll_deg, math.nan, offset_mm, std_mm,
                         "spin at zero tilt", len(c), rms, [note, f"arc swept: {arc_deg:.0f} deg"])


def run_calibrate_mount(source: Source, tracker: PairTracker, out_dir: Path | str,
                        boxes_image_px: ArrayLike | str | None, setup: UserSetup,
                        known: Path | str | None = None,
                        max_frames: int | None = None) -> MountEstimate:
    """Track ``source``, estimate the mount (module docstring) and write ``camera.yaml`` (the
    setup's camera file with the estimated mount) and ``mount_report.md`` into ``out_dir``."""
    out = Path(out_dir)
    table_known = None if known is None else read_known_attitudes(known)
    outcome = run_track(source, tracker, out / "track", boxes_image_px, setup=setup,
                        max_frames=max_frames, write_video=False)
    t = outcome.table
    used = t[t["attitude_source"] == ATTITUDE_SOURCES[0]]
    idx = used["frame_index"].to_numpy(int)
    centres = np.stack([used[["red_u_px", "red_v_px"]].to_numpy(),
                        used[["yellow_u_px", "yellow_v_px"]].to_numpy()], axis=1)
    if table_known is None:
        if len(idx) < 3:
            raise UserInputError(f"only {len(idx)} frames with both markers measured: record "
                                 f"the rotor spinning at zero tilt through at least "
                                 f"{MIN_ARC_DEG:g} deg")
        est = estimate_from_spin(centres, setup.params, setup.markers_m)
    else:
        per_frame = known_attitudes_per_frame(table_known)
        keep = np.array([k in per_frame for k in idx], dtype=bool)
        q_known = np.array([per_frame[k] for k in idx[keep]]).reshape(-1, 4)
        est = estimate_from_known(centres[keep], q_known, setup.params, setup.markers_m)
    est.camera_file(setup.camera).save(out / "camera.yaml")
    lines = [f"# Camera mount: {source.name}", "",
             f"Tracker: {tracker.name}; {len(t)} frames tracked, {len(idx)} with both markers "
             "measured.", "", *[f"- {s}" for s in est.summary_lines()], "",
             "`camera.yaml`: the camera file with `mount_roll_deg` and `mount_offset_mm` set; "
             "pass it to `pmspm track --camera`.", ""]
    (out / "mount_report.md").write_text("\n".join(lines))
    return est
