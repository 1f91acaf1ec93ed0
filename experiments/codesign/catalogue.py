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
  centre. KCF and CSRT inside the GK assistance (not in the benchmark) take GK-TransT's row:
  with the sub-pixel circle fit the centre is the fit's, whichever tracker found the marker
  (the benchmark's dual TransT with the fit, ``dual_transt_refine``, has GK-TransT's median
  errors), and the GK assistance re-detects a lost marker for all three.
* **loss**: re-detection after a loss, ``reacquire_after_frames`` of the measurement model,
  from the re-acquisition the benchmark measured after its occlusion
  (``<row>_occlusion_main_reacquire_frames`` and ``_aux_`` of ``bench_tracking.json``, frames
  after the marker reappeared until it was tracked within 20 px for 5 frames): the frame it is
  lost on plus the slower marker's frames; None (never) where the tracker never re-acquired
  it. The search window and blur limit stay ``TrackerModel``'s defaults (not measured).
* **image-in-the-loop**: the tracker's own name (``observer.trackers.TRACKERS``), which a
  scenario renders with.
"""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path

import pandas as pd

from latency.models import SEED_LATENCY_S

#: The tracking benchmark's results (benchmarks/bench_tracking.py).
RESULTS_DIR = Path(__file__).resolve().parents[2] / "benchmarks" / "results"
BENCH_JSON = RESULTS_DIR / "bench_tracking.json"
METRICS_CSV = RESULTS_DIR / "tracking_metrics.csv"
#: The benchmark row whose centre errors are the reference (noise scale 1).
REFERENCE_ROW = "gk_transt"
#: Catalogue tracker -> (the benchmark row of its accuracy and loss, its seed 000 Table 1
#: latency name or None for the benchmark's measured latency).
CATALOGUE: dict[str, tuple[str, str | None]] = {
    "gk_transt": ("gk_transt", "gk_transt"),
    "dual_transt": ("dual_transt", "dual_transt"),
    "kcf_gk": ("gk_transt", "kcf"),
    "csrt_gk": ("gk_transt", "csrt"),
    "k2cf": ("k2cf", None),
}


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


def reacquire_after_frames(row: str, bench_json: Path = BENCH_JSON) -> int | None:
    """Processed frames until ``row`` re-detects a lost marker (module docstring): 1 + the
    larger of the two markers' re-acquisition frames after the benchmark's occlusion, rounded
    up; None when it never re-acquired one."""
    figures = json.loads(Path(bench_json).read_text())
    keys = [f"{row}_occlusion_{m}_reacquire_frames" for m in ("main", "aux")]
    missing = [k for k in keys if k not in figures]
    if missing:
        raise ValueError(f"{bench_json}: no {missing}")
    frames = max(float(figures[k]) for k in keys)
    return None if math.isinf(frames) else 1 + math.ceil(frames)


@functools.cache
def catalogue_figures() -> dict[str, dict]:
    """Per catalogue tracker: ``latency_s``, ``noise_scale``, ``reacquire_after_frames`` and
    ``image_tracker`` (module docstring), from the benchmark's files."""
    scales = noise_scales()
    out = {}
    for name, (row, seed_name) in CATALOGUE.items():
        if row not in scales:
            raise ValueError(f"{METRICS_CSV}: no clean rows of {row!r} (for {name!r})")
        latency = (SEED_LATENCY_S[seed_name] if seed_name is not None
                   else measured_latency_s(row))
        out[name] = {"latency_s": latency, "noise_scale": float(scales[row]),
                     "reacquire_after_frames": reacquire_after_frames(row),
                     "image_tracker": name}
    return out
