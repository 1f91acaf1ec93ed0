"""``lti_margins`` on MATLAB's published ``allmargin`` example, against closed-loop poles with a
high-order Padé delay and python-control's own margins, and its bad input."""

import math

import control as ct
import numpy as np
import pytest

from latency.margins import lti_margins

#: MATLAB's ``allmargin`` example (Control System Toolbox documentation): the loop
#: L(s) = 25 / (s^3 + 10 s^2 + 10 s + 10) has a gain margin of 3.6 at 3.1623 rad/s, a phase
#: margin of 29.11 deg at 1.7844 rad/s and a delay margin of 0.2847 s.
PLANT = ct.tf([25.0], [1.0, 10.0, 10.0, 10.0])


def test_the_published_allmargin_example():
    """The published figures (to their printed digits), and the phase crossover exactly: on
    s = jw the denominator is 10 - 10 w² + j (10 w - w³), real at w = √10 where it is -90, so
    the gain margin is 90/25 = 3.6."""
    m = lti_margins(PLANT, 1.0)
    assert m.stable
    assert m.gain_margin == pytest.approx(3.6, rel=1e-9)
    assert m.phase_crossover_rad_s == pytest.approx(math.sqrt(10.0), rel=1e-9)
    assert m.phase_margin_deg == pytest.approx(29.11, abs=5e-3)
    assert m.crossover_rad_s == pytest.approx(1.7844, abs=5e-5)
    assert m.delay_margin_s == pytest.approx(0.2847, abs=5e-5)
    assert len(m.crossovers_rad_s) == 1


def test_an_added_delay_lowers_the_delay_margin_by_itself():
    """With 0.1 s of delay in the loop the delay margin drops by 0.1 s; the gain crossover
    stays and its phase margin loses w_c · 0.1 s."""
    m0 = lti_margins(PLANT, 1.0)
    m1 = lti_margins(PLANT, 1.0, delay_s=0.1)
    assert m1.stable and m1.delay_s == 0.1
    assert m1.delay_margin_s == pytest.approx(m0.delay_margin_s - 0.1, abs=1e-9)
    assert m1.crossover_rad_s == pytest.approx(m0.crossover_rad_s, rel=1e-9)
    lost_deg = math.degrees(m0.crossover_rad_s * 0.1)
    assert m1.phase_margin_deg == pytest.approx(m0.phase_margin_deg - lost_deg, abs=1e-7)


def test_the_delay_margin_against_closed_loop_poles_with_a_pade_delay():
    """Independent check: the closed loop with a 12th-order Padé of the delay margin's total
    delay (0.1 s in the loop plus the margin) less 1 % is stable, plus 1 % unstable."""
    m = lti_margins(PLANT, 1.0, delay_s=0.1)
    total = 0.1 + m.delay_margin_s
    worst = []
    for factor in (0.99, 1.01):
        num, den = ct.pade(factor * total, 12)
        closed = ct.feedback(PLANT * ct.tf(num, den), 1)
        worst.append(float(np.max(np.real(ct.poles(closed)))))
    assert worst[0] < 0 < worst[1]


def test_without_delay_it_agrees_with_python_controls_margin():
    """Without a delay, python-control's ``margin`` (gain margin, phase margin in degrees, and
    their frequencies) gives the same numbers; a gain controller is the same loop as the gain
    written as a transfer function, and a controller with dynamics gives the margins of the
    product."""
    gm, pm, wpc, wc = ct.margin(PLANT)
    m = lti_margins(PLANT, 1.0)
    assert (m.gain_margin, m.phase_margin_deg) == pytest.approx((gm, pm), rel=1e-6)
    assert (m.phase_crossover_rad_s, m.crossover_rad_s) == pytest.approx((wpc, wc), rel=1e-6)
    lead = ct.tf([0.5, 1.0], [0.05, 1.0])
    gm, pm, wpc, wc = ct.margin(PLANT * lead * 0.8)
    m = lti_margins(PLANT, lead * 0.8)
    assert (m.gain_margin, m.phase_margin_deg) == pytest.approx((gm, pm), rel=1e-6)
    assert (m.phase_crossover_rad_s, m.crossover_rad_s) == pytest.approx((wpc, wc), rel=1e-6)
    as_tf = lti_margins(PLANT, ct.tf([2.0], [1.0]))
    as_gain = lti_margins(PLANT, 2.0)
    assert as_gain.gain_margin == pytest.approx(as_tf.gain_margin, rel=1e-12)
    assert as_gain.phase_margin_deg == pytest.approx(as_tf.phase_margin_deg, rel=1e-12)


def test_a_gain_past_the_gain_margin_is_unstable():
    """A gain of 1.01 times the gain margin destabilises the loop: no margins, "unstable"."""
    m = lti_margins(PLANT, 3.6 * 1.01)
    assert not m.stable and m.unstable_poles == 2
    assert math.isnan(m.phase_margin_deg) and m.summary().startswith("unstable")


def test_the_hold_costs_phase():
    """A sample-and-hold at T: the phase margin at the (nearly unchanged) crossover drops by
    about w_c T / 2 (the hold's phase lag; its gain sinc(w T / 2) moves the crossover a
    little)."""
    T = 0.02
    m0 = lti_margins(PLANT, 1.0)
    mT = lti_margins(PLANT, 1.0, sample_period_s=T)
    assert mT.formulation == "hybrid" and mT.stable
    expected = m0.phase_margin_deg - math.degrees(m0.crossover_rad_s * T / 2)
    assert mT.phase_margin_deg == pytest.approx(expected, abs=0.05)


@pytest.mark.parametrize(
    ("plant", "controller", "kw", "match"),
    [
        (PLANT, "1.0", {}, "controller must be a python-control LTI system or a gain"),
        (PLANT, math.inf, {}, "controller gain must be finite"),
        ("25/(s^3+10s^2+10s+10)", 1.0, {}, "plant must be a python-control LTI system"),
        (PLANT, 1.0, {"delay_s": -0.1}, "delay_s must be finite and >= 0"),
        (PLANT, 1.0, {"sample_period_s": 0.0}, "sample_period_s must be > 0"),
        (ct.tf([1.0], [1.0, 1.0], 0.1), 1.0, {}, "plant must be a continuous-time"),
        (PLANT, ct.tf([1.0], [1.0, 0.5], 0.1), {"sample_period_s": 0.05}, "differs from"),
        (PLANT, 1.0, {"delay_s": "0.1"}, "delay_s must be a number of seconds, got str"),
        (PLANT, 1.0, {"delay_s": True}, "delay_s must be a number of seconds, got bool"),
        (PLANT, 0.0, {}, "controller is zero: the loop is open"),
        (ct.tf([0.0], [1.0, 1.0]), 1.0, {}, "plant is zero: the loop is open"),
        (ct.tf([math.nan], [1.0, 1.0]), 1.0, {}, "plant has non-finite coefficients"),
        (PLANT, ct.tf([1.0], [1.0, math.inf]), {}, "controller has non-finite coefficients"),
    ],
)
def test_bad_input_is_a_value_error_naming_the_argument(plant, controller, kw, match):
    with pytest.raises(ValueError, match=match):
        lti_margins(plant, controller, **kw)
