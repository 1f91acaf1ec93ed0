"""The tracker catalogue's figures, read from what this project measured.

Each catalogue tracker is named as ``observer.trackers.make_pair_tracker`` names it. Its figures:

* **latency**: seed 000 Table 1 (``latency.models.SEED_LATENCY_S``) where the seed timed it;
  otherwise the mean latency the tracking benchmark measured on this machine,
  ``1 / <row>_fps`` of ``benchmarks/results/bench_tracking.json`` (its FPS is 1 / the mean
  per-frame latency on the clean sequences; docs/tracking.md).
* **accuracy**: the pixel-noise scale, the tracker's centre error relative to GK-TransT's on the
  same rendered frames: the mean of the per-sequence median centre errors of both markers
  (``main_err_median_px``, ``aux_err_median_px``) over the ``clean`` rows of
  ``benchmarks/results/tracking_metrics.csv`` (the same benchmark's per-run rows; the JSON
  holds no centre errors). GK-TransT is 1: the camera mode's noise stands for the GK sub-pixel
  centre. KCF and CSRT inside the GK assistance take GK-TransT's row: with the sub-pixel
  circle fit the centre is the fit's, whichever tracker found the marker (the benchmark's
  dual TransT with the fit, ``dual_transt_refine``, has GK-TransT's median errors).
* **image-in-the-loop**: the scenario tracker that renders with it
  (``experiments.scenario.PAIR_TRACKER_OF``), None where scenarios have none.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

import pandas as pd

from experiments.scenario import PAIR_TRACKER_OF
from latency.models import SEED_LATENCY_S

#: The tracking benchmark's results (benchmarks/bench_tracking.py).
RESULTS_DIR = Path(__file__).resolve().parents[2] / "benchmarks" / "results"
BENCH_JSON = RESULTS_DIR / "bench_tracking.json"
METRICS_CSV = RESULTS_DIR / "tracking_metrics.csv"
#: The benchmark row whose centre errors are the reference (noise scale 1).
REFERENCE_ROW = "gk_transt"
#: Catalogue tracker -> (the benchmark row of its accuracy, its seed 000 Table 1 latency name
#: or None for the benchmark's measured latency).
CATALOGUE: dict[str, tuple[str, str | None]] = {
    "gk_transt": ("gk_transt", "gk_transt"),
    "dual_transt": ("dual_transt", "dual_transt"),
    "kcf_gk": ("gk_transt", "kcf"),
    "csrt_gk": ("gk_transt", "csrt"),
    "k2cf": ("k2cf", None),
}
#: ``make_pair_tracker`` name -> the scenario tracker that runs it on rendered frames.
SCENARIO_TRACKER_OF = {pair: scenario for scenario, pair in PAIR_TRACKER_OF.items()}


def noise_scales(metrics_csv: Path = METRICS_CSV) -> dict[str, float]:
    """Per benchmark row, its centre error relative to ``REFERENCE_ROW``'s (module docstring):
    the mean over the clean runs and both markers of the median centre error, sensor px,
    divided by the reference's."""
    df = pd.read_csv(metrics_csv)
    clean = df[df["case"] == "clean"]
    err = clean.groupby("tracker")[["main_err_median_px", "aux_err_median_px"]].mean()
    per_row = err.mean(axis=1)
    if REFERENCE_ROW not in per_row:
        raise ValueError(f"{metrics_csv}: no clean rows of {REFERENCE_ROW!r}")
    return (per_row / per_row[REFERENCE_ROW]).to_dict()


def measured_latency_s(row: str, bench_json: Path = BENCH_JSON) -> float:
    """The mean per-frame latency (s) the tracking benchmark measured for ``row``:
    ``1 / <row>_fps``."""
    figures = json.loads(Path(bench_json).read_text())
    key = f"{row}_fps"
    if key not in figures:
        raise ValueError(f"{bench_json}: no {key!r}")
    return 1.0 / float(figures[key])


@functools.cache
def catalogue_figures() -> dict[str, dict]:
    """Per catalogue tracker: ``latency_s``, ``noise_scale`` and ``image_tracker`` (module
    docstring), from the benchmark's files."""
    scales = noise_scales()
    out = {}
    for name, (row, seed_name) in CATALOGUE.items():
        if row not in scales:
            raise ValueError(f"{METRICS_CSV}: no clean rows of {row!r} (for {name!r})")
        latency = (SEED_LATENCY_S[seed_name] if seed_name is not None
                   else measured_latency_s(row))
        out[name] = {"latency_s": latency, "noise_scale": float(scales[row]),
                     "image_tracker": SCENARIO_TRACKER_OF.get(name)}
    return out
