"""Controller compute cost and step responses.

* PID: wall-clock time per ``command`` call.
* MPC: solve time (median, p95) of every solver option on the same closed-loop scenarios,
  with the number of solves that hit the iteration cap or failed, and the closed-loop result so
  that a faster solver is not a worse controller.
* Step response (settling time to the 2 % band, overshoot) of PID and MPC on a 5° tilt step with
  ground-truth feedback on the MuJoCo plant.

Run from the repository root: python benchmarks/bench_controllers.py
"""

from __future__ import annotations

import os
import time

import numpy as np
from _report import record

from controller.mpc import MPCController
from controller.mpc_config import MPCConfig
from controller.pid import PIDConfig, PIDController, truth_estimate
from controller.reference import RandomSmooth, Steps, pure_tilt
from plant import attitude
from plant.dynamics import MujocoPlant
from plant.params import PlantParams

PARAMS = PlantParams()
DT = PARAMS.physics_dt_s


def tilt_step(tilt_deg: float) -> Steps:
    return Steps(times_s=(0.0,), attitudes=(tuple(pure_tilt(np.deg2rad(tilt_deg))),))


def closed_loop(ctl, ref, duration_s: float, period_s: float) -> dict[str, np.ndarray]:
    """Ground-truth loop on MuJoCo: the controller every ``period_s``, its torque held, currents
    re-allocated every physics step."""
    plant = MujocoPlant(PARAMS)
    n, every = round(duration_s / DT), round(period_s / DT)
    T = np.zeros(3)
    tilt, err, stop = np.empty(n), np.empty(n), False
    for k in range(n):
        t = k * DT
        if k % every == 0:
            T = ctl.command(truth_estimate(plant.q, plant.omega, t), ref, t)
        plant.step(plant.allocate(T).currents, DT)
        tilt[k] = attitude.tilt(plant.q)
        err[k] = attitude.geodesic_angle(plant.q, ref.sample(t + DT).q)
        stop |= plant.tilt_stop_active()
    return {"t": np.arange(1, n + 1) * DT, "tilt": tilt, "err": err, "stop": np.array(stop)}


def step_metrics(run: dict[str, np.ndarray], final_rad: float) -> tuple[float, float]:
    """Overshoot (%) and 2 % settling time (s); inf if it never settles within the run."""
    y, t = run["tilt"], run["t"]
    overshoot = 100.0 * (y.max() - final_rad) / final_rad
    outside = np.nonzero(np.abs(y - final_rad) > 0.02 * final_rad)[0]
    settle = t[outside[-1] + 1] if outside[-1] + 1 < len(t) else np.inf
    return float(overshoot), float(settle)


def main() -> None:
    figures: dict[str, float] = {}
    load0 = os.getloadavg()[0]

    # --- PID command time (1 kHz loop, 2 s, a 5° tilt step) -------------------------------
    pid = PIDController(PIDConfig(crossover_rad_s=25.0), PARAMS)
    closed_loop(pid, tilt_step(5.0), 2.0, DT)
    ct = np.asarray(pid.compute_times_s)
    figures["pid_command_median_s"] = float(np.median(ct))
    figures["pid_command_p95_s"] = float(np.percentile(ct, 95))

    # --- MPC solvers on the same scenarios ------------------------------------------------
    scenarios = [
        ("step5", tilt_step(5.0), 1.0),
        ("step20", tilt_step(20.0), 1.0),  # beyond the stop: the tilt constraint is active
        ("random", RandomSmooth(seed=0, max_rate_rad_s=1.5, tilt_max_deg=12.0), 2.0),
    ]
    variants = {
        "sqp_hpipm": MPCConfig(solver="sqp_hpipm"),
        "sqp_qpoases": MPCConfig(solver="sqp_qpoases"),
        "sqp_qrqp": MPCConfig(solver="sqp_qrqp"),
        "sqp_osqp": MPCConfig(solver="sqp_osqp"),
        "ipopt": MPCConfig(solver="ipopt"),
        "ipopt_exact_hessian": MPCConfig(solver="ipopt", hessian="exact"),
    }
    for name, cfg in variants.items():
        cfg = cfg.model_copy(update={"compute_latency_s": 0.0})
        t0 = time.perf_counter()
        mpc = MPCController(cfg, PARAMS)
        figures[f"mpc_{name}_build_s"] = time.perf_counter() - t0
        rms = {}
        for label, ref, dur in scenarios:
            mpc.reset()
            run = closed_loop(mpc, ref, dur, 0.01)
            rms[label] = float(np.sqrt(np.mean(run["err"][round(0.3 / DT) :] ** 2)))
            if label == "step20":
                figures[f"mpc_{name}_step20_max_tilt_deg"] = float(np.degrees(run["tilt"].max()))
        s = np.asarray(mpc.solve_times_s)
        c = np.asarray(mpc.compute_times_s)
        figures[f"mpc_{name}_solve_median_s"] = float(np.median(s))
        figures[f"mpc_{name}_solve_p95_s"] = float(np.percentile(s, 95))
        figures[f"mpc_{name}_command_median_s"] = float(np.median(c))
        figures[f"mpc_{name}_unconverged_fraction"] = mpc.unconverged / len(s)
        figures[f"mpc_{name}_failures"] = float(mpc.failures)
        figures[f"mpc_{name}_random_rms_error_deg"] = float(np.degrees(rms["random"]))

    # --- step responses (5° tilt, ground truth, controllers at 100 Hz) --------------------
    final = np.deg2rad(5.0)
    runs = {
        "pid_default_wc10": (PIDController(PIDConfig(), PARAMS), 8.0),
        "pid_wc25": (PIDController(PIDConfig(crossover_rad_s=25.0), PARAMS), 2.0),
        "mpc_default": (MPCController(MPCConfig(compute_latency_s=0.0), PARAMS), 1.0),
    }
    for name, (ctl, dur) in runs.items():
        run = closed_loop(ctl, tilt_step(5.0), dur, 0.01)
        os_pct, ts = step_metrics(run, final)
        figures[f"step5_{name}_overshoot_pct"] = os_pct
        figures[f"step5_{name}_settling_2pct_s"] = ts
        figures[f"step5_{name}_final_error_deg"] = float(np.degrees(abs(run["tilt"][-1] - final)))

    figures["load_average_1min_start"] = load0
    figures["load_average_1min_end"] = os.getloadavg()[0]
    record(
        "bench_controllers",
        "Controllers: PID command time, MPC solve time per solver, 5° tilt step responses",
        figures,
        notes="Ground-truth feedback on the MuJoCo plant (1 ms physics, currents re-allocated "
        "every step for the held torque). MPC: N = 15 steps of 10 ms, called every 10 ms; "
        "solve = the nlpsol call, command = the whole call (prediction, parameters, solve). "
        "Solver scenarios per variant: 5° tilt step (1 s), 20° request held at the 14.5° tilt "
        "constraint (1 s), seeded random trajectory at 1.5 rad/s peak (2 s): 400 solves. "
        "random_rms_error: geodesic tracking error after 0.3 s. Step responses: controllers at "
        "100 Hz; PID defaults ω_c = 10 rad/s, and ω_c = 25 rad/s (about the MPC default's loop "
        "crossover, 1.7 ω_n). The machine is shared with other jobs: see the load averages.",
    )


if __name__ == "__main__":
    main()
