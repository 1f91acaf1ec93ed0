"""Analysis and simulation agree : the PID loop simulated in the
measurement-model mode is stable at 0.9x and unstable at 1.1x the predicted delay margin, at two
crossover frequencies.

The prediction is the exact sampled-data delay margin (latency.margins.sampled_margins) of the
PID as it runs (``PIDController.discrete_transfer_function``: called once per frame on
attitude-only estimates) on the per-axis plant 1/(J s^2 + b s). The simulation is the full
nonlinear MuJoCo plant in the timed loop with noise-free pixels, the per-frame least-squares
solver, and a pipelined observer whose latency is the extra delay; Coulomb friction is switched off
(the linear analysis has no dry friction).
"""

import numpy as np
import pytest

from controller.pid import PIDConfig, PIDController
from controller.reference import Steps, pure_tilt
from latency.frontends import MeasurementConfig, MeasurementFrontEnd
from latency.loop import ClosedLoop
from latency.loop_config import LoopConfig
from latency.margins import attitude_plant, sampled_margins
from latency.models import Constant, LatencyModel
from latency.pipeline import PipelineConfig, PipelineMode
from observer.cor_model import CorModel
from observer.cor_solver import CorSolver
from observer.pixel_observer import SolverObserver
from plant.params import PlantParams, RotorParams

P = PlantParams(rotor=RotorParams(coulomb_Nm=0.0))
T = 1.0 / P.camera.frame_rate_hz


def predicted_delay_margin(wc: float) -> float:
    ctrl = PIDController(PIDConfig(crossover_rad_s=wc), P)
    plant = attitude_plant(float(ctrl.J[1]), P.rotor.viscous_Nms_per_rad)
    m = sampled_margins(
        plant, ctrl.discrete_transfer_function(T, axis=1), delay_s=0.5 * P.camera.exposure_s
    )
    assert m.stable
    return m.delay_margin_s  # extra delay on top of the half exposure


def simulated_rate_amplitudes(
    wc: float, observer: LatencyModel, mode: PipelineMode
) -> tuple[float, float, dict]:
    """Peak |omega_y| (rad/s) in the middle and the last third of a 4 s run after a 0.5° tilt
    step about Y, the observer's latency drawn from ``observer`` (s) in pipeline ``mode``, and
    the run's summary."""
    ref = Steps(
        times_s=(0.0, 0.1),
        attitudes=((1.0, 0.0, 0.0, 0.0), tuple(pure_tilt(np.deg2rad(0.5), 0.0))),
    )
    front = MeasurementFrontEnd(P, MeasurementConfig(sigma_px=0.0), np.random.default_rng(0))
    cfg = LoopConfig(duration_s=4.0, pipeline=PipelineConfig(mode=mode, observer=observer))
    obs = SolverObserver(CorSolver(CorModel.nominal(P)))
    r = ClosedLoop(P, PIDController(PIDConfig(crossover_rad_s=wc), P), ref, front, obs, cfg).run()
    w = np.abs(r.steps.omega_y_rad_s.to_numpy())
    n = len(w)
    return w[n // 3 : 2 * n // 3].max(), w[2 * n // 3 :].max(), r.summary


def rate_amplitudes(wc: float, extra_delay_s: float) -> tuple[float, float]:
    """:func:`simulated_rate_amplitudes` with a pipelined observer of constant latency
    ``extra_delay_s`` (s), checking the loop's mean latency."""
    mid, late, summary = simulated_rate_amplitudes(
        wc, Constant(value_s=extra_delay_s), "pipelined"
    )
    assert summary["mean_latency_s"] == pytest.approx(0.5 * P.camera.exposure_s + extra_delay_s)
    return mid, late


@pytest.mark.parametrize("wc", [10.0, 15.0])
def test_simulated_instability_matches_the_predicted_delay_margin(wc):
    dm = predicted_delay_margin(wc)
    mid, late = rate_amplitudes(wc, 0.9 * dm)
    assert late < 0.8 * mid  # decaying: stable
    mid, late = rate_amplitudes(wc, 1.1 * dm)
    assert late > 1.25 * mid  # growing: unstable
