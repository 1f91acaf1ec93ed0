"""Which runs the compiled run loop computes (``coverage``), and for the others why not: the
first of the run's parts or settings that it lacks."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from controller.mpc import MPCController
from controller.mpc_machine import machine_mpc
from controller.pid import PIDController
from latency.frontends import MeasurementFrontEnd
from latency.loop import ClosedLoop
from observer.cor_solver import CorSolver
from observer.pixel_observer import PixelKalmanObserver, SolverObserver


@dataclass(frozen=True)
class Coverage:
    """The batched engine's path for a run (``coverage``): ``"compiled"`` (the compiled run
    loop) or ``"lockstep"`` (the lockstep rounds of ``latency.batched``), and for the latter
    why the compiled loop does not compute it."""

    path: Literal["compiled", "lockstep"]
    reason: str = ""


def coverage(loop: ClosedLoop) -> Coverage:
    """Which path computes ``loop`` (``latency.compiled``'s case), from the types of its parts
    and its settings, with the reason when it is not the compiled run loop. For an MPC this
    builds (once per process and problem; compiled once, cached on disk) its solver's machine
    code."""
    c, fe, p = loop.config, loop.front_end, loop.params
    inner = _solver_observer(loop)
    checks = (
        (isinstance(inner, SolverObserver),
         f"observer {type(loop.observer).__name__}: the compiled loop has the per-frame "
         "least-squares observer, alone or behind the pixel Kalman filters"),
        (inner is not None and isinstance(inner.solver, CorSolver),
         "the per-frame observer's solver is not the CoR solver (CorSolver)"),
        (isinstance(fe, MeasurementFrontEnd),
         f"front end {type(fe).__name__}: the compiled loop has the measurement model"),
        (isinstance(fe, MeasurementFrontEnd) and fe.params == p,
         "the front end's plant parameters differ from the loop's"),
        (p.camera.dist_coeffs[2:4] == (0.0, 0.0), "a lens with tangential distortion"),
        (c.controller_rate_hz is None, "a controller clock (controller_rate_hz)"),
        (c.controller_latency != "measured", "a measured controller latency"),
        (c.observer_latency == "model", "a measured observer latency"),
        (not any(c.disturbance_psd_Nm2s), "a disturbance torque (disturbance_psd_Nm2s)"),
        (c.mujoco_sensor_delay_s is None, "MuJoCo's sensor delay (mujoco_sensor_delay_s)"),
    )
    for ok, reason in checks:
        if not ok:
            return Coverage("lockstep", reason)
    ctrl = loop.controller
    if isinstance(ctrl, PIDController):
        return Coverage("compiled")
    if not isinstance(ctrl, MPCController):
        return Coverage("lockstep", f"controller {type(ctrl).__name__}: the compiled loop has "
                        "the PID and the MPC")
    cfg = ctrl.config
    if cfg.solver != "sqp_hpipm" or cfg.hessian != "gauss_newton":
        return Coverage("lockstep", f"MPC solver {cfg.solver!r} with the {cfg.hessian!r} "
                        "Hessian: the compiled loop has SQP + HPIPM with the Gauss-Newton one")
    if cfg.compute_latency_s is None:
        return Coverage("lockstep", "the MPC's delay compensation assumes its measured compute "
                        "times (compute_latency_s: None)")
    if machine_mpc(ctrl.problem) is None:
        return Coverage("lockstep", "the MPC's solver could not be compiled to machine code "
                        "(no C compiler, or compiling failed)")
    return Coverage("compiled")


def _solver_observer(loop: ClosedLoop) -> SolverObserver | None:
    """The per-frame solver observer of the run: its observer, or the one behind its pixel
    Kalman filters; None for other observers."""
    obs = loop.observer
    if isinstance(obs, PixelKalmanObserver):
        return obs.inner
    return obs if isinstance(obs, SolverObserver) else None
