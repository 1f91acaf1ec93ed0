"""The event loop's tables (``ClosedLoop.timeline``'s frames and events) from the compiled
run loop's records, and the shared buffers of summary-only runs."""

from __future__ import annotations

import functools

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from latency.compiled.layout import (
    _F_CENTRE,
    _F_DROPPED,
    _F_EST,
    _F_HELD_FROM,
    _F_INDEX,
    _F_LATENCY,
    _F_LOST,
    _F_REASON,
    _F_REASON_VALUE,
    _F_RELEASED,
    _F_T_EXP,
    _F_T_REL,
    _F_TRUE,
    _F_VALID,
    _R_LOST,
    _R_OK,
    CAPTURE_REASONS,
    EVENT_KINDS,
)
from latency.loop import _StepLog
from observer.cor_solver import CorSolver, failure_reason


@functools.lru_cache(maxsize=4)
def _summary_rows(n_rows: int) -> NDArray[np.float64]:
    """The step rows (``latency.loop._StepLog``'s layout) of summary-only runs of ``n_rows``
    grid points, one buffer per length, reused from run to run."""
    return np.empty((n_rows, _StepLog.WIDTH))


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
