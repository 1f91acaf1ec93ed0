"""The MEMS scheme on the same truth, and one axis's step test with all schemes
(``experiments.reproduction``)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from experiments.reproduction.camera import run_camera
from experiments.reproduction.results import ReproductionConfig, StepTestResult, Trace
from experiments.reproduction.steady import (
    SteadyState,
    measured_angle,
    steady_state_rmse,
    unwrap_to_reference,
)
from experiments.reproduction.table import CAMERA_BACKENDS, MEMS_VARIANTS, Axis, RotaryTable
from observer import mems
from observer.imu import ImuConfig, Trajectory, simulate_imu_from
from plant.params import PlantParams


# ------------------------------------------------------------------------------------------------
# The MEMS scheme
# ------------------------------------------------------------------------------------------------
def truth_trajectory(table: RotaryTable, rate_hz: float = 200.0) -> Trajectory:
    """The table's exact truth at ``rate_hz`` (the IMU's rate, seed 000 Table 2: 200 Hz) over
    [0, duration]: attitude, body rate (rad/s) and body acceleration (rad/s²)."""
    t = np.arange(int(math.floor(table.duration_s * rate_hz + 1e-9)) + 1) / rate_hz
    samples = [table.sample(float(x)) for x in t]
    return Trajectory(t, np.array([s.q for s in samples]),
                           np.array([s.omega for s in samples]),
                           np.array([s.alpha for s in samples]))


def run_mems(table: RotaryTable, frame_times_s: ArrayLike, known_start: bool, seed: int,
             imu: ImuConfig | None = None, estimator: mems.MemsEstimatorConfig | None = None,
             truth: Trajectory | None = None) -> NDArray[np.float64]:
    """The MEMS scheme's angle (rad) for the table's axis at ``frame_times_s`` (NaN where the
    estimator has no valid output yet, e.g. during zeroing).

    The IMU model and estimator are ``observer.imu``'s and ``observer.mems``'s defaults unless
    given; ``known_start`` hands the estimator the table's start attitude (then the accelerometer
    bias is zeroed too). Spin and yaw are the seed's decoupled, unwrapped and zeroed Ψ plus the
    table's angle at the first valid sample; tilt is the estimate's β.
    """
    imu = imu or ImuConfig()
    truth = truth or truth_trajectory(table, imu.rate_hz)
    samples = simulate_imu_from(truth, imu, seed)
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
        imu = ImuConfig()
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
