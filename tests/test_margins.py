"""Exact-delay margins (latency.margins) against independent computations.

Independent references used here: closed forms for a double integrator with PD control and a
delay, and for k/(s(s+a)) (jitter margin); closed-loop poles of a Padé approximation computed
directly with numpy; a time-domain simulation of the delay-differential equation; python-control's
own c2d and stability_margins on the exact discrete loop; an ODE solver for the fractional-delay
discretisation.
"""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
import scipy.integrate
import scipy.optimize
from matplotlib.figure import Figure

from latency.margins import (
    attitude_delay_sweep,
    attitude_margins,
    bode_data,
    first_unstable_delay,
    jitter_margin,
    loop_frd,
    loop_margins,
    loop_model,
    loop_pade,
    nyquist_count,
    pade_margins,
    plot_bode,
    plot_nyquist,
    sampled_margins,
    sampled_plant,
)

# double integrator J s^2 with PD  C = Kp + Kd s (normalised units)
J, KP, KD = 1.0, 1.0, 1.5


def pd_closed_forms(tau: float) -> dict[str, float]:
    """Hand-derived margins of L = (Kp + Kd s) e^{-s tau} / (J s^2).

    |L(jw)| = sqrt(Kp^2 + Kd^2 w^2) / (J w^2) = 1  <=>  J^2 w^4 - Kd^2 w^2 - Kp^2 = 0, so
    w_c^2 = (Kd^2 + sqrt(Kd^4 + 4 J^2 Kp^2)) / (2 J^2). arg L = -pi + atan(Kd w / Kp) - w tau, so
    PM = atan(Kd w_c / Kp) - w_c tau and the delay margin is PM / w_c. The phase crossover solves
    atan(Kd w / Kp) = w tau (one root for tau > 0 below the first wrap), GM = 1 / |L| there.
    """
    wc = math.sqrt((KD**2 + math.sqrt(KD**4 + 4 * J**2 * KP**2)) / (2 * J**2))
    pm = math.atan(KD * wc / KP) - wc * tau
    out = {"wc": wc, "pm_deg": math.degrees(pm), "dm": pm / wc}
    if tau > 0:
        wpc = scipy.optimize.brentq(lambda w: math.atan(KD * w / KP) - w * tau, 1e-9, 50.0)
        out["wpc"] = wpc
        out["gm"] = J * wpc**2 / math.hypot(KP, KD * wpc)
    return out


def pd_model(tau: float):
    return loop_model(ct.tf([1.0], [J, 0.0, 0.0]), ct.tf([KD, KP], [1.0]), delay_s=tau)


def pade_closed_loop_poles(tau: float, order: int = 10) -> np.ndarray:
    """Roots of J s^2 d(s) + (Kd s + Kp) n(s), n/d the Padé approximant of e^{-s tau}."""
    n, d = ct.pade(tau, order)
    char = np.polyadd(np.polymul([J, 0.0, 0.0], d), np.polymul([KD, KP], n))
    return np.roots(char)


def simulate_dde(tau: float, t_end: float, steps_per_delay: int = 200) -> np.ndarray:
    """Heun integration of J th'' = -Kp th(t - tau) - Kd th'(t - tau), th = 1, th' = 0 for t <= 0.

    Returns |th| on the grid. The delayed values sit exactly on the grid (h = tau / M)."""
    h = tau / steps_per_delay
    n = int(t_end / h)
    M = steps_per_delay
    th = np.empty(n + 1)
    om = np.empty(n + 1)
    th[0], om[0] = 1.0, 0.0

    def u(k: int) -> float:
        if k - M < 0:
            return -KP * 1.0
        return -KP * th[k - M] - KD * om[k - M]

    for k in range(n):
        u0, u1 = u(k), u(k + 1)
        a0 = u0 / J
        th_p, om_p = th[k] + h * om[k], om[k] + h * a0
        a1 = u1 / J
        th[k + 1] = th[k] + 0.5 * h * (om[k] + om_p)
        om[k + 1] = om[k] + 0.5 * h * (a0 + a1)
        del th_p
    return np.abs(th)


@pytest.mark.parametrize("tau", [0.0, 0.2, 0.5])
def test_double_integrator_pd_matches_closed_forms(tau: float) -> None:
    ref = pd_closed_forms(tau)
    m = loop_margins(pd_model(tau))
    assert m.stable
    assert m.crossovers_rad_s == pytest.approx((ref["wc"],), rel=1e-10)
    assert m.crossover_rad_s == pytest.approx(ref["wc"], rel=1e-10)
    assert m.phase_margin_deg == pytest.approx(ref["pm_deg"], abs=1e-8)
    assert m.delay_margin_s == pytest.approx(ref["dm"], rel=1e-9)
    if tau > 0:
        assert m.phase_crossover_rad_s == pytest.approx(ref["wpc"], rel=1e-9)
        assert m.gain_margin == pytest.approx(ref["gm"], rel=1e-9)
    else:
        assert math.isinf(m.gain_margin)  # phase never reaches -180 deg without delay


def test_stable_just_below_and_unstable_just_above_the_delay_margin() -> None:
    tau_max = pd_closed_forms(0.0)["dm"]  # total delay margin with no delay in the loop
    below, above = 0.98 * tau_max, 1.02 * tau_max
    assert loop_margins(pd_model(below)).stable
    m_above = loop_margins(pd_model(above))
    assert not m_above.stable and m_above.unstable_poles == 2
    # independent 1: closed-loop poles of a 10th-order Padé approximation
    assert np.max(pade_closed_loop_poles(below).real) < -0.01
    assert np.max(pade_closed_loop_poles(above).real) > 0.01
    # independent 2: time-domain simulation of the delay-differential equation (rightmost
    # roots at about -0.0226 and +0.0213 1/s: the envelope shrinks or grows by ~e^5 over 240 s)
    for tau, grows in ((below, False), (above, True)):
        th = simulate_dde(tau, 300.0)
        t = np.linspace(0.0, 300.0, th.size)
        early = th[(t > 20) & (t < 60)].max()
        late = th[t > 260].max()
        assert (late > 20 * early) if grows else (late < early / 20)


def test_python_control_is_misled_but_we_say_unstable() -> None:
    """tau = 3 s: the phase at crossover is -391 deg; stability_margins wraps it and reports
    a phase margin of about +149 deg for a loop with two closed-loop poles in the RHP."""
    tau = 3.0
    frd = loop_frd(
        ct.tf([1.0], [J, 0.0, 0.0]),
        ct.tf([KD, KP], [1.0]),
        delay_s=tau,
        omega=np.logspace(-2, 2, 4000),
    )
    _, pm_ct, *_ = ct.stability_margins(frd)
    assert pm_ct > 100.0  # the misleading number
    m = loop_margins(pd_model(tau))
    assert not m.stable
    assert math.isnan(m.phase_margin_deg) and math.isnan(m.delay_margin_s)
    assert m.summary().startswith("unstable")
    assert np.max(pade_closed_loop_poles(tau).real) > 0.0
    # the raw wrapped value is still available for diagnosis and equals what python-control saw
    assert m.phase_margins_deg[0] == pytest.approx(pm_ct, abs=0.05)


def test_open_loop_unstable_plant_hand_margins() -> None:
    """L = K e^{-s tau} / (s - 1), K = 2: one open-loop RHP pole; |L| = 1 at w = sqrt(K^2-1),
    arg L = -pi + atan(w) - w tau, so the delay margin is atan(sqrt 3)/sqrt 3 = pi/(3 sqrt 3)."""
    K = 2.0
    wc = math.sqrt(K**2 - 1)
    tau_max = math.atan(wc) / wc
    for tau in (0.0, 0.3):
        model = loop_model(ct.tf([K], [1.0, -1.0]), 1.0, delay_s=tau)
        assert model.open_loop_rhp_poles == 1
        m = loop_margins(model)
        assert m.stable
        assert m.phase_margin_deg == pytest.approx(math.degrees(math.atan(wc) - wc * tau), abs=1e-8)
        assert m.delay_margin_s == pytest.approx(tau_max - tau, rel=1e-9)
        # lowering the gain below 1 destabilises: gain_margin_lower = 1/|L(0)| = 1/K
        assert m.gain_margin_lower == pytest.approx(1.0 / K, rel=1e-9)
    assert not loop_margins(loop_model(ct.tf([K], [1.0, -1.0]), 1.0, delay_s=1.02 * tau_max)).stable
    Z, N, _, _ = nyquist_count(loop_model(ct.tf([0.5], [1.0, -1.0]), 1.0))
    assert (Z, N) == (1, 0)  # too little gain: the unstable pole stays


def test_jitter_margin_matches_kao_lincoln_by_hand() -> None:
    """L = k / (s (s + a)): T = k / (s^2 + a s + k) and w|T| = k / sqrt((k - w^2)^2/w^2 + a^2)
    peaks at w = sqrt(k) with value k / a, so delta_max = a / k (Kao & Lincoln 2004)."""
    for k, a in ((4.0, 2.0), (1.0, 0.5), (30.0, 3.0)):
        model = loop_model(ct.tf([k], [1.0, a, 0.0]), 1.0)
        dmax, wpk = jitter_margin(model)
        assert dmax == pytest.approx(a / k, rel=1e-8)
        assert wpk == pytest.approx(math.sqrt(k), rel=1e-4)
        m = loop_margins(model)
        assert m.jitter_margin_s == pytest.approx(a / k, rel=1e-8)
        assert m.jitter_margin_s <= m.delay_margin_s  # a constant delay is one admissible case


def test_jitter_margin_with_a_constant_delay_against_the_definition() -> None:
    """With the delay inside L, delta_max = 1 / max_w w |L/(1+L)|, evaluated by brute force."""
    tau = 0.3
    model = pd_model(tau)
    w = np.logspace(-3, 4, 400_001)
    Lw = (KP + KD * 1j * w) / (J * (1j * w) ** 2) * np.exp(-1j * w * tau)
    brute = 1.0 / np.max(w * np.abs(Lw / (1 + Lw)))
    m = loop_margins(model)
    assert m.jitter_margin_s == pytest.approx(brute, rel=1e-6)
    assert m.jitter_margin_s < m.delay_margin_s


# ---------------------------------------------------------------------------------------------
# Sampling: the hold term against the exact discrete loop
# ---------------------------------------------------------------------------------------------

JR, BR = 2.2e-3, 2.0e-3  # rotor inertia and damping (plant/params.py defaults)


def lead_controller(wc: float, T: float, a: float = 9.0) -> ct.TransferFunction:
    """Lead PD centred on wc (same rule as the benchmark), Tustin with prewarping at wc."""
    K = JR * wc**2 / math.sqrt(a)
    C = K * ct.tf([math.sqrt(a) / wc, 1.0], [1.0 / (wc * math.sqrt(a)), 1.0])
    return ct.c2d(C, T, "tustin", prewarp_frequency=wc)


def test_hold_term_is_the_unaliased_part_of_the_exact_discrete_response() -> None:
    """c2d(P, 'zoh')(e^{jwT}) = sum_k H_T(jw_k) P(jw_k), w_k = w + 2 pi k / T (Poisson sum);
    the hybrid model keeps k = 0 only."""
    T = 1 / 36
    P = ct.tf([1.0], [JR, BR, 0.0])
    Pd = ct.c2d(P, T, "zoh")
    w = np.array([1.0, 10.0, 30.0, 80.0])
    exact = np.array([complex(Pd(np.exp(1j * x * T))) for x in w])
    k = np.arange(-20000, 20001)
    ws = 2 * np.pi / T
    alias = np.array(
        [
            np.sum(
                ((1 - np.exp(-1j * (x + k * ws) * T)) / (1j * (x + k * ws) * T))
                * P(1j * (x + k * ws))
            )
            for x in w
        ]
    )
    assert np.allclose(alias, exact, rtol=1e-7)
    hybrid = loop_model(P, 1.0, sample_period_s=T).response(w)
    kept = ((1 - np.exp(-1j * w * T)) / (1j * w * T)) * P(1j * w)
    assert np.allclose(hybrid, kept, rtol=1e-12)


@pytest.mark.parametrize(("fc", "frame_hz"), [(3.0, 36.0), (5.0, 36.0), (5.0, 61.23)])
def test_hybrid_margins_against_the_exact_discrete_loop(fc: float, frame_hz: float) -> None:
    """Phase margin of the hybrid model vs python-control's margins of c2d(P, zoh) * C(z).

    The tolerance is derived from the aliasing the hybrid model neglects: with
    r = max |L_d - L_h| / |L_h| near crossover, the phase differs by at most asin(r) at a given
    frequency, and the crossover moves by at most -ln(1 - r) / |d ln|L| / d ln w|, which costs
    |d arg L / d ln w| times that in phase."""
    T = 1 / frame_hz
    wc = 2 * np.pi * fc
    P = ct.tf([1.0], [JR, BR, 0.0])
    Cd = lead_controller(wc, T)
    Ld = ct.c2d(P, T, "zoh") * Cd
    assert np.all(np.abs(ct.feedback(Ld, 1).poles()) < 1)
    _, pm_d, _, _, wc_d, _ = ct.stability_margins(Ld)
    hyb = loop_model(P, Cd)
    m = loop_margins(hyb)
    assert m.stable
    band = np.linspace(0.7 * wc_d, 1.3 * wc_d, 2001)
    Lh = hyb.response(band)
    Lde = np.array([complex(Ld(np.exp(1j * x * T))) for x in band])
    r = float(np.max(np.abs(Lde - Lh) / np.abs(Lh)))
    lnw = np.log(band)
    slope_mag = np.min(np.abs(np.gradient(np.log(np.abs(Lh)), lnw)))
    slope_ph = np.max(np.abs(np.gradient(np.unwrap(np.angle(Lh)), lnw)))
    bound = math.degrees(math.asin(r) + slope_ph * (-math.log(1 - r)) / slope_mag)
    assert 0 < bound < 1.0
    assert abs(m.phase_margin_deg - pm_d) <= bound
    assert m.crossover_rad_s == pytest.approx(wc_d, rel=-math.log(1 - r) / slope_mag + 1e-9)
    # the exact sampled formulation reproduces python-control's discrete margins
    s = sampled_margins(P, Cd)
    assert s.phase_margin_deg == pytest.approx(pm_d, abs=1e-6)
    assert s.crossover_rad_s == pytest.approx(wc_d, rel=1e-8)


def test_sampled_plant_with_fractional_delay_against_an_ode_solver() -> None:
    """x[k] of sampled_plant equals the continuous plant driven by the delayed held input."""
    T, tau = 0.05, 0.083  # tau = 1.66 T: m = 1, fractional part 0.66 T
    P = ct.ss(ct.tf([1.0], [JR, BR, 0.0]))
    A, B, C = (np.asarray(M, dtype=float) for M in (P.A, P.B, P.C))
    rng = np.random.default_rng(3)
    u = rng.normal(size=40) * 1e-3
    # discrete model
    Pd = sampled_plant(P, T, tau)
    _, yd = ct.forced_response(Pd, T=np.arange(40) * T, U=u)
    # ODE: u_k acts on [kT + tau, (k+1)T + tau)
    edges = np.concatenate([[0.0], np.arange(40) * T + tau])
    vals = np.concatenate([[0.0], u])
    x = np.zeros(A.shape[0])
    t_now = 0.0
    yc = [float((C @ x)[0])]
    for k in range(1, 40):
        t_next = k * T
        cuts = [c for c in edges if t_now < c < t_next] + [t_next]
        for c in cuts:
            ui = vals[np.searchsorted(edges, t_now, side="right") - 1]
            sol = scipy.integrate.solve_ivp(
                lambda _t, z, ui=ui: A @ z + B[:, 0] * ui, (t_now, c), x, rtol=1e-11, atol=1e-15
            )
            x = sol.y[:, -1]
            t_now = c
        yc.append(float((C @ x)[0]))
    assert np.allclose(yd, yc, rtol=1e-7, atol=1e-12)
    # integer delay: the same as c2d(zoh) followed by z^-2
    Pd2 = sampled_plant(P, T, 2 * T)
    w = np.array([0.5, 5.0, 40.0])
    z = np.exp(1j * w * T)
    ref = np.array([complex(ct.c2d(P, T, "zoh")(zi)) for zi in z]) * z**-2
    got = np.array([complex(Pd2(zi)) for zi in z])
    assert np.allclose(got, ref, rtol=1e-9)


def test_sampled_delay_margin_agrees_with_the_hybrid_delay_margin() -> None:
    """Two different computations (eigenvalue scan of the sampled loop; PM / w_c of the hybrid
    exact-delay loop) agree within the aliasing error, and the scan brackets the boundary."""
    T = 1 / 36
    Cd = lead_controller(2 * np.pi * 3.0, T)
    P = ct.tf([1.0], [JR, BR, 0.0])
    h = attitude_margins(
        Cd, inertia_kgm2=JR, damping_Nms_per_rad=BR, frame_period_s=T, delay_s=0.01633
    )
    s = attitude_margins(
        Cd,
        inertia_kgm2=JR,
        damping_Nms_per_rad=BR,
        frame_period_s=T,
        delay_s=0.01633,
        formulation="sampled",
    )
    assert s.delay_margin_s == pytest.approx(h.delay_margin_s, rel=0.01)
    inside = sampled_margins(P, Cd, delay_s=0.01633 + 0.99 * s.delay_margin_s)
    outside = sampled_margins(P, Cd, delay_s=0.01633 + 1.01 * s.delay_margin_s)
    assert inside.stable and not outside.stable


# ---------------------------------------------------------------------------------------------
# Padé comparison, sweeps, plots, bad input
# ---------------------------------------------------------------------------------------------


def test_pade_version_agrees_with_the_exact_delay_where_pade_is_accurate() -> None:
    T = 1 / 61.23
    Cd = lead_controller(2 * np.pi * 3.0, T)
    model = loop_model(ct.tf([1.0], [JR, BR, 0.0]), Cd, delay_s=0.01633)
    exact = loop_margins(model)
    approx = pade_margins(model, order=6)
    assert approx.stable == exact.stable
    assert approx.phase_margin_deg == pytest.approx(exact.phase_margin_deg, abs=0.01)
    Lr = loop_pade(model, 6)
    w = np.array([1.0, 10.0, exact.crossover_rad_s])
    assert np.allclose(Lr(1j * w), model.response(w), rtol=1e-6)


def test_delay_sweep_table() -> None:
    T = 1 / 36
    Cd = lead_controller(2 * np.pi * 5.0, T)
    df = attitude_delay_sweep(
        Cd,
        inertia_kgm2=JR,
        damping_Nms_per_rad=BR,
        frame_period_s=T,
        delays_s=np.linspace(0, 0.03, 7),
    )
    assert list(df.columns) == [
        "delay_s",
        "phase_margin_deg",
        "gain_margin",
        "crossover_rad_s",
        "delay_margin_s",
        "jitter_margin_s",
        "gain_margin_lower",
        "n_crossovers",
        "conditionally_stable",
        "stable",
    ]
    st = df[df.stable]
    assert np.all(np.diff(st.phase_margin_deg) < 0)
    # the delay margin is the distance to the first unstable delay
    first_unstable = df.delay_s[~df.stable].min()
    last_stable = st.delay_s.max()
    edge = last_stable + st.delay_margin_s.iloc[-1]
    assert last_stable < edge < first_unstable
    assert df[~df.stable].phase_margin_deg.isna().all()


def test_bode_nyquist_and_plots() -> None:
    model = pd_model(0.2)
    w, mag, ph = bode_data(model)
    assert np.all(np.diff(w) > 0) and mag.shape == ph.shape == w.shape
    # arg L = -180 + atan(Kd w / Kp) - w tau, unwrapped
    assert np.allclose(ph, -180 + np.degrees(np.arctan(KD * w / KP) - 0.2 * w), atol=1e-9)
    m = loop_margins(model)
    assert isinstance(plot_bode(model, m), Figure)
    assert isinstance(plot_nyquist(model, m), Figure)


def test_bad_input() -> None:
    P = ct.tf([1.0], [1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="delay_s"):
        loop_model(P, 1.0, delay_s=-0.01)
    with pytest.raises(ValueError, match="SISO"):
        loop_model(P, ct.ss(np.zeros((1, 1)), np.ones((1, 2)), np.ones((1, 1)), np.zeros((1, 2))))
    with pytest.raises(ValueError, match="differs"):
        loop_model(P, ct.tf([1.0], [1.0], 0.1), sample_period_s=0.05)
    with pytest.raises(ValueError, match="strictly proper"):
        loop_model(ct.tf([1.0, 0.0], [1.0, 1.0]), ct.tf([1.0, 1.0], [1.0]))
    with pytest.raises(ValueError, match="continuous"):
        loop_model(ct.tf([1.0], [1.0, 1.0], 0.1), 1.0)
    with pytest.raises(ValueError, match="unit circle"):
        loop_model(P, ct.tf([1.0], [1.0, -1.5], 0.1))
    with pytest.raises(ValueError, match="discrete"):
        sampled_margins(P, ct.tf([1.0], [1.0]))


def test_nyquist_verdict_agrees_with_sampled_eigenvalues_on_random_loops() -> None:
    """40 random rotor loops (PD or PID, crossover 1-8 Hz, frames 30-120 Hz, delay 0-60 ms):
    the Nyquist count on the hybrid exact-delay model and the eigenvalues of the exact sampled
    loop give the same verdict wherever the sampled spectral radius is not within 2 % of 1 (the
    hybrid model's aliasing error could legitimately flip cases that close to the boundary)."""
    rng = np.random.default_rng(7)
    P = ct.tf([1.0], [JR, BR, 0.0])
    checked = unstable = 0
    for _ in range(40):
        fc, fr, tau = rng.uniform(1, 8), rng.uniform(30, 120), rng.uniform(0, 0.06)
        T = 1 / fr
        Cd = lead_controller(2 * np.pi * fc, T)
        if rng.random() < 0.5:
            Cd = Cd * ct.c2d(ct.tf([1.0, 2 * np.pi * fc / 10], [1.0, 0.0]), T, "tustin")
        cl = ct.feedback(ct.series(sampled_plant(P, T, tau), ct.ss(Cd)), 1)
        rho = np.max(np.abs(np.linalg.eigvals(cl.A)))
        if abs(rho - 1) < 0.02:
            continue
        checked += 1
        unstable += rho > 1
        assert loop_margins(loop_model(P, Cd, delay_s=tau)).stable == (rho < 1)
    assert checked >= 30 and 5 <= unstable <= checked - 5


# --- several gain crossovers, the critical one, conditional stability ---------------------------
# L(s) = K (s/z + 1) / (s (s²/wn² + 2 zeta s/wn + 1)): a lightly damped resonance above the first
# crossover lifts |L| through 1 twice more. Stable (Routh on the closed loop, checked below).
RES_K, RES_Z, RES_WN, RES_ZETA = 1.0, 2.0, 10.0, 0.05


def _resonant_loop() -> ct.TransferFunction:
    num = np.polymul([RES_K], [1.0 / RES_Z, 1.0])
    den = np.polymul([1.0, 0.0], [1.0 / RES_WN**2, 2 * RES_ZETA / RES_WN, 1.0])
    return ct.tf(num, den)


def _resonant_crossovers() -> tuple[np.ndarray, np.ndarray]:
    """Crossovers and phase margins by hand: |L|² = 1 is a cubic in x = w²,
    K² (1 + x/z²) = x ((1 - x/wn²)² + 4 zeta² x/wn²); arg L = atan(w/z) - 90° - arg(resonance)."""
    a = 1.0 / RES_WN**2
    resonance_sq = np.polyadd(np.polymul([-a, 1.0], [-a, 1.0]), [4 * RES_ZETA**2 * a, 0.0])
    cubic = np.polysub(np.polymul([1.0, 0.0], resonance_sq), [RES_K**2 / RES_Z**2, RES_K**2])
    roots = np.roots(cubic)
    x = np.sort(roots.real[np.abs(roots.imag) < 1e-9])
    w = np.sqrt(x[x > 0])
    resonance = np.arctan2(2 * RES_ZETA * w / RES_WN, 1 - (w / RES_WN) ** 2)
    phase = np.arctan(w / RES_Z) - np.pi / 2 - resonance
    pm = np.degrees(np.angle(np.exp(1j * (np.pi + phase))))
    return w, pm


def test_every_crossover_is_reported_and_the_critical_one_is_closest_to_minus_one() -> None:
    L = _resonant_loop()
    cl = np.roots(np.polyadd(L.den[0][0], np.polyadd(np.zeros(4), L.num[0][0])))
    assert np.all(cl.real < 0)  # the closed loop is stable (independent of the code)
    w_ref, pm_ref = _resonant_crossovers()
    assert len(w_ref) == 3
    m = loop_margins(loop_model(L, 1.0))
    assert m.stable
    assert m.crossovers_rad_s == pytest.approx(tuple(w_ref), rel=1e-9)
    assert m.phase_margins_deg == pytest.approx(tuple(pm_ref), abs=1e-7)
    k = int(np.argmin(np.abs(pm_ref)))  # closest to -1: |1 + L| = 2 sin(|PM|/2) is smallest
    assert m.critical_crossover == k and k == 2
    assert m.phase_margin_deg == pytest.approx(pm_ref[k], abs=1e-7)
    assert m.crossover_rad_s == pytest.approx(w_ref[k], rel=1e-9)
    assert m.delay_margin_s == pytest.approx(
        min(math.radians(p % 360.0) / x for p, x in zip(pm_ref, w_ref, strict=True)), rel=1e-7
    )
    assert not m.conditionally_stable
    lines = m.crossover_lines()
    assert len(lines) == 3 and "critical" in lines[2] and "critical" not in lines[0] + lines[1]


def test_conditionally_stable_only_with_a_lower_gain_margin() -> None:
    """L = K (s + 1)² / s³: closed loop s³ + K s² + 2K s + K is stable iff K > 1/2 (Routh); the
    phase is -180° at w = 1 where |L| = 2K, so the gain may shrink by 1/(2K) before instability."""
    K = 2.0
    m = loop_margins(loop_model(ct.tf(K * np.array([1.0, 2.0, 1.0]), [1.0, 0.0, 0.0, 0.0]), 1.0))
    assert m.stable and m.conditionally_stable
    assert m.gain_margin_lower == pytest.approx(1.0 / (2.0 * K), rel=1e-9)
    assert math.isinf(m.gain_margin)
    assert "conditionally stable" in m.summary()
    # the double-integrator PD loop has no lower gain margin: not conditionally stable
    pd = loop_margins(pd_model(0.2))
    assert pd.stable and not pd.conditionally_stable
    assert "conditionally" not in pd.summary()


def test_first_unstable_delay_finds_the_closed_form_delay_margin() -> None:
    dm = pd_closed_forms(0.0)["dm"]  # the PD loop is stable for every delay below dm
    found = first_unstable_delay(lambda d: loop_margins(pd_model(d)).stable, 0.1, step_s=0.05,
                                 limit_s=3.0, tol_s=1e-7)
    assert found == pytest.approx(dm, abs=2e-7)
    assert first_unstable_delay(lambda d: True, 0.0, limit_s=0.01) == math.inf
