"""Steady-state windows and RMSE (seed 000 §5), and the angle each scheme measures
(``experiments.reproduction``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from experiments.reproduction.table import STEADY_STD_MAX_RAD, STEADY_WINDOW_FRAMES, Axis
from observer import mems
from observer.cor_model import CorModel
from plant import attitude
from plant.params import PlantParams


# ------------------------------------------------------------------------------------------------
# Steady state and RMSE (seed 000 §5)
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SteadyState:
    """The steady-state frames of one trace and the RMSE over them.

    Attributes
    ----------
    mask : (N,) bool, the frame lies in at least one steady window.
    rmse_rad : RMSE of measured − reference over the masked frames, rad (NaN if none).
    n_frames : number of steady-state frames.
    n_dwells : number of dwells (distinct ids ≥ 0).
    dwells_without_steady : ids of dwells with no steady window.
    """

    mask: NDArray[np.bool_]
    rmse_rad: float
    n_frames: int
    n_dwells: int
    dwells_without_steady: tuple[int, ...]

    @property
    def rmse_deg(self) -> float:
        """RMSE in degrees (for reports)."""
        return math.degrees(self.rmse_rad)


def steady_state_mask(
    angle_rad: ArrayLike,
    dwell_id: ArrayLike,
    window_frames: int = STEADY_WINDOW_FRAMES,
    std_max_rad: float = STEADY_STD_MAX_RAD,
) -> NDArray[np.bool_]:
    """Frames (N,) that lie in a steady window (seed 000 §5; semantics in the module docstring).

    ``angle_rad`` (N,) is the measured angle of equally spaced frames in time order (NaN =
    invalid frame); ``dwell_id`` (N,) the dwell of each frame (−1 outside the dwells). A window is
    ``window_frames`` consecutive frames of one dwell, all finite, with ``np.std`` (ddof = 0)
    strictly below ``std_max_rad``.
    """
    x = np.asarray(angle_rad, dtype=float).reshape(-1)
    d = np.asarray(dwell_id).reshape(-1)
    if x.shape != d.shape:
        raise ValueError(f"angle_rad and dwell_id differ in length: {x.shape} vs {d.shape}")
    w = int(window_frames)
    if w < 1:
        raise ValueError(f"window_frames must be >= 1, got {window_frames!r}")
    mask = np.zeros(x.shape, dtype=bool)
    # Runs of equal dwell id (a dwell is contiguous in time; a repeated id elsewhere is a new run).
    edges = np.flatnonzero(np.diff(d) != 0) + 1
    for lo, hi in zip(np.r_[0, edges], np.r_[edges, len(d)], strict=True):
        if d[lo] < 0 or hi - lo < w:
            continue
        seg = x[lo:hi]
        win = np.lib.stride_tricks.sliding_window_view(seg, w)
        finite = np.all(np.isfinite(win), axis=1)
        with np.errstate(invalid="ignore"):
            std = np.where(finite, np.std(np.where(finite[:, None], win, 0.0), axis=1), np.inf)
        for s in np.flatnonzero(std < std_max_rad):
            mask[lo + s: lo + s + w] = True
    return mask


def steady_state_rmse(
    measured_rad: ArrayLike,
    reference_rad: ArrayLike,
    dwell_id: ArrayLike,
    window_frames: int = STEADY_WINDOW_FRAMES,
    std_max_rad: float = STEADY_STD_MAX_RAD,
) -> SteadyState:
    """Seed 000 §5's RMSE over the steady-state frames of ``measured_rad`` against the table's
    ``reference_rad`` (both (N,), rad; see ``steady_state_mask``)."""
    m = np.asarray(measured_rad, dtype=float).reshape(-1)
    r = np.asarray(reference_rad, dtype=float).reshape(-1)
    d = np.asarray(dwell_id).reshape(-1)
    if not (m.shape == r.shape == d.shape):
        raise ValueError(f"lengths differ: measured {m.shape}, reference {r.shape}, "
                         f"dwell_id {d.shape}")
    mask = steady_state_mask(m, d, window_frames, std_max_rad)
    n = int(mask.sum())
    rmse = float(np.sqrt(np.mean((m[mask] - r[mask]) ** 2))) if n else math.nan
    dwells = sorted({int(k) for k in d if k >= 0})
    without = tuple(k for k in dwells if not np.any(mask & (d == k)))
    return SteadyState(mask, rmse, n, len(dwells), without)


# ------------------------------------------------------------------------------------------------
# Angles of a scheme
# ------------------------------------------------------------------------------------------------
def unwrap_to_reference(angle_rad: ArrayLike, reference_rad: ArrayLike) -> NDArray[np.float64]:
    """Temporal phase unwrapping (seed 000 §5.3, ``observer.mems.unwrap_phase``), then the 2π
    branch that puts the first finite sample within π of the reference there. NaN stays NaN."""
    a = mems.unwrap_phase(angle_rad)
    r = np.asarray(reference_rad, dtype=float).reshape(-1)
    ok = np.flatnonzero(np.isfinite(a))
    if len(ok):
        i = ok[0]
        a = a + 2.0 * math.pi * round((r[i] - a[i]) / (2.0 * math.pi))
    return a


def measured_angle(axis: Axis, q: ArrayLike) -> NDArray[np.float64]:
    """The angle a scheme reports for ``axis`` from attitudes ``q`` (N, 4) (NaN rows stay NaN),
    rad, before unwrapping: spin → decoupled yaw Ψ (turn about Z at zero tilt), tilt → β,
    yaw → Z-Y-Z γ (module docstring)."""
    q = np.asarray(q, dtype=float).reshape(-1, 4)
    out = np.full(len(q), np.nan)
    ok = np.all(np.isfinite(q), axis=1)
    if not np.any(ok):
        return out
    qo = q[ok]
    if axis == "spin":
        out[ok] = mems.decoupled_yaw(qo)
    else:
        zyz = attitude.to_zyz_array(qo)
        out[ok] = zyz[:, 1] if axis == "tilt" else zyz[:, 2]
    return out


def disc_centroid_offset_px(q: ArrayLike, params: PlantParams | None = None,
                            n_points: int = 2048) -> NDArray[np.float64]:
    """Perspective offset (2, 2), sensor px, of each marker disc's image *area centroid* from
    the image of its centre (``Frame.marker_px``) at attitude ``q``: red then yellow, (du, dv).

    A tilted circle images as a conic whose centroid is not the projection of the circle's
    centre, so a tracker that finds the centre of the blob (circle fit, centroid) is biased by
    this much even on perfect pixels. Computed from the projected outline polygon (``n_points``
    vertices; the shoelace centroid), independent of any renderer.
    """
    from plant.camera import Camera, rotor_to_stator
    from plant.scene import disc_outlines_rotor, ground_truth

    p = params or PlantParams()
    q = attitude.normalize(q)
    outline = disc_outlines_rotor(p, n_points)
    uv = Camera.from_plant(p).project(rotor_to_stator(q, outline.reshape(-1, 3)), 1)
    uv = uv.reshape(outline.shape[:2] + (2,))
    x, y = uv[..., 0], uv[..., 1]
    xn, yn = np.roll(x, -1, axis=1), np.roll(y, -1, axis=1)
    cross = x * yn - xn * y
    area = cross.sum(axis=1) / 2.0
    cx = ((x + xn) * cross).sum(axis=1) / (6.0 * area)
    cy = ((y + yn) * cross).sum(axis=1) / (6.0 * area)
    centres, _ = ground_truth(p, q)
    return np.column_stack([cx, cy]) - centres


def crb_angle_rms_rad(axis: Axis, q: ArrayLike, sigma_px: float,
                      params: PlantParams | None = None) -> float:
    """Cramér–Rao bound on the RMS error (rad) of the test's angle (``measured_angle``) over the
    attitudes ``q`` (M, 4), for independent Gaussian pixel noise of ``sigma_px`` (sensor px) per
    coordinate of both markers (``observer.crb``; intrinsics, CoR and markers known).

    Per pose the variance is g C gᵀ with C = ``crb_body`` and g the gradient of the angle with
    respect to the body rotation vector (central differences, 1e-6 rad). At zero tilt the tilt is
    the norm of the cross-boresight error, whose mean square is the trace of the camera-frame
    cross-boresight block of the bound; that is used there. Returns sqrt(mean variance).
    """
    from observer.crb import crb_body, crb_camera

    p = params or PlantParams()
    model = CorModel.nominal(p)
    qs = np.asarray(q, dtype=float).reshape(-1, 4)
    h = 1e-6
    var = []
    for qi in qs:
        if axis == "tilt" and attitude.tilt(qi) < 1e-4:
            c = crb_camera(model, qi, sigma_px)
            var.append(c[0, 0] + c[1, 1])
            continue
        g = np.zeros(3)
        for j in range(3):
            e = np.zeros(3)
            e[j] = h
            plus = measured_angle(axis, attitude.multiply(qi, attitude.from_rotvec(e)))[0]
            minus = measured_angle(axis, attitude.multiply(qi, attitude.from_rotvec(-e)))[0]
            g[j] = float(attitude.wrap_angle(plus - minus)) / (2.0 * h)
        var.append(float(g @ crb_body(model, qi, sigma_px) @ g))
    return float(np.sqrt(np.mean(var)))
