"""Plant step rate (MuJoCo and the CasADi twin, same 1 ms step) and allocation time per call,
and the measured plant properties quoted in docs/plant.md:

- the worst condition number of K(q) over a dense workspace grid (16 tilts 0-15° x 72 spins x
  72 yaws = 82,944 attitudes);
- the torque capacity at i_max (largest torque in a direction that bounded currents deliver,
  by an LP) over 300 random workspace attitudes and directions;
- the MuJoCo-CasADi twin gap over 1 s of the same current sequence (the test's: random ±0.3 A
  patterns as +u, -u, -u, +u over 4 x 25 ms), with and without a centre-of-mass offset;
- the calibration errors of ``plant.calibration.calibrate_from_renders`` (default 12 x 9 board,
  80 views) for the ideal and a k1 = -0.3 lens, at seed 0 and the worst over seeds 0-19; the
  same with all five distortion terms free (seeds 0-9); and OpenCV's classic 9 x 6 board with
  30 views (the earlier default) over seeds 0-19, for comparison.

Fixed seeds throughout. Run: python benchmarks/bench_plant.py
"""

from __future__ import annotations

import itertools
import time

import numpy as np
from _report import record
from scipy.optimize import linprog

from plant import attitude
from plant.calibration import calibrate_from_renders
from plant.dynamics import MujocoPlant
from plant.params import CameraParams, PlantParams, RotorParams
from plant.torque import TorqueMap, allocate
from plant.twin import CasadiTwin

TILT_MAX_RAD = np.deg2rad(15.0)  # seed 000 §2.4
CALIB_SEEDS = range(20)
CALIB_SEEDS_ALL_TERMS = range(10)
DISTORTED = (-0.3, 0.0, 0.0, 0.0, 0.0)


def per_call(fn, n: int) -> np.ndarray:
    """Seconds per call of ``fn(i)`` for i in range(n)."""
    out = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        fn(i)
        out[i] = time.perf_counter() - t0
    return out


def worst_condition_number(tm: TorqueMap, n_tilt=16, n_spin=72, n_yaw=72) -> tuple[float, int]:
    """max cond K(q) over the grid tilt in [0, 15°] (inclusive) x spin x yaw, and the grid size."""
    worst, n = 0.0, 0
    for b, a, g in itertools.product(
        np.linspace(0.0, TILT_MAX_RAD, n_tilt),
        np.linspace(0.0, 2 * np.pi, n_spin, endpoint=False),
        np.linspace(0.0, 2 * np.pi, n_yaw, endpoint=False),
    ):
        worst = max(worst, float(np.linalg.cond(tm(attitude.from_zyz(a, b, g)))))
        n += 1
    return worst, n


def capacity(K: np.ndarray, d: np.ndarray, i_max: float) -> float:
    """Largest s (N·m) with K I = s d, |I_i| <= i_max: an LP over (I, s)."""
    res = linprog(np.r_[np.zeros(K.shape[1]), -1.0], A_eq=np.hstack([K, -d[:, None]]),
                  b_eq=np.zeros(3), bounds=[(-i_max, i_max)] * K.shape[1] + [(0, None)])
    return float(res.x[-1])


def torque_capacities(tm: TorqueMap, i_max: float, n: int, rng) -> np.ndarray:
    """Capacity (N·m) at ``n`` random workspace attitudes, each in a random direction."""
    out = np.empty(n)
    for k in range(n):
        q = attitude.from_zyz(rng.uniform(0, 2 * np.pi), rng.uniform(0, TILT_MAX_RAD),
                              rng.uniform(0, 2 * np.pi))
        d = rng.normal(size=3)
        out[k] = capacity(tm(q), d / np.linalg.norm(d), i_max)
    return out


def twin_gap(com_m) -> tuple[float, float, float]:
    """(max geodesic gap rad, max rate gap rad/s, max tilt rad) between MuJoCo and the twin
    over the 1 s sequence of ``tests/test_dynamics.py::test_twin_and_mujoco_agree_...``."""
    p = PlantParams(rotor=RotorParams(com_offset_m=com_m))
    rng = np.random.default_rng(0)
    B = rng.uniform(-0.3, 0.3, (10, 16))
    U = np.repeat(np.stack([B, -B, -B, B], axis=1).reshape(-1, 16), 25, axis=0)
    q0, w0 = attitude.from_zyz(0.3, np.deg2rad(5), 1.0), np.array([0.1, -0.1, 4.0])
    Qm, Wm = MujocoPlant(p, q0, w0).simulate(U)
    Qt, Wt = CasadiTwin(p).simulate(q0, w0, U)
    gap = max(attitude.geodesic_angle(a, b) for a, b in zip(Qm, Qt, strict=True))
    return (float(gap), float(np.abs(np.asarray(Wm) - np.asarray(Wt)).max()),
            float(max(attitude.tilt(q) for q in Qm)))


def calibration_figures() -> dict[str, float]:
    """Relative calibration errors in percent (flat keys)."""
    out: dict[str, float] = {}
    names = ("fx", "fy", "cx", "cy")
    lenses = {"ideal": PlantParams(),
              "k1m03": PlantParams(camera=CameraParams(dist_coeffs=DISTORTED))}

    def worst(prefix, params, seeds, **kw):
        errs = []
        for s in seeds:
            r = calibrate_from_renders(params, seed=s, **kw)
            e = r.relative_errors()
            errs.append([e[k] for k in names])
            if s == 0:
                for k in names:
                    out[f"{prefix}_seed0_{k}_err_pct"] = 100 * e[k]
                out[f"{prefix}_seed0_rms_image_px"] = r.rms_px
                out[f"{prefix}_seed0_views_used"] = float(r.n_used)
        a = 100 * np.abs(np.array(errs))
        for k, v in zip(names, a.max(axis=0), strict=True):
            out[f"{prefix}_max_abs_{k}_err_pct"] = float(v)
        out[f"{prefix}_n_seeds"] = float(len(errs))

    for name, params in lenses.items():
        worst(f"calib_{name}", params, CALIB_SEEDS)
    worst("calib_k1m03_all5terms", lenses["k1m03"], CALIB_SEEDS_ALL_TERMS, flags=0)
    worst("calib_k1m03_board9x6_30views", lenses["k1m03"], CALIB_SEEDS, n_views=30,
          pattern=(9, 6))
    return out


def main() -> None:
    p = PlantParams()
    rng = np.random.default_rng(0)
    n = 5000
    U = rng.uniform(-0.05, 0.05, (n, 16))
    q0, w0 = attitude.from_zyz(0.3, 0.05, 1.0), np.array([0.1, -0.1, 2.0])

    plant = MujocoPlant(p, q0, w0)
    mj = per_call(lambda i: plant.step(U[i], p.physics_dt_s), n)

    twin = CasadiTwin(p)
    x = np.r_[q0, w0]
    state = {"x": x}

    def twin_step(i):
        state["x"] = np.asarray(twin.step(state["x"], U[i])).ravel()

    tw = per_call(twin_step, n)
    t0 = time.perf_counter()
    twin.simulate(q0, w0, U)
    tw_batch = (time.perf_counter() - t0) / n

    tm = TorqueMap(p.motor)
    qs = [
        attitude.from_zyz(*rng.uniform(0, 2 * np.pi, 1), rng.uniform(0, 0.26), 1.0)
        for _ in range(500)
    ]
    kmap = per_call(lambda i: tm(qs[i]), 500)
    Ks = [tm(q) for q in qs]
    small = rng.normal(scale=0.05, size=(500, 3))
    big = rng.normal(scale=2.0, size=(500, 3))
    a_small = per_call(lambda i: allocate(small[i], Ks[i], p.motor.i_max_A), 500)
    a_big = per_call(lambda i: allocate(big[i], Ks[i], p.motor.i_max_A), 500)

    t_props = time.perf_counter()
    cond_max, n_grid = worst_condition_number(tm)
    caps = torque_capacities(tm, p.motor.i_max_A, 300, np.random.default_rng(1))
    gap0 = twin_gap((0.0, 0.0, 0.0))
    gap1 = twin_gap((3e-4, -2e-4, -2e-3))
    t_calib = time.perf_counter()
    calib = calibration_figures()
    t_end = time.perf_counter()

    figures = {
        "mujoco_step_median_s": float(np.median(mj)),
        "mujoco_step_rate_hz": float(1 / np.median(mj)),
        "twin_step_median_s": float(np.median(tw)),
        "twin_step_rate_hz": float(1 / np.median(tw)),
        "twin_mapaccum_per_step_s": tw_batch,
        "mujoco_over_twin_step_time_ratio": float(np.median(mj) / np.median(tw)),
        "torque_map_median_s": float(np.median(kmap)),
        "allocate_within_limits_median_s": float(np.median(a_small)),
        "allocate_within_limits_p95_s": float(np.percentile(a_small, 95)),
        "allocate_saturated_median_s": float(np.median(a_big)),
        "allocate_saturated_p95_s": float(np.percentile(a_big, 95)),
        "torque_map_cond_max_over_grid": cond_max,
        "torque_map_cond_grid_attitudes": float(n_grid),
        "torque_capacity_min_Nm": float(caps.min()),
        "torque_capacity_median_Nm": float(np.median(caps)),
        "torque_capacity_max_Nm": float(caps.max()),
        "twin_gap_max_rad": gap0[0],
        "twin_gap_rate_max_rad_s": gap0[1],
        "twin_run_tilt_max_rad": gap0[2],
        "twin_gap_com_offset_max_rad": gap1[0],
        "twin_gap_com_offset_rate_max_rad_s": gap1[1],
        "twin_run_com_offset_tilt_max_rad": gap1[2],
        **calib,
        "properties_wall_time_s": t_calib - t_props,
        "calibration_wall_time_s": t_end - t_calib,
    }
    record(
        "bench_plant",
        "Plant step rate and allocation",
        figures,
        notes=f"{n} physics steps of {p.physics_dt_s} s each; MuJoCo steps include K(q) and the "
        "held torque; the twin step is one call of the CasADi Function from Python "
        "(mapaccum: the same steps in one call). Allocation over 500 random workspace "
        "attitudes: small requests (least-norm) and requests beyond capacity (LP + BVLS). "
        f"Condition number: {n_grid} grid attitudes, tilt 0-15° in 16 steps, spin and yaw in "
        "72 steps. Capacity: largest torque bounded currents deliver in one direction (LP), at "
        f"i_max = {p.motor.i_max_A} A, 300 random workspace attitudes and directions (seed 1). "
        "Twin gap: geodesic (rad) and body-rate (rad/s) gaps over 1 s of random ±0.3 A "
        "patterns as +u, -u, -u, +u over 4 x 25 ms (seed 0), without and with a centre-of-mass "
        "offset (0.3, -0.2, -2) mm. Calibration (`calib_*`): relative errors in percent of "
        "`calibrate_from_renders` at its defaults (12 x 9 board, 80 views, k1 and k2 free), "
        "ideal lens and k1 = -0.3, seed 0 and the worst over seeds 0-19; `all5terms`: flags=0, "
        "seeds 0-9; `board9x6_30views`: the earlier default board and view count.",
    )


if __name__ == "__main__":
    main()
