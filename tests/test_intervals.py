"""Coverage of the study's 95 % intervals on synthetic data with a known truth."""

import numpy as np
import pandas as pd
import pytest
import scipy.stats

from experiments.intervals import bootstrap_mean_ci, frame_fraction_ci, seed_intervals, wilson_ci


@pytest.mark.parametrize("p", [0.05, 0.2, 0.5])
def test_wilson_interval_covers_the_true_fraction_about_95_percent_of_the_time(p):
    """Exact coverage over every outcome k of n = 32 runs, weighted by the binomial pmf."""
    n = 32
    ks = np.arange(n + 1)
    covered = np.array([lo <= p <= hi for _, lo, hi in (wilson_ci(k, n) for k in ks)])
    coverage = float(np.sum(scipy.stats.binom.pmf(ks, n, p)[covered]))
    assert 0.92 <= coverage <= 0.99
    # the interval never collapses at 0 of n (the normal approximation would give [0, 0])
    _, lo, hi = wilson_ci(0, n)
    assert lo == 0.0 and hi == pytest.approx(1.96**2 / (n + 1.96**2), rel=1e-3)


def test_bootstrap_interval_of_a_mean_covers_the_true_mean():
    """Gamma(4, 0.5) samples of 32 seeds, true mean 2: the interval holds it ~95 % of the
    time (percentile bootstrap, slightly below nominal for a skewed law at this size)."""
    rng = np.random.default_rng(1)
    reps, hits = 300, 0
    for i in range(reps):
        x = rng.gamma(4.0, 0.5, size=32)
        mean, lo, hi = bootstrap_mean_ci(x, seed=i)
        assert lo <= mean <= hi and mean == pytest.approx(np.mean(x))
        hits += lo <= 2.0 <= hi
    assert 0.89 <= hits / reps <= 0.99


def test_seed_intervals_table_groups_and_names_the_columns():
    runs = pd.DataFrame({
        "controller": ["pid"] * 4 + ["mpc"] * 4,
        "rms_error_deg": [1.0, 2.0, 3.0, np.nan, 0.5, 0.5, 0.5, 0.5],
        "lost_frame_fraction": [0.0] * 8,
        "loss_of_control": [0, 0, 1, 1, 0, 0, 0, 0],
    })
    t = seed_intervals(runs, ["controller"]).set_index("controller")
    assert t.loc["pid", "rms_error_deg"] == pytest.approx(2.0)  # NaN ignored
    assert t.loc["pid", "p_loss_of_control"] == pytest.approx(0.5)
    assert t.loc["mpc", "rms_error_deg_lo"] == t.loc["mpc", "rms_error_deg_hi"] == 0.5
    assert t.loc["mpc", "p_loss_of_control_hi"] > 0.0 and t.loc["mpc", "n_runs"] == 4
    assert np.isnan(bootstrap_mean_ci([1.0])[1])


def test_frame_fraction_interval_of_runs_without_a_lost_frame_is_the_exact_binomial_one():
    # 12 runs of 190 frames, none lost: the exact two-sided 95 % bound on 0 of n frames is
    # 1 - 0.025 ** (1 / n) (Clopper-Pearson), about 3.7 / n; a bootstrap would claim [0, 0]
    n = 12 * 190
    mean, lo, hi = frame_fraction_ci(np.zeros(12), np.full(12, 190))
    assert mean == lo == 0.0 and hi == pytest.approx(1 - 0.025 ** (1 / n), rel=1e-9)
    # every frame lost: the mirror image
    mean, lo, hi = frame_fraction_ci(np.full(12, 190), np.full(12, 190))
    assert mean == hi == 1.0 and lo == pytest.approx(0.025 ** (1 / n), rel=1e-9)


def test_frame_fraction_interval_with_lost_frames_is_the_runs_bootstrap():
    lost, frames = np.array([0, 3, 10, 0, 1]), np.array([200, 180, 190, 210, 200])
    assert frame_fraction_ci(lost, frames) == bootstrap_mean_ci(lost / frames)
    with pytest.raises(ValueError, match="0 <= lost <= frames"):
        frame_fraction_ci([5], [4])


def test_seed_intervals_counts_frames_where_the_runs_have_their_counts():
    runs = pd.DataFrame({
        "side": ["image"] * 3 + ["model"] * 3,
        "rms_error_deg": [1.0, 2.0, 3.0, 1.0, 2.0, 3.0],
        "lost_frame_fraction": [0.0] * 6,
        "loss_of_control": [0] * 6,
        "lost_frames": [0, 0, 0, np.nan, np.nan, np.nan],
        "processed_frames": [100, 100, 100, np.nan, np.nan, np.nan],
    })
    counts = {"lost_frame_fraction": ("lost_frames", "processed_frames")}
    t = seed_intervals(runs, ["side"], frame_counts=counts).set_index("side")
    # image runs: 0 of 300 pooled frames; the model runs carry no counts: the bootstrap's [0, 0]
    assert t.loc["image", "lost_frame_fraction_hi"] == pytest.approx(1 - 0.025 ** (1 / 300))
    assert t.loc["model", "lost_frame_fraction_hi"] == 0.0
