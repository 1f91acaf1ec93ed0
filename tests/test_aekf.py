"""Quaternion EKF/AEKF: against ground truth from the MuJoCo plant, and its delay compensation."""

import numpy as np
import pytest

from observer.aekf import AEKFConfig, QuaternionAEKF
from plant import attitude as A
from plant.camera import marker_pixels
from plant.dynamics import MujocoPlant
from plant.params import PlantParams

P = PlantParams()
H = P.physics_dt_s
FRAME = 1.0 / P.camera.frame_rate_hz


def torque(t):
    """Stator-frame torque (N·m) that spins the rotor and wobbles it below the tilt stop."""
    return np.array([0.0015 * np.cos(4 * t), -0.0015 * np.sin(5 * t), 0.03 * np.sin(2 * t)])


@pytest.fixture(scope="module")
def truth():
    """2 s of MuJoCo truth at 1 kHz: attitudes (N+1, 4)."""
    plant = MujocoPlant(P)
    qs = [plant.q]
    for k in range(2000):
        plant.step(plant.allocate(torque(k * H)).currents, H)
        qs.append(plant.q)
    qs = np.array(qs)
    assert max(A.tilt(q) for q in qs) < np.deg2rad(14)  # away from the stop
    return qs


def run(truth, config, delay_s, sigma_true_px, seed=1):
    """Frames every FRAME s, released after delay_s; returns compensated and uncompensated
    geodesic errors (rad) at the release times, and the update results."""
    f = QuaternionAEKF(P, config)
    rng = np.random.default_rng(seed)
    k_done, err_c, err_u, results = 0, [], [], []
    for j in range(1, 200):
        k_e = round(j * FRAME / H)
        k_a = k_e + round(delay_s / H)
        if k_a >= len(truth):
            break
        for k in range(k_done, k_a):
            f.set_torque(k * H, torque(k * H))
        k_done = k_a
        z = marker_pixels(P, truth[k_e]) + rng.normal(scale=sigma_true_px, size=(2, 2))
        results.append(f.update(z, k_e * H))
        q_now, _, _ = f.estimate_at(k_a * H)
        err_c.append(A.geodesic_angle(q_now, truth[k_a]))
        err_u.append(A.geodesic_angle(f.q, truth[k_a]))
    return np.array(err_c[20:]), np.array(err_u[20:]), results


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def test_delay_compensation_predicts_the_present(truth):
    # GK-TransT's seed latency, 16.33 ms, and the dual TransT's 31.23 ms (seed 000 Table 1).
    for delay in (0.01633, 0.03123):
        err_c, err_u, results = run(truth, AEKFConfig(), delay, 1.0)
        assert all(r.accepted for r in results[5:])
        print(f"delay {delay * 1e3:.2f} ms: compensated RMS {np.degrees(rms(err_c)):.3f} deg, "
              f"uncompensated {np.degrees(rms(err_u)):.3f} deg")
        assert rms(err_c) < np.deg2rad(0.3)
        assert rms(err_u) > 10 * rms(err_c)


def test_prediction_without_measurements_follows_the_plant():
    # From the true initial state and the known torque the filter's model alone tracks MuJoCo.
    # MuJoCo holds the coil currents and the Coulomb torque over each physics step while the
    # filter integrates the continuous-time model, so the gap is first order in the step: it
    # must shrink about 4x when the physics step does.
    gaps = []
    for dt in (1e-3, 2.5e-4):
        p = P.model_copy(update={"physics_dt_s": dt})
        plant = MujocoPlant(p)
        n = round(0.5 / dt)
        for k in range(n):
            plant.step(plant.allocate(torque(k * dt)).currents, dt)
        f = QuaternionAEKF(p, AEKFConfig())
        for k in range(n):
            f.set_torque(k * dt, torque(k * dt))
        q, _, _ = f.estimate_at(0.5)
        gaps.append(A.geodesic_angle(q, plant.q))
    assert A.geodesic_angle(plant.q, [1.0, 0, 0, 0]) > 0.3  # it did move (18°)
    assert gaps[0] < 2e-4
    assert 3.0 < gaps[0] / gaps[1] < 5.0


@pytest.fixture(scope="module")
def underestimated(truth):
    """EKF and AEKF assuming 1 px of noise on pixels with 4 px (16x the variance)."""
    cfg = {"sigma_px": 1.0}
    return (run(truth, AEKFConfig(adaptive=False, **cfg), 0.02, 4.0),
            run(truth, AEKFConfig(adaptive=True, **cfg), 0.02, 4.0))


def _median_lambda(underestimated) -> float:
    _, (_, _, res_aekf) = underestimated
    lam = np.array([r.lam for r in res_aekf[20:]])
    assert len(lam) >= 50  # 71 frames of 27.8 ms after the first 20
    return float(np.median(lam))


def test_adaptive_filter_inflates_R_when_the_noise_is_underestimated(truth, underestimated):
    """True variance 16x the assumed one. λ matches the innovation covariance
    tr(H P Hᵀ + R): the sample innovation covariance is H P Hᵀ + 16 R at most, so
    1 < λ < 16 (16 only if P vanished)."""
    (err_ekf, _, res_ekf), (err_aekf, _, _) = underestimated
    assert 1.0 < _median_lambda(underestimated) < 16.0
    assert all(r.lam == 1.0 for r in res_ekf)
    assert rms(err_aekf) < rms(err_ekf)
    # With the right noise level the two agree closely.
    e1, _, _ = run(truth, AEKFConfig(adaptive=False), 0.02, 1.0)
    e2, _, _ = run(truth, AEKFConfig(adaptive=True), 0.02, 1.0)
    assert rms(e2) == pytest.approx(rms(e1), rel=0.2)


def test_adaptive_filter_lambda_does_not_regress(underestimated):
    """A regression guard: the median λ measured here, 2.69 with this seed (2.7-3.1 over seeds
    1-3), the figure quoted in docs/observer.md, stays in its band; beside it the derived
    bound 1 < λ < 16 of the test above."""
    lam = _median_lambda(underestimated)
    assert 1.0 < lam < 16.0
    assert 2.2 < lam < 3.5


def test_covariance_is_consistent_at_rest():
    # Normalised estimation error squared over Monte Carlo runs: mean ~ 3 for a consistent filter.
    q_true = A.from_zyz(0.4, np.deg2rad(8), 1.1)
    nees = []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        # No process noise: the rotor is at rest, so the filter is a recursive least squares.
        cfg = AEKFConfig(adaptive=False, q_quat_per_s=0.0, q_omega_rad2_per_s3=0.0)
        f = QuaternionAEKF(P, cfg, q0=A.from_zyz(0.41, 0.14, 1.1))
        for j in range(1, 31):
            f.update(marker_pixels(P, q_true) + rng.normal(size=(2, 2)), j * FRAME)
        q, _, C = f.estimate_at(f.t)
        d = A.to_rotvec(A.multiply(A.conjugate(q), q_true))
        nees.append(d @ np.linalg.solve(C, d))
    # 40 runs of a chi-square(3): the mean lies within [2.2, 3.9] with probability > 99 %.
    assert 2.2 < np.mean(nees) < 3.9


def test_each_filter_models_its_own_plant():
    """Filters share their model functions per plant: a filter on a plant with a longer lens,
    built after one on the default plant, fed the exact pixels of its own camera at rest,
    settles on the true attitude (to 1e-6 rad; measured 6e-8); with the default camera's model
    it would not (the pixels are 20 % further from the centre: measured 1e-2 rad off)."""
    other = PlantParams(camera={"focal_length_m": 1.2 * P.camera.focal_length_m})
    q_true = A.from_zyz(0.4, np.deg2rad(8), 1.1)
    cfg = AEKFConfig(adaptive=False, q_quat_per_s=0.0, q_omega_rad2_per_s3=0.0)
    errors = {}
    for name, params in (("default", P), ("other", other)):
        f = QuaternionAEKF(params, cfg, q0=A.from_zyz(0.41, 0.14, 1.1),
                           P0_diag=(1e-2, 1e-2, 1e-2, 1e-2, 1.0, 1.0, 1.0))  # a weak prior
        for j in range(1, 31):
            f.update(marker_pixels(params, q_true), j * FRAME)
        errors[name] = A.geodesic_angle(f.estimate_at(f.t)[0], q_true)
    assert errors["default"] < 1e-6 and errors["other"] < 1e-6


def test_missing_stale_and_outlying_measurements_are_flagged():
    f = QuaternionAEKF(P, AEKFConfig())
    z = marker_pixels(P, [1.0, 0, 0, 0])
    assert f.update(np.vstack([z[0], [np.nan, np.nan]]), 0.03).accepted  # one marker still helps
    r = f.update(np.full((2, 2), np.nan), 0.06)
    assert not r.accepted and "finite" in r.reason
    r = f.update(z, 0.01)
    assert not r.accepted and "stale" in r.reason
    r = f.update(z + 500.0, 0.09)
    assert not r.accepted and "gate" in r.reason
    assert A.geodesic_angle(f.q, [1.0, 0, 0, 0]) < np.deg2rad(0.5)


@pytest.mark.parametrize("t", [np.nan, np.inf, "soon"])
def test_non_finite_exposure_time_raises_a_value_error_naming_it(t):
    f = QuaternionAEKF(P, AEKFConfig())
    z = marker_pixels(P, [1.0, 0, 0, 0])
    with pytest.raises(ValueError, match="^t_exposure must be a finite time") as info:
        f.update(z, t)
    assert "cannot convert" not in str(info.value)
    with pytest.raises(ValueError, match="^t_exposure"):
        f.update_points(np.zeros((3, 3)), np.zeros((3, 2)), t)
    assert f.t == 0.0 and f.update(z, 0.03).accepted  # the filter is untouched and still works


def test_configuration_errors_name_the_field():
    with pytest.raises(ValueError, match="sigma_px"):
        AEKFConfig(sigma_px=-1.0)
    with pytest.raises(ValueError, match="window_N"):
        AEKFConfig(window_N=0)
    with pytest.raises(ValueError, match="P0_diag"):
        QuaternionAEKF(P, P0_diag=[1, 1, 1, 1, 1, 1, -1])
