"""95 % confidence intervals for the Monte-Carlo points of the study.

* A mean over seeds (e.g. the RMS attitude error of a point): percentile bootstrap of the mean
  (``scipy.stats.bootstrap``; Efron & Tibshirani, *An Introduction to the Bootstrap*, 1993,
  §13). Seeds are independent runs, so the per-seed values are resampled with replacement.
* A fraction of runs (e.g. the probability of loss of control, ``k`` of ``n`` runs): the Wilson
  score interval (Wilson, JASA 22(158), 1927; ``scipy.stats.binomtest``), which keeps its
  coverage near the nominal level for small ``n`` and for fractions near 0 or 1, where the
  normal approximation collapses to a zero-width interval.
* A fraction of frames averaged over runs (e.g. the lost-frame fraction): the bootstrap of the
  runs' fractions, except when no run lost a frame (or every run lost all): a bootstrap then has
  no spread to resample and would claim the zero-width interval [0, 0]. The interval is then the
  exact (Clopper-Pearson) binomial interval of 0 (or all) in the pooled frames
  (``frame_fraction_ci``). Frames of a run are correlated (losses come in bursts), so the pooled
  frames overstate the information and this is the narrowest defensible interval, not a wide one.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
import scipy.stats
from numpy.typing import ArrayLike

CONFIDENCE = 0.95
N_RESAMPLES = 2000  # bootstrap resamples; our choice (the percentile ends vary by < 2 % of width)


def bootstrap_mean_ci(
    values: ArrayLike, confidence: float = CONFIDENCE, seed: int = 0
) -> tuple[float, float, float]:
    """``(mean, low, high)`` of the mean of ``values`` (NaN ignored), percentile bootstrap.

    With one finite value the interval is ``(nan, nan)``: one run says nothing about spread.
    The generator is seeded, so a table is reproducible.
    """
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan"), float("nan"), float("nan")
    mean = float(np.mean(x))
    if x.size < 2 or np.all(x == x[0]):
        return (mean, float("nan"), float("nan")) if x.size < 2 else (mean, mean, mean)
    res = scipy.stats.bootstrap(
        (x,), np.mean, confidence_level=confidence, n_resamples=N_RESAMPLES,
        method="percentile", rng=np.random.default_rng(seed),
    )
    return mean, float(res.confidence_interval.low), float(res.confidence_interval.high)


def frame_fraction_ci(
    lost_frames: ArrayLike, frames: ArrayLike, confidence: float = CONFIDENCE, seed: int = 0
) -> tuple[float, float, float]:
    """``(mean, low, high)`` of the mean over runs of ``lost_frames / frames`` (one entry per
    run): ``bootstrap_mean_ci`` of the runs' fractions, or, when none or all of the pooled frames
    are lost, the exact binomial interval of the pooled frames (module docstring)."""
    k = np.asarray(lost_frames, dtype=float)
    n = np.asarray(frames, dtype=float)
    if k.shape != n.shape or np.any(n <= 0) or np.any((k < 0) | (k > n)):
        raise ValueError("need one (lost, frames) pair per run, 0 <= lost <= frames, frames > 0")
    k_all, n_all = int(k.sum()), int(n.sum())
    if 0 < k_all < n_all:
        return bootstrap_mean_ci(k / n, confidence, seed)
    ci = scipy.stats.binomtest(k_all, n_all).proportion_ci(confidence, method="exact")
    return k_all / n_all, float(ci.low), float(ci.high)


def wilson_ci(k: int, n: int, confidence: float = CONFIDENCE) -> tuple[float, float, float]:
    """``(k/n, low, high)``: the Wilson score interval of a fraction of ``k`` in ``n`` runs."""
    if n <= 0:
        return float("nan"), float("nan"), float("nan")
    ci = scipy.stats.binomtest(int(k), int(n)).proportion_ci(confidence, method="wilson")
    return k / n, float(ci.low), float(ci.high)


def widest_wilson_width(n: int, confidence: float = CONFIDENCE) -> float:
    """The width of the widest Wilson interval (``wilson_ci``) of a fraction of ``n`` runs:
    the one at half the runs, k = n // 2 (the width grows with p (1 - p)). Closed form (Wilson
    1927): ``2 z / (1 + z²/n) sqrt(p (1 - p) / n + z² / (4 n²))`` with p = k / n."""
    if n <= 0:
        raise ValueError(f"n must be a positive number of runs, got {n}")
    z = float(scipy.stats.norm.ppf(0.5 + 0.5 * confidence))
    p = (n // 2) / n
    return 2.0 * z / (1.0 + z * z / n) * float(np.sqrt(p * (1.0 - p) / n + z * z / (4.0 * n * n)))


def intervals_overlap(a: tuple[float, float, float], b: tuple[float, float, float]) -> bool:
    """Two ``(value, low, high)`` intervals overlap; an interval without ends (NaN: every run
    equal, or one run) stands for its value."""
    lo_a, hi_a = (a[1], a[2]) if np.isfinite(a[1]) else (a[0], a[0])
    lo_b, hi_b = (b[1], b[2]) if np.isfinite(b[1]) else (b[0], b[0])
    return bool(lo_a <= hi_b + 1e-12 and lo_b <= hi_a + 1e-12)


def seed_intervals(
    runs: pd.DataFrame,
    by: Sequence[str],
    means: Sequence[str] = ("rms_error_deg", "lost_frame_fraction"),
    fractions: Sequence[str] = ("loss_of_control",),
    frame_counts: Mapping[str, tuple[str, str]] | None = None,
) -> pd.DataFrame:
    """One row per group of ``runs`` (one run per row, e.g. one seed) with 95 % intervals.

    For each column ``c`` of ``means``: ``c`` (the mean over the group's runs), ``c_lo`` and
    ``c_hi`` (bootstrap; for a fraction of frames named in ``frame_counts`` with its columns
    of lost and processed frames, ``frame_fraction_ci`` when every run of the group has its
    counts). For each 0/1 column ``f`` of ``fractions``: ``p_f`` (the fraction of
    runs with 1), ``p_f_lo``, ``p_f_hi`` (Wilson). Also ``n_runs``.
    """
    rows = []
    for key, g in runs.groupby(list(by), sort=True):
        row = dict(zip(by, key if isinstance(key, tuple) else (key,), strict=True))
        row["n_runs"] = len(g)
        for c in means:
            counts = (frame_counts or {}).get(c)
            if counts is not None and g[list(counts)].notna().all(axis=None):
                row[c], row[f"{c}_lo"], row[f"{c}_hi"] = frame_fraction_ci(*(g[k] for k in counts))
            else:
                row[c], row[f"{c}_lo"], row[f"{c}_hi"] = bootstrap_mean_ci(g[c])
        for f in fractions:
            flags = g[f].to_numpy(dtype=float)
            flags = flags[np.isfinite(flags)]
            row[f"p_{f}"], row[f"p_{f}_lo"], row[f"p_{f}_hi"] = wilson_ci(
                int(np.sum(flags > 0.5)), len(flags)
            )
        rows.append(row)
    return pd.DataFrame(rows)
