"""The compiled run loop: a whole measurement-model run, events and physics, in one numba call.

The default measurement-model case (``covers``): the measurement front end (pixel noise,
dropouts, outliers, the tracker-window loss model, the blur limit, the region of interest), the
per-frame least-squares observer (``observer.pixel_observer.SolverObserver`` with
``observer.cor_solver.CorSolver``) alone or behind the pixel Kalman filters
(``PixelKalmanObserver``), the PID (``controller.pid.PIDController``) or the MPC
(``controller.mpc.MPCController`` with its default SQP + HPIPM solver and a fixed compute
latency, its whole solver as machine code: ``controller.mpc_machine``), sequential or pipelined
frames, an observer and a controller latency from a model (any ``latency.models`` kind), no
disturbance, the controller on each released estimate. The event loop
(``latency.loop.ClosedLoop``) stays the reference: this module computes the same run, run by
run, and the agreement tests (tests/test_batched.py) hold it to it.

How. In such a run the events' times do not depend on the rotor's state: frames come on the
camera's clock, the frame scheduler decides from the observer's latencies alone which frames it
drops and when it releases the others, and each command comes one controller latency after its
release. So the run's event sequence is built first, with the run's own latency streams and
the loop's tie rule (``_schedule``: the latencies drawn as the event loop draws them, then
``FrameScheduler``'s rules and the same priority queue compiled, ``_event_queue``), and the
reference is sampled at the grid points and at the events' times
(``Reference.sample_many``). Then ``_run_events`` (numba, cached on disk) walks the events:
between two events it advances the rotor with the compiled physics step
(``plant.rigid_body._step_row``, the one code of the physics) as ``_advance_segment`` does,
records the steps table's rows and the tilt-stop events; on a frame it runs the front end,
drawing its noise from the front end's own ``numpy.random.Generator`` (numba draws the same
numbers as numpy from the same Generator, in the same order as ``MeasurementFrontEnd.capture``);
on a release the pixel Kalman filters (when the run has them), the warm-started
Levenberg-Marquardt solve (``observer.cor_solver._lm``) and the PID law (``_pid``) or the
MPC's command (``_mpc``: the delay compensation, the warm start and the generated SQP solver,
called through its address); on a command the least-norm current allocation. A command whose
least-norm currents break the limits returns to Python for the LP of ``plant.torque.allocate``
and the kernel resumes from it. The per-step and per-frame logs are arrays; the events are
codes with their numbers, written out as the event loop's texts at the end.

Where it differs from the event loop: the controller's compute time is not timed per call
(``frames.controller_compute_s`` is NaN; the controller latency is a model in every run it
covers), and the arithmetic of a few small products is ordered differently (rounding, 1e-16);
the MPC's solver is the event loop's SQP written out as C (the same iterates to rounding), and
its solver statistics (``MPCController.unconverged`` and the like) are not kept.

``coverage`` says which path the batched engine takes for a run and, for the lockstep rounds,
why (the first of the run's parts or settings that the compiled loop lacks).
"""

from __future__ import annotations

import functools
import heapq
from dataclasses import dataclass
from typing import Literal

import numpy as np
import pandas as pd
from numba import njit
from numpy.typing import NDArray

from controller.mpc import MPCController
from controller.mpc_machine import MachineMPC, call_casadi, machine_mpc, weight_values
from controller.pid import PIDController
from latency.frontends import (
    LOST_BLUR,
    LOST_CALIBRATED,
    LOST_DROPOUT,
    LOST_OUTSIDE_ROI,
    LOST_OUTSIDE_WINDOW,
    CalibratedLoss,
    MeasurementFrontEnd,
)
from latency.loop import ClosedLoop, LoopResult, _StepLog, run_streams
from latency.metrics import frame_values, step_values, summarize, summarize_values
from latency.models import Constant
from latency.numba_cache import drop_stale_cache
from latency.pipeline import FrameScheduler
from observer import cor_solver
from observer.cor_model import CorModel
from observer.cor_solver import (
    _CONVERGED,
    _SINGULAR,
    BEHIND_CAMERA,
    DEGENERATE,
    FAR_SIDE,
    ILL_CONDITIONED,
    NOT_CONVERGED,
    RESIDUAL_TOO_LARGE,
    CorSolver,
    _lm,
    _residual_jac,
    _solve3,
    condition_number,
    failure_reason,
    normal_equations,
)
from observer.gk import pixel_kalman
from observer.gk.pixel_kalman import F_CV, H_CV
from observer.pixel_observer import PixelKalmanObserver, SolverObserver
from plant import attitude, rigid_body, torque
from plant.attitude import _geodesic_of, _hamilton, _matrix_elements
from plant.params import PlantParams
from plant.rigid_body import (
    FASTMATH,
    PAIR_REUSE_RAD,
    PHYSICS_SUBSTEPS,
    SUBSTEP_ANGLE_RAD,
    RigidBody,
    _pair_lists,
    _rotor_tuples,
    _step_row,
)
from plant.torque import N_COILS, TorqueMap, allocate

# The kernel compiles in the physics step, the solver's iteration, the filter's matrices and
# the attitude formulas: an edit there drops this module's numba cache.
drop_stale_cache(__file__, (rigid_body, cor_solver, pixel_kalman, torque, attitude))

# --- event kinds of the schedule, event codes of the record -----------------------------------
_FRAME, _RELEASE, _COMMAND = 0, 1, 2
#: The event loop's event kinds, in the order of their codes in ``_run_events``'s record.
EVENT_KINDS = ("frame_dropped", "tracking_loss", "reacquisition", "invalid_estimate",
               "invalid_command", "saturation", "tilt_stop_contact", "tilt_stop_release",
               "divergence")
(_EV_DROPPED, _EV_LOSS, _EV_REACQ, _EV_INVALID_EST, _EV_INVALID_CMD, _EV_SATURATION,
 _EV_CONTACT, _EV_RELEASE, _EV_DIVERGENCE) = range(len(EVENT_KINDS))
#: Why a front end lost a frame (``MeasurementFrontEnd.capture``'s reasons), by code.
CAPTURE_REASONS = ("", LOST_DROPOUT, LOST_OUTSIDE_WINDOW, LOST_OUTSIDE_ROI, LOST_BLUR,
                   LOST_CALIBRATED)
#: A solve's outcome (``_solve``): ``observer.cor_solver``'s failure codes (``failure_reason``),
#: and two of its own: a clean solution, and a frame the front end lost (not solved).
_R_OK, _R_LOST = -1, -2

# --- the scalar state of a run (``st``), by index ---------------------------------------------
_T, _K, _SAT, _STOP, _LOST, _DIV = 0, 1, 2, 3, 4, 5
_Q, _W, _CUR = 6, 10, 13  # plant: attitude (4), body rate (3), actual coil currents (16)
_CMD, _TCMD, _TDEL = 29, 45, 48  # commanded currents (16), commanded and delivered torque (3)
_EST = 51  # the latest released estimate's attitude (4), NaN before the first
_OBS_Q, _OBS_T = 55, 59  # the observer's solution (4) and the time of its last valid one
_INT, _PEND, _D, _D_INIT, _T_PREV = 60, 63, 66, 69, 70  # PID: integral, dI/dt, filtered rate
_RATE_Q, _RATE_T, _RATE_W, _LAST_TAU = 71, 75, 76, 79  # PID: rate from attitude, held torque
_FE_HAS, _FE_LAST, _FE_MOTION, _FE_LOST, _FE_SINCE = 82, 83, 87, 91, 92  # the front end
_N_EV, _ALLOC_T, _ALLOC_Q, _DIV_DEG, _ALLOC_SAT = 93, 94, 97, 101, 102
#: The pixel Kalman filters of the two markers: per marker, initialised, X (4), P (4 x 4).
_KF, _KF_SIZE = 103, 21
_N_STATE = _KF + 2 * _KF_SIZE

# --- the settings of a run (``par``), by index ------------------------------------------------
(_P_DURATION, _P_H, _P_TAU_L, _P_N_STEPS, _P_COS_STOP, _P_DIV_DEG, _P_LOSS_PX, _P_SIGMA,
 _P_DROPOUT, _P_OUTLIER, _P_OUTLIER_PX, _P_SEARCH, _P_PREDICT, _P_REACQ, _P_MAX_IT, _P_STEP_TOL,
 _P_MAX_RMS, _P_MAX_TILT, _P_MAX_COND, _P_MAX_INVALID, _P_TAU_F, _P_LIMIT, _P_FRIC, _P_FRIC_W,
 _P_FF, _P_AW, _P_HOLD, _P_I_MAX, _P_TRUTH, _P_KT_COS) = range(30)
_P_KP, _P_KI, _P_KD, _P_TT, _P_J = 30, 33, 36, 39, 42
_P_KF_ON, _P_KF_Q, _P_KF_R, _P_KF_V0 = 45, 46, 62, 66  # pixel Kalman: on, Q (4 x 4), R (2 x 2)
# the front end's region of interest (on, cols, rows, follow), the sensor's size (px), the blur
# limit (px, NaN: none) and the camera's exposure (s)
_P_ROI, _P_ROI_COLS, _P_ROI_ROWS, _P_ROI_FOLLOW, _P_SENSOR_W, _P_SENSOR_H = range(67, 73)
_P_BLUR, _P_EXPOSURE = 73, 74
_P_MPC = 75  # 1: the MPC computes the commands (``_mpc``), 0: the PID
# the calibrated loss model (latency.loss_model): on, hazard (3), persistence (4)
_P_CAL_ON, _P_CAL_HAZ, _P_CAL_PER = 76, 77, 80
_N_PAR = 84
_AW_MODES = ("back_calculation", "conditional", "none")

# --- the frame record (``fr``), by column -----------------------------------------------------
_F_INDEX, _F_T_EXP, _F_T_REL, _F_DROPPED = range(4)
_F_TRUE, _F_MEAS = 4, 8  # true and measured pixels, (red u, v, yellow u, v)
_F_CENTRE, _F_LOST, _F_CAP_LOST, _F_CAP_REASON, _F_RELEASED = range(12, 17)
_F_EST = 17  # the released estimate's attitude (4)
_F_VALID, _F_REASON, _F_REASON_VALUE, _F_HELD_FROM, _F_LATENCY = range(21, 26)
_F_TORQUE = 26  # the command computed on the release (3)
_N_FR = 29


@dataclass(frozen=True)
class Coverage:
    """The batched engine's path for a run (``coverage``): ``"compiled"`` (the compiled run
    loop) or ``"lockstep"`` (the lockstep rounds of ``latency.batched``), and for the latter
    why the compiled loop does not compute it."""

    path: Literal["compiled", "lockstep"]
    reason: str = ""


def coverage(loop: ClosedLoop) -> Coverage:
    """Which path computes ``loop`` (the module docstring's case), from the types of its parts
    and its settings, with the reason when it is not the compiled run loop. For an MPC this
    builds (once per process and problem; compiled once, cached on disk) its solver's machine
    code."""
    c, fe, p = loop.config, loop.front_end, loop.params
    inner = _solver_observer(loop)
    checks = (
        (isinstance(inner, SolverObserver),
         f"observer {type(loop.observer).__name__}: the compiled loop has the per-frame "
         "least-squares observer, alone or behind the pixel Kalman filters"),
        (inner is not None and isinstance(inner.solver, CorSolver),
         "the per-frame observer's solver is not the CoR solver (CorSolver)"),
        (isinstance(fe, MeasurementFrontEnd),
         f"front end {type(fe).__name__}: the compiled loop has the measurement model"),
        (isinstance(fe, MeasurementFrontEnd) and fe.params == p,
         "the front end's plant parameters differ from the loop's"),
        (p.camera.dist_coeffs[2:4] == (0.0, 0.0), "a lens with tangential distortion"),
        (c.controller_rate_hz is None, "a controller clock (controller_rate_hz)"),
        (c.controller_latency != "measured", "a measured controller latency"),
        (c.observer_latency == "model", "a measured observer latency"),
        (not any(c.disturbance_psd_Nm2s), "a disturbance torque (disturbance_psd_Nm2s)"),
        (c.mujoco_sensor_delay_s is None, "MuJoCo's sensor delay (mujoco_sensor_delay_s)"),
    )
    for ok, reason in checks:
        if not ok:
            return Coverage("lockstep", reason)
    ctrl = loop.controller
    if isinstance(ctrl, PIDController):
        return Coverage("compiled")
    if not isinstance(ctrl, MPCController):
        return Coverage("lockstep", f"controller {type(ctrl).__name__}: the compiled loop has "
                        "the PID and the MPC")
    cfg = ctrl.config
    if cfg.solver != "sqp_hpipm" or cfg.hessian != "gauss_newton":
        return Coverage("lockstep", f"MPC solver {cfg.solver!r} with the {cfg.hessian!r} "
                        "Hessian: the compiled loop has SQP + HPIPM with the Gauss-Newton one")
    if cfg.compute_latency_s is None:
        return Coverage("lockstep", "the MPC's delay compensation assumes its measured compute "
                        "times (compute_latency_s: None)")
    if machine_mpc(ctrl.problem) is None:
        return Coverage("lockstep", "the MPC's solver could not be compiled to machine code "
                        "(no C compiler, or compiling failed)")
    return Coverage("compiled")


def covers(loop: ClosedLoop) -> bool:
    """Whether the compiled run loop computes ``loop`` (``coverage``)."""
    return coverage(loop).path == "compiled"


def _solver_observer(loop: ClosedLoop) -> SolverObserver | None:
    """The per-frame solver observer of the run: its observer, or the one behind its pixel
    Kalman filters; None for other observers."""
    obs = loop.observer
    if isinstance(obs, PixelKalmanObserver):
        return obs.inner
    return obs if isinstance(obs, SolverObserver) else None


def _schedule(loop: ClosedLoop) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """The run's handled events in the event loop's order, and its frames' timing.

    The event loop's queue (``ClosedLoop.timeline``: the first frame at mid-exposure, each
    frame pushing the next frame and then its release, each release its command; ties in the
    order pushed) with the run's own streams (``latency.loop.run_streams``): the frames'
    observer latencies drawn from the pipeline's stream, one per processed frame in order
    (``FrameScheduler.next_frame``), the commands' controller latencies from the controller's,
    one per release in order. The draws come first, as many as the run has frames (each
    stream serves one purpose, so the numbers a run uses are the same), and the queue then
    runs compiled (``_event_queue``). Returns the events' times (s), kinds and frame indices,
    and per frame (t_exposure, t_release, dropped)."""
    c = loop.config
    pipe = c.pipeline
    FrameScheduler.check(pipe)
    period, exposure = pipe.frame_period_s, pipe.exposure_s
    n_frames = max(int(np.ceil((c.duration_s - 1e-12 - 0.5 * exposure) / period)), 0) + 1
    if isinstance(pipe.observer, Constant) and isinstance(c.controller_latency, Constant):
        # constant latencies draw nothing: the streams are not needed
        observer = np.full(n_frames, pipe.observer.value_s)
        controller = np.full(n_frames, c.controller_latency.value_s)
    else:
        rng_pipe, rng_ctrl, _ = run_streams(c.seed)
        observer = np.array([pipe.observer.sample(rng_pipe) for _ in range(n_frames)])
        controller = np.array([c.controller_latency.sample(rng_ctrl) for _ in range(n_frames)])
    ev, frames, bad = _event_queue(period, exposure, pipe.readout_s, pipe.mode == "sequential",
                                   pipe.mode == "pipelined", c.duration_s, observer, controller)
    if bad >= 0:
        raise ValueError(f"observer latency must be finite and >= 0, got {observer[bad]}")
    return ev[:, 0].copy(), ev[:, 1].astype(np.int64), ev[:, 2].astype(np.int64), frames


@njit(cache=True)
def _event_queue(period, exposure, readout, sequential, pipelined, duration, observer,
                 controller):
    """The event loop's queue (``_schedule``) with the latencies drawn: the events (time,
    kind, frame) in the order handled, the frames (t_exposure, t_release, dropped) as
    ``FrameScheduler.next_frame`` times them, and the index of the first invalid observer
    latency used (-1: none)."""
    queue = [(0.5 * exposure, 0, _FRAME, 0)]
    heapq.heapify(queue)
    order = 1
    n = observer.shape[0]
    events = np.empty((3 * n, 3))
    frames = np.empty((n, 3))
    n_ev = n_fr = used_obs = used_ctrl = 0
    busy_until = last_release = -np.inf
    while len(queue) > 0 and queue[0][0] < duration - 1e-12:
        t, _, kind, index = heapq.heappop(queue)
        events[n_ev, 0], events[n_ev, 1], events[n_ev, 2] = t, kind, index
        n_ev += 1
        if kind == _FRAME:
            t0 = index * period
            t_exposure, t_ready = t0 + 0.5 * exposure, t0 + exposure + readout
            heapq.heappush(queue, ((index + 1) * period + 0.5 * exposure, order, _FRAME,
                                   index + 1))
            order += 1
            if sequential and t_ready < busy_until:
                frames[n_fr, 0], frames[n_fr, 1], frames[n_fr, 2] = t_exposure, np.nan, 1.0
            else:
                latency = observer[used_obs]
                if latency < 0 or not np.isfinite(latency):
                    return events[:n_ev], frames[:n_fr], used_obs
                used_obs += 1
                t_release = t_ready + latency
                if pipelined:
                    t_release = max(t_release, last_release)
                busy_until = last_release = t_release
                frames[n_fr, 0], frames[n_fr, 1], frames[n_fr, 2] = t_exposure, t_release, 0.0
                heapq.heappush(queue, (t_release, order, _RELEASE, index))
                order += 1
            n_fr += 1
        elif kind == _RELEASE:
            heapq.heappush(queue, (t + controller[used_ctrl], order, _COMMAND, index))
            used_ctrl += 1
            order += 1
    return events[:n_ev], frames[:n_fr], -1


def _settings(loop: ClosedLoop) -> NDArray[np.float64]:
    """The run's numbers for the kernel (``par``; the ``_P_*`` indices)."""
    c, p = loop.config, loop.params
    fe: MeasurementFrontEnd = loop.front_end  # type: ignore[assignment]
    m = fe.config
    inner = _solver_observer(loop)
    assert inner is not None and isinstance(inner.solver, CorSolver)
    solver = inner.solver
    par = np.zeros(_N_PAR)
    par[_P_DURATION], par[_P_H] = c.duration_s, p.physics_dt_s
    par[_P_TAU_L], par[_P_N_STEPS] = p.motor.coil_time_constant_s, loop.n_steps
    par[_P_COS_STOP] = np.cos(np.deg2rad(p.rotor.tilt_stop_deg))
    par[_P_DIV_DEG], par[_P_LOSS_PX] = c.divergence_deg, c.loss_threshold_px
    par[_P_SIGMA], par[_P_DROPOUT] = m.noise_sigma_px, m.dropout_prob
    par[_P_OUTLIER], par[_P_OUTLIER_PX] = m.outlier_prob, m.outlier_px
    w = m.window
    par[_P_SEARCH] = np.nan if w is None or w.search_radius_px is None else w.search_radius_px
    par[_P_PREDICT] = m.predictive
    par[_P_REACQ] = 1.0 if w is None else w.reacquire_after_frames
    if m.roi is not None:
        par[_P_ROI], par[_P_ROI_COLS], par[_P_ROI_ROWS] = 1.0, m.roi.cols, m.roi.rows
        par[_P_ROI_FOLLOW] = m.roi.follow
    par[_P_SENSOR_W], par[_P_SENSOR_H] = p.camera.sensor_width_px, p.camera.sensor_height_px
    par[_P_BLUR] = np.nan if w is None or w.blur_limit_px is None else w.blur_limit_px
    if isinstance(m.loss, CalibratedLoss):
        model = m.loss.model
        par[_P_CAL_ON] = 1.0
        par[_P_CAL_HAZ : _P_CAL_HAZ + 3] = model.hazard
        par[_P_CAL_PER : _P_CAL_PER + 4] = model.persistence
    par[_P_EXPOSURE] = p.camera.exposure_s
    sc = solver.config
    par[_P_MAX_IT], par[_P_STEP_TOL] = sc.max_iterations, sc.step_tol_rad
    par[_P_MAX_RMS], par[_P_MAX_TILT] = sc.max_residual_rms_px, sc.max_tilt_rad
    par[_P_MAX_COND] = sc.max_condition
    par[_P_MAX_INVALID] = inner.max_invalid_s
    if isinstance(loop.observer, PixelKalmanObserver):
        kf = loop.observer.config
        par[_P_KF_ON], par[_P_KF_V0] = 1.0, kf.velocity_var0
        par[_P_KF_Q : _P_KF_Q + 16] = np.ravel(kf.Q)
        par[_P_KF_R : _P_KF_R + 4] = np.ravel(kf.R)
    par[_P_I_MAX], par[_P_TRUTH] = p.motor.i_max_A, c.allocate_with == "truth"
    par[_P_KT_COS] = np.cos(np.deg2rad(p.motor.cutoff_deg))
    if isinstance(loop.controller, MPCController):
        par[_P_MPC] = 1.0  # its settings: ``_mpc_arrays``
        return par
    pid: PIDController = loop.controller  # type: ignore[assignment]
    pc = pid.config
    par[_P_TAU_F], par[_P_LIMIT] = pid.tau_f, pid.torque_limit
    par[_P_FRIC] = pc.friction_compensation_Nm
    par[_P_FRIC_W] = np.radians(pc.friction_compensation_width_deg)
    par[_P_FF], par[_P_AW] = pc.feedforward, _AW_MODES.index(pc.anti_windup)
    par[_P_HOLD] = pc.invalid_command == "hold"
    for at, v in ((_P_KP, pid.Kp), (_P_KI, pid.Ki), (_P_KD, pid.Kd), (_P_TT, pid.T_t),
                  (_P_J, pid.J)):
        par[at : at + 3] = v
    return par


# --- the kernel's pieces (numba) -------------------------------------------------------------
# Small vectors and matrices as tuples of floats, multiplied out: numba hands ``@`` on 2-D
# arrays to BLAS, whose call costs more than these few products, and each small array costs
# an allocation.
@njit(cache=True)
def _unit(q):
    """The quaternion q (4 numbers) over its norm, as a 4-tuple."""
    n = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return q[0] / n, q[1] / n, q[2] / n, q[3] / n


@njit(cache=True)
def _conj_mul(a, b):
    """a* ⊗ b (4-tuple) for the quaternions a and b, each normalised first
    (``plant.attitude``)."""
    a, b = _unit(a), _unit(b)
    return _hamilton(a[0], -a[1], -a[2], -a[3], b[0], b[1], b[2], b[3])


@njit(cache=True)
def _matrix(q):
    """R(q), rotor to stator, of the normalised q, row by row as a 9-tuple
    (``plant.attitude.to_matrix``)."""
    w, x, y, z = _unit(q)
    return _matrix_elements(w, x, y, z)


@njit(cache=True)
def _mv(R, v):
    """R v (3-tuple) for R a 9-tuple (``_matrix``) and v three numbers."""
    return (R[0] * v[0] + R[1] * v[1] + R[2] * v[2], R[3] * v[0] + R[4] * v[1] + R[5] * v[2],
            R[6] * v[0] + R[7] * v[1] + R[8] * v[2])


@njit(cache=True)
def _mtv(R, v):
    """Rᵀ v (3-tuple) for R a 9-tuple (``_matrix``) and v three numbers."""
    return (R[0] * v[0] + R[3] * v[1] + R[6] * v[2], R[1] * v[0] + R[4] * v[1] + R[7] * v[2],
            R[2] * v[0] + R[5] * v[1] + R[8] * v[2])


@njit(cache=True)
def _rotvec(q):
    """Rotation vector (3-tuple, rad, angle in [0, pi]) of q (``plant.attitude.to_rotvec``)."""
    w, x, y, z = _unit(q)
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    s = np.sqrt(x * x + y * y + z * z)
    f = 2.0 if s < 1e-12 else 2.0 * np.arctan2(s, w) / s
    return f * x, f * y, f * z


@njit(cache=True)
def _geodesic(q1, q2):
    """Angle (rad) of the rotation from q1 to q2 (``plant.attitude.geodesic_angle``)."""
    return _geodesic_of(q1[0], q1[1], q1[2], q1[3], q2[0], q2[1], q2[2], q2[3])


@njit(cache=True)
def _project(q, P, t_cor, intr):
    """Marker pixels (2, 2) at attitude q: the CoR model's projection (``observer.cor_model``,
    the same as ``plant.camera.marker_pixels`` for a lens without tangential distortion)."""
    r, _ = _residual_jac(q, P, np.zeros((P.shape[0], 2)), t_cor, intr)
    return -r.reshape(P.shape[0], 2)


@njit(cache=True)
def _roi_misses(st, par, truth):
    """``MeasurementFrontEnd._inside_roi`` negated: a marker's centre outside the region of
    interest, centred on the sensor or on the mean predicted marker position
    (``roi_centre_px``), shifted to lie on the sensor."""
    size = (par[_P_SENSOR_W], par[_P_SENSOR_H])
    extent = (par[_P_ROI_COLS], par[_P_ROI_ROWS])
    predict = 1.0 if par[_P_PREDICT] > 0 else 0.0
    for k in range(2):
        centre = (size[k] - 1.0) / 2.0
        if par[_P_ROI_FOLLOW] > 0 and st[_FE_HAS] > 0:
            centre = 0.0
            for j in range(2):
                centre += 0.5 * (st[_FE_LAST + 2 * j + k] + predict * st[_FE_MOTION + 2 * j + k])
        half = 0.5 * min(extent[k], size[k])
        centre = min(max(centre, half - 0.5), size[k] - 0.5 - half)
        for j in range(2):
            if abs(truth[j, k] - centre) > 0.5 * extent[k]:
                return True
    return False


@njit(cache=True)
def _blur_travel_px(q, w, par, P, t_cor, intr):
    """``MeasurementFrontEnd._blur_travel_px``: the largest marker travel (px) over the
    camera's exposure at the body rate w, from the attitudes half an exposure either side."""
    ends = np.empty((2, 2, 2))
    for s in range(2):
        rv = (2.0 * s - 1.0) * 0.5 * par[_P_EXPOSURE] * w
        theta = np.sqrt(rv @ rv)
        if theta < 1e-12:
            dq = np.array([1.0, 0.5 * rv[0], 0.5 * rv[1], 0.5 * rv[2]])
            dq = dq / np.sqrt(dq @ dq)
        else:
            c, sn = np.cos(0.5 * theta), np.sin(0.5 * theta) / theta
            dq = np.array([c, sn * rv[0], sn * rv[1], sn * rv[2]])
        qs = _hamilton(q[0], q[1], q[2], q[3], dq[0], dq[1], dq[2], dq[3])
        ends[s] = _project(np.array(_unit(qs)), P, t_cor, intr)
    d = ends[1] - ends[0]
    return max(np.sqrt(d[0] @ d[0]), np.sqrt(d[1] @ d[1]))


@njit(cache=True)
def _calibrated_lost(st, q, w, par, P, t_cor, intr, truth, u):
    """``LossModel.p_lost`` on the front end's state (``MeasurementFrontEnd.capture`` with a
    calibrated loss): whether the uniform draw ``u`` loses this frame."""
    offset = 0.0
    if st[_FE_HAS] > 0:
        for j in range(2):
            du = truth[j, 0] - (st[_FE_LAST + 2 * j] + st[_FE_MOTION + 2 * j])
            dv = truth[j, 1] - (st[_FE_LAST + 2 * j + 1] + st[_FE_MOTION + 2 * j + 1])
            offset = max(offset, np.sqrt(du * du + dv * dv))
    a = np.log1p(offset)
    b = np.log1p(_blur_travel_px(q, w, par, P, t_cor, intr))
    n = st[_FE_LOST]
    if n <= 0:
        x = par[_P_CAL_HAZ] + par[_P_CAL_HAZ + 1] * a + par[_P_CAL_HAZ + 2] * b
    else:
        x = (par[_P_CAL_PER] + par[_P_CAL_PER + 1] * a + par[_P_CAL_PER + 2] * b
             + par[_P_CAL_PER + 3] * np.log1p(n))
    return u < 0.5 * (1.0 + np.tanh(0.5 * x))


@njit(cache=True)
def _capture(st, q, w, par, P, t_cor, intr, rng, meas):
    """``MeasurementFrontEnd.capture`` at the attitude q and body rate w: writes the measured
    pixels into ``meas`` (NaN when lost) and returns (true pixels, lost, reason code of
    ``CAPTURE_REASONS``). Draws from ``rng`` as capture does."""
    truth = _project(q, P, t_cor, intr)
    meas[:] = np.nan
    if rng.random() < par[_P_DROPOUT]:
        return truth, True, 1
    st[_FE_SINCE] += 1.0
    if par[_P_ROI] > 0 and _roi_misses(st, par, truth):
        st[_FE_LOST] += 1.0
        return truth, True, 3
    predict = 1.0 if par[_P_PREDICT] > 0 else 0.0
    if par[_P_CAL_ON] > 0:
        if _calibrated_lost(st, q, w, par, P, t_cor, intr, truth, rng.random()):
            st[_FE_LOST] += 1.0
            return truth, True, 5
    elif np.isfinite(par[_P_SEARCH]) and st[_FE_HAS] > 0 and st[_FE_LOST] < par[_P_REACQ]:
        worst = 0.0
        for j in range(2):
            du = truth[j, 0] - (st[_FE_LAST + 2 * j] + predict * st[_FE_MOTION + 2 * j])
            dv = truth[j, 1] - (st[_FE_LAST + 2 * j + 1] + predict * st[_FE_MOTION + 2 * j + 1])
            worst = max(worst, np.sqrt(du * du + dv * dv))
        if worst > par[_P_SEARCH]:
            st[_FE_LOST] += 1.0
            return truth, True, 2
    if np.isfinite(par[_P_BLUR]) and _blur_travel_px(q, w, par, P, t_cor, intr) > par[_P_BLUR]:
        return truth, True, 4
    z = np.empty((2, 2))
    for j in range(2):
        for k in range(2):
            z[j, k] = truth[j, k] + (0.0 + par[_P_SIGMA] * rng.normal())
    if rng.random() < par[_P_OUTLIER]:
        angle = rng.uniform(0.0, 2.0 * np.pi)
        j = rng.integers(0, 2)
        z[j, 0] += par[_P_OUTLIER_PX] * np.cos(angle)
        z[j, 1] += par[_P_OUTLIER_PX] * np.sin(angle)
    for j in range(2):
        for k in range(2):
            if st[_FE_HAS] > 0:
                st[_FE_MOTION + 2 * j + k] = (z[j, k] - st[_FE_LAST + 2 * j + k]) / st[_FE_SINCE]
            st[_FE_LAST + 2 * j + k] = z[j, k]
    st[_FE_HAS], st[_FE_LOST], st[_FE_SINCE] = 1.0, 0.0, 0.0
    meas[:, :] = z
    return truth, False, 0


@njit(cache=True)
def _solve(q_prev, uv, P, t_cor, intr, par):
    """``CorSolver.solve`` warm-started at q_prev on both markers' pixels uv (2, 2) (the front
    end measures both or none): (q, valid, reason code, its number)."""
    nan4 = np.full(4, np.nan)
    q = q_prev / np.sqrt(q_prev @ q_prev)
    r, _ = _residual_jac(q, P, uv, t_cor, intr)
    if not np.all(np.isfinite(r)):
        return nan4, False, BEHIND_CAMERA, 0.0
    q, status, it, cost, J = _lm(q, P, uv, t_cor, intr, int(par[_P_MAX_IT]), par[_P_STEP_TOL])
    if status == _SINGULAR:
        return nan4, False, DEGENERATE, 0.0
    if status != _CONVERGED:
        return nan4, False, NOT_CONVERGED, 0.0
    q = q / np.sqrt(q @ q)
    if q[0] < 0:
        q = -q
    rms = np.sqrt(cost / r.shape[0])
    cond = condition_number(normal_equations(J, r)[0])
    if not np.isfinite(cond) or cond > par[_P_MAX_COND]:
        return nan4, False, ILL_CONDITIONED, cond
    if rms > par[_P_MAX_RMS]:
        return nan4, False, RESIDUAL_TOO_LARGE, rms
    tilt = np.arccos(min(max(1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2]), -1.0), 1.0))
    if tilt > par[_P_MAX_TILT]:
        return nan4, False, FAR_SIDE, tilt
    return q, True, _R_OK, 0.0


@njit(cache=True)
def _pixel_kalman(st, par, z, lost):
    """The filters of ``PixelKalmanObserver.process`` (``observer.gk.pixel_kalman.PixelKalman``,
    filterpy's equations: the prior, then the update in Joseph form, or coasting on the prior
    when the frame is lost) on the measured centres z (2, 2), sensor px: the filtered centres
    (NaN for a filter not yet initialised)."""
    Q = par[_P_KF_Q : _P_KF_Q + 16].copy().reshape(4, 4)
    R = par[_P_KF_R : _P_KF_R + 4].copy().reshape(2, 2)
    out = np.full((2, 2), np.nan)
    for i in range(2):
        b = _KF + i * _KF_SIZE
        x = st[b + 1 : b + 5].copy()
        P = st[b + 5 : b + 21].copy().reshape(4, 4)
        initialised = st[b] > 0
        if initialised:
            x = F_CV @ x
            P = 1.0 * ((F_CV @ P) @ F_CV.T) + Q
        if not lost and np.isfinite(z[i, 0]) and np.isfinite(z[i, 1]):
            if not initialised:
                x = np.array([z[i, 0], z[i, 1], 0.0, 0.0])
                P = np.zeros((4, 4))
                P[:2, :2] = R
                P[2, 2] = P[3, 3] = par[_P_KF_V0]
                initialised = True
            else:
                PHT = P @ H_CV.T
                K = PHT @ np.linalg.inv(H_CV @ PHT + R)
                x = x + K @ (z[i] - H_CV @ x)
                I_KH = np.eye(4) - K @ H_CV
                P = (I_KH @ P) @ I_KH.T + (K @ R) @ K.T
        st[b] = 1.0 if initialised else 0.0
        st[b + 1 : b + 5] = x
        st[b + 5 : b + 21] = P.ravel()
        if initialised:
            out[i] = x[:2]
    return out


@njit(cache=True)
def _attitude_rate(st, q, t_state):
    """``controller.pid.RateFromAttitude.update`` with the unit attitude q (4-tuple) described
    at ``t_state`` (s): the rate estimate (rad/s) in ``st[_RATE_W : _RATE_W + 3]``."""
    has_prev = not np.isnan(st[_RATE_Q])
    if has_prev and t_state > st[_RATE_T]:
        rv = _rotvec(_conj_mul(st[_RATE_Q : _RATE_Q + 4], q))
        for i in range(3):
            st[_RATE_W + i] = rv[i] / (t_state - st[_RATE_T])
    if not has_prev or t_state > st[_RATE_T]:
        for i in range(4):
            st[_RATE_Q + i] = q[i]
        st[_RATE_T] = t_state


@njit(cache=True)
def _pid(st, par, valid, q_est, t_state, ref_q, ref_w, ref_a):
    """``PIDController.command`` on an estimate (valid, attitude, the time it describes) with
    the reference sampled at the call: the stator-frame torque (3,), N·m."""
    if not valid:
        st[_PEND : _PEND + 3] = 0.0
        st[_T_PREV] = t_state
        if par[_P_HOLD] == 0:
            st[_LAST_TAU : _LAST_TAU + 3] = 0.0
        return st[_LAST_TAU : _LAST_TAU + 3].copy()
    dt = 0.0 if np.isnan(st[_T_PREV]) else max(t_state - st[_T_PREV], 0.0)
    st[_T_PREV] = t_state
    q = _unit(q_est)
    q_e = _conj_mul(q, ref_q)
    e = _rotvec(q_e)
    R_e = _matrix(q_e)
    w_r = _mv(R_e, ref_w)
    a_r = _mv(R_e, ref_a)
    _attitude_rate(st, q, t_state)
    if np.isfinite(st[_RATE_W]) and np.isfinite(st[_RATE_W + 1]) and np.isfinite(st[_RATE_W + 2]):
        blend = 1.0 - np.exp(-dt / par[_P_TAU_F])
        for i in range(3):
            x = w_r[i] - st[_RATE_W + i]
            st[_D + i] = x if st[_D_INIT] == 0 else st[_D + i] + blend * (x - st[_D + i])
        st[_D_INIT] = 1.0
    tau = np.empty(3)
    for i in range(3):
        st[_INT + i] = st[_INT + i] + st[_PEND + i] * dt
        tau[i] = par[_P_KP + i] * e[i] + st[_INT + i] + par[_P_KD + i] * st[_D + i]
        if par[_P_FRIC] > 0.0:
            tau[i] = tau[i] + par[_P_FRIC] * np.tanh(e[i] / par[_P_FRIC_W])
    if par[_P_FF] > 0:
        J = (par[_P_J], par[_P_J + 1], par[_P_J + 2])
        Jw = (J[0] * w_r[0], J[1] * w_r[1], J[2] * w_r[2])
        gyro = (w_r[1] * Jw[2] - w_r[2] * Jw[1], w_r[2] * Jw[0] - w_r[0] * Jw[2],
                w_r[0] * Jw[1] - w_r[1] * Jw[0])
        for i in range(3):
            tau[i] = tau[i] + J[i] * a_r[i] + gyro[i]
    R = _matrix(q)
    T = _mv(R, tau)
    n = np.sqrt(T[0] * T[0] + T[1] * T[1] + T[2] * T[2])
    saturated = n > par[_P_LIMIT]
    if saturated:
        f = par[_P_LIMIT] / n
        T = (T[0] * f, T[1] * f, T[2] * f)
    tau_sat = _mtv(R, T)
    for i in range(3):
        rate = par[_P_KI + i] * e[i]
        excess = tau[i] - tau_sat[i]
        if par[_P_AW] == 0:
            rate = rate + (tau_sat[i] - tau[i]) / par[_P_TT + i]
        elif par[_P_AW] == 1 and saturated and np.sign(e[i]) == np.sign(excess) and abs(excess) > 0:
            rate = 0.0
        st[_PEND + i] = rate
        st[_LAST_TAU + i] = T[i]
    return np.array(T)


# --- the MPC (``MPCController._command``) ---------------------------------------------------
# Its settings (``mpar``), by index: horizon N, step h (s), decision variables, constraints,
# parameters, torque limit (N·m), the lead of each command (compute latency plus actuation
# delay, s), delay-aware, hold on invalid estimates, the history's span (s), the prediction's
# step (s), the RK4 chunk's length
(_MP_N, _MP_H, _MP_NW, _MP_NG, _MP_NP, _MP_LIMIT, _MP_LEAD, _MP_AWARE, _MP_HOLD, _MP_KEEP,
 _MP_DSTEP, _MP_CHUNK) = range(12)
#: Its state (``mst``): the last torque (3), a warm start (0/1), its t0 (s), the history's
#: first and end rows; then the warm start's w (nw), lam_x (nw) and lam_g (ng).
_M_TORQUE, _M_WARM, _M_WARM_T0, _M_HIST_FIRST, _M_HIST_END, _M_W = 0, 3, 4, 5, 6, 7


@njit(cache=True)
def _mpc_record(mst, mhist, t_apply, torque, keep):
    """``MPCController.record_command``: the stator torque (N·m) acts from ``t_apply`` (s);
    the rows (time, torque) older than ``keep`` s before it are forgotten (all but one)."""
    n = int(mst[_M_HIST_END])
    mhist[n, 0] = t_apply
    mhist[n, 1:4] = torque
    mst[_M_HIST_END] = n + 1
    while (mst[_M_HIST_END] - mst[_M_HIST_FIRST] > 1
           and mhist[int(mst[_M_HIST_FIRST]) + 1, 0] < t_apply - keep):
        mst[_M_HIST_FIRST] += 1


@njit(cache=True)
def _mpc_predict(x, t_from, t_to, mpar, mst, mhist, rk4, r_in, r_out):
    """``MPCController.predict``: the twin's state x (7,) carried from ``t_from`` to ``t_to``
    (s) under the history's torques (zero before the first), in steps of at most the
    prediction step, a chunk of RK4 steps per call of the generated ``rk4_chunk`` (padded with
    zero steps, as ``predict`` pads)."""
    if t_to <= t_from:
        return x
    first, end = int(mst[_M_HIST_FIRST]), int(mst[_M_HIST_END])
    chunk, dmax = int(mpar[_MP_CHUNK]), mpar[_MP_DSTEP]
    # the segments' ends: t_from, the commands' start times inside (t_from, t_to), t_to
    edges = [t_from]
    for r in range(first, end):
        if t_from < mhist[r, 0] < t_to:
            edges.append(mhist[r, 0])
    edges.append(t_to)
    filled = 0
    x_at, T_at, h_at = 0, 7, 7 + 3 * chunk  # the chunk's inputs x (7), T (3 x chunk), h (chunk)
    r_in[x_at : x_at + 7] = x
    for s in range(len(edges) - 1):
        a, b = edges[s], edges[s + 1]
        k = first - 1  # the last command started at or before a (searchsorted, side right)
        for r in range(first, end):
            if mhist[r, 0] <= a:
                k = r
        n = max(int(np.ceil((b - a) / dmax - 1e-9)), 1)
        for _ in range(n):
            for c in range(3):
                r_in[T_at + 3 * filled + c] = mhist[k, 1 + c] if k >= first else 0.0
            r_in[h_at + filled] = (b - a) / n
            filled += 1
            if filled == chunk:
                call_casadi(rk4[0], rk4[1], rk4[2], rk4[3], rk4[4])
                r_in[x_at : x_at + 7] = r_out[7 * (chunk - 1) : 7 * chunk]
                filled = 0
    if filled > 0:
        r_in[T_at + 3 * filled : h_at] = 0.0
        r_in[h_at + filled : h_at + chunk] = 0.0
        call_casadi(rk4[0], rk4[1], rk4[2], rk4[3], rk4[4])
        r_in[x_at : x_at + 7] = r_out[7 * (chunk - 1) : 7 * chunk]
    return r_in[x_at : x_at + 7].copy()


@njit(cache=True)
def _mpc(st, valid, q_est, t_state, t, frame, mpc):
    """``MPCController.command`` on an estimate (valid, attitude, the time it describes) at
    the release time ``t`` (s) of frame ``frame``: the stator-frame torque (3,), N·m. The
    NLP's parameters of each release are sampled beforehand (``_mpc_arrays``; the reference's
    signs are aligned here, as ``_parameters`` aligns them on the initial attitude); the solve
    is the generated SQP solver (``controller.mpc_machine``)."""
    (mpar, mref, mbounds, mix, miu, mis, mst, mhist, calls, s_in, s_out, r_in, r_out) = mpc
    N, h = int(mpar[_MP_N]), mpar[_MP_H]
    nw, ng, n_p = int(mpar[_MP_NW]), int(mpar[_MP_NG]), int(mpar[_MP_NP])
    torque = mst[_M_TORQUE : _M_TORQUE + 3]
    if not valid:  # ``_safe``: the invalid-estimate policy
        if mpar[_MP_HOLD] == 0:
            torque[:] = 0.0
        _mpc_record(mst, mhist, t + mpar[_MP_LEAD], torque, mpar[_MP_KEEP])
        return torque.copy()
    # ``_initial_state``: the attitude, the rate from successive attitudes, the prediction
    q = _unit(q_est)
    _attitude_rate(st, q, t_state)
    x = np.empty(7)
    for i in range(4):
        x[i] = q[i]
    for i in range(3):
        w = st[_RATE_W + i]
        x[4 + i] = w if np.isfinite(w) else 0.0
    t0 = t
    if mpar[_MP_AWARE] > 0:
        t0 = t + mpar[_MP_LEAD]
        x = _mpc_predict(x, t_state, t0, mpar, mst, mhist, calls[1], r_in, r_out)
    # ``_parameters``: each reference attitude on the side of the one before (and of x0)
    at_p, at_lbx, at_ubx, at_lbg = nw, nw + n_p, 2 * nw + n_p, 3 * nw + n_p
    at_lam_x, at_lam_g = 3 * nw + n_p + 2 * ng, 4 * nw + n_p + 2 * ng
    s_in[at_p : at_p + n_p] = mref[frame]
    prev = x[:4].copy()
    for k in range(N + 1):
        qk = s_in[at_p + 4 * k : at_p + 4 * k + 4]
        if qk[0] * prev[0] + qk[1] * prev[1] + qk[2] * prev[2] + qk[3] * prev[3] < 0:
            qk *= -1.0
        prev = qk.copy()
    # ``_initial_guess``: the previous solution shifted by the elapsed steps, or x0 held
    guess = s_in[:nw]
    lam = s_in[at_lam_x : at_lam_g + ng]
    lam[:] = 0.0
    if mst[_M_WARM] == 0:
        for k in range(N + 1):
            guess[mix[k]] = x
        for k in range(N):
            guess[miu[k]] = 0.0
        guess[mis] = 0.0
    else:
        w_prev = mst[_M_W : _M_W + nw]
        m = int(np.rint((t0 - mst[_M_WARM_T0]) / h))
        m = min(max(m, 0), N)
        for k in range(N + 1):
            guess[mix[k]] = w_prev[mix[min(k + m, N)]]
        for k in range(N):
            guess[miu[k]] = w_prev[miu[min(k + m, N - 1)]]
            guess[mis[k]] = w_prev[mis[min(k + m, N - 1)]]
        guess[mix[0]] = x
        guess[mis[0]] = 0.0
        for k in range(N + 1):
            qk = guess[mix[k][:4]]
            if qk[0] * x[0] + qk[1] * x[1] + qk[2] * x[2] + qk[3] * x[3] < 0:
                guess[mix[k][:4]] = -qk
        if m == 0:
            lam[:] = mst[_M_W + nw : _M_W + 2 * nw + ng]
    # ``_Problem.bounds``: the first state fixed to x0
    s_in[at_lbx : at_lbg + 2 * ng] = mbounds
    s_in[at_lbx : at_lbx + 7] = x
    s_in[at_ubx : at_ubx + 7] = x
    solve = calls[0]
    status = call_casadi(solve[0], solve[1], solve[2], solve[3], solve[4])
    w = s_out[:nw]
    if status != 0 or not np.all(np.isfinite(w)):  # a failed solve: hold the torque
        mst[_M_WARM] = 0.0
    else:
        at_lx = nw + 1 + ng  # the outputs x, f, g, lam_x, lam_g, lam_p
        mst[_M_W : _M_W + nw] = w
        mst[_M_W + nw : _M_W + 2 * nw + ng] = s_out[at_lx : at_lx + nw + ng]
        mst[_M_WARM], mst[_M_WARM_T0] = 1.0, t0
        T = w[miu[0]]
        n = np.sqrt(T[0] * T[0] + T[1] * T[1] + T[2] * T[2])
        if n > mpar[_MP_LIMIT]:  # solver tolerance: never ask beyond the limit
            T *= mpar[_MP_LIMIT] / n
        torque[:] = T
    _mpc_record(mst, mhist, t0, torque, mpar[_MP_KEEP])
    return torque.copy()


@njit(cache=True, fastmath=FASTMATH)
def _torque_map(q, coils, magnets, gain, cos_cut):
    """K(q) (3, 16), N·m/A (``plant.torque.TorqueMap``); ``gain`` is k_T s_j (18,). The
    magnet axes in the stator frame as three rows, and the windows without a branch, so
    that the sum over the magnets compiles to vector instructions."""
    R = _matrix(q)
    n = magnets.shape[0]
    r = np.empty((3, n))
    for j in range(n):
        for k in range(3):
            r[k, j] = (R[3 * k] * magnets[j, 0] + R[3 * k + 1] * magnets[j, 1]
                       + R[3 * k + 2] * magnets[j, 2])
    scale = 1.0 / (1.0 - cos_cut)
    K = np.empty((3, coils.shape[0]))
    for i in range(coils.shape[0]):
        c0, c1, c2 = coils[i, 0], coils[i, 1], coils[i, 2]
        v0 = v1 = v2 = 0.0
        for j in range(n):
            x = max(c0 * r[0, j] + c1 * r[1, j] + c2 * r[2, j] - cos_cut, 0.0) * scale
            g = gain[j] * x * x
            v0 += g * r[0, j]
            v1 += g * r[1, j]
            v2 += g * r[2, j]
        K[0, i] = c1 * v2 - c2 * v1
        K[1, i] = c2 * v0 - c0 * v2
        K[2, i] = c0 * v1 - c1 * v0
    return K


@njit(cache=True)
def _least_norm(K, torque):
    """The least-norm currents I = Kᵀ (K Kᵀ)⁻¹ T (n,), A, of the torque map K (3, n) for the
    torque T (3,), N·m (``plant.torque.allocate`` within the limits), the torque K I they
    deliver, and False when K Kᵀ is singular."""
    n = K.shape[1]
    G = np.zeros((3, 3))
    for a in range(3):
        for b in range(3):
            for i in range(n):
                G[a, b] += K[a, i] * K[b, i]
    x, solved = _solve3(G, torque)
    currents = np.empty(n)
    delivered = np.zeros(3)
    for i in range(n):
        currents[i] = K[0, i] * x[0] + K[1, i] * x[1] + K[2, i] * x[2]
        for a in range(3):
            delivered[a] += K[a, i] * currents[i]
    return currents, delivered, solved


@njit(cache=True)
def _event(st, evs, t, code, a, b, c, d):
    """Append an event (time s, code of ``EVENT_KINDS``, up to four numbers) to the record."""
    n = int(st[_N_EV])
    evs[n, 0], evs[n, 1], evs[n, 2], evs[n, 3], evs[n, 4], evs[n, 5] = t, code, a, b, c, d
    st[_N_EV] = n + 1


@njit(cache=True)
def _record(st, k, ref_grid, log, evs, par):
    """Row k of the steps table (``latency.loop._StepLog``) from the state at grid point k;
    a tilt-stop contact or release event where the flag changes (each row shows the flag of
    the row before)."""
    row = log[k]
    row[0] = k * par[_P_H]
    # element by element: a slice per field costs more than the copy itself
    for i in range(4):
        row[1 + i] = st[_Q + i]
        row[8 + i] = ref_grid[k, i]
        row[34 + i] = st[_EST + i]
    for i in range(3):
        row[5 + i] = st[_W + i]
        row[12 + i] = st[_TCMD + i]
        row[15 + i] = st[_TDEL + i]
    for i in range(N_COILS):
        row[18 + i] = st[_CUR + i]
    row[38] = st[_SAT]
    row[39] = st[_STOP]
    stop = 1.0 if 1.0 - 2.0 * (st[_Q + 1] ** 2 + st[_Q + 2] ** 2) < par[_P_COS_STOP] else 0.0
    if stop != st[_STOP]:
        _event(st, evs, row[0], _EV_CONTACT if stop > 0 else _EV_RELEASE, 0.0, 0.0, 0.0, 0.0)
    st[_STOP] = stop


@njit(cache=True, fastmath=FASTMATH)
def _advance(st, target, ref_grid, log, evs, par, J, J_inv, com, m_g, coils, magnets, gain,
             scal, pairs):
    """``latency.loop._advance_segment`` on the run's state: to the next grid point or the
    target, whichever is first (whole steps, a shortened last one, the coils' first-order
    lag exact at each step's start), recording each grid point, until within 1e-12 s of the
    target."""
    h, tau_l, n_steps = par[_P_H], par[_P_TAU_L], int(par[_P_N_STEPS])
    # one rotor's state as tuples, stepped by the physics kernel's per-row function with the
    # run's pair lists ``pairs`` (no array per step)
    q = (st[_Q], st[_Q + 1], st[_Q + 2], st[_Q + 3])
    w = (st[_W], st[_W + 1], st[_W + 2])
    cur = st[_CUR : _CUR + N_COILS].copy()
    cmd = st[_CMD : _CMD + N_COILS]
    rotor = _rotor_tuples(J, J_inv, com, m_g, scal)
    cutoff = np.arccos(scal[3])
    decay_h = np.exp(-h / tau_l) if tau_l > 0 else 0.0  # the coils' lag over a whole step
    t, k = st[_T], int(st[_K])
    while True:
        t_grid = (k + 1) * h
        t_to = min(target, t_grid)
        if t_to > t:
            dt = t_to - t
            n = int(np.floor(dt / h + 1e-9))
            rest = dt - n * h
            for s in range(n + 1):
                hk = h if s < n else rest
                if s == n and not rest > 1e-12:
                    break
                decay = (decay_h if hk == h else np.exp(-hk / tau_l)) if tau_l > 0 else 0.0
                for i in range(N_COILS):
                    cur[i] = cmd[i] + (cur[i] - cmd[i]) * decay
                q, w, _ = _step_row(q, w, cur, hk, (0.0, 0.0, 0.0), PHYSICS_SUBSTEPS, rotor,
                                    coils, magnets, gain, cutoff, pairs, SUBSTEP_ANGLE_RAD)
            t = t_to
            st[_Q], st[_Q + 1], st[_Q + 2], st[_Q + 3] = q
            st[_W], st[_W + 1], st[_W + 2] = w
            for i in range(N_COILS):
                st[_CUR + i] = cur[i]
        if abs(t - t_grid) < 1e-12 and k + 1 <= n_steps:
            k += 1
            _record(st, k, ref_grid, log, evs, par)
        if t >= target - 1e-12:
            break
    st[_T], st[_K] = t, k


@njit(cache=True)
def _run_events(e, alloc_ready, ev_t, ev_kind, ev_idx, frames, ref_grid, ref_q, ref_w, ref_a,
                par, J, J_inv, com, m_g, coils, magnets, gain, scal, true_model, obs_model,
                tm_gain, rng, st, log, fr, evs, mpc):
    """Run the events from index e on (the module docstring). Returns the index of a command
    whose currents need ``plant.torque.allocate`` (its torque and attitude in ``st``; call
    again with ``alloc_ready`` and the allocation in ``st``), or the number of events when the
    run is complete. ``true_model`` and ``obs_model`` are (markers (2, 3), m; CoR in the camera
    frame (3,), m; intrinsics (7,)) of the camera's truth and of the observer's model. ``mpc``:
    the MPC's arrays (``_mpc_arrays``; placeholders for a PID run)."""
    duration = par[_P_DURATION]
    if st[_K] < 0:
        st[_K] = 0.0
        _record(st, 0, ref_grid, log, evs, par)
    meas = np.empty((2, 2))
    # the rotor's pair lists, kept from step to step while they cover its turn
    pairs = _pair_lists(magnets.shape[0], coils.shape[0], PAIR_REUSE_RAD)
    while e < ev_t.shape[0]:
        target = min(ev_t[e], duration)
        if target > st[_T]:
            _advance(st, target, ref_grid, log, evs, par, J, J_inv, com, m_g, coils, magnets,
                     gain, scal, pairs)
        t = st[_T]
        i = ev_idx[e]
        f = fr[i]
        if ev_kind[e] == _FRAME:
            q = st[_Q : _Q + 4]
            err = np.degrees(_geodesic(q, ref_q[e]))
            newly = (not np.isfinite(err) or err > par[_P_DIV_DEG]) and st[_DIV] == 0
            if newly:
                st[_DIV], st[_DIV_DEG] = 1.0, err
            f[_F_INDEX], f[_F_T_EXP], f[_F_T_REL] = i, frames[i, 0], frames[i, 1]
            f[_F_DROPPED] = frames[i, 2]
            if frames[i, 2] > 0:
                _event(st, evs, t, _EV_DROPPED, i, 0.0, 0.0, 0.0)
            else:
                truth, cap_lost, reason = _capture(st, q, st[_W : _W + 3], par, *true_model, rng,
                                                   meas)
                worst, any_finite, lost = -np.inf, False, cap_lost
                for j in range(2):
                    du, dv = meas[j, 0] - truth[j, 0], meas[j, 1] - truth[j, 1]
                    d = np.sqrt(du * du + dv * dv)
                    if np.isfinite(d):
                        any_finite = True
                        worst = max(worst, d)
                    if not d <= par[_P_LOSS_PX]:
                        lost = True
                if lost != (st[_LOST] > 0):
                    _event(st, evs, t, _EV_LOSS if lost else _EV_REACQ, reason,
                           worst if any_finite else np.nan, 0.0, 0.0)
                    st[_LOST] = 1.0 if lost else 0.0
                f[_F_TRUE : _F_TRUE + 4] = truth.ravel()
                f[_F_MEAS : _F_MEAS + 4] = meas.ravel()
                f[_F_CENTRE] = worst if any_finite else np.nan
                f[_F_LOST] = 1.0 if lost else 0.0
                f[_F_CAP_LOST] = 1.0 if cap_lost else 0.0
                f[_F_CAP_REASON] = reason
            if newly:
                _event(st, evs, t, _EV_DIVERGENCE, st[_DIV_DEG], 0.0, 0.0, 0.0)
        elif ev_kind[e] == _RELEASE:
            t_exp = f[_F_T_EXP]
            uv = f[_F_MEAS : _F_MEAS + 4].copy().reshape(2, 2)
            lost = f[_F_CAP_LOST] > 0
            if par[_P_KF_ON] > 0:  # the filters' prior stands in for a lost frame
                uv = _pixel_kalman(st, par, uv, lost)
                lost = lost and not np.all(np.isfinite(uv))
            if lost:
                code, value = _R_LOST, f[_F_CAP_REASON]
            else:
                q_sol, ok, code, value = _solve(st[_OBS_Q : _OBS_Q + 4], uv, *obs_model, par)
                if ok:
                    st[_OBS_Q : _OBS_Q + 4], st[_OBS_T] = q_sol, t_exp
            valid = t_exp - st[_OBS_T] <= par[_P_MAX_INVALID]
            st[_EST : _EST + 4] = st[_OBS_Q : _OBS_Q + 4]
            f[_F_RELEASED] = 1.0
            f[_F_EST : _F_EST + 4] = st[_OBS_Q : _OBS_Q + 4]
            f[_F_VALID], f[_F_REASON], f[_F_REASON_VALUE] = 1.0 if valid else 0.0, code, value
            f[_F_HELD_FROM] = st[_OBS_T] if st[_OBS_T] < t_exp else np.nan
            f[_F_LATENCY] = t - t_exp
            if not valid:
                _event(st, evs, t, _EV_INVALID_EST, i, 0.0, 0.0, 0.0)
            if par[_P_MPC] > 0:
                torque = _mpc(st, valid, st[_EST : _EST + 4], st[_OBS_T], t, i, mpc)
            else:
                torque = _pid(st, par, valid, st[_EST : _EST + 4], st[_OBS_T], ref_q[e],
                              ref_w[e], ref_a[e])
            if not np.all(np.isfinite(torque)):
                _event(st, evs, t, _EV_INVALID_CMD, torque[0], torque[1], torque[2], 0.0)
                torque[:] = 0.0
            f[_F_TORQUE : _F_TORQUE + 3] = torque
        else:
            torque = f[_F_TORQUE : _F_TORQUE + 3]
            if alloc_ready:  # the allocation of ``plant.torque.allocate``, set by the caller
                alloc_ready = False
                saturated = st[_ALLOC_SAT]
            else:  # the least-norm currents, when they are within the limits
                truth_q = par[_P_TRUTH] > 0 or f[_F_VALID] == 0
                q_alloc = st[_Q : _Q + 4].copy() if truth_q else f[_F_EST : _F_EST + 4].copy()
                K = _torque_map(q_alloc, coils, magnets, tm_gain, par[_P_KT_COS])
                currents, delivered, solved = _least_norm(K, torque)
                if not solved or np.max(np.abs(currents)) > par[_P_I_MAX]:
                    st[_ALLOC_T : _ALLOC_T + 3] = torque
                    st[_ALLOC_Q : _ALLOC_Q + 4] = q_alloc
                    return e
                st[_CMD : _CMD + N_COILS] = currents
                st[_TDEL : _TDEL + 3] = delivered
                saturated = 0.0
            if saturated != st[_SAT]:
                if saturated > 0:
                    delivered = st[_TDEL : _TDEL + 3]
                    _event(st, evs, t, _EV_SATURATION, np.sqrt(delivered @ delivered),
                           np.sqrt(torque @ torque), 0.0, 0.0)
                st[_SAT] = saturated
            st[_TCMD : _TCMD + 3] = torque
        e += 1
    if duration > st[_T]:
        _advance(st, duration, ref_grid, log, evs, par, J, J_inv, com, m_g, coils, magnets,
                 gain, scal, pairs)
    return e


# --- the run ----------------------------------------------------------------------------------
def run(loop: ClosedLoop, tables: bool = True) -> LoopResult:
    """Run ``loop`` (``covers(loop)`` must hold) and return what ``loop.run()`` returns: the
    same tables and ``summarize`` metrics (module docstring: where they differ).

    ``tables=False`` leaves the steps, frames and events tables of the result empty (tables
    without rows that all such results share; do not modify them): the summary is computed
    from the kernel's arrays, without building the tables or the events' texts (for sweeps
    that keep the summaries only)."""
    if (cov := coverage(loop)).path != "compiled":
        raise ValueError(f"the compiled run loop does not cover this run ({cov.reason}); use "
                         "the event loop")
    c, p = loop.config, loop.params
    ev_t, ev_kind, ev_idx, frames = _schedule(loop)
    n_steps = loop.n_steps
    ref_grid = np.ascontiguousarray(
        loop.reference.sample_many(np.arange(n_steps + 1) * p.physics_dt_s).q)
    ref = loop.reference.sample_many(ev_t)
    body_consts, tm, camera_truth, tm_gain = _plant_parts(p)
    solver = _solver_observer(loop).solver  # type: ignore[union-attr]
    par = _settings(loop)
    st = np.zeros(_N_STATE)
    q0 = np.asarray(c.q0, dtype=float) / np.linalg.norm(c.q0)
    st[_Q : _Q + 4], st[_W : _W + 3], st[_OBS_Q : _OBS_Q + 4] = q0, c.omega0_rad_s, q0
    st[_K], st[_T_PREV], st[_RATE_T] = -1.0, np.nan, -np.inf
    for b in (_KF, _KF + _KF_SIZE):  # PixelKalman.reset: X = 0, P = I, not initialised
        st[b + 5 : b + 21] = np.eye(4).ravel()
    for at, n in ((_EST, 4), (_RATE_Q, 4), (_RATE_W, 3)):
        st[at : at + n] = np.nan
    # A summary-only run's step rows are read before the next run writes them: one buffer
    # serves them all (each row is written whole before it is read).
    log = _StepLog(n_steps + 1) if tables else None
    rows = log.a if log is not None else _summary_rows(n_steps + 1)
    fr = np.full((len(frames), _N_FR), np.nan)
    evs = np.zeros((4 * len(frames) + n_steps + 8, 6))
    mpc = _mpc_arrays(loop, ev_t, ev_kind, ev_idx, len(frames))
    args = (ev_t, ev_kind, ev_idx, frames, ref_grid, np.ascontiguousarray(ref.q),
            np.ascontiguousarray(ref.omega), np.ascontiguousarray(ref.alpha), par, *body_consts,
            camera_truth, _model_arrays(solver.model), tm_gain, loop.front_end.rng, st, rows,
            fr, evs, mpc)
    e, ready = 0, False
    while (e := _run_events(e, ready, *args)) < len(ev_t):
        # least-norm currents beyond the limits: the LP and bounded solve of ``allocate``
        alloc = allocate(st[_ALLOC_T : _ALLOC_T + 3], tm(st[_ALLOC_Q : _ALLOC_Q + 4]),
                         p.motor.i_max_A)
        st[_CMD : _CMD + N_COILS], st[_TDEL : _TDEL + 3] = alloc.currents, alloc.delivered
        st[_ALLOC_SAT], ready = float(alloc.saturated), True
    n_rows = int(st[_K]) + 1
    evs = evs[: int(st[_N_EV])]
    stopped = f"divergence: geodesic error {st[_DIV_DEG]:.1f} deg" if st[_DIV] > 0 else ""
    if not tables:
        # The summary straight from the kernel's arrays: no tables, no events' texts.
        a = rows[:n_rows]
        values = step_values(a[:, 0], a[:, 1:5], a[:, 8:12], a[:, 15:18], a[:, 39] > 0,
                             c.step_metrics)
        frame_metrics = frame_values(fr[:, _F_T_EXP], fr[:, _F_DROPPED] > 0,
                                     fr[:, _F_LOST] == 1.0, fr[:, _F_LATENCY], a[-1, 0])
        summary = summarize_values(values, a[-1, 0], frame_metrics, len(evs), c.duration_s,
                                   stopped)
        return LoopResult(_NO_ROWS, _NO_ROWS, _NO_EVENTS, summary, c.model_dump(mode="json"))
    assert log is not None
    steps = log.columns(n_rows)
    frames_cols = _frames_columns(fr, solver)
    events = _events_table(evs, frames_cols)
    summary = summarize(steps, frames_cols, events, c.duration_s, stopped, c.step_metrics)
    return LoopResult(pd.DataFrame(steps), pd.DataFrame(frames_cols), events, summary,
                      c.model_dump(mode="json"))


def _mpc_arrays(loop: ClosedLoop, ev_t: NDArray, ev_kind: NDArray, ev_idx: NDArray,
                n_frames: int) -> tuple:
    """The ``mpc`` argument of ``_run_events``: the MPC's settings (``_MP_*``), the NLP's
    parameters of each frame's release (as ``MPCController._parameters`` makes them before
    it aligns the signs, then the cost's weights, ``weight_values``; row = frame), the bounds
    (lbx, ubx, lbg, ubg), the decision vector's layout (X, U, S positions), the MPC's state
    and command history, the generated functions' call arguments (solver, RK4 chunk) and
    their input and output arrays. A PID run gets placeholders of the same types."""
    ctrl = loop.controller
    if not isinstance(ctrl, MPCController):
        f1, f2 = np.zeros(1), np.zeros((1, 1))
        i1, i2 = np.zeros(1, np.int64), np.zeros((1, 1), np.int64)
        return (f1, f2, f1, i2, i2, i1, f1, np.zeros((1, 4)), np.zeros((2, 5), np.int64), f1,
                f1, f1, f1)
    cfg, pr = ctrl.config, ctrl.problem
    machine: MachineMPC | None = machine_mpc(pr)
    assert machine is not None and cfg.compute_latency_s is not None  # ``coverage``
    N, h, nw, ng = pr.N, pr.h, pr.nw, pr.ng
    lead = cfg.compute_latency_s + cfg.actuation_delay_s
    released = ev_kind == _RELEASE
    t_rel, rows = ev_t[released], ev_idx[released]
    n_rel = len(t_rel)
    if cfg.reference_preview:
        t0 = t_rel + lead if cfg.delay_aware else t_rel
        ref = loop.reference.sample_many((t0[:, None] + h * np.arange(N + 1)).ravel())
        qr = attitude.normalize(np.asarray(ref.q, float).reshape(n_rel, N + 1, 4), "reference.q")
        wr = np.asarray(ref.omega, float).reshape(n_rel, N + 1, 3)
        ar = np.asarray(ref.alpha, float).reshape(n_rel, N + 1, 3)[:, :N]
    else:  # the reference at the call, held, without rate
        held = attitude.normalize(np.asarray(loop.reference.sample_many(t_rel).q, float),
                                  "reference.q")
        qr = np.repeat(held[:, None], N + 1, axis=1)
        wr, ar = np.zeros((n_rel, N + 1, 3)), np.zeros((n_rel, N, 3))
    J = pr.J
    tau = J * ar + np.cross(wr[:, :N], J * wr[:, :N])  # body frame of the reference
    tff = np.einsum("rkij,rkj->rki", attitude.to_matrix(qr[:, :N]), tau)  # R(q) = R(-q)
    weights = weight_values(pr)  # the machine code's extra parameters, the same at each release
    n_p = 7 * (N + 1) + 3 * N + len(weights)
    mref = np.zeros((n_frames, n_p))
    mref[rows] = np.concatenate([qr.reshape(n_rel, -1), wr.reshape(n_rel, -1),
                                 tff.reshape(n_rel, -1), np.tile(weights, (n_rel, 1))], axis=1)
    mpar = np.zeros(12)
    mpar[_MP_N], mpar[_MP_H], mpar[_MP_NW], mpar[_MP_NG], mpar[_MP_NP] = N, h, nw, ng, n_p
    mpar[_MP_LIMIT], mpar[_MP_LEAD] = ctrl.torque_limit, lead
    mpar[_MP_AWARE], mpar[_MP_HOLD] = cfg.delay_aware, cfg.invalid_command == "hold"
    mpar[_MP_KEEP], mpar[_MP_DSTEP] = N * h + 1.0, cfg.prediction_step_s
    mpar[_MP_CHUNK] = pr.chunk
    solve, rk4 = machine.solver, machine.rk4_chunk
    # the inputs' and outputs' layout that ``_mpc`` and ``_mpc_predict`` assume
    assert list(np.diff(solve.offsets_in)) == [nw, n_p, nw, nw, ng, ng, nw, ng]
    assert list(np.diff(solve.offsets_out)[:5]) == [nw, 1, ng, nw, ng]
    assert list(np.diff(rk4.offsets_in)) == [7, 3 * pr.chunk, pr.chunk]
    bounds = np.concatenate([pr.lbw, pr.ubw, pr.lbg, pr.ubg])
    calls = np.array([solve.call_args(), rk4.call_args()], dtype=np.int64)
    return (mpar, mref, bounds, np.ascontiguousarray(pr.ix), np.ascontiguousarray(pr.iu),
            np.ascontiguousarray(pr.i_s), np.zeros(_M_W + 2 * nw + ng),
            np.zeros((n_frames + 1, 4)), calls, solve.inputs, solve.outputs, rk4.inputs,
            rk4.outputs)


@functools.lru_cache(maxsize=16)
def _plant_parts(params: PlantParams) -> tuple[tuple, TorqueMap, tuple, NDArray]:
    """The physics kernel's constants (``RigidBody.consts``), the torque map, the camera's
    true projection (``_model_arrays`` of the nominal CoR model) and the torque map's gains
    k_T s_j (18,) of a plant, made once per parameter set (a sweep's runs share them;
    ``PlantParams`` is frozen)."""
    tm = TorqueMap(params.motor)
    return (RigidBody(params).consts, tm, _model_arrays(CorModel.nominal(params)),
            params.motor.k_T_Nm_per_A * tm.s)


@functools.lru_cache(maxsize=4)
def _summary_rows(n_rows: int) -> NDArray[np.float64]:
    """The step rows (``latency.loop._StepLog``'s layout) of summary-only runs of ``n_rows``
    grid points, one buffer per length, reused from run to run."""
    return np.empty((n_rows, _StepLog.WIDTH))


def _model_arrays(model: CorModel) -> tuple[NDArray, NDArray, NDArray]:
    """A CoR model for the kernel: markers (n, 3), m, CoR in the camera frame (3,), m, and the
    intrinsics (fx, fy, cx, cy, k1, k2, k3)."""
    return (np.ascontiguousarray(model.markers_m, dtype=float),
            np.asarray(model.t_cor_m, dtype=float), model.intrinsics.as_array())


def _flag_column(values: NDArray[np.float64]) -> NDArray:
    """A flag column as the event loop's list of row dicts gives it: bool, or object with NaN
    where some rows lack it."""
    present = ~np.isnan(values)
    if present.all():
        return values.astype(bool)
    out = np.full(len(values), np.nan, dtype=object)
    out[present] = values[present].astype(bool)
    return out


def _reason(f: NDArray[np.float64], solver: CorSolver) -> str:
    """The estimate's ``reason`` of a released frame's record (``SolverObserver.release``)."""
    code, value = int(f[_F_REASON]), f[_F_REASON_VALUE]
    if code == _R_OK:
        text = ""
    elif code == _R_LOST:
        text = CAPTURE_REASONS[int(value)]
    else:
        text = failure_reason(code, value, solver.config)
    if np.isfinite(f[_F_HELD_FROM]):
        text = f"{text}; holding the solution from t = {f[_F_HELD_FROM]:.4f} s"
    return text


def _frames_columns(fr: NDArray[np.float64], solver: CorSolver) -> dict[str, NDArray]:
    """The frames table of ``ClosedLoop.timeline`` from the kernel's frame record, as columns:
    the same columns in the same order and types (a column appears once a frame has it)."""
    if not len(fr):
        return {}
    data: dict[str, NDArray] = {
        "frame": fr[:, _F_INDEX].astype(np.int64),
        "t_exposure_s": fr[:, _F_T_EXP],
        "t_release_s": fr[:, _F_T_REL],
        "dropped": fr[:, _F_DROPPED].astype(bool),
    }
    captured = ~data["dropped"]
    if captured.any():
        for k, name in enumerate(("true_red_u_px", "true_red_v_px", "true_yellow_u_px",
                                  "true_yellow_v_px", "meas_red_u_px", "meas_red_v_px",
                                  "meas_yellow_u_px", "meas_yellow_v_px")):
            data[name] = fr[:, _F_TRUE + k]
        data["centre_error_px"] = fr[:, _F_CENTRE]
        data["lost"] = _flag_column(fr[:, _F_LOST])
        data["observer_compute_s"] = np.where(captured, 0.0, np.nan)
    released = fr[:, _F_RELEASED] == 1.0
    if released.any():
        for k, name in enumerate(("est_qw", "est_qx", "est_qy", "est_qz")):
            data[name] = fr[:, _F_EST + k]
        data["est_valid"] = _flag_column(fr[:, _F_VALID])
        reasons = np.full(len(fr), np.nan, dtype=object)
        for i in np.flatnonzero(released):
            reasons[i] = _reason(fr[i], solver)
        data["est_reason"] = reasons
        data["latency_s"] = fr[:, _F_LATENCY]
        data["controller_compute_s"] = np.full(len(fr), np.nan)  # not timed per call
    return data


#: The tables of a summary-only result: a table without rows, and the events table without
#: rows, built once and shared by every such result (an empty frame costs pandas 0.03 ms).
_NO_ROWS = pd.DataFrame()
_NO_EVENTS = pd.DataFrame({"t_s": np.zeros(0), "kind": np.zeros(0, dtype=object),
                           "detail": np.zeros(0, dtype=object)})


def _events_table(evs: NDArray[np.float64], frames: dict[str, NDArray]) -> pd.DataFrame:
    """The events table (time, kind, detail) from the kernel's record, with the event loop's
    texts."""
    rows = []
    for t, code, a, b, c, _ in evs:
        kind = EVENT_KINDS[int(code)]
        if kind == "frame_dropped":
            detail = f"frame {int(a)}"
        elif kind in ("tracking_loss", "reacquisition"):
            detail = CAPTURE_REASONS[int(a)] or f"centre error {b:.1f} px"
        elif kind == "invalid_estimate":
            detail = frames["est_reason"][int(a)]
        elif kind == "invalid_command":
            detail = f"controller returned {np.array([a, b, c])!r}"
        elif kind == "saturation":
            detail = f"delivered {a:.3g} of {b:.3g} N·m"
        elif kind == "divergence":
            detail = f"divergence: geodesic error {a:.1f} deg"
        else:
            detail = ""
        rows.append((float(t), kind, detail))
    return pd.DataFrame(rows, columns=["t_s", "kind", "detail"])
