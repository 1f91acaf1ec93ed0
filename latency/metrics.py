"""A closed-loop run's scalar metrics, from its steps, frames and events tables.

Both engines summarise a run here: the event loop (``latency.loop``) from its tables, the
compiled run loop (``latency.compiled``) straight from its arrays. The per-step metrics come
from one compiled pass over the steps (``_step_pass``): the geodesic error, the Z-Y-Z angle
errors, the torque, the step response after the reference's last change, the steady state,
the longest tilt-stop contact and the error and reference speed over the run's last half
(the loss-of-control verdict's window), with the formulas of
``plant.attitude``. The per-frame ones read the frames table's few columns with numpy.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import pandas as pd
from numba import njit
from numpy.typing import NDArray

from latency.numba_cache import drop_stale_cache
from plant import attitude
from plant.attitude import _geodesic_of, _hamilton, _matrix_elements

drop_stale_cache(__file__, (attitude,))

#: Loss of control (our choices, docs/closed_loop.md): any of these over a run.
LOC_TILT_STOP_S = 0.25  # continuous contact with the tilt stop for this long, s
LOC_MARKER_LOSS_S = 0.5  # markers lost on every processed frame for this long, s
LOC_LOST_FRACTION = 0.5  # or this fraction of the processed frames lost
#: ... or the RMS error over the run's second half above what the reference demands there:
#: ``LOC_ERROR_FLOOR_DEG`` plus ``LOC_LAG_S`` times the reference's mean angular speed over
#: the same half (deg/s), i.e. the rotor trails the reference by more than that much of its
#: motion. Validated against the exact margins (benchmarks/bench_verdict.py).
LOC_ERROR_FLOOR_DEG = 2.0
LOC_LAG_S = 0.25
#: The verdict's window: the run's last ``LOC_LATE_FRACTION`` (clear of the start, where the
#: loop at rest meets a reference already in motion).
LOC_LATE_FRACTION = 0.5
#: Absolute settling band around the commanded attitude, deg (2 % of the study's 5° step).
SETTLE_BAND_DEG = 0.1
#: Steady-state error: mean geodesic error over this final stretch of the run, s.
STEADY_STATE_WINDOW_S = 0.5
#: Reference rows further apart than this, rad, are a change of the reference.
_CHANGE_RAD = 1e-9
#: A commanded step smaller than this, rad, has no step metrics.
_MIN_STEP_RAD = 1e-6

#: A run's table as named columns: a ``pandas.DataFrame``, or a mapping of column names to
#: arrays (the same columns, before the frame is built; empty for a table without rows, so
#: that ``len`` is 0 exactly when the table has no rows).
Columns = pd.DataFrame | Mapping[str, NDArray]

#: What ``_step_pass`` returns, in its order (the last three feed ``loss_of_control``).
_STEP_VALUES = ("rms_error_deg", "max_error_deg", "rms_spin_error_deg", "rms_tilt_error_deg",
                "rms_yaw_error_deg", "max_spin_error_deg", "max_tilt_error_deg",
                "max_yaw_error_deg", "control_effort_N2m2s", "rms_torque_Nm", "settling_time_s",
                "overshoot_pct", "step_size_deg", "steady_state_error_deg",
                "longest_tilt_stop_s", "late_rms_error_deg", "late_ref_speed_deg_s")


@njit(cache=True)
def _zyz_elements(w, x, y, z):
    """The elements (R02, R12, R20, R21, R22) of R(q) that the Z-Y-Z angles read
    (``attitude._zyz_of_matrix``), q normalised first, and the tilt beta, rad."""
    n = math.sqrt(w * w + x * x + y * y + z * z)
    R = _matrix_elements(w / n, x / n, y / n, z / n)
    return R[2], R[5], R[6], R[7], R[8], math.atan2(math.hypot(R[2], R[5]), R[8])


@njit(cache=True)
def _zyz_differences(a, b):
    """The wrapped differences (rad) of the spin, tilt and yaw of the attitudes whose
    ``_zyz_elements`` are a and b, and whether both tilts exceed 1° (spin and yaw are NaN
    where they do not: Z-Y-Z spin and yaw are not separable near zero tilt). With spin
    alpha = atan2(R21, -R20) and yaw gamma = atan2(R12, R02) (``attitude.to_zyz``), each
    difference is one atan2 of the sine and cosine of the difference (in (-pi, pi], as
    ``attitude.wrap_angle`` gives it); the tilts lie in [0, pi], so theirs needs no wrap."""
    a02, a12, a20, a21, _, a_tilt = a
    b02, b12, b20, b21, _, b_tilt = b
    if not (math.degrees(a_tilt) > 1.0 and math.degrees(b_tilt) > 1.0):
        return np.nan, a_tilt - b_tilt, np.nan, False
    spin = math.atan2(a20 * b21 - a21 * b20, a20 * b20 + a21 * b21)
    yaw = math.atan2(a12 * b02 - a02 * b12, a02 * b02 + a12 * b12)
    return spin, a_tilt - b_tilt, yaw, True


@njit(cache=True)
def _last_step(q_ref):
    """The reference's last change in q_ref (n, 4): the row i0 where the commanded step from
    q_ref[i0 - 1] to q_ref[i0] lands (0 when the reference never changes by more than
    ``_CHANGE_RAD``), the step's size, rad, and its unit rotation axis (3,) in the frame of
    its start (``attitude.to_rotvec`` of conj(from) ⊗ to over its angle; zeros when i0 is 0).
    Found by one pass backwards from the last row."""
    n = q_ref.shape[0]
    i0 = 0
    for k in range(n - 1, 0, -1):
        a, b = q_ref[k - 1], q_ref[k]
        if a[0] == b[0] and a[1] == b[1] and a[2] == b[2] and a[3] == b[3]:
            continue
        if _geodesic_of(a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3]) > _CHANGE_RAD:
            i0 = k
            break
    size = 0.0
    axis = np.zeros(3)
    f, g = q_ref[max(i0 - 1, 0)], q_ref[i0]  # the commanded step's start and target
    if i0 > 0:
        size = _geodesic_of(f[0], f[1], f[2], f[3], g[0], g[1], g[2], g[3])
        d = np.array(_hamilton(f[0], -f[1], -f[2], -f[3], g[0], g[1], g[2], g[3]))
        d = d / math.sqrt(d @ d)
        if d[0] < 0:
            d = -d
        s = math.sqrt(d[1] * d[1] + d[2] * d[2] + d[3] * d[3])
        rv = 2.0 * d[1:] if s < 1e-12 else 2.0 * math.atan2(s, d[0]) * d[1:] / s
        axis = rv / size
    return i0, size, axis


@njit(cache=True)
def _settling(t, q, q_ref, i0, size, axis, settle_band_deg):
    """The step response from row i0 (``_last_step``) on: the last row whose error to the
    step's target exceeds ``settle_band_deg`` (-1 if none), the largest progress along the
    step's axis (1.0 on target, from the step's start) and whether a progress was NaN."""
    f, g = q_ref[max(i0 - 1, 0)], q_ref[i0]
    prog_max, nan_prog, last_out = -np.inf, False, -1
    for k in range(i0, t.shape[0]):
        qk, rk = q[k], q_ref[k]
        rw, rx, ry, rz = _hamilton(f[0], -f[1], -f[2], -f[3], qk[0], qk[1], qk[2], qk[3])
        sw = rw + 1e-300
        sign = 1.0 if sw > 0 else (-1.0 if sw < 0 else (0.0 if sw == 0 else np.nan))
        rw, rx, ry, rz = sign * rw, sign * rx, sign * ry, sign * rz
        s_half = math.sqrt(rx * rx + ry * ry + rz * rz)
        scale = 2.0 * math.atan2(s_half, rw) / max(s_half, 1e-300) if s_half > 1e-12 else 2.0
        prog = scale * (rx * axis[0] + ry * axis[1] + rz * axis[2]) / size
        if math.isnan(prog):
            nan_prog = True
        elif prog > prog_max:
            prog_max = prog
        to = rk if (rk[0] == g[0] and rk[1] == g[1] and rk[2] == g[2] and rk[3] == g[3]) else g
        e_to = math.degrees(_geodesic_of(qk[0], qk[1], qk[2], qk[3], to[0], to[1], to[2], to[3]))
        if e_to > settle_band_deg:
            last_out = k
    return last_out, prog_max, nan_prog


@njit(cache=True)
def _effort_and_contact(t, torque, stop):
    """The control effort (the integral of |T|², N²·m²·s, by the rectangle rule over the
    rows), the sum of |T|² over the rows, and the longest tilt-stop contact, s (from its first
    row to the next row without it, or to the end)."""
    n = t.shape[0]
    sum_T2 = effort = 0.0
    for k in range(n):
        T2 = torque[k, 0] ** 2 + torque[k, 1] ** 2 + torque[k, 2] ** 2
        sum_T2 += T2
        if k > 0:
            effort += T2 * (t[k] - t[k - 1])
    return effort, sum_T2, _longest_run(t, stop, np.zeros(n, dtype=np.bool_), t[n - 1])


@njit(cache=True)
def _longest_run(t, flag, skip, t_end):
    """The longest run of rows with ``flag`` among those not skipped (``skip``), s: from the
    run's first row's time ``t`` to that of the next row not skipped without the flag, or to
    ``t_end`` for a run that lasts to the end; 0 without a flagged row."""
    start, longest = np.nan, 0.0
    for i in range(t.shape[0]):
        if skip[i]:
            continue
        if flag[i]:
            if math.isnan(start):
                start = t[i]
        elif not math.isnan(start):
            longest = max(longest, t[i] - start)
            start = np.nan
    if not math.isnan(start):
        longest = max(longest, t_end - start)
    return longest


@njit(cache=True)
def _error_pass(t, q, q_ref, out, steady_window_s, late_fraction):
    """Into ``out`` (``_STEP_VALUES`` order): the RMS and largest attitude error (deg), the
    RMS and largest Z-Y-Z angle errors (tilt on every row, spin and yaw where both tilts
    exceed 1°, deg); returns the mean error over the last ``steady_window_s`` (s), the RMS
    error over the last ``late_fraction`` of the run (deg) and the reference's mean angular
    speed over that window (its geodesic path over the window's length, deg/s)."""
    n = t.shape[0]
    t_end = t[n - 1]
    sum_e2, max_e, nan_e = 0.0, -np.inf, False
    sums, maxes, counts = np.zeros(3), np.zeros(3), np.zeros(3)
    nan_d = np.zeros(3, dtype=np.bool_)
    late_sum, late_n = 0.0, 0
    late_e2, late_e_n, late_path = 0.0, 0, 0.0
    t_late = (1.0 - late_fraction) * t_end
    ref_prev = np.full(4, np.nan)
    ref_R = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    for k in range(n):
        qk, rk = q[k], q_ref[k]
        e = math.degrees(_geodesic_of(qk[0], qk[1], qk[2], qk[3], rk[0], rk[1], rk[2], rk[3]))
        sum_e2 += e * e
        if math.isnan(e):
            nan_e = True
        elif e > max_e:
            max_e = e
        if not (rk[0] == ref_prev[0] and rk[1] == ref_prev[1] and rk[2] == ref_prev[2]
                and rk[3] == ref_prev[3]):
            ref_R = _zyz_elements(rk[0], rk[1], rk[2], rk[3])
            if k > 0 and t[k - 1] >= t_late:  # the reference's path within the window
                late_path += _geodesic_of(ref_prev[0], ref_prev[1], ref_prev[2], ref_prev[3],
                                          rk[0], rk[1], rk[2], rk[3])
            ref_prev[:] = rk
        d_spin, d_tilt, d_yaw, both_tilted = _zyz_differences(
            _zyz_elements(qk[0], qk[1], qk[2], qk[3]), ref_R)
        for i, d_i in enumerate((d_spin, d_tilt, d_yaw)):
            if i == 1 or both_tilted:
                sums[i] += d_i * d_i
                counts[i] += 1
                if math.isnan(d_i):
                    nan_d[i] = True
                elif abs(d_i) > maxes[i]:
                    maxes[i] = abs(d_i)
        if t[k] >= t_end - steady_window_s:
            late_sum += e
            late_n += 1
        if t[k] >= t_late:
            late_e2 += e * e
            late_e_n += 1
    out[0] = math.sqrt(sum_e2 / n)
    out[1] = np.nan if nan_e else max_e
    for i in range(3):
        if counts[i] > 0:
            out[2 + i] = math.degrees(math.sqrt(sums[i] / counts[i]))
            out[5 + i] = np.nan if nan_d[i] else math.degrees(maxes[i])
    late_s = t_end - t_late
    steady = late_sum / late_n if late_n else np.nan
    late_rms = math.sqrt(late_e2 / late_e_n) if late_e_n else 0.0
    return steady, late_rms, (math.degrees(late_path) / late_s if late_s > 0.0 else 0.0)


@njit(cache=True)
def _step_pass(t, q, q_ref, torque, stop, settle_band_deg, steady_window_s, step_metrics,
               late_fraction):
    """The per-step metrics (``_STEP_VALUES``) of a run from its steps: times t (n,), s,
    attitudes q and references q_ref (n, 4), delivered torques (n, 3), N·m, and tilt-stop
    flags (n,): the errors (``_error_pass``), effort and contact (``_effort_and_contact``)
    and, for a step of at least ``_MIN_STEP_RAD`` (``_last_step``), its settling time to
    within ``settle_band_deg`` and overshoot (``_settling``). Without ``step_metrics`` (a
    reference that is not piecewise constant) the step metrics and the steady-state error
    are NaN. Over the last ``late_fraction`` of the run: the RMS error and the reference's
    mean angular speed (deg/s)."""
    n = t.shape[0]
    out = np.full(len(_STEP_VALUES), np.nan)
    steady, late_rms, late_speed = _error_pass(t, q, q_ref, out, steady_window_s,
                                               late_fraction)
    effort, sum_T2, longest_stop = _effort_and_contact(t, torque, stop)
    out[8], out[9] = effort, math.sqrt(sum_T2 / n)
    i0, size, axis = _last_step(q_ref)
    if step_metrics and i0 > 0 and size >= _MIN_STEP_RAD:
        last_out, prog_max, nan_prog = _settling(t, q, q_ref, i0, size, axis, settle_band_deg)
        if last_out < 0:
            out[10] = 0.0
        elif last_out < n - 1:
            out[10] = t[last_out + 1] - t[i0]
        over = 100.0 * ((np.nan if nan_prog else prog_max) - 1.0)
        out[11] = over if over > 0.0 else 0.0
        out[12] = math.degrees(size)
    out[13] = steady if step_metrics else np.nan
    out[14] = longest_stop
    out[15] = late_rms
    out[16] = late_speed
    return out


def _own(x: NDArray, dtype: type) -> NDArray:
    """A writable C-contiguous copy of ``x`` as ``dtype``: the compiled passes then see one
    array type (numba compiles, and caches, one machine code per layout and read-only flag)."""
    return np.array(x, dtype=dtype, order="C")


def step_values(t: NDArray, q: NDArray, q_ref: NDArray, torque_delivered: NDArray,
                tilt_stop: NDArray, step_metrics: bool = True) -> dict[str, float]:
    """The per-step metrics of a run (``_STEP_VALUES``) from its steps as arrays: times (n,),
    s, attitudes and references (n, 4), delivered torques (n, 3), N·m, tilt-stop flags (n,).
    ``step_metrics``: the reference is piecewise constant (steps), so the step metrics are
    defined; False gives them as NaN."""
    values = _step_pass(_own(t, float), _own(q, float), _own(q_ref, float),
                        _own(torque_delivered, float), _own(tilt_stop, bool), SETTLE_BAND_DEG,
                        STEADY_STATE_WINDOW_S, bool(step_metrics), LOC_LATE_FRACTION)
    return dict(zip(_STEP_VALUES, values.tolist(), strict=True))


def _steps_values(steps: Columns, step_metrics: bool = True) -> dict[str, float]:
    """``step_values`` of a steps table."""
    def stack(names: list[str]) -> NDArray:
        return np.column_stack([np.asarray(steps[c], dtype=float) for c in names])

    return step_values(np.asarray(steps["t_s"], dtype=float),
                       stack([f"q{c}" for c in "wxyz"]), stack([f"ref_q{c}" for c in "wxyz"]),
                       stack([f"torque_delivered_{c}_Nm" for c in "xyz"]),
                       np.asarray(steps["tilt_stop"], dtype=bool), step_metrics)


def summarize(
    steps: Columns,
    frames: Columns,
    events: Columns,
    duration_s: float,
    stopped: str = "",
    step_metrics: bool = True,
) -> dict[str, float]:
    """Scalar metrics of a run (all over the run's whole duration).

    * ``rms_error_deg``, ``max_error_deg``: geodesic attitude error truth vs reference;
    * ``rms_{spin,tilt,yaw}_error_deg``, ``max_{spin,tilt,yaw}_error_deg``: per seed angle,
      wrapped; spin and yaw only where the reference tilt is above 1° (below it Z-Y-Z spin and
      yaw are not separable);
    * step metrics after the reference's last change, against the *commanded* step (from the
      reference before the change to the one after, whatever the attitude was when it came):
      ``step_size_deg``; ``overshoot_pct``, the peak progress beyond the target along the step's
      rotation axis in % of the commanded step; ``settling_time_s``, from the change until the
      geodesic error stays within ``SETTLE_BAND_DEG`` (NaN if it never does);
      ``steady_state_error_deg``, the mean error over the final ``STEADY_STATE_WINDOW_S``;
      only with ``step_metrics`` (a piecewise-constant reference: steps), NaN otherwise (a
      smooth reference changes on every row: its "last change" is no step to measure
      overshoot or settling against);
    * ``control_effort_N2m2s``: ∫ |T_delivered|² dt; ``rms_torque_Nm``;
    * ``lost_frame_fraction``: lost / processed frames; ``dropped_frame_fraction``;
      ``time_to_first_loss_s``, the exposure time of the first lost frame (NaN: none lost);
    * ``mean_latency_s``; ``diverged`` (1.0 if the error ever exceeded the divergence limit,
      ``stopped`` non-empty);
    * ``loss_of_control`` (1.0 or 0.0) and its criteria (:func:`loss_of_control`).

    ``steps``, ``frames`` and ``events`` are the run's tables (``LoopResult``), as frames or as
    their columns (``Columns``): the metrics read the steps' times, attitudes, references,
    delivered torques and tilt-stop flags, the frames' exposure times, dropped and lost flags
    and latencies, and the events' count.
    """
    t_end = float(np.asarray(steps["t_s"])[-1])
    return summarize_values(_steps_values(steps, step_metrics), t_end,
                            _frames_values(frames, t_end),
                            n_rows(events), duration_s, stopped)


def summarize_values(values: dict[str, float], simulated_s: float,
                     frame_metrics: dict[str, float] | None, n_events: int, duration_s: float,
                     stopped: str = "") -> dict[str, float]:
    """``summarize`` from the per-step metrics (``step_values``), the last step's time (s),
    the per-frame ones (``frame_values``; None for a run without frames) and the number of
    events."""
    out: dict[str, float] = {
        "duration_s": float(duration_s),
        "simulated_s": float(simulated_s),
        "rms_error_deg": values["rms_error_deg"],
        "max_error_deg": values["max_error_deg"],
        "diverged": float(bool(stopped)),
    }
    for name in ("spin", "tilt", "yaw"):
        for stat in ("rms", "max"):
            out[f"{stat}_{name}_error_deg"] = values[f"{stat}_{name}_error_deg"]
    for key in ("control_effort_N2m2s", "rms_torque_Nm", "settling_time_s", "overshoot_pct",
                "step_size_deg", "steady_state_error_deg"):
        out[key] = values[key]
    frame_metrics = frame_metrics or _NO_FRAMES
    out["lost_frame_fraction"] = frame_metrics["lost_frame_fraction"]
    out["time_to_first_loss_s"] = frame_metrics["time_to_first_loss_s"]
    if frame_metrics is not _NO_FRAMES:
        out["dropped_frame_fraction"] = frame_metrics["dropped_frame_fraction"]
        out["mean_latency_s"] = frame_metrics["mean_latency_s"]
    out.update(_loss_of_control(values, frame_metrics, bool(stopped)))
    out["n_events"] = float(n_events)
    return out


#: The per-frame metrics of a run without frames.
_NO_FRAMES = {"lost_frame_fraction": 0.0, "longest_marker_loss_s": 0.0,
              "time_to_first_loss_s": np.nan}
#: What ``_frame_pass`` returns, in its order.
_FRAME_VALUES = ("dropped_frame_fraction", "lost_frame_fraction", "mean_latency_s",
                 "longest_marker_loss_s", "time_to_first_loss_s")


@njit(cache=True)
def _frame_pass(t_exposure, dropped, lost, latency, t_end):
    """The per-frame metrics (``_FRAME_VALUES``) from the frames' exposure times (n,), s,
    dropped and lost flags (n,) and latencies (n,), s (NaN: not released): the dropped
    fraction of all frames; over the processed (not dropped) ones the lost fraction, the mean
    known latency, the longest run of lost frames, from its first frame's exposure to the
    next processed frame's that is not lost (or ``t_end``, s), and the first lost frame's
    exposure time (NaN if none is lost)."""
    n = t_exposure.shape[0]
    n_dropped = n_processed = n_lost = n_known = 0
    latency_sum = 0.0
    first_loss = np.nan
    for i in range(n):
        if dropped[i]:
            n_dropped += 1
            continue
        n_processed += 1
        if not math.isnan(latency[i]):
            latency_sum += latency[i]
            n_known += 1
        if lost[i]:
            if n_lost == 0:
                first_loss = t_exposure[i]
            n_lost += 1
    longest = _longest_run(t_exposure, lost, dropped, t_end)
    return (n_dropped / n, n_lost / n_processed if n_processed else 0.0,
            latency_sum / n_known if n_known else np.nan, longest, first_loss)


def frame_values(t_exposure: NDArray, dropped: NDArray, lost: NDArray, latency: NDArray,
                 t_end: float) -> dict[str, float] | None:
    """The per-frame metrics of a run (``_FRAME_VALUES``) from its frames as arrays (see
    ``_frame_pass``; the last step's time ``t_end``, s); None for a run without frames."""
    if not len(t_exposure):
        return None
    values = _frame_pass(_own(t_exposure, float), _own(dropped, bool), _own(lost, bool),
                         _own(latency, float), float(t_end))
    return dict(zip(_FRAME_VALUES, values, strict=True))


def _frames_values(frames: Columns, t_end: float) -> dict[str, float] | None:
    """``frame_values`` of a frames table: a flag that is missing counts as not lost, a
    latency that is missing as not released."""
    if not len(frames):
        return None
    n = n_rows(frames)
    lost = np.zeros(n, dtype=bool)
    if "lost" in frames:
        flags = np.asarray(frames["lost"])
        lost = flags if flags.dtype == bool else np.where(pd.isna(flags), False, flags).astype(bool)
    latency = (np.asarray(frames["latency_s"], dtype=float) if "latency_s" in frames
               else np.full(n, np.nan))
    return frame_values(np.asarray(frames["t_exposure_s"], dtype=float),
                        np.asarray(frames["dropped"], dtype=bool), lost, latency, t_end)


def n_rows(table: Columns) -> int:
    """The number of rows of a table given as a frame or as its columns."""
    if isinstance(table, pd.DataFrame):
        return len(table)
    return len(next(iter(table.values()))) if len(table) else 0


def loss_of_control(steps: Columns, frames: Columns, diverged: bool) -> dict[str, float]:
    """Whether the loop lost control of the rotor during a run, and why (1.0 = yes).

    A verdict about the loop, not about the reference's schedule: every criterion reads the
    rotor, the markers or the error against what the reference asks at the same time. Any of
    (our thresholds, module constants): ``loc_tilt_stop``, the rotor rests against the tilt
    stop for ``LOC_TILT_STOP_S`` without a break; ``loc_marker_loss``, the markers are lost
    on every processed frame for ``LOC_MARKER_LOSS_S`` or on at least ``LOC_LOST_FRACTION``
    of them; ``loc_excess_error``, over the run's last ``LOC_LATE_FRACTION`` the RMS error
    exceeds ``late_error_bound_deg`` = ``LOC_ERROR_FLOOR_DEG`` + ``LOC_LAG_S`` x the
    reference's mean angular speed there (deg/s): the rotor trails the reference by more than
    ``LOC_LAG_S`` of its motion (an unstable loop's oscillation grows until it does; a stable
    loop's error stays a fraction of it); ``loc_divergence``, the error exceeded the loop's
    divergence limit. Also returns ``longest_tilt_stop_s``, ``longest_marker_loss_s``,
    ``late_rms_error_deg`` and ``late_error_bound_deg``.

    Validated against the exact margins (docs/closed_loop.md, benchmarks/bench_verdict.py):
    the runs must be long enough for an unstable mode that grows slowly (20 ms beyond the
    PID's margin, about 1.3 per second) to reach the bound.
    """
    t_end = float(np.asarray(steps["t_s"])[-1])
    return _loss_of_control(_steps_values(steps), _frames_values(frames, t_end) or _NO_FRAMES,
                            diverged)


def _loss_of_control(values: dict[str, float], frame_metrics: dict[str, float],
                     diverged: bool) -> dict[str, float]:
    """``loss_of_control`` from the per-step and per-frame metrics (``step_values``,
    ``frame_values``)."""
    loss_s, lost_frac = frame_metrics["longest_marker_loss_s"], frame_metrics["lost_frame_fraction"]
    stop_s = values["longest_tilt_stop_s"]
    late_rms = values["late_rms_error_deg"]
    bound = LOC_ERROR_FLOOR_DEG + LOC_LAG_S * values["late_ref_speed_deg_s"]
    flags = {
        "loc_tilt_stop": stop_s >= LOC_TILT_STOP_S,
        "loc_marker_loss": loss_s >= LOC_MARKER_LOSS_S or lost_frac >= LOC_LOST_FRACTION,
        # NaN (a NaN attitude) counts as beyond the bound
        "loc_excess_error": not late_rms <= bound,
        "loc_divergence": bool(diverged),
    }
    out = {k: float(v) for k, v in flags.items()}
    out["loss_of_control"] = float(any(flags.values()))
    out["longest_tilt_stop_s"] = stop_s
    out["longest_marker_loss_s"] = float(loss_s)
    out["late_rms_error_deg"] = late_rms
    out["late_error_bound_deg"] = bound
    return out
