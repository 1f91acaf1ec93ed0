"""Tracking benchmark (seed 000 §4): GK-TransT, dual TransT, KCF, CSRT, K²CF on the validation
sequences, clean and with the seed's occlusion and blur cases.

Sequences (``experiments.sequences``): hand-style motions rendered by the analytic renderer from
the *validation* seeds 7,000,000 + i (never used for training or tuning), 300 frames each at
36 frames/s, 612 x 512 px (binning 4); cases ``clean``, ``occlusion`` (frames 100-110 black over
both markers + 20 px) and ``blur`` (frames 130-160: K = 5, M = 6). Every tracker starts on frame 0
with the true boxes; frames 1-299 are scored (``experiments.tracking_bench``): precision curves
0-50 px (full-sensor px), precision at 20 px, IoU success AUC, median/p95 latency, FPS = 1/mean
latency, re-acquisition frames after the occlusion. Trackers: GK-TransT with the shipped ``small``
network (sub-pixel centres on, the GK default; ``gk_transt_norefine`` without them, the seed's
algorithm), dual TransT (two ``small`` networks, box centres), OpenCV KCF and CSRT (one per
marker, box centres), the numpy KCF and K²CF (one per marker).

Writes ``benchmarks/results/tracking_*.png`` (precision curves per case like seed Figures 11,
12a/c, 14a/c; centre error over frames of the first sequence per case like 12b/d, 14b/d),
``results/tracking_metrics.csv`` (one row per run) and appends the tables to ``RESULTS.md``.

Run: python benchmarks/bench_tracking.py            (about 5-10 min on two shared cores)
     python benchmarks/bench_tracking.py --seeds 1 --cases clean     (quick look)
     python benchmarks/bench_tracking.py --stand-in --no-record      (plumbing without weights)

Without the TransT weights (``observer/transt/weights/transt_small.pt``) the TransT rows are
skipped with a message; ``--stand-in`` runs GK-TransT and dual TransT with the numpy KCF in the
network's place (rows named ``gk_standin`` / ``dual_standin``; not TransT numbers).
"""

from __future__ import annotations

import os

# Before torch loads its OpenMP runtime: idle threads sleep instead of spinning. On two cores
# shared with other jobs, spinning threads made a 2-thread network call take 1.5 s instead of
# 16 ms (measured here; see docs/tracking.md).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from _report import HERE, record  # noqa: E402

from experiments import tracking_bench as tb  # noqa: E402
from experiments.sequences import CASES, render_sequence, validation_suite  # noqa: E402
from observer.trackers import make_pair_tracker  # noqa: E402
from observer.trackers.kcf_numpy import NumpyKCF  # noqa: E402

TARGET_PRECISION_CLEAN = 0.95  # issue 4
TARGET_PRECISION_DISTURBED = 0.90  # issue 4
TARGET_RATIO = 0.6  # issue 4 (seed: 0.523)
TARGET_MEDIAN_MS = 16.33  # issue 4 / seed 000 Table 1


def transt_factory():
    """``TransTTracker.small`` if the shipped weights load, else (None, why)."""
    try:
        from observer.transt.tracker import TransTTracker

        TransTTracker.small()
        return TransTTracker.small, ""
    except Exception as exc:  # noqa: BLE001 - report any reason the network is unavailable
        return None, f"{type(exc).__name__}: {exc}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=2, help="validation seeds (default 2)")
    ap.add_argument("--frames", type=int, default=300, help="frames per sequence (>= 161)")
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("--trackers", nargs="+",
                    default=["gk_transt", "gk_transt_norefine", "dual_transt", "kcf", "csrt",
                             "kcf_numpy", "k2cf"],
                    help="names of observer.trackers.make_pair_tracker, plus gk_transt_norefine "
                    "(GK-TransT without the sub-pixel circle fit: the seed's algorithm)")
    ap.add_argument("--stand-in", action="store_true",
                    help="numpy KCF in place of the TransT network (plumbing check)")
    ap.add_argument("--no-record", action="store_true", help="do not append to RESULTS.md")
    ap.add_argument("--torch-threads", type=int, default=1,
                    help="torch intra-op threads (default 1: on this shared 2-core machine the "
                    "small network was as fast with 1 thread and far steadier)")
    a = ap.parse_args(argv)
    try:
        import torch

        torch.set_num_threads(a.torch_threads)
    except ImportError:
        pass

    factories = {}
    note_transt = ""
    net, why = (NumpyKCF, "") if a.stand_in else transt_factory()
    for name in a.trackers:
        if name.startswith(("gk_transt", "dual_transt")):
            if net is None:
                note_transt = (f"TransT rows skipped: the shipped network is not available "
                               f"({why.splitlines()[0]}).")
                print(note_transt, file=sys.stderr)
                continue
            label = name.replace("_transt", "_standin") if a.stand_in else name
            kind, refine = name.removesuffix("_norefine"), None
            if name.endswith("_norefine"):
                refine = False
            factories[label] = (lambda kind=kind, refine=refine: make_pair_tracker(
                kind, refine=refine, transt_factory=net))
        else:
            factories[name] = (lambda name=name: make_pair_tracker(name))

    specs = validation_suite(a.seeds, tuple(a.cases), a.frames)
    t0 = time.perf_counter()
    metrics, runs, seqs = tb.run_benchmark(
        factories, [lambda s=s: render_sequence(s) for s in specs],
        progress=lambda msg: print(f"[{time.perf_counter() - t0:6.0f} s] {msg}", flush=True),
        keep_images=False)
    wall = time.perf_counter() - t0

    out = HERE / "results"
    out.mkdir(exist_ok=True)
    metrics.to_csv(out / "tracking_metrics.csv", index=False)
    plots = []
    for case in a.cases:
        plots.append(tb.plot_precision_curves(runs, seqs, case,
                                              out / f"tracking_precision_{case}.png"))
        first = next(s for s in seqs if s.case == case)
        plots.append(tb.plot_error_curves(runs, first, out / f"tracking_errors_{case}.png"))

    summary = tb.summary_table(metrics)
    t1_cases = ["clean"] if "clean" in a.cases else None
    t1 = tb.table1(runs, t1_cases)
    gk = "gk_standin" if a.stand_in else "gk_transt"
    dual = "dual_standin" if a.stand_in else "dual_transt"
    ratio_med = tb.latency_ratio(t1, gk, dual, "latency_median_ms")
    ratio_mean = tb.latency_ratio(t1, gk, dual, "latency_mean_ms")

    figures: dict[str, float] = {}
    for _, r in summary.iterrows():
        key = f"{r.tracker}_{r.case}"
        figures[f"{key}_main_precision_20px"] = float(r.main_precision_20px)
        figures[f"{key}_aux_precision_20px"] = float(r.aux_precision_20px)
        figures[f"{key}_main_success_auc"] = float(r.main_success_auc)
        figures[f"{key}_aux_success_auc"] = float(r.aux_success_auc)
        if "main_reacquire_frames" in summary.columns and r.case == "occlusion":
            figures[f"{key}_main_reacquire_frames"] = float(r.main_reacquire_frames)
            figures[f"{key}_aux_reacquire_frames"] = float(r.aux_reacquire_frames)
    for _, r in t1.iterrows():
        figures[f"{r.algorithm}_latency_median_s"] = r.latency_median_ms / 1e3
        figures[f"{r.algorithm}_latency_p95_s"] = r.latency_p95_ms / 1e3
        figures[f"{r.algorithm}_fps"] = float(r.fps)
    figures[f"{gk}_over_{dual}_median_latency_ratio"] = ratio_med
    figures[f"{gk}_over_{dual}_mean_latency_ratio"] = ratio_mean

    # targets (issue 4), GK-TransT only
    checks = []
    if gk in set(metrics.tracker):
        s = summary.set_index(["tracker", "case"])
        for case in a.cases:
            if (gk, case) not in s.index:
                continue
            target = TARGET_PRECISION_CLEAN if case == "clean" else TARGET_PRECISION_DISTURBED
            for m in ("main", "aux"):
                v = float(s.loc[(gk, case), f"{m}_precision_20px"])
                checks.append(f"{gk} {case} {m} precision@20px {v:.3f} (target >= {target}): "
                              f"{'met' if v >= target else 'NOT met'}")
        med = float(t1.set_index("algorithm").loc[gk, "latency_median_ms"])
        checks.append(f"{gk} median latency {med:.2f} ms (target <= {TARGET_MEDIAN_MS}): "
                      f"{'met' if med <= TARGET_MEDIAN_MS else 'NOT met'}")
        if math.isfinite(ratio_med):
            checks.append(f"{gk}/{dual} median latency ratio {ratio_med:.3f} (target <= "
                          f"{TARGET_RATIO}; seed 0.523): "
                          f"{'met' if ratio_med <= TARGET_RATIO else 'NOT met'}")

    t1_show = t1[["algorithm", "fps", "latency_median_ms", "latency_mean_ms", "latency_p95_ms",
                  "seed_fps", "seed_latency_ms"]]
    sum_cols = ["tracker", "case", "main_precision_20px", "aux_precision_20px",
                "seed_main_precision", "seed_aux_precision", "main_success_auc",
                "aux_success_auc"]
    if "main_reacquire_frames" in summary.columns:
        sum_cols += ["main_reacquire_frames", "aux_reacquire_frames"]
    try:
        import torch

        threads = (f"torch threads {torch.get_num_threads()}, OMP_WAIT_POLICY="
                   f"{os.environ.get('OMP_WAIT_POLICY')}")
    except Exception:  # noqa: BLE001
        threads = "torch unavailable"
    seeds = sorted({s.seed for s in specs})
    notes = "\n\n".join(x for x in [
        f"Validation seeds {seeds}, cases {a.cases}, {a.frames} frames each (frames 1-"
        f"{a.frames - 1} scored), 612 x 512 px; errors in full-sensor px. Wall time "
        f"{wall:.0f} s; {threads}; the two cores are shared with other jobs (a background "
        "network training may be running), so latencies are upper bounds and noisy.",
        note_transt,
        f"Table 1 measured here ({'clean' if t1_cases else 'all'} sequences; FPS = 1/mean "
        "latency) beside the seed's (RTX 4060 laptop GPU):\n\n"
        + tb.markdown_table(t1_show, ".2f"),
        f"Latency ratio {gk}/{dual} in this run: median {ratio_med:.3f}, mean "
        f"{ratio_mean:.3f} (seed: 16.33/31.23 = 0.523).",
        "Precision at 20 px and success AUC, mean over seeds (seed's precision beside; "
        "re-acquisition = frames after frame 110 until measured within 20 px for 5 frames):"
        "\n\n" + tb.markdown_table(summary[sum_cols]),
        "Targets (issue 4):\n\n" + "\n".join(f"- {c}" for c in checks) if checks else "",
        "Plots: " + ", ".join(f"`results/{Path(p).name}`" for p in plots),
    ] if x)
    if a.no_record:
        print(notes)
    else:
        title = "Tracking benchmark: GK-TransT, dual TransT, KCF, CSRT, K²CF (seed 000 §4)"
        if a.stand_in:
            title += " [numpy-KCF stand-in for the TransT network]"
        record("bench_tracking", title, figures, notes)
        print(notes)
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    raise SystemExit(main())
