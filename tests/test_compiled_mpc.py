"""The MPC in the compiled run loop: its machine-code solver against the event loop's solver,
its runs against the event loop's, run by run, and the engine's choice of path with its reason."""

import numpy as np
import pytest
from numba import njit

from controller import codegen
from controller.mpc import MPCController
from controller.mpc_config import MPCConfig
from controller.mpc_machine import call_casadi, machine_mpc, weight_values
from experiments import study_config, study_sweep
from latency import Scenario, build_loop, compiled
from latency.batched import run_batched
from latency.mpc_law import _Hold
from plant import attitude as A
from plant.params import PlantParams

pytestmark = [pytest.mark.skipif(codegen.compiler() is None, reason="no C compiler"),
              pytest.mark.engine]  # runs the compiled engines

QUAT = ["qw", "qx", "qy", "qz"]


@njit
def _call(fn, arg, res, iw, w):
    return call_casadi(fn, arg, res, iw, w)


def _machine_solve(machine, args: dict, problem) -> np.ndarray:
    """The machine solver on the inputs of a ``casadi.nlpsol`` call of ``problem`` (its
    parameters followed by the problem's weights): its x."""
    s = machine.solver
    o = s.offsets_in
    args = {**args, "p": np.r_[args["p"], weight_values(problem)]}
    for k, name in enumerate(("x0", "p", "lbx", "ubx", "lbg", "ubg", "lam_x0", "lam_g0")):
        s.inputs[o[k] : o[k + 1]] = args.get(name, 0.0)
    assert _call(*s.call_args()) == 0
    return s.outputs[: s.offsets_out[1]].copy()


@pytest.mark.parametrize("config", [
    MPCConfig(compute_latency_s=0.0),
    MPCConfig(compute_latency_s=0.0, bandwidth_rad_s=9.0, damping=1.0, torque_limit_Nm=0.02,
              tilt_max_deg=5.0, tilt_slack_l1=500.0, tilt_slack_l2=2e4),
], ids=["default", "other weights and limits"])
def test_the_machine_solver_gives_the_event_loops_solves(config):
    """Cold start from a tilted, turning rotor, then a warm start with the multipliers of the
    first solve and a moved initial state: the same iterate as ``MPCController.solver`` (the
    SQP with the compiled derivatives) to 1e-9, for the default MPC and for one with other
    weights and limits, which shares the default's machine code (its weights are
    parameters)."""
    mpc = MPCController(config, PlantParams())
    pr = mpc.problem
    machine = machine_mpc(pr)
    assert machine is not None
    assert machine is machine_mpc(MPCController(MPCConfig(), PlantParams()).problem)
    ref = _Hold(A.from_rotvec([0.08, 0.0, 0.0]))
    x0 = np.r_[A.from_rotvec([0.05, -0.03, 0.02]), 0.1, 0.0, -0.2]
    cold = dict(**pr.bounds(x0), p=mpc._parameters(ref, 0.0, x0[:4]),
                x0=pr.pack(np.tile(x0, (pr.N + 1, 1)), np.zeros((pr.N, 3)), np.zeros(pr.N)))
    sol = mpc.solver(**cold)
    w = np.asarray(sol["x"]).ravel()
    assert np.max(np.abs(_machine_solve(machine, cold, pr) - w)) < 1e-9
    x1 = np.r_[A.from_rotvec([0.045, -0.02, 0.02]), 0.2, 0.1, -0.1]
    warm = dict(**pr.bounds(x1), p=mpc._parameters(ref, 0.0, x1[:4]), x0=w,
                lam_x0=np.asarray(sol["lam_x"]).ravel(), lam_g0=np.asarray(sol["lam_g"]).ravel())
    w_warm = np.asarray(mpc.solver(**warm)["x"]).ravel()
    assert np.max(np.abs(w_warm - w)) > 1e-3  # a different problem
    assert np.max(np.abs(_machine_solve(machine, warm, pr) - w_warm)) < 1e-9


def _mpc_scenario(**kw) -> Scenario:
    base = {"duration_s": 0.5, "observer": {"kind": "solver"}, "controller": {"kind": "mpc"}}
    return Scenario.model_validate({**base, **kw})


#: MPC runs: the default (delay-aware, previewing) step behind the pixel Kalman filters; a run
#: without preview on a cone with dropouts (invalid estimates: the torque held) and random
#: pipelined latencies; a run without delay awareness, zero torque on invalid estimates. The
#: observer holds a solution for ``MAX_INVALID_S`` (instead of 0.5 s), so that dropouts make
#: invalid estimates.
MPC_GRID = {
    "step, pixel Kalman": _mpc_scenario(seed=0, observer={"kind": "pixel_kalman"}),
    "no preview, dropouts, random latencies": _mpc_scenario(
        seed=1, controller={"kind": "mpc", "config": {"reference_preview": False}},
        measurement={"dropout_prob": 0.3, "outlier_prob": 0.1},
        reference={"kind": "cone", "args": {"tilt_deg": 6.0, "yaw_rate_rad_s": 4.0}},
        pipeline={"observer": {"kind": "gamma", "shape_k": 9.0, "scale_theta_s": 0.003},
                  "mode": "pipelined"},
        controller_latency={"kind": "uniform", "low_s": 0.002, "high_s": 0.006},
    ),
    "not delay-aware, zero on invalid": _mpc_scenario(
        seed=2, controller={"kind": "mpc", "config": {"delay_aware": False,
                                              "invalid_command": "zero"}},
        measurement={"dropout_prob": 0.4},
    ),
}


MAX_INVALID_S = 0.03


def _loop(s: Scenario):
    loop = build_loop(s)
    inner = compiled._solver_observer(loop)
    inner.max_invalid_s = MAX_INVALID_S
    return loop


@pytest.fixture(scope="module")
def mpc_runs():
    scenarios = list(MPC_GRID.values())
    for s in scenarios:
        assert compiled.coverage(_loop(s)).path == "compiled"
    event = [_loop(s).run() for s in scenarios]
    batched = run_batched([_loop(s) for s in scenarios])
    return dict(zip(MPC_GRID, zip(event, batched, strict=True), strict=True))


@pytest.mark.parametrize("case", list(MPC_GRID))
def test_compiled_mpc_runs_follow_the_event_loop(mpc_runs, case):
    """Same seed, same run: every step's attitude within 1e-9 rad and torque within 1e-9 N·m
    (the solver's tolerance is 1e-5), the same events, the summary metrics equal to 1e-9."""
    ev, bt = mpc_runs[case]
    assert len(ev.steps) == len(bt.steps)
    assert np.max(A.geodesic_angle(ev.steps[QUAT].to_numpy(), bt.steps[QUAT].to_numpy())) < 1e-9
    torque = [c for c in ev.steps.columns if c.startswith("torque_cmd")]
    assert len(torque) == 3
    assert np.max(np.abs(ev.steps[torque].to_numpy() - bt.steps[torque].to_numpy())) < 1e-9
    assert ev.events.kind.tolist() == bt.events.kind.tolist()
    assert ev.summary.keys() == bt.summary.keys()
    for key, value in ev.summary.items():
        assert bt.summary[key] == pytest.approx(value, rel=1e-9, abs=1e-12, nan_ok=True), key


def test_the_mpc_grid_covers_what_it_claims(mpc_runs):
    """Invalid estimates in the runs with dropouts, and the MPC moving the rotor."""
    for case in ("no preview, dropouts, random latencies",
                 "not delay-aware, zero on invalid"):
        ev = mpc_runs[case][0]
        assert "invalid_estimate" in set(ev.events.kind), case
    step = mpc_runs["step, pixel Kalman"][0]
    assert step.steps.error_deg.iloc[-1] < 0.5 * step.steps.error_deg.max()


def test_coverage_names_the_path_and_the_reason():
    """The compiled loop for the PID and the default MPC; the lockstep rounds, with the reason,
    for an MPC without a fixed compute latency, another MPC solver, or another observer; the
    compiled run loop refuses those runs naming the reason."""
    assert compiled.coverage(build_loop(_mpc_scenario(controller={"kind": "pid"}))).path \
        == "compiled"
    measured = build_loop(_mpc_scenario(controller_latency="measured"))
    cov = compiled.coverage(measured)
    assert cov.path == "lockstep" and "measured controller latency" in cov.reason
    free = build_loop(_mpc_scenario())
    free.controller = MPCController(free.controller.config.model_copy(
        update={"compute_latency_s": None}), free.params)
    assert "compute_latency_s: None" in compiled.coverage(free).reason
    ipopt = _mpc_scenario(controller={"kind": "mpc", "config": {
        "solver": "ipopt", "compute_latency_s": 0.011}})
    assert "'ipopt'" in compiled.coverage(build_loop(ipopt)).reason
    aekf = build_loop(_mpc_scenario(observer={"kind": "aekf"}))
    assert "observer FilterObserver" in compiled.coverage(aekf).reason
    with pytest.raises(ValueError, match="observer FilterObserver"):
        compiled.run(aekf)


def test_the_studys_mpc_runs_take_the_compiled_path():
    """Every run of the study's closed-loop sweep, PID and MPC, goes through the compiled run
    loop (the MPC's runs used to take the lockstep rounds)."""
    configs = study_sweep.sweep_configs(study_config.StudyConfig(workers=1, n_seeds=1))
    paths = {}
    for c in configs:
        s = Scenario.model_validate(study_sweep._scenario_part(c))
        paths.setdefault(s.controller.kind, set()).add(compiled.coverage(build_loop(s)).path)
    assert paths == {"pid": {"compiled"}, "mpc": {"compiled"}}


def test_simulate_says_which_path_computes_the_run(tmp_path):
    """``pmspm simulate`` names the engine and path, and the reason when a run is not the
    compiled run loop's (here an MPC behind the AEKF)."""
    import yaml
    from typer.testing import CliRunner

    from experiments.cli import app

    path = tmp_path / "s.yaml"
    lines = {}
    for name, observer in (("solver", "solver"), ("aekf", "aekf")):
        path.write_text(yaml.safe_dump({"duration_s": 0.2, "observer": {"kind": observer},
                                        "controller": {"kind": "mpc"}}))
        res = CliRunner().invoke(app, ["simulate", str(path), "--out", str(tmp_path / name)])
        assert res.exit_code == 0, res.output
        lines[name] = [ln for ln in res.output.splitlines() if ln.startswith("engine:")]
    assert lines["solver"] == ["engine: batched, compiled run loop"]
    assert len(lines["aekf"]) == 1
    assert lines["aekf"][0].startswith("engine: batched, not the compiled run loop (observer "
                                       "FilterObserver")
