"""The accuracy of a tracking run's attitudes against a known truth (rendered or bench data).

A run's table (``experiments.track.run_track``) says on what each attitude rests
(``attitude_source``); these summaries count only the frames whose two markers were measured
unless asked otherwise, and say how many frames with a predicted marker they left out.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from observer.tracking import ATTITUDE_SOURCES
from plant import attitude


def attitude_errors_deg(table: pd.DataFrame, q_true: Sequence[ArrayLike],
                        include_predicted: bool = False) -> NDArray[np.float64]:
    """Geodesic angle (deg) between each row's attitude and ``q_true[frame_index]``; NaN where
    the run has no attitude and, unless ``include_predicted``, where the attitude does not rest
    on two measured markers (``attitude_source``)."""
    q = table[["q_w", "q_x", "q_y", "q_z"]].to_numpy()
    qt = np.asarray(q_true, dtype=float)[table["frame_index"].to_numpy(int)]
    err = np.full(len(q), np.nan)
    ok = np.all(np.isfinite(q), axis=1)
    if not include_predicted:
        ok &= measured_rows(table)
    if ok.any():
        err[ok] = np.rad2deg(attitude.geodesic_angle(q[ok], qt[ok]))
    return err


def measured_rows(table: pd.DataFrame) -> NDArray[np.bool_]:
    """Rows whose attitude rests on two measured markers."""
    return (table["attitude_source"] == ATTITUDE_SOURCES[0]).to_numpy(bool)


def attitude_accuracy(table: pd.DataFrame, q_true: Sequence[ArrayLike],
                      include_predicted: bool = False) -> dict[str, float]:
    """Median, RMS and largest geodesic attitude error (deg) against ``q_true[frame_index]``
    over the frames with an attitude resting on two measured markers (all frames with an
    attitude when ``include_predicted``), how many frames were scored and how many frames with
    a predicted marker were left out."""
    err = attitude_errors_deg(table, q_true, include_predicted)
    scored = err[np.isfinite(err)]
    left_out = 0 if include_predicted else int((~measured_rows(table)).sum())
    stats = {"median_deg": float(np.median(scored)),
             "rms_deg": float(np.sqrt(np.mean(scored ** 2))),
             "max_deg": float(scored.max())} if scored.size else \
        {"median_deg": np.nan, "rms_deg": np.nan, "max_deg": np.nan}
    return {**stats, "frames_scored": float(scored.size),
            "predicted_frames_left_out": float(left_out)}
