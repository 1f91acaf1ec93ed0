"""TransT per-frame latency: ``small`` (shipped weights) in eager PyTorch, ``torch.compile`` and
ONNX Runtime, and the published-size ``transt50`` (random weights; only the time matters).

What is timed: ``TransTTracker.track`` as a whole (``compute_time_s``, ``time.perf_counter``
around the frame check, the search crop and normalisation, the network and the decoding) on a
rendered validation sequence (analytic renderer, 612 x 512 frames, seed 3001, never used in
training). ``small``: one warm-up pass over the first 20 frames (this is where ``torch.compile``
compiles; its first call is reported separately), then two passes of ``N_FRAMES`` frames per
backend, interleaved so that the machine's background load hits all backends alike. transt50:
``N_FRAMES_50`` frames after two warm-up frames, eager only. Threads: torch and ONNX Runtime use
the two cores (``torch.set_num_threads(2)``, ``intra_op_num_threads=2``). The machine is shared,
so medians are the figures to compare; p95 shows the load.

Also recorded: the centre error (full-sensor px, against ``Frame.marker_px[0]``) of each
backend on the same frames, to show that the backends agree.

Run: python benchmarks/bench_transt.py
"""

from __future__ import annotations

import time

import numpy as np
import torch
from _report import record

from observer.transt.network import count_parameters
from observer.transt.tracker import TransTTracker
from observer.transt.training.validation import red_box_image, validation_sequence
from observer.transt.weights import load_weights

N_FRAMES = 200
N_FRAMES_50 = 20
SEQ_SEED = 3001


def run(trk: TransTTracker, frames: list, n: int) -> tuple[list[float], list[float]]:
    """Track frames[1 : n + 1] from the true first box; (times s, centre errors sensor px)."""
    trk.initialize(frames[0].image, red_box_image(frames[0]))
    times, errs = [], []
    for f in frames[1 : n + 1]:
        r = trk.track(f.image)
        box = r.box_image_px
        times.append(r.compute_time_s)
        c = (box[:2] + box[2:] / 2 + 0.5) * f.binning - 0.5
        errs.append(float(np.hypot(*(c - f.marker_px[0]))))
    return times, errs


def main() -> None:
    torch.set_num_threads(2)
    frames = validation_sequence(SEQ_SEED, N_FRAMES + 1)
    net, meta = load_weights()
    figures: dict[str, float] = {"small_parameters": float(count_parameters(net))}

    trackers: dict[str, TransTTracker] = {}
    for backend in ("eager", "compile", "onnx"):
        t0 = time.perf_counter()
        try:
            trk = TransTTracker(net, backend=backend)
            trk.initialize(frames[0].image, red_box_image(frames[0]))
            trk.track(frames[1].image)  # compiles / exports here
        except Exception as exc:  # an optional backend that does not work here
            print(f"backend {backend} unavailable: {exc!r}")
            continue
        figures[f"small_{backend}_first_call_s"] = time.perf_counter() - t0
        run(trk, frames, 20)  # warm-up
        trackers[backend] = trk

    times: dict[str, list[float]] = {b: [] for b in trackers}
    errs: dict[str, list[float]] = {b: [] for b in trackers}
    for _ in range(2):
        for backend, trk in trackers.items():
            t, e = run(trk, frames, N_FRAMES)
            times[backend] += t
            errs[backend] = e
    for backend in trackers:
        t = np.asarray(times[backend])
        figures[f"small_{backend}_median_s"] = float(np.median(t))
        figures[f"small_{backend}_p95_s"] = float(np.percentile(t, 95))
        figures[f"small_{backend}_fps_median"] = float(1.0 / np.median(t))
        figures[f"small_{backend}_centre_err_median_px"] = float(np.median(errs[backend]))
    best = min(trackers, key=lambda b: figures[f"small_{b}_median_s"])

    torch.manual_seed(0)
    big = TransTTracker.from_config("transt50")
    figures["transt50_parameters"] = float(count_parameters(big.net))
    run(big, frames, 2)
    t50, _ = run(big, frames, N_FRAMES_50)
    figures["transt50_eager_median_s"] = float(np.median(t50))
    figures["transt50_eager_p95_s"] = float(np.percentile(t50, 95))
    figures["transt50_over_small_eager_median"] = (
        figures["transt50_eager_median_s"] / figures["small_eager_median_s"]
    )

    record(
        "bench_transt",
        "TransT track step: small (eager / torch.compile / ONNX Runtime) and transt50",
        figures,
        notes=f"Sequence seed {SEQ_SEED} (612 x 512, analytic renderer), {N_FRAMES} frames x 2 "
        f"passes per small backend, {N_FRAMES_50} frames for transt50 (random weights). "
        "Times: TransTTracker.compute_time_s (perf_counter around the whole track step). "
        f"Fastest small backend in this run: {best}. small weights: the last training stage "
        f"took {meta.get('steps')} steps (1300 in all, observer/transt/weights/MODEL_CARD.md). "
        "ONNX Runtime: one intra-op thread, no spinning (the default).",
    )


if __name__ == "__main__":
    main()
