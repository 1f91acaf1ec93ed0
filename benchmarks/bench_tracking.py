"""Tracking benchmark (seed 000 §4): GK-TransT, dual TransT, KCF, CSRT, K²CF on the validation
sequences, clean and with the seed's occlusion and blur cases.

Sequences (``experiments.sequences``): hand-style motions rendered by the analytic renderer from
the *validation* seeds 7,000,000 + i (never used for training or tuning), 300 frames each at
36 frames/s, 612 x 512 px (binning 4); cases ``clean``, ``occlusion`` (frames 100-110 black over
both markers + 20 px) and ``blur`` (frames 130-160: K = 5, M = 6). Every tracker starts on frame 0
with the true boxes; frames 1-299 are scored (``experiments.tracking_bench``): precision curves
0-50 px (full-sensor px), precision at 20 px, IoU success AUC, median/p95 latency, FPS = 1/mean
latency, re-acquisition frames after the occlusion. Trackers: GK-TransT with the shipped ``small``
network (sub-pixel centres on, the GK default, and the smaller search crop in steady frames;
``gk_transt_norefine`` without the sub-pixel centres, the seed's algorithm;
``gk_transt_fullcrop`` on the full crop in every frame, the configuration before), dual TransT
(two ``small`` networks, box centres; ``dual_transt_refine`` with the circle fit, for a
like-for-like latency ratio with GK-TransT), OpenCV KCF and CSRT (one per marker, box centres),
the numpy KCF and K²CF (one per marker).

Writes ``benchmarks/results/tracking_*.png`` (precision curves per case like seed Figures 11,
12a/c, 14a/c; centre error over frames of the first sequence per case like 12b/d, 14b/d),
``results/tracking_metrics.csv`` (one row per run) and records its figures (``RESULTS.md`` is
generated from them).

The composition (trackers, sequences, metrics, tables, plots, the targets) is
``experiments.tracking_bench.run_tracking_benchmark``, shared with ``pmspm bench-trackers``; this
script adds the torch thread setting and the record in RESULTS.md.

Hard cases (``--cases hard``, frames 100-140 of each sequence, ``experiments.sequences``):
finger occluders of skin, red-brown, dark and blue colour over the red marker, a glare on both
markers, a red or a yellow disc beside the pair, a motion burst at 3x speed and a brightness
drop to 30 %; ``--cases heldout``: the appearance families the network never saw in training
(a checker rotor pattern, an off-axis light spot, purple occluders). Rows ``dual_transt`` are
the network alone (box centres, no GK); the notes put them beside GK-TransT per case, with the
fraction of frames reported as measured but wrong. Rows ``dual_transt_unseen`` are the network
alone on the same motion and case rendered by a second, independent image source
(``plant.render_unseen``: MuJoCo with drawn materials, lights and backgrounds through a sensor
model with Bayer demosaicing, rolling shutter, gamma, vignetting and JPEG; never used for
training); ``--no-unseen`` leaves them out.

Run: python benchmarks/bench_tracking.py            (about 5-10 min on two shared cores)
     python benchmarks/bench_tracking.py --seeds 1 --cases clean     (quick look)
     python benchmarks/bench_tracking.py --stand-in --no-record      (plumbing without weights)
     python benchmarks/bench_tracking.py --profile --frames 150      (where a step's time goes)

``--ort-threads N`` runs the shipped network with N ONNX Runtime intra-op threads (default 1,
``observer.transt.export.onnx_session``); every TransT tracker of the run shares the one
network, so GK-TransT and dual TransT stay like for like. ``--profile`` records nothing: it runs
GK-TransT and dual TransT (box centres, and with the circle fit) over the first validation
sequence, clean, under ``cProfile`` and prints each stage's time per frame and share of the
step (``STAGES``; the profiler's own cost inflates the many small Python calls of the GK stage
more than the network's one call, so read the shares, not the milliseconds).

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
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from _report import HERE, record  # noqa: E402

from experiments import tracking_bench as tb  # noqa: E402
from experiments.sequences import ALL_CASES, CASES, HARD_CASES, HELDOUT_CASES  # noqa: E402

#: Shorthands for ``--cases``.
CASE_GROUPS = {"seed": CASES, "hard": HARD_CASES, "heldout": HELDOUT_CASES, "all": ALL_CASES}

#: ``--profile``: the stages of a tracking step, each the cumulative time of the functions
#: (path suffix, name) that do it. Nested: the circle fits run inside the trust rule and the
#: GK step, the network inside the TransT step.
STAGES: dict[str, tuple[tuple[str, str], ...]] = {
    "whole step": (("observer/trackers/__init__.py", "step"),),
    "TransT step (crop, network, decoding)": (("observer/transt/tracker.py", "track"),),
    "  search crop": (("observer/transt/crop.py", "crop_square"),),
    "  normalisation": (("observer/transt/crop.py", "normalise"),),
    "  network (backbone, fusion, heads)": (("observer/transt/service.py", "_run"),),
    "GK trust rule (and re-detection)": (("observer/gk/trust.py", "judge"),
                                         ("observer/gk/trust.py", "redetect")),
    "GK step (Kalman filter, yellow marker)": (("observer/gk/assist.py", "step"),),
    "  circle fits (trust rule, yellow, refinement)": (
        ("observer/gk/subpixel.py", "refine_marker_centre"),),
    "plate": (("observer/trackers/gk_transt.py", "_plate_markers"),
              ("observer/trackers/gk_transt.py", "_plate_after")),
    "drift check": (("observer/gk/drift.py", "check"),),
    "frame checks": (("observer/gk/hsv_gate.py", "check_frame"),),
}


def stage_profile(frames: int) -> str:
    """GK-TransT and dual TransT (box centres, and with the circle fit) over the first
    validation sequence, clean, each profiled alone after ten warm-up frames: a markdown table
    of each ``STAGES`` entry's time per frame (ms) and share of the whole step."""
    import cProfile
    import pstats

    import pandas as pd

    from experiments.sequences import SequenceSpec, render_sequence, validation_seeds
    from experiments.tracking_runs import markdown_table
    from observer.trackers import make_pair_tracker

    seq = render_sequence(SequenceSpec(seed=validation_seeds(1)[0], n_frames=frames))
    rows = {}
    for label in ("gk_transt", "gk_transt_norefine", "gk_transt_fullcrop", "dual_transt",
                  "dual_transt_refine"):
        name, kwargs = tb.VARIANTS.get(label, (label, {}))
        tracker = make_pair_tracker(name, **kwargs)
        tracker.start(seq.images[0], seq.boxes_px[0], seq.binning)
        for k in range(1, 11):
            tracker.step(seq.images[k])
        prof = cProfile.Profile()
        prof.enable()
        for k in range(11, seq.n_frames):
            tracker.step(seq.images[k])
        prof.disable()
        stats = pstats.Stats(prof).stats  # type: ignore[attr-defined]
        n = seq.n_frames - 11
        ms = {stage: 1e3 / n * sum(ct for (path, _, func), (_, _, _, ct, _) in stats.items()
                                   if any(path.endswith(p) and func == f for p, f in keys))
              for stage, keys in STAGES.items()}
        rows[label] = [f"{v:.2f} ({v / ms['whole step']:.0%})" for v in ms.values()]
    t = pd.DataFrame({"stage": list(STAGES), **rows})
    return (f"Per-stage time per frame, ms (share of the step), {seq.n_frames - 11} frames of "
            f"{seq.name}, under cProfile:\n\n" + markdown_table(t))



def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=2, help="validation seeds (default 2)")
    ap.add_argument("--frames", type=int, default=300,
                    help="frames per sequence (clean >= 2, occlusion >= 116, blur >= 161)")
    ap.add_argument("--cases", nargs="+", default=list(CASES),
                    choices=list(ALL_CASES) + list(CASE_GROUPS),
                    help="cases, or the groups seed (default), hard, heldout, all")
    ap.add_argument("--trackers", nargs="+", default=list(tb.DEFAULT_TRACKERS),
                    help="names of observer.trackers.make_pair_tracker, plus the variants of "
                    "experiments.tracking_bench.VARIANTS: gk_transt_norefine (GK-TransT without "
                    "the sub-pixel circle fit: the seed's algorithm), dual_transt_refine (dual "
                    "TransT with it), gk_transt_fullcrop (GK-TransT on the full search crop in "
                    "every frame), dual_transt_hold (dual TransT whose networks keep their box on "
                    "a frame scored as lost)")
    ap.add_argument("--stand-in", action="store_true",
                    help="numpy KCF in place of the TransT network (plumbing check)")
    ap.add_argument("--no-unseen", action="store_true",
                    help="skip the network-alone rows on the unseen image source "
                    "(plant.render_unseen, MuJoCo; needs OpenGL, MUJOCO_GL=egl)")
    ap.add_argument("--no-record", action="store_true",
                    help="do not record the figures (results/*.json, RESULTS.md); the plots "
                    "and tables go to a temporary folder")
    ap.add_argument("--torch-threads", type=int, default=1,
                    help="torch intra-op threads (default 1: on this shared 2-core machine the "
                    "small network was as fast with 1 thread and far steadier)")
    ap.add_argument("--ort-threads", type=int, default=None,
                    help="ONNX Runtime intra-op threads of the shipped network (default: "
                    "PMSPM_ORT_THREADS, else 1); shared by every TransT tracker of the run")
    ap.add_argument("--profile", action="store_true",
                    help="print where a step's time goes, per stage (see STAGES), and exit "
                    "without recording")
    a = ap.parse_args(argv)
    if a.ort_threads is not None:
        if a.ort_threads < 1:
            ap.error(f"--ort-threads must be >= 1, got {a.ort_threads}")
        os.environ["PMSPM_ORT_THREADS"] = str(a.ort_threads)
    try:
        import torch

        torch.set_num_threads(a.torch_threads)
    except ImportError:
        pass
    if a.profile:
        print(stage_profile(a.frames))
        return 0

    cases = list(dict.fromkeys(c for name in a.cases for c in CASE_GROUPS.get(name, (name,))))
    t0 = time.perf_counter()
    # A run that records nothing leaves the recorded run's plots and tables alone.
    out = Path(tempfile.mkdtemp(prefix="bench_tracking-")) if a.no_record else HERE / "results"
    # The one code path, shared with `pmspm bench-trackers` (experiments/tracking_bench.py).
    report = tb.run_tracking_benchmark(
        out, seeds=a.seeds, frames=a.frames, cases=cases, trackers=a.trackers,
        stand_in=a.stand_in, link_prefix="results/", unseen=not a.no_unseen,
        progress=lambda msg: print(f"[{time.perf_counter() - t0:6.0f} s] {msg}", flush=True))
    if a.no_record:
        print(report.notes)
        print(f"(not recorded: plots and tables in {out})")
    else:
        title = "Tracking benchmark: GK-TransT, dual TransT, KCF, CSRT, K²CF (seed 000 §4)"
        if a.stand_in:
            title += " [numpy-KCF stand-in for the TransT network]"
        record("bench_tracking", title, report.figures, report.notes)
        print(report.notes)
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    raise SystemExit(main())
