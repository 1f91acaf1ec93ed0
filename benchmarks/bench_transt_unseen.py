"""The TransT network alone on frames from elsewhere: accuracy on the unseen image source.

The network-alone tracker (the dual TransT: one ``small`` network per marker, box centres, no
GK assistance) tracks the validation sequences (``experiments.sequences``, seeds 7,000,000 + i)
rendered by ``plant.render_unseen``: MuJoCo with materials, lights and backgrounds drawn from
wide ranges, through a sensor model (Bayer demosaicing, rolling shutter, gamma, vignetting,
JPEG), a source never used for training. Figures: per case and marker, precision at 20 sensor
px and the median centre error (sensor px). Accuracy only: no latency is recorded, so a loaded
machine does not change the figures.

With the shipped weights (the default) the figures are also written, with the weights'
SHA-256, to ``observer/transt/weights/unseen_accuracy.json``, which the study's report quotes
beside its tracking-loss curves. ``--weights`` evaluates another file (not recorded there).

Run: python benchmarks/bench_transt_unseen.py                       (clean and occlusion, 1 seed)
     python benchmarks/bench_transt_unseen.py --seeds 2 --cases clean occlusion blur
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch loads OpenMP
os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco loads

import argparse  # noqa: E402
import datetime as dt  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import torch  # noqa: E402
from _report import record  # noqa: E402

from experiments import tracking_bench as tb  # noqa: E402
from experiments.sequences import ALL_CASES  # noqa: E402
from experiments.tracking_runs import markdown_table  # noqa: E402
from observer.transt.weights import SMALL_WEIGHTS, UNSEEN_ACCURACY, verify  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=1, help="validation seeds (default 1)")
    ap.add_argument("--frames", type=int, default=300, help="frames per sequence")
    ap.add_argument("--cases", nargs="+", default=["clean", "occlusion"], choices=ALL_CASES)
    ap.add_argument("--weights", type=Path, default=SMALL_WEIGHTS,
                    help="weights file (default the shipped one)")
    ap.add_argument("--no-record", action="store_true",
                    help="print only (no results/*.json, RESULTS.md or unseen_accuracy.json)")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    summary, figures = tb.run_unseen_accuracy(a.seeds, a.frames, a.cases, a.weights,
                                              progress=lambda m: print(m, flush=True))
    cols = ["case", "main_precision_20px", "aux_precision_20px", "main_err_median_px",
            "aux_err_median_px"]
    digest = verify(a.weights)
    notes = (f"Network alone (dual TransT, box centres) on the unseen image source "
             f"(`plant.render_unseen`), validation seeds {a.seeds}, {a.frames} frames, weights "
             f"`{a.weights.name}` SHA-256 `{digest}`; errors in full-sensor px. Targets on the "
             f"clean case: precision@20px >= {tb.TARGET_NETWORK_PRECISION}, median error <= "
             f"{tb.TARGET_NETWORK_MEDIAN_PX:g} px.\n\n" + markdown_table(summary[cols]))
    print(notes)
    if a.no_record:
        return 0
    record("bench_transt_unseen", "TransT network alone on the unseen image source",
           figures, notes)
    if a.weights.resolve() == SMALL_WEIGHTS.resolve():
        UNSEEN_ACCURACY.write_text(json.dumps({
            "weights": SMALL_WEIGHTS.name,
            "weights_sha256": digest,
            "source": "plant.render_unseen",
            "tracker": "dual_transt (network alone, box centres)",
            "seeds": a.seeds,
            "frames": a.frames,
            "cases": a.cases,
            "figures": figures,
            "command": "python " + " ".join([Path(sys.argv[0]).as_posix(), *sys.argv[1:]]),
            "date": dt.datetime.now().isoformat(timespec="seconds"),
        }, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
