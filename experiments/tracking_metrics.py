"""Per-marker metrics of the tracking benchmark (seed 000 §4.2, ``experiments.tracking_bench``).

**Metrics** (seed 000 §4.2 and the OTB conventions it follows):

* centre location error: Euclidean distance between the reported and the true centre in
  full-sensor px; a frame without a finite centre counts as an infinite error. Lost flags do not
  change the error: a flagged guess that happens to be close still counts as close.
* precision curve: fraction of frames with error ≤ t for t = 0, 1, …, 50 px; precision at 20 px
  is the seed's figure.
* success: IoU of the reported and the true box; the success curve is the fraction of frames
  with IoU > t for t = 0, 0.05, …, 1 and its AUC the mean over those 21 thresholds (OTB).
* latency: median, p95 and mean of the compute time; FPS = 1 / mean (seed 000 Table 1:
  61.23 FPS = 1/16.33 ms).
* the same precision over the frames in which the tracker *measured* the marker
  (``*_precision_20px_measured``; ``*_predicted_frames`` counts the frames left out): the
  accuracy of what an attitude back end is given (``observer.tracking.attitude_input``);
* re-acquisition after the occlusion (frames 100-110): the number of frames after the last
  occluded frame until the marker is again *measured* (not predicted) within 20 px and stays
  within 20 px for 5 frames (our choice); 0 = on the first visible frame, inf = never.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Centre-error thresholds of the precision curve, full-sensor px (seed 000 §4.2, Figure 11).
THRESHOLDS_PX = np.arange(0.0, 51.0)
#: The seed's precision threshold, sensor px (seed 000 §4.2).
PRECISION_PX = 20.0
#: IoU thresholds of the success curve (OTB: 0, 0.05, …, 1).
IOU_THRESHOLDS = np.linspace(0.0, 1.0, 21)
#: Frames in a row within the threshold that confirm a re-acquisition (our choice).
REACQUIRE_HOLD = 5


def centre_errors(pred_px: ArrayLike, true_px: ArrayLike) -> NDArray[np.float64]:
    """Centre location errors (N,), px, of predictions (N, 2) against truth (N, 2); a
    non-finite prediction gives +inf (a frame with a NaN truth gives NaN: not scored)."""
    p = np.asarray(pred_px, dtype=float).reshape(-1, 2)
    t = np.asarray(true_px, dtype=float).reshape(-1, 2)
    e = np.hypot(*(p - t).T)
    e[~np.all(np.isfinite(p), axis=1)] = np.inf
    e[~np.all(np.isfinite(t), axis=1)] = np.nan
    return e


def precision_curve(
    errors: ArrayLike, thresholds: ArrayLike = THRESHOLDS_PX
) -> NDArray[np.float64]:
    """Fraction of scored frames (finite or infinite error; NaN = not scored) with error ≤ t."""
    e = np.asarray(errors, dtype=float)
    e = e[~np.isnan(e)]
    th = np.asarray(thresholds, dtype=float)
    if e.size == 0:
        return np.full(th.shape, np.nan)
    return np.mean(e[None, :] <= th[:, None], axis=1)


def precision_at(errors: ArrayLike, threshold_px: float = PRECISION_PX) -> float:
    """Precision at one threshold (seed 000 §4.2: 20 px)."""
    return float(precision_curve(errors, [threshold_px])[0])


def box_iou(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """IoU (N,) of boxes (N, 4) (x, y, w, h); 0 where a box is not finite or empty."""
    A = np.asarray(a, dtype=float).reshape(-1, 4)
    B = np.asarray(b, dtype=float).reshape(-1, 4)
    x0 = np.maximum(A[:, 0], B[:, 0])
    y0 = np.maximum(A[:, 1], B[:, 1])
    x1 = np.minimum(A[:, 0] + A[:, 2], B[:, 0] + B[:, 2])
    y1 = np.minimum(A[:, 1] + A[:, 3], B[:, 1] + B[:, 3])
    inter = np.clip(x1 - x0, 0.0, None) * np.clip(y1 - y0, 0.0, None)
    union = A[:, 2] * A[:, 3] + B[:, 2] * B[:, 3] - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = inter / union
    ok = np.all(np.isfinite(A), axis=1) & np.all(np.isfinite(B), axis=1) & (union > 0)
    return np.where(ok, iou, 0.0)


def success_curve(ious: ArrayLike, thresholds: ArrayLike = IOU_THRESHOLDS) -> NDArray[np.float64]:
    """Fraction of frames with IoU > t for each threshold t."""
    v = np.asarray(ious, dtype=float)
    th = np.asarray(thresholds, dtype=float)
    if v.size == 0:
        return np.full(th.shape, np.nan)
    return np.mean(v[None, :] > th[:, None], axis=1)


def success_auc(ious: ArrayLike, thresholds: ArrayLike = IOU_THRESHOLDS) -> float:
    """Area under the success curve: its mean over the (equally spaced) thresholds (OTB)."""
    return float(np.mean(success_curve(ious, thresholds)))


def latency_stats(times_s: ArrayLike) -> dict[str, float]:
    """Median, p95 and mean latency (ms) and FPS = 1 / mean of per-frame compute times (s)."""
    t = np.asarray(times_s, dtype=float)
    t = t[np.isfinite(t)]
    if t.size == 0:
        return {"latency_median_ms": math.nan, "latency_p95_ms": math.nan,
                "latency_mean_ms": math.nan, "fps": math.nan}
    return {
        "latency_median_ms": 1e3 * float(np.median(t)),
        "latency_p95_ms": 1e3 * float(np.percentile(t, 95)),
        "latency_mean_ms": 1e3 * float(np.mean(t)),
        "fps": 1.0 / float(np.mean(t)),
    }


def reacquisition_frames(
    errors: ArrayLike,
    measured: ArrayLike,
    first_visible: int,
    threshold_px: float = PRECISION_PX,
    hold: int = REACQUIRE_HOLD,
) -> float:
    """Frames after an occlusion until re-acquisition (see the module docstring).

    ``errors`` and ``measured`` are per frame (index = frame number); ``first_visible`` is the
    first frame after the occlusion. Returns k - first_visible for the first frame k ≥
    first_visible that is measured with error ≤ threshold and whose next ``hold`` frames (as
    many as exist) stay within the threshold; inf if none.
    """
    e = np.asarray(errors, dtype=float)
    m = np.asarray(measured, dtype=bool)
    n = len(e)
    for k in range(int(first_visible), n):
        if m[k] and e[k] <= threshold_px:
            nxt = e[k:min(k + hold, n)]
            if np.all(nxt <= threshold_px):
                return float(k - first_visible)
    return math.inf
