"""Attitude controllers (PID, MPC) behind one interface, and reference trajectories.

``command(estimate, reference, t) -> torque`` (controller/base.py): the torque on the rotor in the
stator frame, N·m. See docs/controllers.md for the tuning rule, the MPC formulation and the
measured solve times.
"""

from controller.base import Controller, Reference, RefSample
from controller.mpc import MPCConfig, MPCController
from controller.pid import PIDConfig, PIDController, PIDGains, truth_estimate, tuning_rule
from controller.reference import Cone, Ramp, RandomSmooth, SeedSteps, Steps, pure_tilt

__all__ = [
    "Cone",
    "Controller",
    "MPCConfig",
    "MPCController",
    "PIDConfig",
    "PIDController",
    "PIDGains",
    "RandomSmooth",
    "Ramp",
    "RefSample",
    "Reference",
    "SeedSteps",
    "Steps",
    "pure_tilt",
    "truth_estimate",
    "tuning_rule",
]
