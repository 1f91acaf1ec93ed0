"""The stationary-cost analysis (latency.jitterbug) against Monte Carlo runs of the
measurement-model closed loop.

Same loop on both sides: the per-axis rotor 1/(J s^2 + b s) about body y with white disturbance
torque of intensity q, the PID exactly as it runs (its discrete transfer function at the frame
period), noise-free pixels through the per-frame least-squares solver, 40 frames/s, and a random
latency (half the 2 ms exposure + 4, 9 or 14 ms of processing, equally likely): a pmf on a 1 ms
grain. The simulation is the full nonlinear MuJoCo plant (Coulomb friction off, as the linear
analysis has none).
"""

import control as ct
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from controller.pid import PIDConfig, PIDController
from controller.reference import Steps
from latency.batched import run_batched
from latency.frontends import MeasurementConfig, MeasurementFrontEnd
from latency.jitterbug import compare_with_simulation, stationary_cost
from latency.loop import ClosedLoop
from latency.loop_config import LoopConfig
from latency.models import Empirical
from latency.pipeline import PipelineConfig
from observer.cor_model import CorModel
from observer.cor_solver import CorSolver
from observer.pixel_observer import SolverObserver
from plant.params import PlantParams, RotorParams

pytestmark = pytest.mark.engine  # runs the compiled engines

P = PlantParams(rotor=RotorParams(coulomb_Nm=0.0), camera={"frame_rate_hz": 40.0})
T = 1.0 / 40.0
Q_DIST = 1e-6  # (N·m)^2 s
PROCESSING_S = (4e-3, 9e-3, 14e-3)


@pytest.mark.slow  # 20 runs of 14 s on the lockstep engine (the disturbance): 20 s of CPU
def test_stationary_cost_matches_the_simulated_loop():
    pid = PIDController(PIDConfig(crossover_rad_s=10.0), P)
    J, b = float(pid.J[1]), P.rotor.viscous_Nms_per_rad
    plant = ct.ss([[0.0, 1.0], [0.0, -b / J]], [[0.0], [1.0 / J]], [[1.0, 0.0]], [[0.0]])
    pmf = np.zeros(25)  # grain T/25 = 1 ms; delays 5, 10, 15 ms
    pmf[[round((0.5 * P.camera.exposure_s + p) * 1e3) for p in PROCESSING_S]] = 1.0 / 3.0
    Q1, Q2 = np.diag([1.0, 0.0]), np.zeros((1, 1))  # cost = E theta_y^2 (rad^2)
    analysis = stationary_cost(
        plant,
        pid.discrete_transfer_function(T, axis=1),
        period_s=T,
        delay_pmf=pmf,
        Q1=Q1,
        Q2=Q2,
        R1c=np.diag([0.0, Q_DIST / J**2]),
        R2=np.zeros((1, 1)),
    )
    assert analysis.mean_square_stable

    loops = []
    for seed in range(20):  # 20 runs: SE about 5 % of the cost (5 runs gave 10-20 %)
        cfg = LoopConfig(
            duration_s=14.0,
            seed=seed,
            disturbance_psd_Nm2s=(0.0, Q_DIST, 0.0),
            pipeline=PipelineConfig(
                frame_rate_hz=40.0, mode="pipelined", observer=Empirical(samples_s=PROCESSING_S)
            ),
        )
        front = MeasurementFrontEnd(P, MeasurementConfig(sigma_px=0.0), np.random.default_rng(seed))
        obs = SolverObserver(CorSolver(CorModel.nominal(P)))
        ref = Steps(times_s=(0.0,), attitudes=((1.0, 0.0, 0.0, 0.0),))
        ctrl = PIDController(PIDConfig(crossover_rad_s=10.0), P)
        loops.append(ClosedLoop(P, ctrl, ref, front, obs, cfg))
    runs = []
    for result in run_batched(loops):  # the runs advanced together (same results, faster)
        st = result.steps
        # rotation vector of every logged attitude at once (scipy wants the scalar last)
        q = st[["qx", "qy", "qz", "qw"]].to_numpy()
        theta_y = Rotation.from_quat(q).as_rotvec()[:, 1]
        x = np.column_stack([theta_y, st.omega_y_rad_s.to_numpy()])
        runs.append((st.t_s.to_numpy(), x, st[["torque_delivered_y_Nm"]].to_numpy()))
    cmp = compare_with_simulation(analysis, runs, Q1, Q2, t_start_s=2.0)
    print(cmp)
    assert cmp.standard_error < 0.08 * cmp.analytic  # the comparison has teeth
    assert cmp.agrees(z_max=3.0)
