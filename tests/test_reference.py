"""Reference generators: the seed's step protocol, ramps, cones and smooth random trajectories.

Ground truth: rotation matrices built here by hand, and finite differences of the sampled
attitude for the rates (``omega ≈ rotvec(q(t-h)^-1 ⊗ q(t+h)) / 2h``, body frame).
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.reference import Cone, Ramp, RandomSmooth, SeedSteps, Steps
from plant import attitude as A


def Rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def Ry(b):
    c, s = np.cos(b), np.sin(b)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def fd_omega(ref, t, h=1e-5):
    """Body rate by central differences of the attitude."""
    qm, qp = ref.sample(t - h).q, ref.sample(t + h).q
    return A.to_rotvec(A.multiply(A.conjugate(qm), qp)) / (2 * h)


def fd_alpha(ref, t, h=1e-5):
    """Body acceleration by central differences of the reported rate."""
    return (ref.sample(t + h).omega - ref.sample(t - h).omega) / (2 * h)


def assert_rates_consistent(ref, times, atol_w=1e-6, atol_a=1e-4):
    for t in times:
        s = ref.sample(t)
        w_scale = max(1.0, np.linalg.norm(s.omega))
        a_scale = max(1.0, np.linalg.norm(s.alpha))
        assert np.allclose(s.omega, fd_omega(ref, t), atol=atol_w * w_scale), t
        assert np.allclose(s.alpha, fd_alpha(ref, t), atol=atol_a * a_scale), t


# --- the seed's step protocol (seed 000 §5) ------------------------------------------------


def test_spin_steps_follow_the_seed_protocol():
    ref = SeedSteps(axis="spin")
    assert np.allclose(ref.values(), np.arange(0, 71, 10))  # 0–75° by 10°
    for k, v in enumerate(ref.values()):
        s = ref.sample(5.0 * k + 2.5)  # middle of the k-th 5 s dwell
        assert np.allclose(A.to_matrix(s.q), Rz(np.deg2rad(v)), atol=1e-12)
        assert np.all(s.omega == 0) and np.all(s.alpha == 0)
    assert ref.duration_s == pytest.approx(40.0)


def test_tilt_steps_are_pure_tilts_about_y():
    ref = SeedSteps(axis="tilt")
    assert np.allclose(ref.values(), [0, 5, 10, 15])
    for k, v in enumerate(ref.values()):
        q = ref.sample(5.0 * k + 0.1).q
        assert np.allclose(A.to_matrix(q), Ry(np.deg2rad(v)), atol=1e-12)


def test_tilt_toward_an_azimuth_has_no_turn_about_the_shaft():
    ref = SeedSteps(axis="tilt", azimuth_deg=40.0, values_deg=(10.0,))
    q = ref.sample(0.0).q
    R = A.to_matrix(q)
    g = np.deg2rad(40.0)
    b = np.deg2rad(10.0)
    # The shaft points along azimuth 40° at 10° from Z ...
    assert np.allclose(R[:, 2], [np.sin(b) * np.cos(g), np.sin(b) * np.sin(g), np.cos(b)])
    # ... and the rotation axis is horizontal (no component about Z).
    assert abs(A.to_rotvec(q)[2]) < 1e-12


def test_yaw_steps_turn_the_tilted_rotor_about_global_z_like_the_rotary_table():
    ref = SeedSteps(axis="yaw")
    assert ref.tilt_deg == 15.0 and np.allclose(ref.values(), np.arange(0, 91, 10))
    for k, v in enumerate(ref.values()):
        R = A.to_matrix(ref.sample(5.0 * k + 4.9).q)
        assert np.allclose(R, Rz(np.deg2rad(v)) @ Ry(np.deg2rad(15.0)), atol=1e-12)


def test_yaw_steps_without_shaft_turn_sweep_the_same_cone():
    table = SeedSteps(axis="yaw")
    wobble = SeedSteps(axis="yaw", turn_shaft=False)
    for t in (2.0, 17.0, 33.0):
        Rt, Rw = A.to_matrix(table.sample(t).q), A.to_matrix(wobble.sample(t).q)
        assert np.allclose(Rt[:, 2], Rw[:, 2], atol=1e-12)  # same shaft direction
        assert abs(A.to_rotvec(wobble.sample(t).q)[2]) < 1e-12


def test_steps_switch_at_the_dwell_boundaries():
    ref = SeedSteps(axis="tilt", dwell_s=2.0, t_start_s=1.0)
    tilt = lambda t: np.degrees(A.tilt(ref.sample(t).q))  # noqa: E731
    assert tilt(0.0) == pytest.approx(0.0)  # the first value also before the start
    assert tilt(2.999) == pytest.approx(0.0, abs=1e-9)
    assert tilt(3.0) == pytest.approx(5.0)
    assert tilt(100.0) == pytest.approx(15.0)


def test_step_configs_reject_bad_values():
    with pytest.raises(ValueError, match="values_deg"):
        SeedSteps(axis="tilt", values_deg=(0.0, 20.0))  # beyond the 15° stop
    with pytest.raises(ValueError, match="dwell_s"):
        SeedSteps(axis="spin", dwell_s=0.0)
    with pytest.raises(ValueError, match="attitudes"):
        Steps(times_s=(0.0, 1.0), attitudes=((1.0, 0, 0, 0),))
    with pytest.raises(ValueError, match="times_s"):
        Steps(times_s=(1.0, 1.0), attitudes=((1.0, 0, 0, 0), (1.0, 0, 0, 0)))
    with pytest.raises(ValueError, match="unit quaternion"):
        Steps(times_s=(0.0,), attitudes=((2.0, 0, 0, 0),))
    with pytest.raises(ValueError, match="tilt"):
        Ramp(start_deg=(0, 0, 0), stop_deg=(0, 16, 0), duration_s=1.0)


# --- ramps and cones -----------------------------------------------------------------------


def test_tilt_ramp_moves_linearly_and_holds():
    ref = Ramp(start_deg=(-30, 0, 30), stop_deg=(-30, 12, 30), t_start_s=0.5, duration_s=2.0)
    for t, expect in [(0.0, 0.0), (0.5, 0.0), (1.0, 3.0), (1.5, 6.0), (2.5, 12.0), (9.0, 12.0)]:
        assert np.degrees(A.tilt(ref.sample(t).q)) == pytest.approx(expect, abs=1e-9)
    # A pure tilt ramp rotates about one fixed horizontal axis at a constant rate.
    rate = np.deg2rad(6.0)
    w = ref.sample(1.2).omega
    assert np.linalg.norm(w) == pytest.approx(rate, rel=1e-12)
    assert np.allclose(ref.sample(1.2).alpha, 0.0, atol=1e-12)
    assert np.allclose(ref.sample(3.0).omega, 0.0)


def test_combined_ramp_rates_match_finite_differences():
    ref = Ramp(start_deg=(10, 2, -20), stop_deg=(80, 14, 100), t_start_s=0.0, duration_s=1.5)
    assert_rates_consistent(ref, np.linspace(0.05, 1.45, 9))


@pytest.mark.parametrize("turn_shaft", [True, False])
def test_cone_keeps_the_tilt_and_sweeps_the_azimuth(turn_shaft):
    rate = 1.3
    ref = Cone(tilt_deg=12.0, yaw_rate_rad_s=rate, yaw0_deg=20.0, turn_shaft=turn_shaft)
    for t in np.linspace(0.01, 4.0, 13):
        s = ref.sample(t)
        R = A.to_matrix(s.q)
        assert np.degrees(A.tilt(s.q)) == pytest.approx(12.0, abs=1e-9)
        az = np.arctan2(R[1, 2], R[0, 2])
        assert A.wrap_angle(az - (np.deg2rad(20.0) + rate * t)) == pytest.approx(0.0, abs=1e-9)
        if turn_shaft:  # rigid rotation about stator Z: stator-frame rate (0, 0, rate)
            assert np.allclose(R @ s.omega, [0, 0, rate], atol=1e-12)
            assert np.allclose(s.alpha, 0.0, atol=1e-12)
        else:  # no turn about the shaft: the attitude stays a pure tilt
            assert abs(A.to_rotvec(s.q)[2]) < 1e-9
    assert_rates_consistent(ref, [0.3, 1.7, 3.1])


def test_cone_holds_before_its_start():
    ref = Cone(tilt_deg=10.0, yaw_rate_rad_s=2.0, t_start_s=1.0)
    assert np.allclose(ref.sample(0.5).omega, 0.0)
    assert np.allclose(ref.sample(0.5).q, ref.sample(1.0).q)


# --- smooth random trajectories ------------------------------------------------------------


def test_random_trajectory_is_seeded():
    a = RandomSmooth(seed=3, max_rate_rad_s=2.0)
    b = RandomSmooth(seed=3, max_rate_rad_s=2.0)
    c = RandomSmooth(seed=4, max_rate_rad_s=2.0)
    assert np.array_equal(a.sample(0.7).q, b.sample(0.7).q)
    assert not np.allclose(a.sample(0.7).q, c.sample(0.7).q)


@pytest.mark.parametrize("seed,rate,tilt", [(0, 1.0, 12.0), (7, 3.0, 15.0), (11, 0.5, 5.0)])
def test_random_trajectory_respects_rate_and_tilt_limits(seed, rate, tilt):
    ref = RandomSmooth(seed=seed, max_rate_rad_s=rate, tilt_max_deg=tilt)
    # An independent grid (not the one the generator used), over one period.
    ts = np.linspace(0.0, ref.period_s, 3001)
    rates = np.array([np.linalg.norm(ref.sample(t).omega) for t in ts])
    tilts = np.degrees([A.tilt(ref.sample(t).q) for t in ts])
    assert rates.max() <= rate * (1 + 1e-5)
    assert rates.max() >= rate * 0.999
    assert tilts.max() <= tilt + 1e-6
    assert tilts.max() >= tilt - 0.01
    assert np.allclose(ref.sample(0.0).q, [1, 0, 0, 0])  # starts at rest attitude
    assert np.allclose(ref.sample(0.3).q, ref.sample(0.3 + ref.period_s).q, atol=1e-9)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 1000), frac=st.floats(0.0, 1.0))
def test_random_trajectory_rates_match_finite_differences(seed, frac):
    ref = RandomSmooth(seed=seed, max_rate_rad_s=2.0, n_harmonics=3)
    assert_rates_consistent(ref, [frac * ref.period_s + 0.01])


def test_random_trajectory_rejects_a_tilt_beyond_the_workspace():
    with pytest.raises(ValueError, match="tilt_max_deg"):
        RandomSmooth(max_rate_rad_s=1.0, tilt_max_deg=20.0)
    with pytest.raises(ValueError, match="max_rate_rad_s"):
        RandomSmooth(max_rate_rad_s=0.0)


@pytest.mark.parametrize(
    "ref",
    [
        Steps(times_s=(0.0, 0.3, 0.7), attitudes=((1, 0, 0, 0), tuple(A.from_zyz(0.2, 0.1, 0.5)),
                                                  tuple(A.from_zyz(-0.4, 0.2, 1.0)))),
        SeedSteps(axis="yaw", dwell_s=0.25),
        Ramp(start_deg=(-30.0, 0.0, 30.0), stop_deg=(10.0, 12.0, 80.0), t_start_s=0.2,
             duration_s=0.5),
        Cone(tilt_deg=10.0, yaw_rate_rad_s=6.0, t_start_s=0.1),
        Cone(tilt_deg=8.0, yaw_rate_rad_s=-3.0, spin0_deg=20.0, turn_shaft=False),
        RandomSmooth(seed=3, max_rate_rad_s=4.0),
    ],
    ids=["steps", "seed_steps", "ramp", "cone", "cone_no_shaft_turn", "random"],
)
def test_sample_many_equals_the_scalar_sample_at_every_time(ref):
    """The array sample over a time grid (switches, ramp corners and the start included) is the
    scalar sample at each time: attitude, body rate and body acceleration to rounding."""
    t = np.r_[np.linspace(-0.1, 1.2, 523), 0.3, 0.7, 0.2, 0.1, 0.25]
    many = ref.sample_many(t)
    assert many.q.shape == (len(t), 4)
    for k, tk in enumerate(t):
        one = ref.sample(float(tk))
        assert A.geodesic_angle(many.q[k], one.q) < 1e-12
        np.testing.assert_allclose(many.omega[k], one.omega, atol=1e-12)
        np.testing.assert_allclose(many.alpha[k], one.alpha, atol=1e-10)
