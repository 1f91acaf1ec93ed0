"""The study's headline margins (the per-axis PID loop at GK-TransT's 16.33 ms and the dual
TransT's 31.23 ms, sequential and pipelined observer) against the derivation of
tests/independent_margins.py, which does not call the project's margin, pipeline or
transfer-function code. The study's own table and report are checked against the same
derivation in tests/test_cli.py (``quick_study``)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
import scipy.optimize

from experiments import study, study_config, study_summary
from experiments.study import pid_axis_margins, pid_headroom_s
from experiments.study_config import DUAL_MS, GK_MS
from plant.params import PlantParams
from tests import independent_margins as im

P = PlantParams()
WC = 10.0  # the study's crossover (StudyConfig.crossover_rad_s)
CASES = [(mode, d) for mode in ("sequential", "pipelined") for d in (GK_MS, DUAL_MS)]


@pytest.fixture(scope="module")
def derived() -> dict[tuple[str, float], im.Derived]:
    return {(mode, d): im.derive(P, WC, d / 1e3, mode) for mode, d in CASES}


def test_the_derivation_gives_the_continuous_loop_as_the_period_shrinks():
    """At a 0.1 ms period without delay the sampled loop is the continuous one,
    ``C(s) / (J s² + b s)``, found here from the continuous formula, up to the sampling's phase
    lag: at most one period's worth at the crossover (half a period of hold, and at most half
    of one again from the backward difference in the derivative branch)."""
    ax = im.Axis.of(P, WC)

    def L(w: float) -> complex:
        s = 1j * w
        C = ax.Kp + ax.Ki / s + ax.Kd * s / (ax.tau_f * s + 1)
        return C / (ax.J * s * s + ax.b * s)

    wc = scipy.optimize.brentq(lambda w: abs(L(w)) - 1.0, 1.0, 100.0)
    pm_cont = math.degrees(np.angle(-L(wc)))
    T = 1e-4
    ((wd, pmd),) = im.crossovers(ax, T, 0.0)
    assert wd == pytest.approx(wc, rel=1e-3)
    assert 0.0 < pm_cont - pmd <= math.degrees(wc * T)


def test_the_two_routes_of_the_derivation_agree():
    """The eigenvalue route's instability onset at a fixed period matches the frequency
    route's phase margin / crossover (the delay margin of a sampled loop is that ratio up to
    the aliasing of the plant's higher harmonics, here below 0.2 %)."""
    ax = im.Axis.of(P, WC)
    T, tau = ax.frame_period_s, 0.5 * ax.exposure_s + 16.33e-3
    ((wc, pm),) = im.crossovers(ax, T, tau)
    estimate = math.radians(pm) / wc
    lo, hi = 0.0, 0.2
    while hi - lo > 1e-8:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if im.spectral_radius(ax, T, tau + mid) < 1 else (lo, mid)
    assert lo == pytest.approx(estimate, rel=2e-3)
    rho = [im.spectral_radius(ax, T, tau + f * lo) for f in (0.99, 1.01)]
    assert rho[0] < 1 < rho[1]


def test_the_sequential_observer_halves_the_update_rate_at_the_dual_transts_latency():
    T_f, t_exp = 1 / P.camera.frame_rate_hz, P.camera.exposure_s
    assert im.frames_per_update(GK_MS / 1e3, T_f, t_exp, "sequential") == 1
    assert im.frames_per_update(DUAL_MS / 1e3, T_f, t_exp, "sequential") == 2
    assert im.frames_per_update(DUAL_MS / 1e3, T_f, t_exp, "pipelined") == 1


@pytest.mark.parametrize(("mode", "d_ms"), CASES)
def test_the_studys_margin_functions_match_the_derivation(derived, mode, d_ms):
    """``pid_axis_margins`` (the CLI's, the study's and the notebook's) and
    ``pid_headroom_s`` to 1e-3 of the derivation: phase margin (deg), critical crossover
    (rad/s), headroom (s), update period and loop delay."""
    want = derived[(mode, d_ms)]
    timing, m = pid_axis_margins(P, WC, d_ms / 1e3, mode)
    assert m.stable
    assert timing.update_period_s == pytest.approx(want.T, rel=1e-9)
    assert timing.delay_s == pytest.approx(want.tau, rel=1e-9)
    assert m.phase_margin_deg == pytest.approx(want.phase_margin_deg, rel=1e-3)
    assert m.crossover_rad_s == pytest.approx(want.crossover_rad_s, rel=1e-3)
    assert pid_headroom_s(P, WC, d_ms / 1e3, mode) == pytest.approx(want.headroom_s, rel=1e-3)


def test_the_studys_table_and_summary_match_the_derivation(derived, monkeypatch):
    """``margins_table`` (what the study writes to margins.parquet) at the seed's two latencies
    and 0 ms, and the summary's first finding written from it, against the derivation: the
    table to 1e-3, the summary's printed figures equal to the derived ones at the printed
    precision. The table is restricted to those rows (the study's 0-60 ms grid only adds rows)."""
    monkeypatch.setattr(study, "_vision_delays_ms", lambda _step_ms: [0.0, GK_MS, DUAL_MS])
    table = study.margins_table(P, study_config.StudyConfig())
    n = 0
    for (mode, d_ms), want in derived.items():
        (row,) = (r for _, r in table.iterrows()
                  if r.observer == mode and np.isclose(r.vision_delay_ms, d_ms))
        assert row.phase_margin_deg == pytest.approx(want.phase_margin_deg, rel=1e-3)
        assert row.crossover_rad_s == pytest.approx(want.crossover_rad_s, rel=1e-3)
        assert row.headroom_s == pytest.approx(want.headroom_s, rel=1e-3)
        n += 1
    assert n == len(CASES)
    empty = pd.DataFrame(columns=["controller", "reference", "vision_delay_ms"])
    facts = {"frame_rate_hz": P.camera.frame_rate_hz, "coulomb_Nm": P.rotor.coulomb_Nm,
             "frame_period_ms": 1e3 / P.camera.frame_rate_hz, "processor": "x", "cpus": 2.0}
    (first, *_) = study_summary.summary_text(table, empty, empty, {}, {}, facts,
                                               study_config.StudyConfig())
    gk, dual = derived[("sequential", GK_MS)], derived[("sequential", DUAL_MS)]
    boundary = im.derive(P, WC, 0.0, "sequential").headroom_s
    for text in (f"16.33 ms leaves {gk.phase_margin_deg:.1f}°",
                 f"tolerates {1e3 * gk.headroom_s:.1f} ms more",
                 f"31.23 ms leaves {dual.phase_margin_deg:.1f}°",
                 f"would keep {derived[('pipelined', DUAL_MS)].phase_margin_deg:.1f}°",
                 f"unstable from {1e3 * boundary:.1f} ms of vision delay"):
        assert text in first, (text, first)
