"""The compiled run loop's inputs from a run's Python objects: its settings as numbers
(``par``), the plant's constants and the CoR models' arrays."""

from __future__ import annotations

import functools

import numpy as np
from numpy.typing import NDArray

from controller.mpc import MPCController
from controller.pid import PIDController
from latency.compiled.layout import (
    _AW_MODES,
    _N_PAR,
    _P_AW,
    _P_BLUR,
    _P_CAL_HAZ,
    _P_CAL_ON,
    _P_CAL_PER,
    _P_COS_STOP,
    _P_DIV_DEG,
    _P_DROPOUT,
    _P_DURATION,
    _P_EXPOSURE,
    _P_FF,
    _P_FRIC,
    _P_FRIC_W,
    _P_H,
    _P_HOLD,
    _P_I_MAX,
    _P_J,
    _P_KD,
    _P_KF_ON,
    _P_KF_Q,
    _P_KF_R,
    _P_KF_V0,
    _P_KI,
    _P_KP,
    _P_KT_COS,
    _P_LIMIT,
    _P_LOSS_PX,
    _P_MAX_COND,
    _P_MAX_INVALID,
    _P_MAX_IT,
    _P_MAX_RMS,
    _P_MAX_TILT,
    _P_MPC,
    _P_N_STEPS,
    _P_OUTLIER,
    _P_OUTLIER_PX,
    _P_PREDICT,
    _P_REACQ,
    _P_ROI,
    _P_ROI_COLS,
    _P_ROI_FOLLOW,
    _P_ROI_ROWS,
    _P_SEARCH,
    _P_SENSOR_H,
    _P_SENSOR_W,
    _P_SIGMA,
    _P_STEP_TOL,
    _P_TAU_F,
    _P_TAU_L,
    _P_TRUTH,
    _P_TT,
)
from latency.frontends import CalibratedLoss, MeasurementConfig, MeasurementFrontEnd
from latency.loop import ClosedLoop
from observer.cor_model import CorModel
from observer.cor_solver import CorSolver
from observer.pixel_observer import PixelKalmanObserver, SolverObserver
from plant.params import PlantParams
from plant.rigid_body import RigidBody
from plant.torque import TorqueMap


def physics_settings(p: PlantParams, n_steps: int) -> NDArray[np.float64]:
    """A ``par`` with the numbers the physics between events reads
    (``latency.compiled.steps._advance``): the physics step (s), the coils' time constant (s),
    the run's steps and the cosine of the tilt stop; the rest zero."""
    par = np.zeros(_N_PAR)
    par[_P_H], par[_P_TAU_L], par[_P_N_STEPS] = (p.physics_dt_s, p.motor.coil_time_constant_s,
                                                 n_steps)
    par[_P_COS_STOP] = np.cos(np.deg2rad(p.rotor.tilt_stop_deg))
    return par


def _settings(loop: ClosedLoop) -> NDArray[np.float64]:
    """The run's numbers for the kernel (``par``; the ``_P_*`` indices)."""
    c, p = loop.config, loop.params
    fe: MeasurementFrontEnd = loop.front_end  # type: ignore[assignment]
    par = physics_settings(p, loop.n_steps)
    par[_P_DURATION] = c.duration_s
    par[_P_DIV_DEG], par[_P_LOSS_PX] = c.divergence_deg, c.loss_threshold_px
    _front_end_settings(par, fe.config, p)
    _observer_settings(par, loop.observer)
    par[_P_I_MAX], par[_P_TRUTH] = p.motor.i_max_A, c.allocate_with == "truth"
    par[_P_KT_COS] = np.cos(np.deg2rad(p.motor.cutoff_deg))
    if isinstance(loop.controller, MPCController):
        par[_P_MPC] = 1.0  # its settings: ``latency.compiled.mpc._mpc_arrays``
        return par
    _pid_settings(par, loop.controller)  # type: ignore[arg-type]
    return par


def _front_end_settings(par: NDArray[np.float64], m: MeasurementConfig,
                        p: PlantParams) -> None:
    """The measurement front end's numbers in ``par``: its noise and losses (``m``) and the
    camera's sensor and exposure (``p``)."""
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


def _observer_settings(par: NDArray[np.float64],
                       observer: SolverObserver | PixelKalmanObserver) -> None:
    """The observer's numbers in ``par``: its CoR solver's limits, how long it holds a
    solution, and the pixel Kalman filters' covariances when it has them."""
    inner = observer.inner if isinstance(observer, PixelKalmanObserver) else observer
    assert isinstance(inner.solver, CorSolver)  # ``coverage``
    sc = inner.solver.config
    par[_P_MAX_IT], par[_P_STEP_TOL] = sc.max_iterations, sc.step_tol_rad
    par[_P_MAX_RMS], par[_P_MAX_TILT] = sc.max_residual_rms_px, sc.max_tilt_rad
    par[_P_MAX_COND] = sc.max_condition
    par[_P_MAX_INVALID] = inner.max_invalid_s
    if isinstance(observer, PixelKalmanObserver):
        kf = observer.config
        par[_P_KF_ON], par[_P_KF_V0] = 1.0, kf.velocity_var0
        par[_P_KF_Q : _P_KF_Q + 16] = np.ravel(kf.Q)
        par[_P_KF_R : _P_KF_R + 4] = np.ravel(kf.R)


def _pid_settings(par: NDArray[np.float64], pid: PIDController) -> None:
    """The PID's gains and settings in ``par``."""
    pc = pid.config
    par[_P_TAU_F], par[_P_LIMIT] = pid.tau_f, pid.torque_limit
    par[_P_FRIC] = pc.friction_compensation_Nm
    par[_P_FRIC_W] = np.radians(pc.friction_compensation_width_deg)
    par[_P_FF], par[_P_AW] = pc.feedforward, _AW_MODES.index(pc.anti_windup)
    par[_P_HOLD] = pc.invalid_command == "hold"
    for at, v in ((_P_KP, pid.Kp), (_P_KI, pid.Ki), (_P_KD, pid.Kd), (_P_TT, pid.T_t),
                  (_P_J, pid.J)):
        par[at : at + 3] = v


@functools.lru_cache(maxsize=16)
def _plant_parts(params: PlantParams) -> tuple[tuple, TorqueMap, tuple, NDArray]:
    """The physics kernel's constants (``RigidBody.consts``), the torque map, the camera's
    true projection (``_model_arrays`` of the nominal CoR model) and the torque map's gains
    k_T s_j (18,) of a plant, made once per parameter set (a sweep's runs share them;
    ``PlantParams`` is frozen)."""
    tm = TorqueMap(params.motor)
    return (RigidBody(params).consts, tm, _model_arrays(CorModel.nominal(params)),
            params.motor.k_T_Nm_per_A * tm.s)


def _model_arrays(model: CorModel) -> tuple[NDArray, NDArray, NDArray]:
    """A CoR model for the kernel: markers (n, 3), m, CoR in the camera frame (3,), m, and the
    intrinsics (fx, fy, cx, cy, k1, k2, k3)."""
    return (np.ascontiguousarray(model.markers_m, dtype=float),
            np.asarray(model.t_cor_m, dtype=float), model.intrinsics.as_array())
