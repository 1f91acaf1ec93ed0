"""Tuning the seed's pixel Kalman filter against closed-loop performance.

The filter tuned is the constant-velocity pixel Kalman filter of seed 000 §3.2.1 on each marker
centre (``observer.pixel_observer.PixelKalmanObserver``; scenario observer kind
``"pixel_kalman"``) with ``Q = q·I4`` and ``R = r·I2`` in full-sensor pixels, Δt = 1 processed
frame. The seed's values are ``q = 0.01``, ``r = 0.1``.

Objective (our construction)
----------------------------
One closed-loop run of the measurement-model loop (``latency.scenario``) costs, in degrees,

    J = e_rms + λ · T²_ms + μ · n_lost + D · diverged

* ``e_rms``: RMS geodesic attitude error truth vs reference over the run (deg);
* ``T²_ms``: mean-square delivered torque, ``control_effort_N2m2s / duration``, (N·m)². The
  effort is normalised by the run length so that λ does not depend on it;
* ``n_lost``: number of processed frames on which the front end lost a marker (the loop's
  motion-induced loss model, or the seed's 20 px criterion);
* ``diverged``: 1 if the error exceeded the loop's divergence limit (the run still covers its
  duration).

Defaults, all our choice: **λ = 1000 deg/(N·m)²** (an RMS torque of 0.0316 N·m, 12 % of the
0.264 N·m all-direction limit of controller/pid.py, costs as much as 1° of RMS error),
**μ = 0.1 deg per lost frame**, **D = 60 deg** (the loop's divergence threshold). The cost of a
setting (q, r) is the mean of J over the run seeds × the reference trajectories (a 5° tilt step
and a ``RandomSmooth`` trajectory at 1 rad/s whose random seed is the run seed). It is *not* the
pixel-tracking error: a filter that smooths the pixels best may lag enough to cost phase margin.

The measurement noise is σ = 1.5 sensor px per coordinate (our choice: between the GK sub-pixel
refinement's 0.1 px median error and the dual-TransT stand-in's 1.2–2.5 px median error on the
synthetic sequences of benchmarks/results/tracking_metrics.csv), so that filtering matters. The
vision delay is the observer latency of the pipeline (seed 000 Table 1: GK-TransT 16.33 ms,
dual TransT 31.23 ms) with the seed's sequential host loop: an observer slower than the 27.8 ms
frame period drops every second frame, and the filter and the PID then run at 18 Hz.

Method
------
* ``grid_search``: a log-grid over (q, r) with the seed's point on it, run through
  ``experiments.sweep.run_sweep`` (one Parquet file per run: resumable; local processes or Dask).
  The runs go to the batched engine (``run_costs``, ``BATCH_SIZE`` runs at a time) by default,
  or one by one to the event loop (``run_cost``) with ``engine="event"``.
* ``optuna_search``: TPE (seeded) on the same objective, the study in an SQLite file by default
  (``load_if_exists=True``: a second call resumes it, and several processes or machines can share
  one study). Runs are cached in the same ``runs/`` folder as the grid's.
* ``filter_loop_margins``: the phase margin of each loop *with its filter*. In steady state the
  CV Kalman filter is a linear time-invariant filter; its gain comes from the discrete Riccati
  equation and the transfer function from measured to filtered pixel (``kalman_transfer_function``)
  enters the exact sampled-loop margins (``latency.margins.sampled_margins``) as the observer, in
  series with the PID's discrete transfer function at the processed-frame period.
* ``tune_kalman``: all of it at each delay, with the seed's setting against the tuned one
  re-evaluated on held-out seeds, a heat map and tables written to a folder.

A property worth knowing: scaling Q and R together scales the Riccati solution and leaves the
Kalman gain unchanged, so the steady-state filter, and with it the margins, depend on ``q/r``
only. The absolute scale only changes the start-up transient (``P0 = diag(R, velocity_var0)``),
so the cost is nearly constant along the diagonals of the (log q, log r) heat map.

Modules: ``objective`` (the cost of a run and of a setting), ``filter`` (the steady-state filter
and the margins with it), ``search`` (grid and optuna), ``plots`` (figures) and ``report`` (the
whole tuning and its files). Everything public is importable from ``experiments.tuning``.
"""

from experiments.tuning.filter import (
    filter_loop_margins,
    filter_noise_gain,
    kalman_filter_ss,
    kalman_steady_state,
    kalman_transfer_function,
    margin_columns,
    processed_frame_period,
)
from experiments.tuning.objective import (
    BATCH_SIZE,
    BATCH_TARGET,
    DEFAULT_DELAYS_S,
    GRID_DECADES,
    RUN_TARGET,
    SEED_Q_SCALE,
    SEED_R_SCALE,
    CostWeights,
    TuningObjective,
    aggregate,
    cost_terms,
    evaluate,
    run_cost,
    run_costs,
)
from experiments.tuning.plots import (
    plot_heatmap,
    plot_tradeoff,
)
from experiments.tuning.report import (
    TuningResult,
    compare_on_seeds,
    comparison_markdown,
    tune_kalman,
)
from experiments.tuning.search import (
    grid_search,
    log_grid,
    optuna_search,
    study_name_for,
    trials_table,
)

__all__ = [
    "BATCH_SIZE",
    "BATCH_TARGET",
    "CostWeights",
    "DEFAULT_DELAYS_S",
    "GRID_DECADES",
    "RUN_TARGET",
    "SEED_Q_SCALE",
    "SEED_R_SCALE",
    "TuningObjective",
    "TuningResult",
    "aggregate",
    "compare_on_seeds",
    "comparison_markdown",
    "cost_terms",
    "evaluate",
    "filter_loop_margins",
    "filter_noise_gain",
    "grid_search",
    "kalman_filter_ss",
    "kalman_steady_state",
    "kalman_transfer_function",
    "log_grid",
    "margin_columns",
    "optuna_search",
    "plot_heatmap",
    "plot_tradeoff",
    "processed_frame_period",
    "run_cost",
    "run_costs",
    "study_name_for",
    "trials_table",
    "tune_kalman",
]
