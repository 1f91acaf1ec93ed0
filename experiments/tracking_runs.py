"""Runs and tables of the tracking benchmark (``experiments.tracking_bench``): trackers stepped
through the validation sequences, their metrics per run, and the tidy tables.

**Protocol.** A pair tracker (``observer.trackers``) is started on frame 0 with the true boxes of
both markers and stepped through frames 1 … N-1; frame 0 is not scored. The trackers of a
benchmark take turns frame by frame (``run_trackers``), so that on a shared machine they all meet
the same background load and latency ratios are fair. Per frame and marker
(main = red, auxiliary = yellow) we keep the reported centre and box (full-sensor px), the lost
and measured flags and the tracker's measured compute time (``PairResult.compute_time_s``,
``time.perf_counter`` around the whole step).

The seed's numbers (Table 1 and §4.2-4.3) are kept in ``SEED_TABLE1`` and ``SEED_PRECISION``
for the side-by-side tables; ``run_benchmark`` returns tidy pandas tables.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from experiments.sequences import TrackingSequence
from experiments.tracking_metrics import (
    PRECISION_PX,
    THRESHOLDS_PX,
    box_iou,
    centre_errors,
    latency_stats,
    precision_at,
    precision_curve,
    reacquisition_frames,
    success_auc,
)
from latency.models import SEED_FPS, seed_latency_ms
from observer.trackers import MARKERS
from observer.tracking import PairResult, PairTracker, attitude_source

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
