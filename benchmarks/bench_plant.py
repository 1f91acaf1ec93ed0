"""Plant step rate (MuJoCo and the CasADi twin, same 1 ms step) and allocation time per call.

Run: python benchmarks/bench_plant.py
"""

from __future__ import annotations

import time

import numpy as np
from _report import record

from plant import attitude
from plant.dynamics import MujocoPlant
from plant.params import PlantParams
from plant.torque import TorqueMap, allocate
from plant.twin import CasadiTwin


def per_call(fn, n: int) -> np.ndarray:
    """Seconds per call of ``fn(i)`` for i in range(n)."""
    out = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        fn(i)
        out[i] = time.perf_counter() - t0
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
    }
    record(
        "bench_plant",
        "Plant step rate and allocation",
        figures,
        notes=f"{n} physics steps of {p.physics_dt_s} s each; MuJoCo steps include K(q) and the "
        "held torque; the twin step is one call of the CasADi Function from Python "
        "(mapaccum: the same steps in one call). Allocation over 500 random workspace "
        "attitudes: small requests (least-norm) and requests beyond capacity (LP + BVLS).",
    )


if __name__ == "__main__":
    main()
