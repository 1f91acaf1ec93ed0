"""The measurement front end in the compiled run loop: a frame's true marker pixels, the
tracker's losses (dropouts, the search window, the calibrated loss model, the region of
interest, the blur limit), the noise and the outliers, drawn from the front end's own
``numpy.random.Generator`` (numba draws the same numbers as numpy from the same Generator, in
the same order as ``MeasurementFrontEnd.capture``)."""

from __future__ import annotations

import numpy as np
from numba import njit

from latency.compiled import layout, rotations
from latency.compiled.cache import compiled_in
from latency.compiled.layout import (
    _FE_HAS,
    _FE_LAST,
    _FE_LOST,
    _FE_MOTION,
    _FE_SINCE,
    _P_BLUR,
    _P_CAL_HAZ,
    _P_CAL_ON,
    _P_CAL_PER,
    _P_DROPOUT,
    _P_EXPOSURE,
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
)
from latency.compiled.rotations import _unit
from latency.numba_cache import drop_stale_cache
from observer import cor_solver
from observer.cor_solver import _residual_jac
from plant import attitude
from plant.attitude import _hamilton

#: The modules whose code these kernels compile in (``cache``).
COMPILED_IN = compiled_in((cor_solver, attitude), (layout, rotations))
drop_stale_cache(__file__, COMPILED_IN)


@njit(cache=True)
def _project(q, P, t_cor, intr):
    """Marker pixels (2, 2) at attitude q: the CoR model's projection (``observer.cor_model``,
    the same as ``plant.camera.marker_pixels`` for a lens without tangential distortion).

    Compiled mirror of ``plant.camera.marker_pixels``."""
    r, _ = _residual_jac(q, P, np.zeros((P.shape[0], 2)), t_cor, intr)
    return -r.reshape(P.shape[0], 2)


@njit(cache=True)
def _roi_misses(st, par, truth):
    """Whether a marker's true centre (``truth`` (2, 2), sensor px) lies outside the region of
    interest, centred on the sensor or on the mean predicted marker position, shifted to lie
    on the sensor.

    Compiled mirror of ``plant.camera_mode.RegionOfInterest.contains`` and
    ``plant.camera_mode.RegionOfInterest.centre_px``."""
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
    """The largest marker travel (sensor px) over the camera's exposure at the body rate w
    (rad/s) about the attitude q, from the attitudes half an exposure either side.

    Compiled mirror of ``latency.loss_model.blur_travel_px``."""
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
def _p_lost(st, q, w, par, P, t_cor, intr, truth):
    """The probability that the calibrated loss model loses this frame, on the front end's
    state, from the true pixels ``truth`` (2, 2) and the attitude q and body rate w.

    Compiled mirror of ``latency.loss_model.LossModel.p_lost`` and
    ``latency.loss_model.prediction_offset_px``."""
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
    return 0.5 * (1.0 + np.tanh(0.5 * x))


@njit(cache=True)
def _capture(st, q, w, par, P, t_cor, intr, rng, meas):
    """A frame's capture at the attitude q and body rate w (rad/s): writes the measured pixels
    into ``meas`` (NaN when lost) and returns (true pixels, lost, reason code of
    ``CAPTURE_REASONS``). Draws from ``rng`` as ``MeasurementFrontEnd.capture`` does.

    Compiled mirror of ``latency.frontends.MeasurementFrontEnd.capture``."""
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
        if rng.random() < _p_lost(st, q, w, par, P, t_cor, intr, truth):
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
