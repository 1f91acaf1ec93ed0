"""The tracking benchmark of seed 000 §4: metrics per marker, runs, tables and plots.

One module of about 920 lines: its parts (metrics, runs, tables, plots, the whole benchmark) form
one pipeline that only the benchmark uses; the seams are the section comments below.

**Protocol.** A pair tracker (``observer.trackers``) is started on frame 0 with the true boxes of
both markers and stepped through frames 1 … N-1; frame 0 is not scored. The trackers of a
benchmark take turns frame by frame (``run_trackers``), so that on a shared machine they all meet
the same background load and latency ratios are fair. Per frame and marker
(main = red, auxiliary = yellow) we keep the reported centre and box (full-sensor px), the lost
and measured flags and the tracker's measured compute time (``PairResult.compute_time_s``,
``time.perf_counter`` around the whole step).

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

The seed's numbers (Table 1 and §4.2-4.3) are kept in ``SEED_TABLE1`` and ``SEED_PRECISION``
for the side-by-side tables. ``run_benchmark`` returns tidy pandas tables; ``plot_*`` write the
PNG figures (precision curves like seed Figures 11, 12a/c, 14a/c; error over frames like 12b/d,
14b/d). ``run_tracking_benchmark`` composes the whole benchmark (trackers by name, validation
sequences, metrics CSV, plots, tables, the targets): ``benchmarks/bench_tracking.py`` and
``pmspm bench-trackers`` both call it.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from numpy.typing import ArrayLike, NDArray

from experiments.sequences import OCCLUSION_FRAMES, TrackingSequence
from latency.models import SEED_FPS, seed_latency_ms
from observer.trackers import MARKERS
from observer.tracking import PairResult, PairTracker, attitude_source

#: Centre-error thresholds of the precision curve, full-sensor px (seed 000 §4.2, Figure 11).
THRESHOLDS_PX = np.arange(0.0, 51.0)
#: The seed's precision threshold, sensor px (seed 000 §4.2).
PRECISION_PX = 20.0
#: IoU thresholds of the success curve (OTB: 0, 0.05, …, 1).
IOU_THRESHOLDS = np.linspace(0.0, 1.0, 21)
#: Frames in a row within the threshold that confirm a re-acquisition (our choice).
REACQUIRE_HOLD = 5
MARKER_NAMES = ("main", "aux")

#: Seed 000 Table 1 (RTX 4060 laptop GPU): algorithm -> (FPS, latency ms).
SEED_TABLE1: dict[str, tuple[float, float]] = {
    name: (SEED_FPS[name], seed_latency_ms(name)) for name in SEED_FPS
}
#: Seed 000 §4.2-4.3 precision at 20 px: (algorithm, case) -> (main, aux). For KCF under
#: occlusion the seed gives one number (0.295).
SEED_PRECISION: dict[tuple[str, str], tuple[float, float]] = {
    ("gk_transt", "clean"): (0.909, 0.944),
    ("dual_transt", "clean"): (0.909, 0.917),
    ("csrt", "clean"): (0.947, 0.971),
    ("kcf", "clean"): (0.894, 0.868),
    ("gk_transt", "occlusion"): (0.891, 0.944),
    ("kcf", "occlusion"): (0.295, 0.295),
    ("gk_transt", "blur"): (0.897, 0.926),
    ("kcf", "blur"): (0.428, 0.431),
}


# --- metrics ------------------------------------------------------------------------------------
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


# --- runs ---------------------------------------------------------------------------------------
@dataclass
class TrackRun:
    """One tracker on one sequence: per-frame outputs (index = frame number; frame 0 holds the
    start boxes and is not scored).

    Attributes
    ----------
    tracker, sequence, case : names.
    marker_px : (N, 2, 2) reported centres, sensor px.
    boxes_px : (N, 2, 4) reported boxes, sensor px.
    lost, measured : (N, 2) flags per marker.
    compute_time_s : (N,) per-frame compute time, s (NaN at frame 0).
    reasons : per-frame reasons.
    """

    tracker: str
    sequence: str
    case: str
    marker_px: NDArray[np.float64]
    boxes_px: NDArray[np.float64]
    lost: NDArray[np.bool_]
    measured: NDArray[np.bool_]
    compute_time_s: NDArray[np.float64]
    reasons: list[str] = field(default_factory=list)

    def errors(self, seq: TrackingSequence) -> NDArray[np.float64]:
        """(N, 2) centre errors, sensor px, main then aux (frame 0 NaN: not scored)."""
        e = np.stack([centre_errors(self.marker_px[:, m], seq.marker_px[:, m])
                      for m in range(2)], axis=1)
        e[0] = np.nan
        return e

    def frames_table(self, seq: TrackingSequence) -> pd.DataFrame:
        """One row per frame: the reported centres (sensor px), the lost and measured flags
        (the tracker's own), ``attitude_source``, the centre errors (sensor px) and the compute
        time (s); frame 0 is the start (the true boxes)."""
        e = self.errors(seq)
        rows = {"tracker": self.tracker, "sequence": self.sequence, "case": self.case,
                "frame": np.arange(len(self.marker_px))}
        for m, colour in enumerate(MARKERS):
            rows |= {f"{colour}_u_px": self.marker_px[:, m, 0],
                     f"{colour}_v_px": self.marker_px[:, m, 1],
                     f"{colour}_lost": self.lost[:, m], f"{colour}_measured": self.measured[:, m],
                     f"{colour}_error_px": e[:, m]}
        rows["attitude_source"] = [attitude_source(*f) for f in self.measured]
        rows["compute_time_s"] = self.compute_time_s
        return pd.DataFrame(rows)

    def ious(self, seq: TrackingSequence) -> NDArray[np.float64]:
        """(N, 2) IoU with the true boxes (frame 0 NaN)."""
        v = np.stack([box_iou(self.boxes_px[:, m], seq.boxes_px[:, m]) for m in range(2)],
                     axis=1)
        v[0] = np.nan
        return v


def run_trackers(
    trackers: Sequence[PairTracker],
    seq: TrackingSequence,
    interleave: bool = True,
    on_step: Callable[[], None] | None = None,
) -> list[TrackRun]:
    """Start each tracker on frame 0 with the true boxes and step it through the sequence.

    With ``interleave`` (default) the trackers take turns frame by frame, in an order rotated
    by one every frame, so that on a shared machine they meet the same background load and
    their latency ratio is measured fairly; each keeps its own state, so the results are those
    of separate runs. Otherwise each runs through the whole sequence in turn. ``on_step`` is
    called once per scored frame (after every tracker has processed it), for a progress bar.
    """
    n, m = seq.n_frames, len(trackers)
    marker = np.full((m, n, 2, 2), np.nan)
    boxes = np.full((m, n, 2, 4), np.nan)
    lost = np.zeros((m, n, 2), bool)
    measured = np.zeros((m, n, 2), bool)
    times = np.full((m, n), np.nan)
    reasons = [[""] * n for _ in range(m)]

    def one(i: int, k: int) -> None:
        r: PairResult = trackers[i].step(seq.images[k])
        marker[i, k] = r.marker_px
        boxes[i, k] = r.boxes_px
        lost[i, k] = (r.red_lost, r.yellow_lost)
        measured[i, k] = (r.red_measured, r.yellow_measured)
        times[i, k] = r.compute_time_s
        reasons[i][k] = r.reason

    for i, tr in enumerate(trackers):
        tr.start(seq.images[0], seq.boxes_px[0], seq.binning)
        marker[i, 0], boxes[i, 0], measured[i, 0] = seq.marker_px[0], seq.boxes_px[0], True
    if interleave:
        for k in range(1, n):
            for j in range(m):
                one((j + k) % m, k)
            if on_step:
                on_step()
    else:
        for i in range(m):
            for k in range(1, n):
                one(i, k)
                if on_step and i == m - 1:
                    on_step()
    return [TrackRun(tr.name, seq.name, seq.case, marker[i], boxes[i], lost[i], measured[i],
                     times[i], reasons[i]) for i, tr in enumerate(trackers)]


def run_tracker(tracker: PairTracker, seq: TrackingSequence) -> TrackRun:
    """Start ``tracker`` on frame 0 with the true boxes and step it through the sequence."""
    return run_trackers([tracker], seq)[0]


def evaluate(run: TrackRun, seq: TrackingSequence) -> dict[str, float | str]:
    """One row of metrics for a run: per marker precision@20 px, success AUC, median error,
    lost and measured fractions, re-acquisition frames (occlusion case), and the latency."""
    e = run.errors(seq)
    v = run.ious(seq)
    row: dict[str, float | str] = {"tracker": run.tracker, "sequence": run.sequence,
                                   "case": run.case, "frames": float(seq.n_frames - 1)}
    occl = np.flatnonzero(seq.occluded)
    for m, name in enumerate(MARKER_NAMES):
        em = e[1:, m]
        row[f"{name}_precision_20px"] = precision_at(em)
        measured = run.measured[1:, m]
        row[f"{name}_precision_20px_measured"] = precision_at(np.where(measured, em, np.nan))
        row[f"{name}_predicted_frames"] = float(np.sum(~measured))
        row[f"{name}_success_auc"] = success_auc(v[1:, m])
        row[f"{name}_err_median_px"] = float(np.nanmedian(np.where(np.isinf(em), 1e9, em)))
        row[f"{name}_lost_fraction"] = float(np.mean(run.lost[1:, m]))
        row[f"{name}_measured_fraction"] = float(np.mean(run.measured[1:, m]))
        # reported as measured but more than 20 px off: what a trust rule must keep at zero
        row[f"{name}_wrong_measured_fraction"] = float(
            np.mean(run.measured[1:, m] & ~(em <= PRECISION_PX)))
        if occl.size:
            row[f"{name}_reacquire_frames"] = reacquisition_frames(
                e[:, m], run.measured[:, m], int(occl.max()) + 1)
    row.update(latency_stats(run.compute_time_s[1:]))
    return row


TrackerFactory = Callable[[], PairTracker]


def run_benchmark(
    trackers: dict[str, TrackerFactory],
    sequences: Iterable[TrackingSequence | Callable[[], TrackingSequence]],
    progress: Callable[[str], None] | None = None,
    keep_images: bool = True,
    interleave: bool = True,
    on_step: Callable[[], None] | None = None,
) -> tuple[pd.DataFrame, list[TrackRun], list[TrackingSequence]]:
    """Run every tracker on every sequence (a fresh tracker per run; frame-interleaved, see
    ``run_trackers``; ``on_step`` once per scored frame of each sequence).

    ``sequences`` may hold sequences or callables that render one (rendered one at a time).
    The returned sequences keep their ground truth for the plots; with ``keep_images=False``
    their frames are dropped after the runs (a 300-frame sequence holds 280 MB of images).
    Returns (metrics table, runs, sequences).
    """
    rows, runs, seqs = [], [], []
    for s in sequences:
        seq = s() if callable(s) else s
        if progress:
            progress(f"{', '.join(trackers)} on {seq.name}")
        built = [make() for make in trackers.values()]
        runs_here = run_trackers(built, seq, interleave, on_step)
        for name, run in zip(trackers, runs_here, strict=True):
            run.tracker = name
            runs.append(run)
            rows.append(evaluate(run, seq))
        if not keep_images:
            seq = replace(seq, images=np.zeros((seq.n_frames, 1, 1, 3), np.uint8))
        seqs.append(seq)
    return pd.DataFrame(rows), runs, seqs


def pooled_precision(
    runs: Sequence[TrackRun], seqs: Sequence[TrackingSequence], tracker: str, case: str
) -> NDArray[np.float64]:
    """(2, T) precision curves (main, aux) over all frames of a tracker's runs in one case."""
    by_name = {s.name: s for s in seqs}
    errs = [r.errors(by_name[r.sequence])[1:] for r in runs
            if r.tracker == tracker and r.case == case]
    if not errs:
        return np.full((2, len(THRESHOLDS_PX)), np.nan)
    e = np.concatenate(errs)
    return np.stack([precision_curve(e[:, m]) for m in range(2)])


def summary_table(metrics: pd.DataFrame) -> pd.DataFrame:
    """Mean over sequences per (tracker, case) of precision, AUC and re-acquisition, with the
    seed's precision beside it."""
    cols = [c for c in metrics.columns if c.endswith(("precision_20px", "success_auc",
                                                      "reacquire_frames", "lost_fraction",
                                                      "err_median_px",
                                                      "wrong_measured_fraction"))]
    g = metrics.groupby(["tracker", "case"], sort=False)[cols].mean().reset_index()
    g["seed_main_precision"] = [SEED_PRECISION.get((t, c), (math.nan, math.nan))[0]
                                for t, c in zip(g.tracker, g.case, strict=True)]
    g["seed_aux_precision"] = [SEED_PRECISION.get((t, c), (math.nan, math.nan))[1]
                               for t, c in zip(g.tracker, g.case, strict=True)]
    return g


def table1(runs: Sequence[TrackRun], cases: Sequence[str] | None = None) -> pd.DataFrame:
    """Seed Table 1 measured here: per tracker FPS (1/mean) and latency (median, mean, p95) over
    all scored frames of its runs (optionally only ``cases``), beside the seed's figures, with
    the GK-TransT / dual-TransT ratio of median latencies when both ran."""
    rows = []
    for name in dict.fromkeys(r.tracker for r in runs):
        t = np.concatenate([r.compute_time_s[1:] for r in runs if r.tracker == name
                            and (cases is None or r.case in cases)])
        st = latency_stats(t)
        seed = SEED_TABLE1.get(name, (math.nan, math.nan))
        rows.append({"algorithm": name, "fps": st["fps"],
                     "latency_median_ms": st["latency_median_ms"],
                     "latency_mean_ms": st["latency_mean_ms"],
                     "latency_p95_ms": st["latency_p95_ms"], "frames": float(len(t)),
                     "seed_fps": seed[0], "seed_latency_ms": seed[1]})
    return pd.DataFrame(rows)


def latency_ratio(table: pd.DataFrame, num: str = "gk_transt", den: str = "dual_transt",
                  column: str = "latency_median_ms") -> float:
    """Ratio of two trackers' latencies from a ``table1`` (seed: 16.33 / 31.23 = 0.523)."""
    t = table.set_index("algorithm")
    if num not in t.index or den not in t.index:
        return math.nan
    return float(t.loc[num, column] / t.loc[den, column])


# --- plots --------------------------------------------------------------------------------------
def plot_precision_curves(
    runs: Sequence[TrackRun], seqs: Sequence[TrackingSequence], case: str
) -> Figure:
    """Precision curves of every tracker in one case, main and auxiliary marker side by side
    (seed Figure 11; 12a/c and 14a/c for the occlusion and blur cases)."""
    fig = Figure(figsize=(10, 4))
    axes = fig.subplots(1, 2, sharey=True)
    for name in dict.fromkeys(r.tracker for r in runs if r.case == case):
        curves = pooled_precision(runs, seqs, name, case)
        for m, ax in enumerate(axes):
            p20 = curves[m][int(PRECISION_PX)]
            ax.plot(THRESHOLDS_PX, curves[m], label=f"{name} [{p20:.3f}]")
    for m, ax in enumerate(axes):
        ax.axvline(PRECISION_PX, color="0.6", lw=0.8, ls="--")
        ax.set_title(f"{('main (red)', 'auxiliary (yellow)')[m]} marker, {case}")
        ax.set_xlabel("centre location error threshold (sensor px)")
        ax.set_xlim(0, THRESHOLDS_PX[-1])
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right", fontsize=8)
    axes[0].set_ylabel("precision")
    fig.tight_layout()
    return fig


def plot_error_curves(
    runs: Sequence[TrackRun], seq: TrackingSequence, ymax_px: float = 100.0
) -> Figure:
    """Centre error over frames of every tracker on one sequence, main and auxiliary marker
    (seed Figures 12b/d, 14b/d); disturbed frames shaded; errors beyond ``ymax_px`` leave the
    chart as in the seed's figures."""
    fig = Figure(figsize=(10, 6))
    axes = fig.subplots(2, 1, sharex=True)
    frames = np.arange(seq.n_frames)
    for r in runs:
        if r.sequence != seq.name:
            continue
        e = r.errors(seq)
        for m, ax in enumerate(axes):
            # a frame without an estimate (inf) is drawn off the chart; frame 0 (NaN) is not
            ax.plot(frames, np.where(np.isinf(e[:, m]), 10 * ymax_px, e[:, m]), lw=1,
                    label=r.tracker)
    for m, ax in enumerate(axes):
        for flags, colour, label in ((seq.occluded, "0.3", "occluded"),
                                     (seq.blurred, "tab:orange", "blurred")):
            idx = np.flatnonzero(flags)
            if idx.size:
                ax.axvspan(idx.min() - 0.5, idx.max() + 0.5, color=colour, alpha=0.15,
                           label=label)
        ax.axhline(PRECISION_PX, color="0.6", lw=0.8, ls="--")
        ax.set_ylim(0, ymax_px)
        ax.set_ylabel(f"{MARKER_NAMES[m]} error (sensor px)")
        ax.grid(alpha=0.3)
    axes[0].set_title(f"centre location error, {seq.name}")
    axes[0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[1].set_xlabel("frame")
    fig.tight_layout()
    return fig


def markdown_table(df: pd.DataFrame, floatfmt: str = ".3f") -> str:
    """A pandas table as GitHub markdown (without the optional ``tabulate`` dependency)."""
    cols = list(df.columns)
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, row in df.iterrows():
        cells = []
        for c in cols:
            v = row[c]
            cells.append(format(v, floatfmt) if isinstance(v, (float, np.floating)) else str(v))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


# --- the whole benchmark: bench_tracking.py and ``pmspm bench-trackers`` -------------------------
#: The benchmark's trackers: names of ``observer.trackers.make_pair_tracker`` plus
#: ``gk_transt_norefine`` (GK-TransT without the sub-pixel circle fit: the seed's algorithm) and
#: ``dual_transt_refine`` (dual TransT with the circle fit), so that the latency ratio can be
#: taken like for like both ways.
DEFAULT_TRACKERS: tuple[str, ...] = ("gk_transt", "gk_transt_norefine", "dual_transt",
                                     "dual_transt_refine", "kcf", "csrt", "kcf_numpy", "k2cf")
#: GK-TransT / dual TransT latency ratios reported (numerator, denominator, what is compared).
RATIO_PAIRS: tuple[tuple[str, str, str], ...] = (
    ("gk_transt_norefine", "dual_transt", "the seed's algorithms: box centres on both sides"),
    ("gk_transt", "dual_transt_refine", "both with the sub-pixel circle fit"),
    ("gk_transt", "dual_transt", "the defaults: GK-TransT with, dual TransT without the fit"),
)
#: The targets for GK-TransT: precision at 20 px (clean; occlusion and blur), the median
#: latency (seed 000 Table 1: 16.33 ms) and the GK-TransT / dual TransT latency ratio (seed 0.523).
TARGET_PRECISION_CLEAN = 0.95
TARGET_PRECISION_DISTURBED = 0.90
TARGET_RATIO = 0.6
TARGET_MEDIAN_MS = seed_latency_ms("gk_transt")
#: Targets on the hard cases and held-out appearance families: GK-TransT precision at 20 px on
#: both markers; the network alone (dual TransT: two networks, box centres, no GK) on the clean
#: held-out families: median centre error (one image px at 4x binning) and precision.
TARGET_PRECISION_HARD = 0.95
TARGET_NETWORK_MEDIAN_PX = 4.0
TARGET_NETWORK_PRECISION = 0.95
#: The row that shows the network alone: dual TransT runs one network per marker and reports
#: its box centres, with no GK assistance and no circle fit.
NETWORK_ALONE = "dual_transt"


def case_target(case: str) -> float:
    """GK-TransT's precision target at 20 px for a case."""
    from experiments.sequences import CASES

    if case == "clean":
        return TARGET_PRECISION_CLEAN
    return TARGET_PRECISION_DISTURBED if case in CASES else TARGET_PRECISION_HARD


def min_frames(case: str) -> int:
    """Fewest frames per sequence for a case: 2 (one scored frame) for ``clean`` and the
    held-out appearance families; the disturbance must fit, so ``occlusion`` (frames 100-110)
    needs the occlusion plus ``REACQUIRE_HOLD`` frames after it (116), ``blur`` (frames
    130-160) needs 161 and the hard cases (``HARD_FRAMES``, 100-140) 146."""
    from experiments.sequences import ALL_CASES, BLUR_FRAMES, HARD_FRAMES

    if case not in ALL_CASES:
        raise KeyError(case)
    if case in ("clean", "heldout_pattern", "heldout_lighting"):
        return 2
    return {"occlusion": OCCLUSION_FRAMES.stop + REACQUIRE_HOLD,
            "blur": BLUR_FRAMES.stop}.get(case, HARD_FRAMES.stop + REACQUIRE_HOLD)


def transt_network() -> tuple[Callable[[], object] | None, str]:
    """``TransTTracker.small`` if the shipped weights load, else (None, why)."""
    try:
        from observer.transt.tracker import TransTTracker

        TransTTracker.small()
        return TransTTracker.small, ""
    except Exception as exc:  # noqa: BLE001 - report any reason the network is unavailable
        return None, f"{type(exc).__name__}: {exc}"


def tracker_factories(
    names: Sequence[str], stand_in: bool = False, require_transt: bool = False
) -> tuple[dict[str, TrackerFactory], str]:
    """Factories of the named pair trackers (``DEFAULT_TRACKERS`` names) and a note.

    With ``stand_in`` the numpy KCF takes the TransT network's place in GK-TransT and dual
    TransT (rows ``gk_standin``, ``dual_standin``: not TransT numbers). Without the shipped
    TransT weights (missing, corrupt, or a bad checksum file) the TransT rows are left out and
    the note says which and why, or, with ``require_transt``, ``ValueError`` says so. Unknown
    names raise ``ValueError``."""
    from observer.trackers import PAIR_TRACKERS, make_pair_tracker

    known = tuple(PAIR_TRACKERS) + ("gk_transt_norefine", "dual_transt_refine")
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(f"unknown trackers {unknown}; choose from {', '.join(known)}")
    factories: dict[str, TrackerFactory] = {}
    note = ""
    network = None
    if any(n.startswith(("gk_transt", "dual_transt")) for n in names):
        if stand_in:
            from observer.trackers.kcf_numpy import NumpyKCF

            network, why = NumpyKCF, ""
        else:
            network, why = transt_network()
        if network is None:
            rows = [n for n in names if n.startswith(("gk_transt", "dual_transt"))]
            note = (f"TransT rows {', '.join(rows)} skipped: the shipped network is not "
                    f"available ({why.splitlines()[0]}).")
            if require_transt:
                raise ValueError(
                    f"the trackers {', '.join(rows)} need the shipped TransT network, which "
                    f"is not available:\n  {why}\nRun with --stand-in for a plumbing run, "
                    "or leave these trackers out."
                )
    for name in names:
        if name.startswith(("gk_transt", "dual_transt")):
            if network is None:
                continue
            label = name.replace("_transt", "_standin") if stand_in else name
            kind = name.removesuffix("_norefine").removesuffix("_refine")
            refine = {"_norefine": False, "_refine": True}.get(name[len(kind):])
            factories[label] = (lambda kind=kind, refine=refine: make_pair_tracker(
                kind, refine=refine, transt_factory=network))
        else:
            factories[name] = (lambda name=name: make_pair_tracker(name))
    return factories, note


@dataclass
class BenchmarkReport:
    """What ``run_tracking_benchmark`` measured and wrote.

    Attributes
    ----------
    metrics : one row per (tracker, sequence) (``evaluate``); written as CSV.
    summary : ``summary_table`` of the metrics; table1 : ``table1`` (clean cases if run).
    runs, seqs : the runs and their sequences (images dropped).
    ratio_median, ratio_mean : GK-TransT / dual TransT latency ratios (NaN unless both ran).
    checks : the targets, met or not, one line each (GK-TransT only).
    figures : flat figures for ``benchmarks/RESULTS.md`` (SI units in the names).
    notes : the tables and notes as markdown.
    files : the files written (metrics CSV, per-frame Parquet ``tracking_frames.parquet``,
        plots).
    wall_s : wall time of the runs, s.
    """

    metrics: pd.DataFrame
    summary: pd.DataFrame
    table1: pd.DataFrame
    runs: list[TrackRun]
    seqs: list[TrackingSequence]
    ratio_median: float
    ratio_mean: float
    checks: list[str]
    figures: dict[str, float]
    notes: str
    files: list[Path]
    wall_s: float


def tag_of(stand_in: bool) -> str:
    """What replaces ``_transt`` in the TransT rows' names: ``_standin`` or itself."""
    return "_standin" if stand_in else "_transt"


def unseen_row(network: str) -> str:
    """Name of the rows of ``network`` on the unseen image source (``plant.render_unseen``)."""
    return f"{network}_unseen"


def network_checks(summary: pd.DataFrame, network: str, cases: Sequence[str]) -> list[str]:
    """The network-alone targets on the clean held-out families (or, for the rows of the
    unseen image source, the clean case), one line each."""
    st = summary.set_index(["tracker", "case"])
    out = []
    for case in cases:
        if (network, case) not in st.index:
            continue
        row = st.loc[(network, case)]
        for m in ("main", "aux"):
            med, prec = float(row[f"{m}_err_median_px"]), float(row[f"{m}_precision_20px"])
            ok = med <= TARGET_NETWORK_MEDIAN_PX and prec >= TARGET_NETWORK_PRECISION
            what = ("network alone, unseen renderer" if network.endswith("_unseen")
                    else "network alone")
            out.append(f"{network} ({what}) {case} {m} median error {med:.1f} px "
                       f"(target <= {TARGET_NETWORK_MEDIAN_PX:g}), precision@20px {prec:.3f} "
                       f"(target >= {TARGET_NETWORK_PRECISION}): {'met' if ok else 'NOT met'}")
    return out


def network_and_gk_table(summary: pd.DataFrame, gk: str, network: str) -> str:
    """Markdown table of the network alone beside GK-TransT per case (empty if either is
    missing): precision at 20 px, median error and the fraction of frames reported as measured
    but wrong, per marker."""
    unseen = unseen_row(network)
    rows = summary[summary.tracker.isin([gk, network, unseen])]
    if not {gk, network} <= set(rows.tracker):
        return ""
    cols = ["case", "tracker", "main_precision_20px", "aux_precision_20px",
            "main_err_median_px", "aux_err_median_px", "main_wrong_measured_fraction",
            "aux_wrong_measured_fraction"]
    t = rows[cols].sort_values(["case", "tracker"], kind="stable")
    labels = {network: f"{network} (network alone)",
              unseen: f"{network} (network alone, unseen renderer)"}
    t = t.assign(tracker=[labels.get(n, n) for n in t.tracker])
    return ("Network alone (dual TransT: box centres, no GK) beside GK-TransT (median errors in "
            "sensor px; wrong_measured = reported as measured but more than 20 px off; "
            "unseen renderer = the same motion and case rendered by `plant.render_unseen`, "
            "MuJoCo in a drawn look through a sensor model, never used for training):\n\n"
            + markdown_table(t))


def _torch_note() -> str:
    """The torch thread settings, if torch was loaded (by a TransT tracker)."""
    import os
    import sys

    if "torch" not in sys.modules:
        return "torch not loaded"
    torch = sys.modules["torch"]
    return (f"torch threads {torch.get_num_threads()}, OMP_WAIT_POLICY="
            f"{os.environ.get('OMP_WAIT_POLICY')}")


def _check_arguments(cases: Sequence[str] | None, seeds: int, frames: int) -> list[str]:
    """The benchmark's cases (all of ``CASES`` if None); ``ValueError`` for an unknown case,
    fewer than one seed or fewer frames than a case needs (``min_frames``)."""
    from experiments.sequences import ALL_CASES, CASES

    cases = list(CASES if cases is None else cases)
    bad = [c for c in cases if c not in ALL_CASES]
    if bad or not cases:
        raise ValueError(f"cases must be among {', '.join(ALL_CASES)}, got {cases}")
    if seeds < 1:
        raise ValueError(f"seeds must be >= 1, got {seeds}")
    need = max(min_frames(c) for c in cases)
    if frames < need:
        each = ", ".join(f"{c} {min_frames(c)}" for c in dict.fromkeys(cases))
        raise ValueError(f"frames must be >= {need} for cases {cases} ({each}), got {frames}")
    return cases


def _write_plots(out: Path, runs: list[TrackRun], seqs: list[TrackingSequence],
                 cases: Sequence[str]) -> list[Path]:
    """Per case, the precision curves and the first sequence's error curve, as PNG files."""
    plots = []
    for case in cases:
        first = next(s for s in seqs if s.case == case)
        for fig, path in ((plot_precision_curves(runs, seqs, case),
                           out / f"tracking_precision_{case}.png"),
                          (plot_error_curves(runs, first), out / f"tracking_errors_{case}.png")):
            fig.savefig(path, dpi=110)
            plots.append(path)
    return plots


_Ratio = tuple[str, str, str, float, float]  # (num, den, what, median ratio, mean ratio)


@dataclass(frozen=True)
class _LatencyRatios:
    """The run's latency ratios: ``default`` is GK-TransT over dual TransT as shipped (not like
    for like; NaN unless both ran), ``like_for_like`` the pairs of ``RATIO_PAIRS`` that ran."""

    default: _Ratio
    like_for_like: list[_Ratio]

    @classmethod
    def of(cls, t1: pd.DataFrame, gk: str, dual: str, tag: str) -> _LatencyRatios:
        """From Table 1; ``tag`` names the network (``_transt`` or ``_standin``)."""
        def ratio(num: str, den: str, what: str) -> _Ratio:
            return (num, den, what, latency_ratio(t1, num, den, "latency_median_ms"),
                    latency_ratio(t1, num, den, "latency_mean_ms"))

        pairs = [(num.replace("_transt", tag), den.replace("_transt", tag), what)
                 for num, den, what in RATIO_PAIRS[:2]]
        return cls(ratio(gk, dual, RATIO_PAIRS[2][2]),
                   [ratio(*p) for p in pairs if {p[0], p[1]} <= set(t1.algorithm)])


def _figures(summary: pd.DataFrame, t1: pd.DataFrame, ratios: _LatencyRatios) -> dict[str, float]:
    """Flat figures for ``benchmarks/RESULTS.md`` (SI units in the names)."""
    figures: dict[str, float] = {}
    for _, r in summary.iterrows():
        key = f"{r.tracker}_{r.case}"
        figures[f"{key}_main_precision_20px"] = float(r.main_precision_20px)
        figures[f"{key}_aux_precision_20px"] = float(r.aux_precision_20px)
        figures[f"{key}_main_success_auc"] = float(r.main_success_auc)
        figures[f"{key}_aux_success_auc"] = float(r.aux_success_auc)
        if r.tracker.endswith("_unseen"):
            figures[f"{key}_main_err_median_px"] = float(r.main_err_median_px)
            figures[f"{key}_aux_err_median_px"] = float(r.aux_err_median_px)
        if "main_reacquire_frames" in summary.columns and r.case == "occlusion":
            figures[f"{key}_main_reacquire_frames"] = float(r.main_reacquire_frames)
            figures[f"{key}_aux_reacquire_frames"] = float(r.aux_reacquire_frames)
    for _, r in t1.iterrows():
        figures[f"{r.algorithm}_latency_median_s"] = r.latency_median_ms / 1e3
        figures[f"{r.algorithm}_latency_p95_s"] = r.latency_p95_ms / 1e3
        figures[f"{r.algorithm}_fps"] = float(r.fps)
    for num, den, _, r_med, r_mean in (ratios.default, *ratios.like_for_like):
        figures[f"{num}_over_{den}_median_latency_ratio"] = r_med
        figures[f"{num}_over_{den}_mean_latency_ratio"] = r_mean
    return figures


def _checks(summary: pd.DataFrame, t1: pd.DataFrame, cases: Sequence[str], gk: str, tag: str,
            ratios: _LatencyRatios) -> list[str]:
    """The GK-TransT targets, met or not, one line each (none if GK-TransT did not run)."""
    if gk not in set(summary.tracker):
        return []
    checks = []
    st = summary.set_index(["tracker", "case"])
    for case in cases:
        if (gk, case) not in st.index:
            continue
        target = case_target(case)
        for m in ("main", "aux"):
            v = float(st.loc[(gk, case), f"{m}_precision_20px"])
            checks.append(f"{gk} {case} {m} precision@20px {v:.3f} (target >= {target}): "
                          f"{'met' if v >= target else 'NOT met'}")
    network = NETWORK_ALONE.replace("_transt", tag)
    checks += network_checks(summary, network, [c for c in cases if c.startswith("heldout_")])
    checks += network_checks(summary, unseen_row(network), ["clean"])
    med = float(t1.set_index("algorithm").loc[gk, "latency_median_ms"])
    checks.append(f"{gk} median latency {med:.2f} ms (target <= {TARGET_MEDIAN_MS}): "
                  f"{'met' if med <= TARGET_MEDIAN_MS else 'NOT met'}")
    for num, den, what, r_med, _ in ratios.like_for_like:
        checks.append(f"{num}/{den} median latency ratio {r_med:.3f}, {what} (target <= "
                      f"{TARGET_RATIO}; seed 0.523): "
                      f"{'met' if r_med <= TARGET_RATIO else 'NOT met'}")
    num, den, what, r_med, _ = ratios.default
    if math.isfinite(r_med):
        checks.append(f"{num}/{den} median latency ratio {r_med:.3f}, {what} (not like for "
                      f"like; target <= {TARGET_RATIO}): "
                      f"{'met' if r_med <= TARGET_RATIO else 'NOT met'}")
    return checks


def _run_note(specs: Sequence, seqs: list[TrackingSequence], cases: Sequence[str], frames: int,
              wall_s: float) -> str:
    """What ran (seeds, cases, frames, image size) and on what machine load."""
    seed_list = sorted({s.seed for s in specs})
    cam, binning = seqs[0].params.camera, seqs[0].binning
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (
        f"Validation seeds {seed_list}, cases {cases}, {frames} frames each (frames 1-"
        f"{frames - 1} scored), {cam.sensor_width_px // binning} x "
        f"{cam.sensor_height_px // binning} px (binning {binning}); errors in full-sensor px. "
        f"Wall time {wall_s:.0f} s; {_torch_note()}; {os.cpu_count()} CPUs seen by Python, load "
        f"average {load:.1f} over the last minute at the end of the run (latencies are wall "
        "time: other jobs on the machine lengthen them)."
    )


def _result_notes(summary: pd.DataFrame, t1: pd.DataFrame, all_cases: bool, gk: str, dual: str,
                  ratios: _LatencyRatios, checks: list[str]) -> list[str]:
    """Table 1, the latency ratios, the precision table, the network beside GK-TransT and the
    targets, as markdown paragraphs (``all_cases``: Table 1 is over all sequences, not only
    the clean ones)."""
    t1_show = t1[["algorithm", "fps", "latency_median_ms", "latency_mean_ms", "latency_p95_ms",
                  "seed_fps", "seed_latency_ms"]]
    sum_cols = ["tracker", "case", "main_precision_20px", "aux_precision_20px",
                "seed_main_precision", "seed_aux_precision", "main_success_auc",
                "aux_success_auc"]
    if "main_reacquire_frames" in summary.columns:
        sum_cols += ["main_reacquire_frames", "aux_reacquire_frames"]
    return [
        f"Table 1 measured here ({'all' if all_cases else 'clean'} sequences; FPS = 1/mean "
        "latency) beside the seed's (RTX 4060 laptop GPU):\n\n"
        + markdown_table(t1_show, ".2f"),
        "Latency ratios in this run (seed: 16.33/31.23 = 0.523): " + "; ".join(
            f"{n}/{d} ({w}) median {a:.3f}, mean {b:.3f}"
            for n, d, w, a, b in (*ratios.like_for_like, ratios.default)) + ".",
        "Precision at 20 px and success AUC, mean over seeds (seed's precision beside; "
        "re-acquisition = frames after frame 110 until measured within 20 px for 5 frames):"
        "\n\n" + markdown_table(summary[sum_cols]),
        network_and_gk_table(summary, gk, dual),
        "Targets:\n\n" + "\n".join(f"- {c}" for c in checks) if checks else "",
    ]


def run_tracking_benchmark(
    out_dir: Path | str,
    seeds: int = 2,
    frames: int = 300,
    cases: Sequence[str] | None = None,
    trackers: Sequence[str] = DEFAULT_TRACKERS,
    stand_in: bool = False,
    progress: Callable[[str], None] | None = None,
    on_step: Callable[[], None] | None = None,
    link_prefix: str = "",
    require_transt: bool = False,
    unseen: bool = True,
) -> BenchmarkReport:
    """The tracking benchmark of seed 000 §4, composed: the named trackers on ``seeds``
    validation sequences per case (``experiments.sequences.validation_suite``, rendered one at
    a time), their metrics, the tables and the targets.

    Writes into ``out_dir``: ``tracking_metrics.csv`` (one row per run),
    ``tracking_precision_<case>.png`` (precision curves, seed Figures 11, 12a/c, 14a/c) and
    ``tracking_errors_<case>.png`` (the first sequence's centre error over frames, 12b/d,
    14b/d). ``progress`` gets a message per sequence, ``on_step`` a call per scored frame;
    ``link_prefix`` is put before the plot names in the notes. Raises ``ValueError`` for an
    unknown case or tracker, fewer than one seed or frames than a case needs (``min_frames``),
    and, with ``require_transt``, TransT trackers without the shipped network (else their
    rows are left out and ``progress`` and the notes say so).

    With ``unseen`` (default) and the network-alone tracker (``NETWORK_ALONE``) among
    ``trackers``, every sequence is rendered a second time from the unseen image source
    (``SequenceSpec.source = "unseen"``: the same motion and case, MuJoCo in a drawn look
    through a sensor model, never used for training) and tracked by the network alone: rows
    ``unseen_row(NETWORK_ALONE)``, checked against the network-alone targets on the clean
    case.
    """
    from experiments.sequences import render_sequence, validation_suite

    cases = _check_arguments(cases, seeds, frames)
    factories, note_transt = tracker_factories(trackers, stand_in, require_transt)
    if not factories:
        raise ValueError(f"no tracker to run: {note_transt}")
    say = progress or (lambda msg: None)
    if note_transt:
        say(note_transt)
    specs = validation_suite(seeds, tuple(cases), frames)

    def render(spec):
        say(f"rendering {spec.name}")
        return render_sequence(spec)

    t0 = time.perf_counter()
    metrics, runs, seqs = run_benchmark(
        factories, [lambda s=s: render(s) for s in specs], progress=say, keep_images=False,
        on_step=on_step)
    network = NETWORK_ALONE.replace("_transt", tag_of(stand_in))
    if unseen and network in factories:
        unseen_specs = [s.model_copy(update={"source": "unseen"}) for s in specs]
        m2, r2, s2 = run_benchmark(
            {unseen_row(network): factories[network]},
            [lambda s=s: render(s) for s in unseen_specs], progress=say, keep_images=False,
            on_step=on_step)
        metrics, runs, seqs = pd.concat([metrics, m2], ignore_index=True), runs + r2, seqs + s2
    wall = time.perf_counter() - t0

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    metrics.to_csv(out / "tracking_metrics.csv", index=False)
    by_name = {s.name: s for s in seqs}
    pd.concat([r.frames_table(by_name[r.sequence]) for r in runs], ignore_index=True) \
        .to_parquet(out / "tracking_frames.parquet", index=False)
    plots = _write_plots(out, runs, seqs, cases)

    summary = summary_table(metrics)
    t1 = table1([r for r in runs if not r.tracker.endswith("_unseen")],
                ["clean"] if "clean" in cases else None)
    gk = "gk_standin" if stand_in else "gk_transt"
    dual = "dual_standin" if stand_in else "dual_transt"
    tag = tag_of(stand_in)
    ratios = _LatencyRatios.of(t1, gk, dual, tag)
    checks = _checks(summary, t1, cases, gk, tag, ratios)
    notes = "\n\n".join(x for x in [
        _run_note(specs, seqs, cases, frames, wall), note_transt,
        *_result_notes(summary, t1, "clean" not in cases, gk, dual, ratios, checks),
        "Plots: " + ", ".join(f"`{link_prefix}{Path(p).name}`" for p in plots),
    ] if x)
    return BenchmarkReport(metrics, summary, t1, runs, seqs, ratios.default[3], ratios.default[4],
                           checks, _figures(summary, t1, ratios), notes,
                           [out / "tracking_metrics.csv", out / "tracking_frames.parquet",
                            *plots], wall)


def run_unseen_accuracy(
    seeds: int = 1,
    frames: int = 300,
    cases: Sequence[str] = ("clean", "occlusion"),
    weights: Path | str | None = None,
    progress: Callable[[str], None] | None = None,
) -> tuple[pd.DataFrame, dict[str, float]]:
    """Accuracy of the network alone (``NETWORK_ALONE``: two networks, box centres, no GK) on
    the unseen image source: the validation sequences of ``cases`` rendered by
    ``plant.render_unseen`` (``SequenceSpec.source = "unseen"``) and tracked with the
    ``weights`` (default the shipped ones). No timing is reported.

    Returns the summary table (``summary_table``) and flat figures
    ``<case>_<main|aux>_precision_20px`` and ``<case>_<main|aux>_err_median_px`` (sensor px).
    Raises ``ValueError`` for bad cases, seeds or frames, and ``WeightsError`` when the
    weights cannot be loaded.
    """
    from experiments.sequences import render_sequence, validation_suite
    from observer.trackers import make_pair_tracker
    from observer.transt.tracker import TransTTracker
    from observer.transt.weights import SMALL_WEIGHTS

    cases = _check_arguments(cases, seeds, frames)
    path = Path(weights) if weights is not None else SMALL_WEIGHTS
    TransTTracker.small(path)  # refuse bad weights before rendering anything

    def factory() -> PairTracker:
        return make_pair_tracker(NETWORK_ALONE, transt_factory=lambda: TransTTracker.small(path))

    specs = [s.model_copy(update={"source": "unseen"})
             for s in validation_suite(seeds, tuple(cases), frames)]
    say = progress or (lambda msg: None)

    def render(spec):
        say(f"rendering {spec.name}")
        return render_sequence(spec)

    metrics, _, _ = run_benchmark({unseen_row(NETWORK_ALONE): factory},
                                  [lambda s=s: render(s) for s in specs], progress=say,
                                  keep_images=False)
    summary = summary_table(metrics)
    figures = {f"{r.case}_{m}_{k}": float(r[f"{m}_{k}"]) for _, r in summary.iterrows()
               for m in MARKER_NAMES for k in ("precision_20px", "err_median_px")}
    return summary, figures


__all__ = [
    "DEFAULT_TRACKERS",
    "IOU_THRESHOLDS",
    "OCCLUSION_FRAMES",
    "PRECISION_PX",
    "RATIO_PAIRS",
    "SEED_PRECISION",
    "SEED_TABLE1",
    "THRESHOLDS_PX",
    "BenchmarkReport",
    "TrackRun",
    "box_iou",
    "centre_errors",
    "evaluate",
    "latency_ratio",
    "latency_stats",
    "markdown_table",
    "case_target",
    "min_frames",
    "network_and_gk_table",
    "network_checks",
    "plot_error_curves",
    "plot_precision_curves",
    "pooled_precision",
    "precision_at",
    "precision_curve",
    "reacquisition_frames",
    "run_benchmark",
    "run_tracker",
    "run_tracking_benchmark",
    "run_trackers",
    "run_unseen_accuracy",
    "success_auc",
    "success_curve",
    "summary_table",
    "table1",
    "tag_of",
    "tracker_factories",
    "transt_network",
    "unseen_row",
]
