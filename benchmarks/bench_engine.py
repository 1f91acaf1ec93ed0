"""Speed of the batched closed-loop engine against the event loop, on one core.

On the default measurement-model scenario with PID and the per-frame least-squares observer (a
5° tilt step, GK-TransT's seed latency), in one process with one BLAS/OpenMP thread:

* aggregate simulated seconds per wall second of the batched engine (``latency.batched``) for
  B = 1, 2, 4, ..., 1024 runs (different seeds) advanced together, and of the event loop
  (``ClosedLoop.run``) in the same process: ``batched_B<B>_realtime_factor`` (every result with
  its tables), ``batched_summaries_B<B>_realtime_factor`` (summaries only, as a sweep keeps
  them), ``event_loop_realtime_factor`` and the ratio at B = 256;
* the compiled physics step alone (``plant.rigid_body.RigidBody.step``), wall time per rotor
  and physics step over B = 1, 256 and 1024 rotors, and the CasADi twin's step for one rotor:
  ``physics_step_{compiled,casadi}_B<B>_s_per_rotor``; and the same step as the compiled run
  loop takes it, 256 rotors each stepped ``REUSE_STEPS`` times, its pair lists made again at
  every step or kept while they cover its turn:
  ``physics_step_{fresh,reused}_lists_B256_s_per_rotor``;
* the same for the MPC (the scenario with ``controller: {kind: mpc}``, its default SQP + HPIPM
  solver and the constant compute latency of ``latency.scenario.MPC_CALL_MEDIAN_S``), whose
  runs the compiled run loop computes with the solver as machine code
  (``controller.mpc_machine``): ``mpc_batched_B64_realtime_factor`` (with tables),
  ``mpc_batched_summaries_B64_realtime_factor``, ``mpc_event_loop_realtime_factor`` and their
  ratios (target: the batched B = 64 at least 50 times the event loop), and
  ``mpc_bound_free_solves_B64_over_event_loop``: the PID's runs of the same scenario on the
  batched engine (summaries), measured in the same part, over the MPC's event loop, i.e. the
  ratio the MPC's batched runs would reach if every solve took no time (an upper bound);
  and what a solve costs and may cost: the solves per simulated s and SQP iterations per solve
  of one event-loop run, the machine solver's wall time per solve on that run's inputs
  (``mpc_machine_solve_s``), one evaluation of the SQP's derivatives
  (``mpc_derivatives_evaluation_s``) and that times the iterations (``mpc_derivatives_floor_
  per_solve_s``: any SQP on this model evaluates them once a QP), against the wall time per
  solve that would leave the batched runs at 50 times the event loop
  (``mpc_solve_budget_for_50x_[summaries_]B64_s``; negative: not even free solves would);
* wall time of the study's closed-loop sweep (``experiments.study_sweep.sweep_configs``), of a small
  ``tune-kalman`` and of a 10,000-run sweep of the default scenario, on each engine (the event
  loop's 10,000-run figure is extrapolated from ``EVENT_SAMPLE_RUNS`` runs, and says so in its
  key).

Run: python benchmarks/bench_engine.py          (the full benchmark; a quiet machine, hours)
     python benchmarks/bench_engine.py --parts throughput,mpc,study
                                                  (only those parts; the record names them)
     python benchmarks/bench_engine.py --quick --out /tmp/bench_engine.json
                                                  (a smoke test in seconds; writes only --out)
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # one core: before numpy is imported

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from experiments import study_config, study_sweep, tuning  # noqa: E402
from latency import Scenario, build_loop  # noqa: E402
from latency.batched import run_batched  # noqa: E402
from latency.simulation import run_summaries, run_summary  # noqa: E402

#: The benchmark's scenario: measurement model, PID, per-frame least squares, 5° tilt step.
CASE = {"observer": {"kind": "solver"}}
#: The same with the MPC.
MPC_CASE = {**CASE, "controller": {"kind": "mpc"}}
#: Runs of the MPC's batched figure.
MPC_BATCH = 64
#: Event-loop runs timed for the 10,000-run sweep's extrapolated figure.
EVENT_SAMPLE_RUNS = 100
#: Physics steps per rotor of the reused-lists figure (the compiled run loop's way).
REUSE_STEPS = 50
#: The benchmark's parts: the throughput curve over B, the MPC's throughput, the study's sweep,
#: tune-kalman, and the 10,000-run sweep.
PARTS = ("throughput", "mpc", "study", "tune", "sweep")


def _configs(n: int, duration_s: float, case: dict = CASE) -> list[dict]:
    return [{**case, "duration_s": duration_s, "seed": s} for s in range(n)]


def _wall(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def throughput(batch: int, duration_s: float, tables: bool = True, case: dict = CASE) -> float:
    """Aggregate simulated s per wall s of ``batch`` runs of ``case`` on the batched engine,
    with their tables or (``tables=False``) their summaries only, as a sweep keeps them."""
    loops = [build_loop(Scenario.model_validate(c)) for c in _configs(batch, duration_s, case)]
    return batch * duration_s / _wall(lambda: run_batched(loops, tables=tables))


def event_loop_speed(duration_s: float, case: dict = CASE) -> float:
    """Simulated s per wall s of one run of ``case`` on the event loop."""
    loop = build_loop(Scenario.model_validate(_configs(1, duration_s, case)[0]))
    return duration_s / _wall(loop.run)


def study_sweep_walls(cfg: study_config.StudyConfig) -> tuple[float, float]:
    """Wall time (s) of the study's sweep in this process: (event loop, batched)."""
    configs = study_sweep.sweep_configs(cfg)
    event = _wall(lambda: [study_sweep.study_run(c) for c in configs])
    batched = _wall(lambda: study_sweep.study_runs(configs))
    return event, batched


def tune_kalman_walls(**kw) -> tuple[float, float]:
    """Wall time (s) of ``tuning.tune_kalman`` in this process: (event loop, batched)."""
    walls = []
    for engine in ("event", "batched"):
        with tempfile.TemporaryDirectory() as tmp:
            walls.append(_wall(lambda e=engine, d=tmp: tuning.tune_kalman(
                d, workers=1, progress=False, engine=e, **kw)))
    return walls[0], walls[1]


def sweep_walls(n_runs: int, n_event: int, duration_s: float, batch: int) -> tuple[float, float]:
    """Wall time (s) of ``n_runs`` runs: the event loop's extrapolated from ``n_event`` runs,
    and the batched engine's measured in batches of ``batch``."""
    configs = _configs(n_runs, duration_s)
    event = _wall(lambda: [run_summary(c) for c in configs[:n_event]]) * n_runs / n_event
    batched = _wall(lambda: [run_summaries(configs[k : k + batch])
                             for k in range(0, n_runs, batch)])
    return event, batched


def physics_kernel_times(batch: int, repeats: int = 20) -> dict[str, float]:
    """Wall time (s) per rotor and physics step of the compiled step (``RigidBody.step``, the
    RKMK4 physics of both engines) over ``batch`` rotors, best of ``repeats``; for one rotor
    also the CasADi twin's step of the same method (``CasadiTwin.step``, its virtual
    machine): the technique choice of docs/closed_loop.md."""
    import numpy as np

    from plant import attitude
    from plant.params import PlantParams
    from plant.rigid_body import RigidBody, _step_series
    from plant.twin import CasadiTwin

    p = PlantParams()
    body = RigidBody(p)
    rng = np.random.default_rng(0)
    q = np.stack([attitude.from_zyz(*rng.uniform(0.0, 0.2, 3)) for _ in range(batch)])
    w, cur = rng.normal(size=(batch, 3)), rng.uniform(-0.3, 0.3, (batch, 16))
    h = p.physics_dt_s
    out = {"compiled": min(_wall(lambda: body.step(q, w, cur, h)) for _ in range(repeats))
           / batch}
    if batch == 256:
        curs = np.repeat(cur[:, None], REUSE_STEPS, axis=1)
        dist = np.zeros((batch, REUSE_STEPS, 3))
        for fresh in (True, False):
            out["fresh_lists" if fresh else "reused_lists"] = min(
                _wall(lambda f=fresh: _step_series(q, w, curs, h, dist, f, *body.consts))
                for _ in range(repeats)) / (batch * REUSE_STEPS)
    if batch == 1:
        step, x = CasadiTwin(p).step, np.r_[q[0], w[0]]
        out["casadi"] = min(_wall(lambda: step(x, cur[0])) for _ in range(repeats))
    return out


def mpc_solve_figures(duration_s: float, repeats: int = 5) -> dict[str, float]:
    """The MPC's solves in one event-loop run of ``MPC_CASE``: their number per simulated s, the
    SQP iterations (QPs) per solve, the machine solver's wall time per solve replayed on the
    same inputs in compiled code (best of ``repeats`` replays, mean over the solves), and the
    wall time of one evaluation of the SQP's derivatives (``MPCProblem.jac_fg_function``,
    compiled as the solver's are; best of ``repeats``). Every QP needs the derivatives at its
    iterate, so iterations x that time is a floor per solve of any SQP on this model."""
    import ctypes

    import casadi as ca
    import numpy as np
    from numba import njit

    from controller import codegen
    from controller.mpc_machine import (
        MachineFunction,
        call_casadi,
        machine_function,
        machine_mpc,
        weight_values,
    )

    @njit
    def calls(fn, arg, res, iw, w, inputs, rows):
        status = 0
        for k in range(rows.shape[0]):
            inputs[:] = rows[k]
            status |= call_casadi(fn, arg, res, iw, w)
        return status

    loop = build_loop(Scenario.model_validate(_configs(1, duration_s, MPC_CASE)[0]))
    ctrl = loop.controller
    solver, rows, iterations = ctrl.solver, [], []
    names = ("x0", "p", "lbx", "ubx", "lbg", "ubg", "lam_x0", "lam_g0")
    problem = ctrl.problem
    weights = weight_values(problem)
    machine = machine_mpc(problem).solver
    sizes = np.diff(machine.offsets_in)

    def recording(**kw):
        """The event loop's solver, its inputs kept as the machine solver takes them."""
        sol = solver(**kw)
        kw["p"] = np.r_[np.ravel(kw["p"]), weights]
        rows.append(np.concatenate([np.ravel(kw.get(n, 0.0) * np.ones(size))
                                    for n, size in zip(names, sizes, strict=True)]))
        iterations.append(solver.stats()["iter_count"])
        return sol

    recording.stats = solver.stats  # the controller reads them after each call
    ctrl.solver = recording
    loop.run()
    table = np.array(rows)

    def best(fn: MachineFunction, data: np.ndarray) -> float:
        """Wall time (s) per row of ``fn`` called on each row of ``data`` in turn."""
        assert calls(*fn.call_args(), fn.inputs, data) == 0, "a generated function failed"
        return min(_wall(lambda: calls(*fn.call_args(), fn.inputs, data))
                   for _ in range(repeats)) / len(data)

    jac = problem.jac_fg_function()
    gen = ca.CodeGenerator("bench_jac_fg.c", {"with_header": False})
    gen.add(jac)
    lib = codegen.compiled_library([gen.dump()], "bench_jac_fg")
    assert lib is not None, "no C compiler"
    derivatives = machine_function(ctypes.CDLL(str(lib)), jac)
    # its inputs (x, p without the weights) lead the solver's (x0, p with the weights appended)
    return {
        "mpc_solves_per_simulated_s": len(rows) / duration_s,
        "mpc_sqp_iterations_per_solve_mean": float(np.mean(iterations)),
        "mpc_machine_solve_s": best(machine, table),
        "mpc_derivatives_evaluation_s": best(
            derivatives, np.ascontiguousarray(table[:, : derivatives.inputs.size])),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny sizes, a smoke test")
    ap.add_argument("--out", type=Path, help="with --quick: write the figures to this JSON")
    ap.add_argument("--parts", default=",".join(PARTS),
                    help=f"comma-separated parts to run, of {', '.join(PARTS)}")
    args = ap.parse_args()
    parts = [p for p in args.parts.split(",") if p]
    if unknown := set(parts) - set(PARTS):
        ap.error(f"unknown parts {sorted(unknown)}; choose from {', '.join(PARTS)}")
    quick = args.quick
    duration = 0.2 if quick else 2.0
    sizes = [1, 4] if quick else [2**k for k in range(11)]
    figures: dict[str, float] = {}
    throughput(2, 0.2)  # warm-up: first-call costs (imports, caches) out of the figures
    event_loop_speed(0.2)
    if "throughput" in parts:
        for b in sizes:
            figures[f"batched_B{b}_realtime_factor"] = throughput(b, duration)
            figures[f"batched_summaries_B{b}_realtime_factor"] = throughput(b, duration, False)
        figures["event_loop_realtime_factor"] = event_loop_speed(duration)
        for b in (1, 256, 1024):
            for name, wall in physics_kernel_times(b).items():
                figures[f"physics_step_{name}_B{b}_s_per_rotor"] = wall
        ref = 4 if quick else 256
        figures[f"batched_B{ref}_over_event_loop"] = (
            figures[f"batched_B{ref}_realtime_factor"] / figures["event_loop_realtime_factor"]
        )
    if "mpc" in parts:
        from latency import compiled

        loop = build_loop(Scenario.model_validate(_configs(1, duration, MPC_CASE)[0]))
        if (cov := compiled.coverage(loop)).path != "compiled":
            raise SystemExit(f"the MPC's runs take the {cov.path} path here: {cov.reason}")
        for tables in (True, False):  # warm-up: the solver's machine code, numba's caches
            throughput(2, 0.2, tables, MPC_CASE)
        event_loop_speed(0.2, MPC_CASE)
        b = 2 if quick else MPC_BATCH
        figures[f"mpc_batched_B{b}_realtime_factor"] = throughput(b, duration, case=MPC_CASE)
        figures[f"mpc_batched_summaries_B{b}_realtime_factor"] = throughput(
            b, duration, False, MPC_CASE)
        figures["mpc_event_loop_realtime_factor"] = event_loop_speed(duration, MPC_CASE)
        for kind in ("", "summaries_"):
            figures[f"mpc_batched_{kind}B{b}_over_event_loop"] = (
                figures[f"mpc_batched_{kind}B{b}_realtime_factor"]
                / figures["mpc_event_loop_realtime_factor"])
        # The most any MPC solver could give: the same runs with the PID (whose law costs
        # next to nothing) are what the MPC's runs would cost if every solve took no time.
        free = {"": throughput(b, duration), "summaries_": throughput(b, duration, False)}
        figures[f"mpc_bound_free_solves_B{b}_over_event_loop"] = (
            free["summaries_"] / figures["mpc_event_loop_realtime_factor"])
        solves = mpc_solve_figures(duration)
        figures.update(solves)
        figures["mpc_derivatives_floor_per_solve_s"] = (
            solves["mpc_sqp_iterations_per_solve_mean"] * solves["mpc_derivatives_evaluation_s"])
        # The wall time per solve that leaves the batched runs at 50x the event loop: 1/(50 x
        # its factor) s per simulated s, less the time of the runs without solves, shared
        # among the solves of a simulated s. Negative: out of reach even with free solves.
        for kind, factor in free.items():
            figures[f"mpc_solve_budget_for_50x_{kind}B{b}_s"] = (
                1.0 / (50.0 * figures["mpc_event_loop_realtime_factor"])
                - 1.0 / factor) / solves["mpc_solves_per_simulated_s"]
    if "study" in parts:
        # The 2-seed sweep (224 runs), comparable across engines and with earlier records; the
        # default 32-seed study's wall time is bench_study's.
        cfg = study_config.StudyConfig(workers=1, n_seeds=2)
        if quick:
            cfg = cfg.model_copy(update={"delays_ms": (study_config.GK_MS,), "max_rates_rad_s": (),
                                         "duration_s": 0.6})
        ev, bt = study_sweep_walls(cfg)
        figures["study_sweep_event_wall_s"], figures["study_sweep_batched_wall_s"] = ev, bt
    if "tune" in parts:
        tk = (dict(delays_s=(0.01633,), grid_points=2, n_trials=0, seeds=(0,),
                   validation_seeds=(100,), duration_s=0.15) if quick else {})
        ev, bt = tune_kalman_walls(**tk)
        figures["tune_kalman_event_wall_s"], figures["tune_kalman_batched_wall_s"] = ev, bt
    if "sweep" in parts:
        n_runs, n_event = (8, 2) if quick else (10_000, EVENT_SAMPLE_RUNS)
        ev, bt = sweep_walls(n_runs, n_event, duration, 4 if quick else 256)
        figures[f"sweep{n_runs}_event_wall_s_extrapolated_from_{n_event}"] = ev
        figures[f"sweep{n_runs}_batched_wall_s"] = bt
    if quick:
        for key, value in figures.items():
            print(f"{key:>50s}  {value:.6g}")
        if args.out is not None:
            args.out.write_text(json.dumps(figures, indent=2) + "\n")
        return
    from _report import record

    record(
        "bench_engine",
        "Batched closed-loop engine against the event loop (one core)",
        figures,
        notes="Default measurement-model scenario (PID, per-frame least squares, 5° tilt step, "
        "GK-TransT seed latency), 2 s runs, one BLAS/OpenMP thread. Target: "
        "batched B = 256 >= 1000x real time; MPC (same scenario with the default MPC, its "
        "solver as machine code in the compiled run loop): batched B = 64 >= 50x the event "
        "loop. The study sweep, tune-kalman (defaults) and the "
        "10,000-run sweep in one process; the event loop's 10,000-run wall time is "
        f"extrapolated from {EVENT_SAMPLE_RUNS} runs. Parts run: {', '.join(parts)}"
        + ("" if parts == list(PARTS) else
           f" (not run: {', '.join(p for p in PARTS if p not in parts)})") + ".",
    )


if __name__ == "__main__":
    main()
