"""The study's random references: each run's drawn from its own seed (or, named as such, one
fixed reference for every run), recorded as ``reference_seed``; the warning for a seed count
too small for a stated interval width."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from controller.reference import RandomSmooth
from experiments.intervals import widest_wilson_width, wilson_ci
from experiments.study_config import StudyConfig
from experiments.study_sweep import FIXED_REFERENCE_SEED, sweep_configs, tidy_sweep
from experiments.sweep import _flatten
from latency import Scenario

pytestmark = pytest.mark.engine  # runs the compiled engines

CFG = dict(n_seeds=4, delays_ms=(16.33,), max_rates_rad_s=(3.0,), duration_s=1.0)


def _random_points(configs: list[dict]) -> dict[tuple, list[dict]]:
    points: dict[tuple, list[dict]] = {}
    for c in configs:
        st = c["study"]
        if st["reference"].startswith("random"):
            key = (st["tracker"], st["controller"], st["reference"], st["delay_ms"])
            points.setdefault(key, []).append(c)
    return points


def test_each_run_of_a_point_follows_its_own_random_reference():
    points = _random_points(sweep_configs(StudyConfig(**CFG)))
    # every variant on the fastest (here the only) random reference with the first tracker,
    # the PID and the MPC with the second tracker too
    assert len(points) == 7
    t = np.linspace(0.0, 1.0, 11)
    for runs in points.values():
        seeds = [c["study"]["reference_seed"] for c in runs]
        assert sorted(seeds) == [0.0, 1.0, 2.0, 3.0]  # distinct: one per run seed
        built = [Scenario.model_validate({k: v for k, v in c.items() if k != "study"})
                 .reference.build() for c in runs]
        # the reference each run follows is the generator drawn from its reference seed
        for c, ref in zip(runs, built, strict=True):
            truth = RandomSmooth(seed=c["study"]["reference_seed"], max_rate_rad_s=3.0)
            np.testing.assert_allclose(ref.sample_many(t).q, truth.sample_many(t).q)
        assert not np.allclose(built[0].sample_many(t).q, built[1].sample_many(t).q)


def test_the_fixed_reference_mode_puts_every_run_on_one_reference():
    configs = sweep_configs(StudyConfig(**CFG, reference_mode="fixed"))
    seeds = {c["study"]["reference_seed"] for c in configs
             if c["study"]["reference"].startswith("random")}
    assert seeds == {float(FIXED_REFERENCE_SEED)}
    steps = [c for c in configs if c["study"]["reference"] == "tilt_step_5deg"]
    assert len(steps) == 4 * 4 and all(np.isnan(c["study"]["reference_seed"]) for c in steps)


def test_the_run_table_carries_the_reference_seed():
    configs = sweep_configs(StudyConfig(**CFG))
    rows = []
    for c in configs:
        row: dict = {"run_id": "x", "error": ""}
        _flatten("config", c, row)
        rows.append(row | {"result.rms_error_deg": 1.0})
    table = tidy_sweep(pd.DataFrame(rows))
    rnd = table[table.reference == "random_3rad_s"]
    assert (rnd.groupby(["controller", "vision_delay_ms"]).reference_seed.nunique() == 4).all()
    assert (rnd.reference_seed == rnd.seed).all()


def test_a_seed_count_too_small_for_the_stated_width_warns_with_the_width_it_achieves():
    _, lo, hi = wilson_ci(4, 8)  # the widest of 8 runs: half of them lost (scipy's Wilson)
    assert widest_wilson_width(8) == pytest.approx(hi - lo, rel=1e-9)
    with pytest.warns(UserWarning, match=f"up to {hi - lo:.3f} wide") as caught:
        StudyConfig(n_seeds=8, loss_interval_width=0.2)
    (message,) = [str(w.message) for w in caught]
    need = int(message.rsplit(">= ", 1)[1].rstrip(")"))
    _, lo_n, hi_n = wilson_ci(need // 2, need)
    _, lo_m, hi_m = wilson_ci((need - 1) // 2, need - 1)
    assert hi_n - lo_n <= 0.2 < hi_m - lo_m  # the smallest count that reaches the width
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        StudyConfig(n_seeds=need, loss_interval_width=0.2)


def test_full_study_runs_every_point_at_32_reference_seeds(monkeypatch, tmp_path):
    """`pmspm study --full` gives the sweep and the image-engine section 32 reference seeds
    per point (the sweep's own count unless --n-seeds is given) and both latencies to every
    tracker; without --full the defaults stay."""
    from typer.testing import CliRunner

    import experiments.study as study
    from experiments.cli import app

    seen: list[StudyConfig] = []

    def fake_run_study(out, cfg):
        seen.append(cfg)
        return tmp_path

    monkeypatch.setattr(study, "run_study", fake_run_study)
    runner = CliRunner()
    for args in (["--full"], ["--full", "--n-seeds", "12"], []):
        result = runner.invoke(app, ["study", "--out", str(tmp_path), *args])
        assert result.exit_code == 0, result.output
    full, full_12, default = seen
    assert (full.n_seeds, full.image_loop_n_seeds, full.image_loop_delays) == (32, 32, "both")
    assert (full_12.n_seeds, full_12.image_loop_n_seeds) == (12, 32)
    assert (default.n_seeds, default.image_loop_n_seeds, default.image_loop_delays) == \
        (10, 8, "own")
    configs = sweep_configs(full.model_copy(update={"delays_ms": (16.33,)}))
    per_point = {len(runs) for runs in _random_points(configs).values()}
    assert per_point == {32}
