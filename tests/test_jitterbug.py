"""Stationary cost with a random delay (latency.jitterbug) against independent computations:
closed forms, the sampled loop of latency.margins (built differently), and a Monte Carlo
simulation of the same linear loop written here from scratch."""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

from latency.jitterbug import compare_with_simulation, stationary_cost, trajectory_cost
from latency.margins import sampled_loop

# a damped double integrator (normalised rotor) with a discrete PD on the sampled angle
JN, BN, T, NG = 1.0, 0.5, 0.25, 5
A = np.array([[0.0, 1.0], [0.0, -BN / JN]])
B = np.array([[0.0], [1.0 / JN]])
C = np.array([[1.0, 0.0]])
PLANT = ct.ss(A, B, C, 0.0)
Q1 = np.diag([1.0, 0.1])
Q2 = np.array([[0.05]])
R1C = np.diag([0.0, 1.0])  # torque noise
R2 = np.array([[1e-3]])


def discrete_pd(kp: float, kd: float) -> ct.StateSpace:
    """u = -(kp y_k + kd (y_k - y_{k-1}) / T); state y_{k-1}; returned as C(z) with u = -C y."""
    return ct.ss([[0.0]], [[1.0]], [[-kd / T]], [[kp + kd / T]], T)


def test_open_loop_stable_scalar_plant_closed_form() -> None:
    """dx = -a x dt + dv, u = 0: E x^2 = R1c / (2a) whatever the delays, so J = q R1c / (2a)."""
    a, q, r1 = 0.7, 2.0, 0.3
    plant = ct.ss([[-a]], [[1.0]], [[1.0]], [[0.0]])
    zero = ct.ss([[0.0]], [[0.0]], [[0.0]], [[0.0]], 0.1)
    for pmf in ([1.0], [0.25, 0.25, 0.5], [0.0, 0.0, 0.0, 1.0]):
        res = stationary_cost(
            plant, zero, period_s=0.1, delay_pmf=pmf, Q1=[[q]], Q2=[[1.0]], R1c=[[r1]], R2=[[0.5]]
        )
        assert res.cost == pytest.approx(q * r1 / (2 * a), rel=1e-10)
        assert res.input_cost == pytest.approx(0.0, abs=1e-14)


def test_integrator_with_static_feedback_closed_form() -> None:
    """dx = u dt + dv, u_k = -K (x_k + e_k) applied at once (tau = 0), held over T.

    x_{k+1} = (1 - KT) x_k - KT e_k + w_k, so P = (R1c T + K^2 T^2 R2) / (1 - (1 - KT)^2).
    Inside the period x(t) = (1 - Kt) x_k - K t e_k + W(t), hence
    int_0^T E x^2 = P (T - K T^2 + K^2 T^3 / 3) + K^2 R2 T^3 / 3 + R1c T^2 / 2, and
    E u^2 = K^2 (P + R2) on the whole period."""
    K, Ts, q, r, r1, r2 = 3.0, 0.2, 1.5, 0.4, 0.8, 0.01
    plant = ct.ss([[0.0]], [[1.0]], [[1.0]], [[0.0]])
    ctrl = ct.ss([[0.0]], [[0.0]], [[0.0]], [[K]], Ts)
    P = (r1 * Ts + K**2 * Ts**2 * r2) / (1 - (1 - K * Ts) ** 2)
    Jx = q / Ts * (P * (Ts - K * Ts**2 + K**2 * Ts**3 / 3) + K**2 * r2 * Ts**3 / 3 + r1 * Ts**2 / 2)
    Ju = r * K**2 * (P + r2)
    for pmf in ([1.0], [1.0, 0.0, 0.0, 0.0]):  # one grain, or four grains with zero delay
        res = stationary_cost(
            plant, ctrl, period_s=Ts, delay_pmf=pmf, Q1=[[q]], Q2=[[r]], R1c=[[r1]], R2=[[r2]]
        )
        assert res.state_cost == pytest.approx(Jx, rel=1e-10)
        assert res.input_cost == pytest.approx(Ju, rel=1e-10)
        assert res.covariance[0, 0] == pytest.approx(P, rel=1e-10)


@pytest.mark.parametrize(("kp", "kd"), [(0.8, 1.2), (4.0, 3.0)])
def test_constant_delay_stability_matches_the_sampled_loop(kp: float, kd: float) -> None:
    """For a one-hot pmf the jump system is an ordinary sampled loop: its second-moment
    spectral radius must be the square of the closed-loop spectral radius of
    latency.margins.sampled_loop (built with the fractional-delay ZOH formula)."""
    ctrl = discrete_pd(kp, kd)
    for j in range(NG):
        pmf = np.zeros(NG)
        pmf[j] = 1.0
        res = stationary_cost(PLANT, ctrl, period_s=T, delay_pmf=pmf, Q1=Q1, Q2=Q2, R1c=R1C, R2=R2)
        L = sampled_loop(PLANT, ctrl, delay_s=j * T / NG)
        rho = np.max(np.abs(np.linalg.eigvals(ct.feedback(L, 1).A)))
        assert res.spectral_radius == pytest.approx(rho**2, rel=1e-10)
        assert res.mean_square_stable == (rho < 1)
        assert math.isfinite(res.cost) == (rho < 1)
    # the (4, 3) controller is unstable with the latest delay: the analysis says so
    if kp == 4.0:
        assert not res.mean_square_stable and math.isinf(res.cost)


def monte_carlo_cost(
    ctrl: ct.StateSpace,
    pmf: np.ndarray,
    runs: int,
    periods: int,
    burn_in: int,
    sub: int,
    seed: int,
) -> tuple[float, float]:
    """Independent simulation: the plant stepped exactly over T/(N sub) with Gaussian process
    noise of the exact covariance (numerical quadrature), the command switched at the sampled
    delay, the state cost integrated with the trapezoidal rule and the (piecewise constant)
    input cost exactly. Returns (mean, standard error) of the per-run time averages."""
    rng = np.random.default_rng(seed)
    h = T / (NG * sub)
    E = scipy.linalg.expm(np.block([[A, B], [np.zeros((1, 3))]]) * h)
    Phi, Gam = E[:2, :2], E[:2, 2:]
    Wf = scipy.integrate.quad_vec(
        lambda s: scipy.linalg.expm(A * s) @ R1C @ scipy.linalg.expm(A * s).T, 0.0, h
    )[0]
    Lw = np.linalg.cholesky(Wf)
    Ac, Bc, Cc, Dc = (
        np.atleast_2d(np.asarray(M, dtype=float)) for M in (ctrl.A, ctrl.B, ctrl.C, ctrl.D)
    )
    x = np.zeros((runs, 2))
    xc = np.zeros((runs, 1))
    u_old = np.zeros((runs, 1))
    acc = np.zeros(runs)

    def qx(z: np.ndarray) -> np.ndarray:
        return np.einsum("ki,ij,kj->k", z, Q1, z)

    for k in range(burn_in + periods):
        y = x @ C.T + rng.normal(size=(runs, 1)) * math.sqrt(R2[0, 0])
        u_new = -(xc @ Cc.T + y @ Dc.T)
        xc = xc @ Ac.T + y @ Bc.T
        j = rng.choice(NG, size=runs, p=pmf)
        for s in range(NG * sub):
            u = np.where((s < j * sub)[:, None], u_old, u_new)
            xn = x @ Phi.T + u @ Gam.T + rng.normal(size=(runs, 2)) @ Lw.T
            if k >= burn_in:
                acc += h * (0.5 * (qx(x) + qx(xn)) + Q2[0, 0] * u[:, 0] ** 2)
            x = xn
        u_old = u_new
    per_run = acc / (periods * T)
    return float(per_run.mean()), float(per_run.std(ddof=1) / math.sqrt(runs))


@pytest.mark.parametrize(
    ("pmf", "seed"),
    [(np.array([0.1, 0.3, 0.3, 0.2, 0.1]), 11), (np.array([0.0, 0.0, 0.2, 0.3, 0.5]), 12)],
)
def test_cost_against_monte_carlo(pmf: np.ndarray, seed: int) -> None:
    """Analytic cost within 4 standard errors of a 1500-run Monte Carlo estimate (about 0.5 %);
    the two pmfs give costs that differ by far more than that, so the delay model matters."""
    ctrl = discrete_pd(2.0, 1.5)
    res = stationary_cost(PLANT, ctrl, period_s=T, delay_pmf=pmf, Q1=Q1, Q2=Q2, R1c=R1C, R2=R2)
    mean, se = monte_carlo_cost(ctrl, pmf, runs=1500, periods=160, burn_in=40, sub=6, seed=seed)
    assert abs(mean - res.cost) <= 4 * se
    assert se < 0.01 * res.cost
    zero_delay = stationary_cost(
        PLANT, ctrl, period_s=T, delay_pmf=[1.0, 0, 0, 0, 0], Q1=Q1, Q2=Q2, R1c=R1C, R2=R2
    )
    assert res.cost - zero_delay.cost > 10 * se


def test_trajectory_cost_and_comparison_hook() -> None:
    t = np.linspace(0.0, 4 * np.pi, 40001)
    x = np.column_stack([np.sin(t), np.zeros_like(t)])
    u = np.where(t < 2 * np.pi, 1.0, 3.0)[:, None]
    # mean of sin^2 is 1/2; u^2 averages (1 + 9) / 2 = 5
    assert trajectory_cost(t, x, u, np.eye(2), [[1.0]]) == pytest.approx(5.5, rel=1e-6)
    assert trajectory_cost(t, x, u, np.eye(2), [[1.0]], t_start_s=2 * np.pi) == pytest.approx(
        9.5, rel=1e-6
    )
    fake = stationary_cost(
        ct.ss([[-1.0]], [[1.0]], [[1.0]], [[0.0]]),
        ct.ss([[0.0]], [[0.0]], [[0.0]], [[0.0]], 0.1),
        period_s=0.1,
        delay_pmf=[1.0],
        Q1=[[1.0]],
        Q2=[[0.0]],
        R1c=[[2.0]],
        R2=[[0.0]],
    )  # cost 1.0
    runs = [(t, np.column_stack([np.sqrt(2) * np.sin(t + ph)]), 0 * t) for ph in (0.0, 0.3, 1.1)]
    cmp = compare_with_simulation(fake, runs, [[1.0]], [[0.0]])
    assert cmp.n_runs == 3 and cmp.analytic == pytest.approx(1.0, rel=1e-10)
    assert cmp.simulated_mean == pytest.approx(1.0, rel=1e-4)


def test_bad_input() -> None:
    ctrl = discrete_pd(1.0, 1.0)
    kw = dict(Q1=Q1, Q2=Q2, R1c=R1C, R2=R2)
    with pytest.raises(ValueError, match="sum to 1"):
        stationary_cost(PLANT, ctrl, period_s=T, delay_pmf=[0.5, 0.4], **kw)
    with pytest.raises(ValueError, match="differs"):
        stationary_cost(PLANT, ctrl, period_s=0.1, delay_pmf=[1.0], **kw)
    with pytest.raises(ValueError, match="discrete"):
        stationary_cost(PLANT, ct.tf([1.0], [1.0]), period_s=T, delay_pmf=[1.0], **kw)
    with pytest.raises(ValueError, match="Q1"):
        stationary_cost(PLANT, ctrl, period_s=T, delay_pmf=[1.0], **{**kw, "Q1": np.eye(3)})
