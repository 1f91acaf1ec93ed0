"""The compiled run loop's arrays, by index: the run's scalar state (``st``), its settings
(``par``), the frame record (``fr``), the events' kinds and codes, and the capture's and the
solve's outcome codes. numba reads these module constants as compile-time constants."""

from __future__ import annotations

from latency.frontends import (
    LOST_BLUR,
    LOST_CALIBRATED,
    LOST_DROPOUT,
    LOST_OUTSIDE_ROI,
    LOST_OUTSIDE_WINDOW,
)

# --- event kinds of the schedule, event codes of the record -----------------------------------
_FRAME, _RELEASE, _COMMAND = 0, 1, 2
#: The event loop's event kinds, in the order of their codes in the kernel's event record.
EVENT_KINDS = ("frame_dropped", "tracking_loss", "reacquisition", "invalid_estimate",
               "invalid_command", "saturation", "tilt_stop_contact", "tilt_stop_release",
               "divergence")
(_EV_DROPPED, _EV_LOSS, _EV_REACQ, _EV_INVALID_EST, _EV_INVALID_CMD, _EV_SATURATION,
 _EV_CONTACT, _EV_RELEASE, _EV_DIVERGENCE) = range(len(EVENT_KINDS))
#: Why a front end lost a frame (``MeasurementFrontEnd.capture``'s reasons), by code.
CAPTURE_REASONS = ("", LOST_DROPOUT, LOST_OUTSIDE_WINDOW, LOST_OUTSIDE_ROI, LOST_BLUR,
                   LOST_CALIBRATED)
#: A solve's outcome: ``observer.cor_solver``'s failure codes (``failure_reason``), and two of
#: its own: a clean solution, and a frame the front end lost (not solved).
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
_P_MPC = 75  # 1: the MPC computes the commands (``latency.compiled.mpc``), 0: the PID
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

#: No kernels here: the constants above are compiled into the other modules' kernels.
COMPILED_IN: tuple = ()
