"""Paper reproduction (issue 7 §1, §3): the rotary-table step tests of seed 000 §5.

The seed checks its camera scheme and a MEMS baseline against a hydraulic rotary table: single-axis
steps with a 5 s dwell after each (spin 0–75° by 10°, §5.1; tilt 0–15° by 5°, §5.2; yaw by 10° at a
15° tilt, turned by the table about the stator Z axis, §5.3), and reports the RMSE over the
steady-state frames of the dwells. This module simulates that bench.

**The table** (``RotaryTable``): a perfect kinematic table. The step attitudes are those of
``controller.reference.SeedSteps``; between two steps the table moves along a minimum-jerk profile
(``move_s``, our choice: 1 s, so that the tracker sees motion and the IMU sees a realistic rate),
then dwells ``dwell_s`` (seed 000 §5: 5 s). Timeline: a rest of ``rest_s`` at the first value (the
MEMS zeroing window, §5.3), then for step k a move [T_k, T_k + move_s) from value k − 1 to value k
(no motion for k = 0) and the dwell [T_k + move_s, T_k + move_s + dwell_s), with
T_k = rest_s + k (move_s + dwell_s). The attitude, body rate and body acceleration are exact
(``controller.reference.zyz_sample``): each protocol is a straight line in the Z-Y-Z angles
``R = Rz(γ) Ry(β) Rz(α)`` (``plant.attitude``), spin (v, 0, 0), tilt (−a, v, a) toward azimuth a,
rotary-table yaw (0, β, v).

**The camera scheme** (``run_camera``): each frame (36 frames/s, mid-exposure times k/36 s) is
rendered at the table's attitude with its body rate (motion blur over the exposure), Gaussian read
noise is added (the sensor noise of our camera model), a tracker + the GK assistance locates the two
markers (GK-TransT when its shipped weights load, else OpenCV KCF + GK assistance), and per-frame
attitude back ends turn the pixels into attitudes: the seed's closed form (§2.3–2.5,
``observer.closed_form``), the CoR-constrained least squares (``observer.cor_solver``), and the
least squares on the seed's pixel Kalman filter (§3.2.1, ``observer.pixel_observer``).

**The MEMS scheme** (``run_mems``): ``observer.mems`` simulates the IMU (ICM42605 class, 200 Hz,
bias drift) on the same truth and runs its estimator with the seed's initial bias zeroing, SO(3)
yaw decoupling Ψ = atan2(R21, R11) and phase unwrapping (§5.3). Its output is sampled at the
camera's frame times (zero-order hold of the latest IMU sample), since the seed collects both
schemes synchronously and counts steady-state windows in frames.

**What each scheme's angle is** (``measured_angle``):

* spin test (§5.1, zero tilt): the total turn about Z, i.e. the decoupled yaw Ψ of the estimate,
  which at β = 0 equals α + γ and is what the seed's image spin (the azimuth of the red → yellow
  vector) measures; for the MEMS its zeroed Ψ;
* tilt test (§5.2): the tilt β of the estimate (``plant.attitude``);
* yaw test (§5.3, 15° tilt): the camera's Z-Y-Z yaw γ (the azimuth of the pole offset, which is
  what the seed's camera yaw is); for the MEMS the seed's decoupled yaw Ψ, unwrapped and zeroed.
  On this bench (α = 0) the true Ψ equals the true γ, the table angle.

Spin and yaw traces are unwrapped (``observer.mems.unwrap_phase``) and put on the 2π branch of the
table's angle at their first valid sample. The camera's angles are absolute (no zeroing). The MEMS
Ψ is zeroed by the estimator at its first valid sample (the seed's "initial bias zeroing"), and the
table's angle at that time is added back, so that all traces compare with the table's angle.

**Steady state and RMSE** (``steady_state_mask``, ``steady_state_rmse``; seed 000 §5): within each
dwell, every run of 90 consecutive frames (2.5 s at 36 frames/s) whose population standard
deviation (ddof = 0) of the measured angle is strictly below 0.3° is a steady window; a window
must lie entirely inside one dwell and contain no invalid frame; windows slide by one frame. The
steady-state frames are the union of all steady windows of all dwells, and
RMSE = sqrt(mean((θ_measured − θ_table)²)) over those frames (seed 000 §5's formula). A dwell
without any steady window contributes no frames (and is counted, see ``SteadyState``).

Units: SI inside (rad, s, sensor px); degrees only in the ``*_deg`` fields, tables and plots.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

from controller.base import RefSample
from controller.reference import SeedSteps, zyz_sample
from observer import mems
from observer.aekf import AEKFConfig
from observer.closed_form import SeedClosedForm
from observer.cor_model import CorModel
from observer.cor_solver import CorSolver
from observer.pixel_observer import FilterObserver, PixelKalmanObserver, SolverObserver
from observer.tracking import PairTracker
from plant import attitude
from plant.params import PlantParams

Axis = Literal["spin", "tilt", "yaw"]
AXES: tuple[Axis, ...] = ("spin", "tilt", "yaw")

#: Seed 000 §5: a steady-state window is 90 frames (2.5 s) ...
STEADY_WINDOW_FRAMES = 90
#: ... whose angular standard deviation is below 0.3°.
STEADY_STD_MAX_RAD = math.radians(0.3)

#: The seed's RMSEs (seed 000 §5.1–5.3), degrees: its numbers, not ours.
SEED_RMSE_DEG: dict[str, dict[Axis, float]] = {
    "camera": {"spin": 0.2979, "tilt": 0.1496, "yaw": 0.8847},
    "mems": {"spin": 1.3120, "tilt": 0.2640, "yaw": 15.0819},
}

#: The camera back ends run on the same tracked pixels: key -> (label, seed row it compares with).
CAMERA_BACKENDS: dict[str, tuple[str, str]] = {
    "camera_closed_form": ("Camera, seed's closed form (§2.3–2.5)", "camera"),
    "camera_least_squares": ("Camera, CoR least squares", "camera"),
    "camera_least_squares_kalman": (
        "Camera, least squares on the seed's pixel Kalman (§3.2.1)",
        "camera",
    ),
    "camera_aekf": (
        "Camera, quaternion AEKF on the marker pixels (seed 001 App. C; no torque input)",
        "camera",
    ),
}

#: The MEMS variants: key -> (label, known start attitude during the zeroing window).
MEMS_VARIANTS: dict[str, tuple[str, bool]] = {
    "mems_known_start": ("MEMS, known start (gyro and accelerometer zeroed)", True),
    "mems_levelled_start": ("MEMS, levelled start (gyro zeroed only)", False),
}


# ------------------------------------------------------------------------------------------------
# The rotary table
# ------------------------------------------------------------------------------------------------
def _min_jerk(tau: float) -> tuple[float, float, float]:
    """Minimum-jerk profile s(τ) = 10τ³ − 15τ⁴ + 6τ⁵ on τ ∈ [0, 1] with ds/dτ and d²s/dτ²
    (zero rate and acceleration at both ends)."""
    t = min(max(tau, 0.0), 1.0)
    s = t * t * t * (10.0 - 15.0 * t + 6.0 * t * t)
    ds = 30.0 * t * t * (1.0 - t) ** 2
    dds = 60.0 * t * (1.0 - t) * (1.0 - 2.0 * t)
    return s, ds, dds


def zyz_line(steps: SeedSteps) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The protocol as a line in the Z-Y-Z angles: ``(α, β, γ) = base + direction · v`` (rad) for
    the table angle v (rad), matching ``SeedSteps.attitude_of`` (tested).

    spin: (v, 0, 0); tilt toward azimuth a: (−a, v, a); yaw at tilt β: (0, β, v) for the rotary
    table (``turn_shaft``), (−v, β, v) for a shaft sweeping the cone without turning.
    """
    if steps.axis == "spin":
        return np.zeros(3), np.array([1.0, 0.0, 0.0])
    if steps.axis == "tilt":
        a = math.radians(steps.azimuth_deg)
        return np.array([-a, 0.0, a]), np.array([0.0, 1.0, 0.0])
    beta = math.radians(steps.tilt_deg)
    return np.array([0.0, beta, 0.0]), np.array([0.0 if steps.turn_shaft else -1.0, 0.0, 1.0])


class RotaryTable:
    """A perfect kinematic rotary table running a ``SeedSteps`` protocol with smooth moves.

    Parameters
    ----------
    steps : SeedSteps
        Axis, step values (deg) and dwell (s) (seed 000 §5); its ``t_start_s`` is not used.
    move_s : float
        Duration of the minimum-jerk move between two steps, s (our choice: 1 s; 0 = jumps).
    rest_s : float
        Rest at the first value before step 0, s (our choice: 2 s, the MEMS zeroing window).

    The timeline is in the module docstring. ``sample(t)`` is a ``controller.base.RefSample``
    (attitude, body rate rad/s, body acceleration rad/s²), exact.
    """

    def __init__(self, steps: SeedSteps, move_s: float = 1.0, rest_s: float = 2.0) -> None:
        if not (math.isfinite(move_s) and move_s >= 0.0):
            raise ValueError(f"move_s must be a finite number >= 0 s, got {move_s!r}")
        if not (math.isfinite(rest_s) and rest_s >= 0.0):
            raise ValueError(f"rest_s must be a finite number >= 0 s, got {rest_s!r}")
        self.steps = steps
        self.axis: Axis = steps.axis
        self.move_s = float(move_s)
        self.rest_s = float(rest_s)
        self.dwell_s = float(steps.dwell_s)
        self.values_rad = np.deg2rad(steps.values())
        self.base, self.direction = zyz_line(steps)

    @property
    def n_steps(self) -> int:
        """Number of steps (dwells)."""
        return len(self.values_rad)

    @property
    def period_s(self) -> float:
        """Move + dwell, s."""
        return self.move_s + self.dwell_s

    @property
    def duration_s(self) -> float:
        """End of the last dwell, s."""
        return self.rest_s + self.n_steps * self.period_s

    def dwell_start_s(self, k: int) -> float:
        """Start of dwell k, s."""
        return self.rest_s + k * self.period_s + self.move_s

    def _where(self, t: float) -> tuple[int, float]:
        """(step k, time since T_k) for t ≥ rest_s; (−1, t − rest_s) before."""
        if t < self.rest_s:
            return -1, t - self.rest_s
        k = min(int((t - self.rest_s) // self.period_s), self.n_steps - 1)
        return k, t - self.rest_s - k * self.period_s

    def value(self, t: float) -> tuple[float, float, float]:
        """Table angle v (rad) with its first (rad/s) and second (rad/s²) derivative at t (s)."""
        k, dt = self._where(float(t))
        if k < 0:
            return float(self.values_rad[0]), 0.0, 0.0
        v1 = float(self.values_rad[k])
        v0 = float(self.values_rad[max(k - 1, 0)])
        if self.move_s == 0.0 or dt >= self.move_s:
            return v1, 0.0, 0.0
        s, ds, dds = _min_jerk(dt / self.move_s)
        d = v1 - v0
        return v0 + d * s, d * ds / self.move_s, d * dds / self.move_s**2

    def values_at(self, t: ArrayLike) -> NDArray[np.float64]:
        """Table angle (rad) at each time of ``t`` (s)."""
        return np.array([self.value(x)[0] for x in np.asarray(t, dtype=float).reshape(-1)])

    def sample(self, t: float) -> RefSample:
        """Attitude (w, x, y, z), body rate (rad/s) and body acceleration (rad/s²) at t (s)."""
        v, dv, ddv = self.value(t)
        return zyz_sample(self.base + self.direction * v, self.direction * dv,
                          self.direction * ddv)

    def dwell_id(self, t: ArrayLike) -> NDArray[np.int64]:
        """Index of the dwell that contains each time of ``t`` (s), −1 outside the dwells
        (rest, moves, after the end). Dwell k is [T_k + move_s, T_k + move_s + dwell_s)."""
        t = np.asarray(t, dtype=float).reshape(-1)
        out = np.full(t.shape, -1, dtype=np.int64)
        rel = t - self.rest_s
        k = np.floor(rel / self.period_s).astype(np.int64)
        phase = rel - k * self.period_s
        inside = (rel >= 0) & (k < self.n_steps) & (phase >= self.move_s - 1e-12)
        out[inside] = k[inside]
        return out

    def frame_times(self, frame_rate_hz: float) -> NDArray[np.float64]:
        """Mid-exposure times k/f (s) of the frames in [0, duration)."""
        n = int(math.floor(self.duration_s * frame_rate_hz + 1e-9))
        return np.arange(n) / float(frame_rate_hz)


def make_table(axis: Axis, values_deg: Sequence[float] | None = None, dwell_s: float = 5.0,
               move_s: float = 1.0, rest_s: float = 2.0, yaw_tilt_deg: float = 15.0
               ) -> RotaryTable:
    """The seed's protocol for ``axis`` (seed 000 §5; ``values_deg`` None = ``SeedSteps``'
    defaults: spin 0–70° by 10°, tilt 0–15° by 5°, yaw 0–90° by 10° at 15° tilt)."""
    steps = SeedSteps(axis=axis, values_deg=None if values_deg is None else tuple(values_deg),
                      dwell_s=dwell_s, tilt_deg=yaw_tilt_deg)
    return RotaryTable(steps, move_s=move_s, rest_s=rest_s)


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


# ------------------------------------------------------------------------------------------------
# Configuration and results
# ------------------------------------------------------------------------------------------------
class ReproductionConfig(BaseModel):
    """Settings of the step-test reproduction. Defaults cite the seed or say they are ours."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    renderer: Literal["mujoco", "analytic"] = Field(
        "mujoco", description="Issue 7: the MuJoCo renderer for this bench (analytic for tests)."
    )
    tracker: Literal["auto", "gk_transt", "kcf_gk"] = Field(
        "auto",
        description="auto: GK-TransT if its shipped weights load, else OpenCV KCF + GK "
        "assistance (seed 000 §3.2).",
    )
    read_noise_dn: float = Field(
        2.0,
        ge=0.0,
        description="Our choice: Gaussian read noise, DN (0-255) per binned pixel, the analytic "
        "renderer's default (see docs/reproduction.md for the justification).",
    )
    camera_seed: int = Field(0, description="Seed of the read noise (our choice).")
    mems_seeds: tuple[int, ...] = Field(
        (0, 1, 2, 3, 4), min_length=1, description="IMU noise seeds (our choice: 5)."
    )
    dwell_s: float = Field(5.0, gt=0.0, description="Seed 000 §5: 5 s dwell.")
    move_s: float = Field(1.0, ge=0.0, description="Our choice: 1 s minimum-jerk move.")
    rest_s: float = Field(2.0, ge=0.0, description="Our choice: 2 s rest (MEMS zeroing).")
    spin_values_deg: tuple[float, ...] | None = Field(
        None, description="None: SeedSteps' 0–70° by 10° (seed 000 §5.1)."
    )
    tilt_values_deg: tuple[float, ...] | None = Field(
        None, description="None: SeedSteps' 0–15° by 5° (seed 000 §5.2)."
    )
    yaw_values_deg: tuple[float, ...] | None = Field(
        None, description="None: SeedSteps' 0–90° by 10° (the seed gives no range; ours)."
    )
    yaw_tilt_deg: float = Field(15.0, ge=0.0, le=15.0, description="Seed 000 §5.3: 15°.")
    window_frames: int = Field(STEADY_WINDOW_FRAMES, ge=1, description="Seed 000 §5: 90.")
    std_max_deg: float = Field(0.3, gt=0.0, description="Seed 000 §5: 0.3°.")

    @model_validator(mode="after")
    def _check(self) -> ReproductionConfig:
        fps = PlantParams().camera.frame_rate_hz
        if self.window_frames > self.dwell_s * fps + 1e-9:
            raise ValueError(
                f"window_frames = {self.window_frames} does not fit in a {self.dwell_s} s dwell "
                f"at {fps} frames/s"
            )
        return self

    def table(self, axis: Axis) -> RotaryTable:
        """The rotary table of one axis."""
        vals = {"spin": self.spin_values_deg, "tilt": self.tilt_values_deg,
                "yaw": self.yaw_values_deg}[axis]
        return make_table(axis, vals, self.dwell_s, self.move_s, self.rest_s, self.yaw_tilt_deg)


@dataclass
class Trace:
    """One scheme's angle over the frames of a step test.

    Attributes
    ----------
    key, label : identifier and human-readable name.
    angle_rad : (N,) the scheme's angle (unwrapped and on the table's branch), NaN when invalid.
    steady : the steady-state frames and RMSE.
    seed_row : "camera" or "mems", the seed's row this trace compares with.
    rmse_spread_rad : (min, max) of the RMSE over noise seeds, when several were run (MEMS).
    noise_seed : the noise seed of the run shown (MEMS: the one with the median RMSE).
    """

    key: str
    label: str
    angle_rad: NDArray[np.float64]
    steady: SteadyState
    seed_row: str
    rmse_spread_rad: tuple[float, float] | None = None
    noise_seed: int | None = None


@dataclass
class CameraRun:
    """Per-frame record of the camera scheme (N frames).

    Attributes
    ----------
    tracker_name : which tracker ran ("gk_transt" or "kcf_gk") and, if it fell back, why.
    marker_true_px, marker_px : (N, 2, 2) true and located centres, sensor px (red, yellow).
    lost : (N,) the tracker flagged the frame lost.
    red_refined : (N,) the red centre is the GK assistance's sub-pixel circle fit inside the
        tracker's box (not the box centre nor a prediction).
    q : backend key -> (N, 4) released attitude (NaN when invalid).
    locate_time_s : (N,) wall-clock time of tracker + GK per frame.
    render_time_s : (N,) wall-clock time of the render (+ noise) per frame.
    """

    tracker_name: str
    tracker_note: str
    marker_true_px: NDArray[np.float64]
    marker_px: NDArray[np.float64]
    lost: NDArray[np.bool_]
    red_refined: NDArray[np.bool_]
    q: dict[str, NDArray[np.float64]]
    locate_time_s: NDArray[np.float64]
    render_time_s: NDArray[np.float64]


@dataclass
class StepTestResult:
    """One axis of the reproduction.

    Attributes
    ----------
    axis : "spin", "tilt" or "yaw".
    t_s : (N,) frame times, s.
    reference_rad : (N,) the table's angle.
    dwell_id : (N,) dwell of each frame (−1 outside).
    q_true : (N, 4) the table's attitude.
    traces : scheme key -> Trace (camera back ends and MEMS variants).
    camera : the camera run's per-frame record (None if the camera was not run).
    wall_time_s : wall-clock time of the whole test.
    """

    axis: Axis
    t_s: NDArray[np.float64]
    reference_rad: NDArray[np.float64]
    dwell_id: NDArray[np.int64]
    q_true: NDArray[np.float64]
    traces: dict[str, Trace] = field(default_factory=dict)
    camera: CameraRun | None = None
    wall_time_s: float = math.nan

    def pixel_error_px(self, dwells_only: bool = True) -> NDArray[np.float64]:
        """(M, 2, 2) located − true marker centres, sensor px, over the frames of the dwells
        (``dwells_only``) or all frames; empty without a camera run."""
        if self.camera is None:
            return np.empty((0, 2, 2))
        e = self.camera.marker_px - self.camera.marker_true_px
        sel = self.dwell_id >= 0 if dwells_only else np.ones(len(e), bool)
        return e[sel]


# ------------------------------------------------------------------------------------------------
# The camera scheme
# ------------------------------------------------------------------------------------------------
def gk_transt_available() -> tuple[bool, str]:
    """(True, "") if ``observer.trackers.gk_transt`` imports and the shipped TransT weights load
    (SHA-256 checked), else (False, why)."""
    try:
        import observer.trackers.gk_transt  # noqa: F401
        from observer.transt.tracker import TransTTracker

        TransTTracker.small()
    except Exception as exc:  # noqa: BLE001 - any reason the network is unavailable
        return False, f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    return True, ""


def make_locator(kind: str, params: PlantParams) -> tuple[PairTracker, str, str]:
    """(pair tracker, name, note): ``kind`` "gk_transt", "kcf_gk" or "auto" (GK-TransT if
    available, else KCF + GK with the reason in the note). For GK-TransT the note names the
    weights' digest (the shipped file may be retrained between runs)."""
    from observer.trackers import make_pair_tracker

    if kind in ("auto", "gk_transt"):
        ok, why = gk_transt_available()
        if ok:
            from observer.transt.weights import SMALL_WEIGHTS, sha256_of

            sha = sha256_of(SMALL_WEIGHTS)
            return make_pair_tracker("gk_transt", params), \
                "gk_transt", f"weights {SMALL_WEIGHTS.name} SHA-256 {sha[:16]}…"
        if kind == "gk_transt":
            raise RuntimeError(f"GK-TransT is not available: {why}")
        return make_pair_tracker("kcf_gk", params), "kcf_gk", \
            f"GK-TransT unavailable ({why}); used KCF + GK"
    if kind == "kcf_gk":
        return make_pair_tracker("kcf_gk", params), "kcf_gk", ""
    raise ValueError(f"tracker must be 'auto', 'gk_transt' or 'kcf_gk', got {kind!r}")


def add_read_noise(image: NDArray[np.uint8], sigma_dn: float,
                   rng: np.random.Generator) -> NDArray[np.uint8]:
    """``image`` + N(0, σ²) per pixel and channel (DN), rounded and clipped to uint8."""
    if sigma_dn <= 0.0:
        return image
    noise = rng.standard_normal(image.shape, dtype=np.float32)
    out = image.astype(np.float32) + np.float32(sigma_dn) * noise + np.float32(0.5)
    return np.clip(out, 0.0, 255.0).astype(np.uint8)


def _make_renderer(cfg: ReproductionConfig, params: PlantParams) -> tuple[Callable, Callable]:
    """(render(q, t, omega) -> Frame with noise, close())."""
    rng = np.random.default_rng(cfg.camera_seed)
    if cfg.renderer == "mujoco":
        from plant.render_mujoco import MujocoRenderer

        r = MujocoRenderer(params)

        def render(q: NDArray, t: float, omega: NDArray):  # noqa: ANN202
            fr = r.render(q, t, omega=omega)
            return fr, add_read_noise(fr.image, cfg.read_noise_dn, rng)

        return render, r.close
    from plant.render_analytic import AnalyticRenderer, AnalyticRenderOptions

    a = AnalyticRenderer(params, options=AnalyticRenderOptions(noise_sigma_dn=cfg.read_noise_dn),
                         seed=rng)

    def render_a(q: NDArray, t: float, omega: NDArray):  # noqa: ANN202
        fr = a.render(q, t, omega=omega)
        return fr, fr.image

    return render_a, lambda: None


def camera_backends(params: PlantParams) -> dict[str, object]:
    """Fresh per-frame back ends, keyed as ``CAMERA_BACKENDS``."""
    model = CorModel.nominal(params)
    return {
        "camera_closed_form": SolverObserver(SeedClosedForm(params)),
        "camera_least_squares": SolverObserver(CorSolver(model)),
        "camera_least_squares_kalman": PixelKalmanObserver(CorSolver(model)),
        # The table's torque is unknown to the filter: it predicts with zero torque, so its
        # model decelerates the moving rotor by friction (τ_c/J ≈ 1.4 rad/s²) while the table
        # also accelerates it (≈ 1 rad/s² peak for a 10° minimum-jerk move in 1 s). Our choice:
        # a rate random walk q_ω ≈ a²·t_move with a ≈ 2.4 rad/s² over the 1 s move, rounded up
        # to 10 rad²/s³ (the default 0.1 loses lock on the first move). Estimate at the
        # exposure time.
        "camera_aekf": FilterObserver(params, AEKFConfig(q_omega_rad2_per_s3=10.0),
                                      compensate_delay=False),
    }


def run_camera(table: RotaryTable, cfg: ReproductionConfig, params: PlantParams | None = None,
               progress: Callable[[str], None] | None = None) -> tuple[NDArray, CameraRun]:
    """Render, track and solve every frame of ``table``; returns (frame times (N,), record).

    The tracker starts on the first frame with the true marker boxes (a user's first-frame
    annotation). The tilt hint of the GK geometric check (D_exp = L·S·cos β, seed 000 §3.2.2)
    comes from the least-squares estimate of the previous frame. Back ends start at the table's
    first attitude (a per-frame solver only uses it as the first warm start).
    """
    p = params or PlantParams()
    fps = p.camera.frame_rate_hz
    ts = table.frame_times(fps)
    render, close = _make_renderer(cfg, p)
    locator, name, note = make_locator(cfg.tracker, p)
    backends = camera_backends(p)
    q0 = table.sample(0.0).q
    for b in backends.values():
        b.reset(q0, 0.0)
    n = len(ts)
    true_px = np.full((n, 2, 2), np.nan)
    px = np.full((n, 2, 2), np.nan)
    lost = np.zeros(n, bool)
    refined = np.zeros(n, bool)
    qs = {k: np.full((n, 4), np.nan) for k in backends}
    t_loc, t_ren = np.zeros(n), np.zeros(n)
    hint: float | None = None
    try:
        for i, t in enumerate(ts):
            s = table.sample(float(t))
            t0 = time.perf_counter()
            frame, image = render(s.q, float(t), s.omega)
            t1 = time.perf_counter()
            if i == 0:
                locator.start(image, frame.boxes_px, frame.binning)
            locator.tilt_hint_rad = hint
            r = locator.step(image)
            uv, lost_i, reason, refined[i] = r.marker_px, r.lost, r.reason, r.red_refined
            t_loc[i], t_ren[i] = time.perf_counter() - t1, t1 - t0
            true_px[i], px[i], lost[i] = frame.marker_px, uv, lost_i
            for key, b in backends.items():
                b.process(uv, float(t), lost_i, reason, t_loc[i])
                est = b.release(float(t))
                if est.valid:
                    qs[key][i] = est.q
            q_ls = qs["camera_least_squares"][i]
            hint = attitude.tilt(q_ls) if np.all(np.isfinite(q_ls)) else hint
            if progress and (i + 1) % 360 == 0:
                progress(f"{table.axis}: frame {i + 1}/{n}")
    finally:
        close()
    return ts, CameraRun(name, note, true_px, px, lost, refined, qs, t_loc, t_ren)


# ------------------------------------------------------------------------------------------------
# The MEMS scheme
# ------------------------------------------------------------------------------------------------
def truth_trajectory(table: RotaryTable, rate_hz: float = 200.0) -> mems.Trajectory:
    """The table's exact truth at ``rate_hz`` (the IMU's rate, seed 000 Table 2: 200 Hz) over
    [0, duration]: attitude, body rate (rad/s) and body acceleration (rad/s²)."""
    t = np.arange(int(math.floor(table.duration_s * rate_hz + 1e-9)) + 1) / rate_hz
    samples = [table.sample(float(x)) for x in t]
    return mems.Trajectory(t, np.array([s.q for s in samples]),
                           np.array([s.omega for s in samples]),
                           np.array([s.alpha for s in samples]))


def run_mems(table: RotaryTable, frame_times_s: ArrayLike, known_start: bool, seed: int,
             imu: mems.ImuConfig | None = None, estimator: mems.MemsEstimatorConfig | None = None,
             truth: mems.Trajectory | None = None) -> NDArray[np.float64]:
    """The MEMS scheme's angle (rad) for the table's axis at ``frame_times_s`` (NaN where the
    estimator has no valid output yet, e.g. during zeroing).

    The IMU model and estimator are ``observer.mems``'s defaults unless given; ``known_start``
    hands the estimator the table's start attitude (then the accelerometer bias is zeroed too).
    Spin and yaw are the seed's decoupled, unwrapped and zeroed Ψ plus the table's angle at the
    first valid sample; tilt is the estimate's β.
    """
    imu = imu or mems.ImuConfig()
    truth = truth or truth_trajectory(table, imu.rate_hz)
    samples = mems.simulate_imu_from(truth, imu, seed)
    est = mems.MemsAttitudeEstimator(estimator, imu, q_init=truth.q[0] if known_start else None)
    trk = est.run(samples)
    tf = np.asarray(frame_times_s, dtype=float).reshape(-1)
    j = np.searchsorted(trk.t, tf + 1e-9, side="right") - 1
    ok = (j >= 0) & trk.valid[np.clip(j, 0, None)]
    jj = np.clip(j, 0, None)
    out = np.full(len(tf), np.nan)
    if table.axis == "tilt":
        out[ok] = trk.euler_zyz[jj[ok], 1]
        return out
    first = np.flatnonzero(trk.valid)
    if len(first) == 0:
        return out
    v0 = table.value(float(trk.t[first[0]]))[0]
    out[ok] = trk.psi_zeroed[jj[ok]] + v0
    return out


# ------------------------------------------------------------------------------------------------
# One axis, all schemes
# ------------------------------------------------------------------------------------------------
def run_step_test(axis: Axis, cfg: ReproductionConfig | None = None,
                  params: PlantParams | None = None, camera: bool = True, mems_run: bool = True,
                  progress: Callable[[str], None] | None = None) -> StepTestResult:
    """The step test of ``axis`` for the camera back ends and the MEMS variants."""
    cfg = cfg or ReproductionConfig()
    p = params or PlantParams()
    t_start = time.perf_counter()
    table = cfg.table(axis)
    ts = table.frame_times(p.camera.frame_rate_hz)
    ref = table.values_at(ts)
    dwell = table.dwell_id(ts)
    q_true = np.array([table.sample(float(t)).q for t in ts])
    res = StepTestResult(axis, ts, ref, dwell, q_true)
    std_max = math.radians(cfg.std_max_deg)

    def steady(angle: NDArray[np.float64]) -> SteadyState:
        return steady_state_rmse(angle, ref, dwell, cfg.window_frames, std_max)

    if camera:
        _, run = run_camera(table, cfg, p, progress)
        res.camera = run
        for key, (label, row) in CAMERA_BACKENDS.items():
            ang = measured_angle(axis, run.q[key])
            if axis != "tilt":
                ang = unwrap_to_reference(ang, ref)
            res.traces[key] = Trace(key, label, ang, steady(ang), row)
    if mems_run:
        imu = mems.ImuConfig()
        truth = truth_trajectory(table, imu.rate_hz)
        for key, (label, known) in MEMS_VARIANTS.items():
            runs = [run_mems(table, ts, known, s, imu, truth=truth) for s in cfg.mems_seeds]
            stats = [steady(a) for a in runs]
            rmses = np.array([s.rmse_rad for s in stats])
            # Report the seed whose RMSE is the median (the first of the two middle ones).
            order = np.argsort(np.where(np.isfinite(rmses), rmses, np.inf))
            pick = int(order[(len(order) - 1) // 2])
            spread = (float(np.nanmin(rmses)), float(np.nanmax(rmses))) if len(runs) > 1 else None
            res.traces[key] = Trace(key, label, runs[pick], stats[pick], "mems", spread,
                                    cfg.mems_seeds[pick])
    res.wall_time_s = time.perf_counter() - t_start
    return res


# ------------------------------------------------------------------------------------------------
# Tables and plots
# ------------------------------------------------------------------------------------------------
def results_table(results: dict[str, StepTestResult]):  # noqa: ANN201 - pandas.DataFrame
    """The step-test table: one row per scheme, for each axis our RMSE (deg), the number of
    steady-state frames and the seed's RMSE (deg; seed 000 §5.1–5.3, labelled as the seed's).

    Columns: ``scheme``, ``label``, then per axis ``{axis}_rmse_deg``, ``{axis}_steady_frames``,
    ``{axis}_seed_rmse_deg``, and for seed-spread rows ``{axis}_rmse_min_deg`` /
    ``{axis}_rmse_max_deg``.
    """
    import pandas as pd

    keys: list[str] = []
    for r in results.values():
        keys += [k for k in r.traces if k not in keys]
    rows = []
    for key in keys:
        row: dict[str, object] = {"scheme": key}
        for axis in AXES:
            r = results.get(axis)
            tr = r.traces.get(key) if r is not None else None
            if tr is not None:
                row.setdefault("label", tr.label)
                row["seed_row"] = tr.seed_row
            row[f"{axis}_rmse_deg"] = tr.steady.rmse_deg if tr else math.nan
            row[f"{axis}_steady_frames"] = tr.steady.n_frames if tr else 0
            spread = tr.rmse_spread_rad if tr else None
            row[f"{axis}_rmse_min_deg"] = math.degrees(spread[0]) if spread else math.nan
            row[f"{axis}_rmse_max_deg"] = math.degrees(spread[1]) if spread else math.nan
        rows.append(row)
    df = pd.DataFrame(rows)
    for axis in AXES:
        df[f"{axis}_seed_rmse_deg"] = [SEED_RMSE_DEG[s][axis] for s in df["seed_row"]]
    return df


def markdown_step_table(df) -> str:  # noqa: ANN001 - pandas.DataFrame from results_table
    """The step-test table in Markdown: ours beside the seed's for each axis."""
    head = ["scheme"]
    for axis in AXES:
        head += [f"{axis} RMSE, ours", f"{axis}, seed 000"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, r in df.iterrows():
        cells = [str(r["label"])]
        for axis in AXES:
            v = r[f"{axis}_rmse_deg"]
            s = "n/a" if not np.isfinite(v) else f"{v:.4f}°"
            lo, hi = r[f"{axis}_rmse_min_deg"], r[f"{axis}_rmse_max_deg"]
            if np.isfinite(lo):
                s += f" ({lo:.4f}–{hi:.4f}°)"
            cells += [s, f"{r[f'{axis}_seed_rmse_deg']:.4f}° (seed)"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot_step_test(result: StepTestResult, path: str, keys: Sequence[str] | None = None) -> str:
    """A figure like seed 000 Figures 17–19: (a) the angle trajectory of the table and each
    scheme, (b) each scheme's error over its steady-state frames. Saves to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = list(keys or result.traces)
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True)
    t = result.t_s
    ax1.plot(t, np.degrees(result.reference_rad), "k-", lw=2.2, label="rotary table (truth)")
    styles = ["-", "--", ":", "-.", "-", "--"]
    for i, k in enumerate(keys):
        tr = result.traces[k]
        ax1.plot(t, np.degrees(tr.angle_rad), styles[i % len(styles)], lw=1.0, label=tr.label)
        e = np.where(tr.steady.mask, np.degrees(tr.angle_rad - result.reference_rad), np.nan)
        ax2.plot(t, e, styles[i % len(styles)], lw=1.0,
                 label=f"{tr.label}: RMSE {tr.steady.rmse_deg:.4f}°")
    name = {"spin": "Spin", "tilt": "Tilt", "yaw": "Yaw"}[result.axis]
    ax1.set_ylabel(f"{name} angle (°)")
    ax1.set_title(f"(a) {name} angle trajectory")
    ax1.legend(fontsize=7, loc="best")
    ax1.grid(alpha=0.3)
    ax2.set_ylabel("error (°)")
    ax2.set_xlabel("time (s)")
    ax2.set_title("(b) Steady-state measurement error (frames in steady windows only)")
    ax2.legend(fontsize=7, loc="best")
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)


# ------------------------------------------------------------------------------------------------
# The tracking table (issue 7 §2 is benchmarks/bench_tracking.py's; we only summarise its output)
# ------------------------------------------------------------------------------------------------
#: Seed 000 §4.2–4.3: precision at 20 px (main, aux) per case (latency and FPS: Table 1,
#: ``experiments.tracking_bench.SEED_TABLE1``).
SEED_TRACKING: dict[str, dict[str, tuple[float, float]]] = {
    "gk_transt": {"clean": (0.909, 0.944), "occlusion": (0.891, 0.944), "blur": (0.897, 0.926)},
    "dual_transt": {"clean": (0.909, 0.917)},
    "kcf": {"clean": (0.894, 0.868), "occlusion": (0.295, 0.295), "blur": (0.428, 0.431)},
    "csrt": {"clean": (0.947, 0.971)},
}


def tracking_table_markdown(csv_path: str) -> str:
    """Summary of ``benchmarks/results/tracking_metrics.csv`` (written by
    benchmarks/bench_tracking.py): mean precision at 20 px (main, aux), median latency and FPS
    per tracker and case, with the seed's numbers beside (seed 000 §4, Table 1)."""
    import pandas as pd

    from experiments.tracking_bench import SEED_TABLE1

    m = pd.read_csv(csv_path)
    g = m.groupby(["tracker", "case"], sort=False).agg(
        sequences=("sequence", "nunique"),
        main=("main_precision_20px", "mean"),
        aux=("aux_precision_20px", "mean"),
        lat=("latency_median_ms", "median"),
        fps=("fps", "median"),
    ).reset_index()
    head = ["tracker", "case", "sequences", "precision@20px main / aux, ours",
            "seed 000", "latency median (ms), ours / seed", "FPS, ours / seed"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, r in g.iterrows():
        base = str(r.tracker).removesuffix("_norefine")
        seed = SEED_TRACKING.get(base, {})
        sp = seed.get(str(r.case))
        sp_s = f"{sp[0]:.3f} / {sp[1]:.3f}" if sp else "—"
        sf, sl = SEED_TABLE1.get(base, (None, None))
        name = str(r.tracker)
        if "standin" in name:
            name += " (numpy-KCF stand-in for the network: not TransT numbers)"
        lines.append(
            f"| {name} | {r.case} | {r.sequences} | {r.main:.3f} / {r.aux:.3f} | {sp_s} | "
            f"{r.lat:.2f} / {sl if sl is not None else '—'} | "
            f"{r.fps:.1f} / {sf if sf is not None else '—'} |"
        )
    return "\n".join(lines)
