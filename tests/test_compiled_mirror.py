"""The compiled run loop's mirror of the event loop, pair by pair.

Each compiled function of ``latency.compiled`` that computes what a Python function of the
event loop computes names it ("Compiled mirror of ...") and is named back ("Mirrored in ...").
``test_every_mirror_is_named_both_ways_and_tested`` reads the pairs from the docstrings; each
other test here drives one pair (or the few pairs of one Python function) with the same seeded
random inputs and checks the outputs equal: bit for bit where both compute the same arithmetic
in the same order, else within a bound derived from how they differ.
"""

from __future__ import annotations

import ast
import importlib
import pkgutil
import re
from pathlib import Path

import numpy as np
import pytest
from numba.core.dispatcher import Dispatcher

from controller import codegen
from controller.base import Reference, RefSample
from controller.mpc import MPCConfig, MPCController
from controller.pid import PIDConfig, PIDController, RateFromAttitude
from latency import Scenario, build_loop, compiled
from latency.compiled import layout as L
from latency.compiled.allocation import _least_norm, _torque_map
from latency.compiled.events import _event_queue
from latency.compiled.frontend import _blur_travel_px, _capture, _p_lost, _project, _roi_misses
from latency.compiled.mpc import (
    _M_HIST_END,
    _M_HIST_FIRST,
    _mpc,
    _mpc_arrays,
    _mpc_predict,
    _mpc_record,
)
from latency.compiled.observer import _pixel_kalman, _solve
from latency.compiled.pid import _attitude_rate, _pid
from latency.compiled.rotations import _rotvec
from latency.compiled.run import _initial_state
from latency.compiled.settings import (
    _front_end_settings,
    _model_arrays,
    _observer_settings,
    _pid_settings,
    _plant_parts,
)
from latency.compiled.steps import _advance
from latency.frontends import MeasurementConfig, MeasurementFrontEnd, SearchWindowLoss
from latency.loop import _StepLog
from latency.loss_model import (
    FORMAT_VERSION,
    LossModel,
    LossModelFile,
    blur_travel_px,
    prediction_offset_px,
)
from latency.pipeline import FrameScheduler, PipelineConfig
from latency.segments import Advance, _advance_segment
from observer.cor_model import CorModel
from observer.cor_solver import CorSolver, failure_reason
from observer.gk.pixel_kalman import PixelKalmanConfig
from observer.pixel_observer import PixelKalmanObserver
from plant import attitude as A
from plant.camera import marker_pixels
from plant.camera_mode import RegionOfInterest
from plant.dynamics import MujocoPlant
from plant.estimate import Estimate
from plant.params import PlantParams
from plant.rigid_body import PAIR_REUSE_RAD, _pair_lists, tilt_stop_contact
from plant.torque import N_COILS, TorqueMap, allocate

pytestmark = pytest.mark.engine  # runs the compiled engines

ROOT = Path(__file__).resolve().parents[1]
EPS = np.finfo(float).eps
PARAMS = PlantParams()

#: Compiled functions without a Python twin: building blocks whose Python counterparts share
#: their code (``plant.attitude``'s compiled formulas) or that only write the kernel's records.
BUILDING_BLOCKS = {
    "latency.compiled.rotations._unit": "q / |q|, the division ``attitude.normalize`` does",
    "latency.compiled.rotations._conj_mul": "``plant.attitude._hamilton``, shared",
    "latency.compiled.rotations._matrix": "``plant.attitude._matrix_elements``, shared",
    "latency.compiled.rotations._mv": "a 3 x 3 product written out",
    "latency.compiled.rotations._mtv": "a 3 x 3 product written out",
    "latency.compiled.rotations._geodesic": "``plant.attitude._geodesic_of``, shared",
    "latency.compiled.steps._event": "appends to the kernel's event record",
}


# --- the pairs, from the docstrings ---------------------------------------------------------
def _names(text: str, lead: str) -> list[str]:
    """The ``dotted.names`` of the sentence of ``text`` that starts with ``lead``."""
    flat = " ".join(text.split())
    found = []
    for m in re.finditer(re.escape(lead) + r"((?:\s*(?:,|and)?\s*``[\w.]+``)+)", flat):
        found += re.findall(r"``([\w.]+)``", m.group(1))
    return found


def _compiled_side() -> tuple[dict[str, list[str]], set[str]]:
    """Per function of ``latency.compiled`` the twins its docstring names, and the names of
    its compiled (numba) functions."""
    twins: dict[str, list[str]] = {}
    kernels: set[str] = set()
    for info in pkgutil.iter_modules(compiled.__path__, "latency.compiled."):
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            fn = obj.py_func if isinstance(obj, Dispatcher) else obj
            if not callable(fn) or getattr(fn, "__module__", None) != info.name:
                continue
            full = f"{info.name}.{name}"
            if isinstance(obj, Dispatcher):
                kernels.add(full)
            named = _names(fn.__doc__ or "", "Compiled mirror of")
            if named:
                twins[full] = named
    return twins, kernels


def _python_side() -> dict[str, list[str]]:
    """Per function, method or class of the project outside ``latency.compiled`` the compiled
    functions its docstring names ("Mirrored in ...")."""
    out: dict[str, list[str]] = {}
    for package in ("plant", "observer", "controller", "latency", "experiments"):
        for path in sorted((ROOT / package).rglob("*.py")):
            rel = path.relative_to(ROOT).with_suffix("")
            if rel.parts[:2] == ("latency", "compiled"):
                continue
            module = ".".join(rel.parts)

            def walk(node: ast.AST, prefix: str) -> None:
                for child in ast.iter_child_nodes(node):
                    if isinstance(child, (ast.FunctionDef, ast.ClassDef)):
                        name = f"{prefix}.{child.name}"
                        named = _names(ast.get_docstring(child) or "", "Mirrored in")
                        if named:
                            out[name] = named
                        walk(child, name)

            walk(ast.parse(path.read_text()), module)
    return out


def _resolve(dotted: str) -> object:
    """The object named ``module.attr.attr``."""
    parts = dotted.split(".")
    for i in range(len(parts) - 1, 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ModuleNotFoundError:
            continue
        for attr in parts[i:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(dotted)


#: Each pair (compiled function, Python twin) and the test of this module that checks it.
TESTED = {
    ("latency.compiled.events._event_queue", "latency.pipeline.FrameScheduler.next_frame"):
        "test_event_queue_times_the_frames_as_the_frame_scheduler",
    ("latency.compiled.rotations._rotvec", "plant.attitude.to_rotvec"):
        "test_rotvec_is_to_rotvec",
    ("latency.compiled.frontend._project", "plant.camera.marker_pixels"):
        "test_project_is_marker_pixels",
    ("latency.compiled.frontend._roi_misses", "plant.camera_mode.RegionOfInterest.contains"):
        "test_roi_misses_is_outside_the_region_of_interest",
    ("latency.compiled.frontend._roi_misses", "plant.camera_mode.RegionOfInterest.centre_px"):
        "test_roi_misses_is_outside_the_region_of_interest",
    ("latency.compiled.frontend._blur_travel_px", "latency.loss_model.blur_travel_px"):
        "test_blur_travel_is_blur_travel_px",
    ("latency.compiled.frontend._p_lost", "latency.loss_model.LossModel.p_lost"):
        "test_p_lost_is_the_loss_models",
    ("latency.compiled.frontend._p_lost", "latency.loss_model.prediction_offset_px"):
        "test_p_lost_is_the_loss_models",
    ("latency.compiled.frontend._capture", "latency.frontends.MeasurementFrontEnd.capture"):
        "test_capture_is_the_measurement_front_ends",
    ("latency.compiled.observer._solve", "observer.cor_solver.CorSolver.solve"):
        "test_solve_is_the_cor_solvers",
    ("latency.compiled.observer._pixel_kalman",
     "observer.pixel_observer.PixelKalmanObserver.process"):
        "test_pixel_kalman_is_the_observers_filters",
    ("latency.compiled.observer._pixel_kalman", "observer.gk.pixel_kalman.PixelKalman"):
        "test_pixel_kalman_is_the_observers_filters",
    ("latency.compiled.pid._attitude_rate", "controller.pid.RateFromAttitude.update"):
        "test_attitude_rate_is_rate_from_attitude",
    ("latency.compiled.pid._pid", "controller.pid.PIDController.command"):
        "test_pid_is_the_pid_controller",
    ("latency.compiled.mpc._mpc_record", "controller.mpc.MPCController.record_command"):
        "test_mpc_record_keeps_the_mpcs_history",
    ("latency.compiled.mpc._mpc_predict", "controller.mpc.MPCController.predict"):
        "test_mpc_predict_is_the_mpcs_prediction",
    ("latency.compiled.mpc._mpc_arrays", "controller.mpc.MPCController._parameters"):
        "test_mpc_is_the_mpc_controller",
    ("latency.compiled.mpc._mpc_parameters", "controller.mpc.MPCController._parameters"):
        "test_mpc_is_the_mpc_controller",
    ("latency.compiled.mpc._mpc_initial_state", "controller.mpc.MPCController._initial_state"):
        "test_mpc_is_the_mpc_controller",
    ("latency.compiled.mpc._mpc_guess", "controller.mpc.MPCController._initial_guess"):
        "test_mpc_is_the_mpc_controller",
    ("latency.compiled.mpc._mpc", "controller.mpc.MPCController.command"):
        "test_mpc_is_the_mpc_controller",
    ("latency.compiled.mpc._mpc_keep", "controller.mpc.MPCController.command"):
        "test_mpc_is_the_mpc_controller",
    ("latency.compiled.allocation._torque_map", "plant.torque.TorqueMap.from_matrix"):
        "test_torque_map_is_the_torque_map",
    ("latency.compiled.allocation._least_norm", "plant.torque.allocate"):
        "test_least_norm_is_allocate_within_the_limits",
    ("latency.compiled.steps._advance", "latency.segments._advance_segment"):
        "test_advance_is_advance_segment",
    ("latency.compiled.steps._record", "latency.loop._StepLog.write_rows"):
        "test_advance_is_advance_segment",
    ("latency.compiled.kernel._on_frame", "latency.loop.ClosedLoop._on_frame"):
        "test_on_frame_is_the_event_loops",
    ("latency.compiled.kernel._on_release", "latency.loop.ClosedLoop._on_release"):
        "test_on_release_is_the_event_loops",
    ("latency.compiled.kernel._on_command", "latency.loop.ClosedLoop._on_command"):
        "test_on_command_is_the_event_loops",
    ("latency.compiled.kernel._run_events", "latency.loop.ClosedLoop.timeline"):
        "test_run_events_is_the_timeline",
}


def test_every_mirror_is_named_both_ways_and_tested():
    """Every compiled function names its Python twin or is a listed building block; every
    pointer resolves and is matched by the pointer back; every pair has its test here."""
    twins, kernels = _compiled_side()
    back = _python_side()
    pairs = {(c, p) for c, ps in twins.items() for p in ps}
    pairs_back = {(c, p) for p, cs in back.items() for c in cs}
    assert pairs == pairs_back, (pairs ^ pairs_back)
    unnamed = kernels - set(twins) - set(BUILDING_BLOCKS)
    assert not unnamed, f"compiled functions that name no Python twin: {sorted(unnamed)}"
    assert not set(BUILDING_BLOCKS) - kernels
    for name in {c for c, _ in pairs} | {p for _, p in pairs}:
        _resolve(name)
    assert set(TESTED) == pairs
    assert set(TESTED.values()) <= set(globals())
    assert len(pairs) == 30


# --- shared inputs ---------------------------------------------------------------------------
def _attitudes(rng: np.random.Generator, n: int, max_deg: float = 20.0) -> np.ndarray:
    """n attitudes (n, 4) within ``max_deg`` of upright, random axes."""
    rv = rng.normal(size=(n, 3))
    rv *= np.radians(rng.uniform(0.0, max_deg, n))[:, None] / np.linalg.norm(rv, axis=1)[:, None]
    return np.array([A.from_rotvec(r) for r in rv])


def _near(q: np.ndarray, rng: np.random.Generator, deg: float) -> np.ndarray:
    """q turned by up to ``deg`` about a random axis."""
    rv = rng.normal(size=3)
    return A.multiply(q, A.from_rotvec(rv / np.linalg.norm(rv) * np.radians(rng.uniform(0, deg))))


class _Table(Reference):
    """A reference given at a few times: each sample is drawn once, at random."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng, self.at = rng, {}

    def sample(self, t: float) -> RefSample:
        if t not in self.at:
            self.at[t] = RefSample(q=_attitudes(self.rng, 1)[0], omega=self.rng.normal(0, 2, 3),
                                   alpha=self.rng.normal(0, 20, 3))
        return self.at[t]


# --- the schedule ----------------------------------------------------------------------------
def test_event_queue_times_the_frames_as_the_frame_scheduler():
    """Random frame periods, exposures, readouts, both modes, random observer latencies: the
    same frames (exposure, release, dropped) as ``FrameScheduler.next_frame`` with those
    latencies, bit for bit (the same arithmetic)."""
    rng = np.random.default_rng(0)
    compared = 0
    for case in range(40):
        period = rng.uniform(0.01, 0.05)
        cfg = PipelineConfig(frame_rate_hz=1.0 / period, exposure_s=rng.uniform(0.1, 1) * period,
                             readout_s=rng.uniform(0, 0.01),
                             mode="pipelined" if case % 2 else "sequential")
        latencies = rng.uniform(0.0, 3.0 * period, 200)
        _, frames, bad = _event_queue(cfg.frame_period_s, cfg.exposure_s, cfg.readout_s,
                                      cfg.mode == "sequential", cfg.mode == "pipelined", 1.0,
                                      latencies, np.zeros(200))
        assert bad == -1
        used = iter(latencies)
        sched = FrameScheduler(cfg, rng)
        want = [sched.next_frame(lambda k, used=used: next(used)) for _ in range(len(frames))]
        expected = np.array([(f.t_exposure, f.t_release, f.dropped) for f in want], dtype=float)
        assert np.array_equal(frames, expected, equal_nan=True)
        compared += len(frames)
    assert compared > 1000


# --- rotations -------------------------------------------------------------------------------
def test_rotvec_is_to_rotvec():
    """Random unit quaternions, both signs of w, angles from 1e-14 rad to pi: the rotation
    vector of ``plant.attitude.to_rotvec`` to 8 eps pi (the same formula with the angle
    2 atan2(s, w) scaled by 1/s before, not after, the multiplication by the axis: two roundings
    of a number below pi ordered differently, and |vec q| summed without BLAS)."""
    rng = np.random.default_rng(1)
    q = rng.normal(size=(600, 4))
    q[:100, 1:] *= 1e-14
    q /= np.linalg.norm(q, axis=1)[:, None]
    diff = [np.max(np.abs(np.array(_rotvec(x)) - A.to_rotvec(x))) for x in q]
    assert len(diff) == 600 and max(diff) <= 8 * EPS * np.pi


# --- the front end ---------------------------------------------------------------------------
TRUE_MODEL = _model_arrays(CorModel.nominal(PARAMS))
#: The largest distance of a marker's pixel from the principal point, px, over the workspace:
#: the scale of the rounding of two codes of the same projection.
PX_SCALE = 4000.0
#: ``_project`` (``observer.cor_model``'s projection, from the CoR) against
#: ``plant.camera.marker_pixels`` (the rotor's points in the stator frame, then the camera):
#: the same pinhole and radial distortion in another order, each some 40 roundings of
#: numbers below ``PX_SCALE`` px: 64 eps PX_SCALE.
PX_TOL = 64 * EPS * PX_SCALE


def test_project_is_marker_pixels():
    """Random attitudes over the workspace: the marker pixels of ``marker_pixels`` to
    ``PX_TOL``."""
    q = _attitudes(np.random.default_rng(2), 300, 25.0)
    diff = [np.max(np.abs(_project(x, *TRUE_MODEL) - marker_pixels(PARAMS, x))) for x in q]
    assert len(diff) == 300 and max(diff) <= PX_TOL


def _front_end_state(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """A front end's state (``st``) with a random last measurement and motion (none in a
    quarter of the draws), the same as ``MarkerPrediction``'s arrays, and the true pixels."""
    st = _initial_state((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    truth = marker_pixels(PARAMS, _attitudes(rng, 1)[0])
    last = truth + rng.normal(0, 80, (2, 2))
    motion = rng.normal(0, 40, (2, 2))
    has = rng.random() > 0.25
    st[L._FE_HAS] = has
    st[L._FE_LAST : L._FE_LAST + 4] = last.ravel()
    st[L._FE_MOTION : L._FE_MOTION + 4] = motion.ravel()
    st[L._FE_LOST] = rng.integers(0, 4)
    return st, (np.stack([last, motion]) if has else None), truth


def test_roi_misses_is_outside_the_region_of_interest():
    """Random regions (size, following or not, with or without the motion), predictions and
    true pixels over the sensor: a miss exactly where ``RegionOfInterest.contains`` at its
    ``centre_px`` says the markers are not all inside (booleans; the centres are the same
    arithmetic: the mean of two numbers is the sum of their halves exactly)."""
    rng = np.random.default_rng(3)
    outcomes = []
    for _ in range(2000):
        st, pred, truth = _front_end_state(rng)
        # the markers anywhere on the sensor, so that the region is shifted at either edge
        shift = rng.uniform(-1.0, 1.0, 2) * [1200.0, 1000.0]
        truth = truth + shift
        st[L._FE_LAST : L._FE_LAST + 4] += np.tile(shift, 2)
        pred = None if pred is None else np.stack([pred[0] + shift, pred[1]])
        roi = RegionOfInterest(rows=int(rng.integers(16, 1200)), cols=int(rng.integers(16, 2000)),
                               follow=bool(rng.random() < 0.7))
        predictive = bool(rng.random() < 0.7)
        par = np.zeros(L._N_PAR)
        config = MeasurementConfig(roi=roi, loss=SearchWindowLoss(predictive_search=predictive))
        _front_end_settings(par, config, PARAMS)
        predicted = None if pred is None else pred[0] + (pred[1] if predictive else 0.0)
        centre = roi.centre_px((PARAMS.camera.sensor_width_px, PARAMS.camera.sensor_height_px),
                               predicted)
        outcomes.append((_roi_misses(st, par, truth), not roi.contains(truth, centre)))
    got, want = np.array(outcomes).T
    assert np.array_equal(got, want) and 200 < want.sum() < 1800


def test_blur_travel_is_blur_travel_px():
    """Random attitudes and body rates up to 20 rad/s: the largest marker travel over the
    exposure of ``blur_travel_px`` to 2 ``PX_TOL`` (the difference of two projections, each
    within ``PX_TOL`` of the other code's, the half-exposure turn built with the same
    axis-angle formula)."""
    rng = np.random.default_rng(4)
    par = np.zeros(L._N_PAR)
    _front_end_settings(par, MeasurementConfig(), PARAMS)
    diff = []
    for q in _attitudes(rng, 300):
        w = rng.normal(0, 8, 3)
        diff.append(abs(_blur_travel_px(q, w, par, *TRUE_MODEL) - blur_travel_px(PARAMS, q, w)))
    assert len(diff) == 300 and max(diff) <= 2 * PX_TOL


def test_p_lost_is_the_loss_models():
    """Random loss models, front-end states (no prediction, a prediction; tracked or lost
    frames before) and motions: the probability of ``LossModel.p_lost`` on
    ``prediction_offset_px`` and ``blur_travel_px`` to 1e-12 (absolute, of a probability):
    the blur feature differs by at most 2 ``PX_TOL`` px, which log1p and the logistic (slope
    at most 1/4) pass on multiplied by at most |h2| / 4 <= 1, and the offset and the
    logistic are the same formulas, rounded in another order (a few eps)."""
    rng = np.random.default_rng(5)
    diff = []
    for _ in range(400):
        hazard, persistence = rng.normal(0, 1, 3), rng.normal(0, 1, 4)
        model = LossModel(LossModelFile(
            format_version=FORMAT_VERSION, tracker="kcf_gk", weights_sha256=None,
            hazard=tuple(hazard),
            persistence=tuple(persistence), noise_sigma_px=0.3, n_frames=1, n_runs=1, design={},
            created_utc=""))
        st, pred, truth = _front_end_state(rng)
        q = _attitudes(rng, 1)[0]
        truth = marker_pixels(PARAMS, q)
        w = rng.normal(0, 8, 3)
        par = np.zeros(L._N_PAR)
        _front_end_settings(par, MeasurementConfig(), PARAMS)
        par[L._P_CAL_HAZ : L._P_CAL_HAZ + 3], par[L._P_CAL_PER : L._P_CAL_PER + 4] = \
            hazard, persistence
        predicted = None if pred is None else pred[0] + pred[1]
        want = model.p_lost(prediction_offset_px(truth, predicted), blur_travel_px(PARAMS, q, w),
                            int(st[L._FE_LOST]))
        diff.append(abs(_p_lost(st, q, w, par, *TRUE_MODEL, truth) - want))
    assert len(diff) == 400 and max(diff) <= 1e-12


#: Front ends of the capture test: noise alone; dropouts and outliers; a narrow search window
#: without the motion; a region of interest and a blur limit; a following region of interest;
#: the calibrated loss
#: model of a tracker with its noise and with the measurement model's.
FRONT_ENDS = [
    {},
    {"dropout_prob": 0.2, "outlier_prob": 0.2, "sigma_px": 1.0},
    {"loss": {"kind": "search_window", "search_radius_px": 30.0, "predictive_search": False,
              "reacquire_after_frames": 3}},
    {"roi": {"rows": 700, "cols": 1100}, "loss": {"kind": "search_window", "blur_limit_px": 40.0}},
    {"roi": {"rows": 300, "cols": 800, "follow": True},
     "loss": {"kind": "search_window", "search_radius_px": 200.0}},
    {"loss": {"kind": "calibrated", "tracker": "kcf_gk"}, "dropout_prob": 0.1},
    {"loss": {"kind": "calibrated", "tracker": "kcf_gk", "noise": "sigma_px"}},
]


@pytest.mark.parametrize("settings", FRONT_ENDS, ids=range(len(FRONT_ENDS)))
def test_capture_is_the_measurement_front_ends(settings):
    """Eighty frames of a rotor on a random walk (jumps of up to 4°, rates up to 10 rad/s)
    through each front end and its compiled mirror, each drawing from its own Generator of the
    same seed: the same frames lost for the same reasons, the true and measured pixels to
    ``PX_TOL`` (the noise and outliers are the same draws added to the true pixels), and the
    Generators in the same state at the end (the same draws, in the same order)."""
    config = MeasurementConfig.model_validate(settings)
    rng = np.random.default_rng(6)
    front_end = MeasurementFrontEnd(PARAMS, config, np.random.default_rng(60))
    mirror_rng = np.random.default_rng(60)
    st = _initial_state((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    par = np.zeros(L._N_PAR)
    _front_end_settings(par, config, PARAMS)
    meas = np.empty((2, 2))
    q = np.array([1.0, 0.0, 0.0, 0.0])
    reasons, worst = [], 0.0
    for k in range(80):
        q = _near(q, rng, 4.0)
        if A.tilt(q) > np.radians(20):
            q = _attitudes(rng, 1, 10.0)[0]
        w = rng.normal(0, 5, 3)
        cap = front_end.capture(q, w, k / 36.0)
        truth, lost, code = _capture(st, q, w, par, *TRUE_MODEL, mirror_rng, meas)
        assert (lost, L.CAPTURE_REASONS[code]) == (cap.lost, cap.reason), k
        assert np.array_equal(np.isnan(meas), np.isnan(cap.marker_px))
        worst = max(worst, np.max(np.abs(truth - cap.true_px)),
                    np.nanmax(np.abs(meas - cap.marker_px), initial=0.0))
        reasons.append(cap.reason)
    assert worst <= PX_TOL
    assert mirror_rng.bit_generator.state == front_end.rng.bit_generator.state
    assert reasons.count("") >= 5  # measured frames among them


# --- the observer ----------------------------------------------------------------------------
def test_solve_is_the_cor_solvers():
    """Random attitudes, pixels with noise of 0.5 px (every fourth case 40 px: residuals too
    large) and warm starts up to 8° off: the same verdict and reason as ``CorSolver.solve``
    and the attitude to 1e-12 (the same compiled iteration from starts that differ by the
    rounding of the warm start's normalisation, sqrt(q.q) against numpy's norm)."""
    rng = np.random.default_rng(7)
    solver = CorSolver(CorModel.nominal(PARAMS))
    obs_model = _model_arrays(solver.model)
    par = np.zeros(L._N_PAR)
    _observer_settings(par, build_loop(Scenario.model_validate(
        {"observer": {"kind": "solver"}})).observer)
    verdicts, worst = [], 0.0
    for case in range(300):
        q = _attitudes(rng, 1, 24.0)[0]
        uv = marker_pixels(PARAMS, q) + rng.normal(0, 40.0 if case % 4 == 0 else 0.5, (2, 2))
        q_prev = _near(q, rng, 8.0)
        want = solver.solve(uv, q_prev)
        got, valid, code, value = _solve(q_prev, uv, *obs_model, par)
        assert valid == want.valid
        if valid:
            worst = max(worst, np.max(np.abs(got - want.q)))
        else:
            assert failure_reason(code, value, solver.config) == want.reason
        verdicts.append(valid)
    assert worst <= 1e-12 and 30 < sum(verdicts) < 290


def test_pixel_kalman_is_the_observers_filters():
    """Sixty frames of two markers moving at random velocities, measured with 1 px noise, some
    frames lost and some markers missing, through ``PixelKalmanObserver.process``'s filters
    (filterpy's ``KalmanFilter``) and the compiled filters: the filtered centres, the states
    and the covariances bit for bit (the same products in the same order)."""
    rng = np.random.default_rng(8)
    cfg = PixelKalmanConfig(Q=(0.05 * np.eye(4)).tolist(), R=(0.3 * np.eye(2)).tolist())
    obs = PixelKalmanObserver(CorSolver(CorModel.nominal(PARAMS)), cfg)
    obs.reset([1.0, 0.0, 0.0, 0.0], 0.0)
    st = _initial_state((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    par = np.zeros(L._N_PAR)
    _observer_settings(par, obs)
    pos, vel = marker_pixels(PARAMS, [1.0, 0.0, 0.0, 0.0]), rng.normal(0, 3, (2, 2))
    for k in range(60):
        pos = pos + vel
        z = pos + rng.normal(0, 1.0, (2, 2))
        lost = rng.random() < 0.15
        if rng.random() < 0.1:
            z[rng.integers(2)] = np.nan
        if lost and rng.random() < 0.5:  # a lost frame coasts, with or without centres
            z[:] = np.nan
        obs.process(z, k / 36.0, lost)
        got = _pixel_kalman(st, par, z, lost)
        for i, f in enumerate(obs.filters):
            b = L._KF + i * L._KF_SIZE
            assert np.array_equal(got[i], f.position, equal_nan=True), k
            assert np.array_equal(st[b + 1 : b + 5], f.kf.x[:, 0]) and \
                np.array_equal(st[b + 5 : b + 21], f.kf.P.ravel()), k


# --- the controllers -------------------------------------------------------------------------
def test_attitude_rate_is_rate_from_attitude():
    """Attitudes at random times (some repeated, some earlier than the last): the rate of
    ``RateFromAttitude.update`` to 1e-9 rad/s (the rotation vectors agree to 8 eps pi,
    ``test_rotvec_is_to_rotvec``, divided by time steps of at least 1 ms; the conjugate
    product is the same formula)."""
    rng = np.random.default_rng(9)
    rate = RateFromAttitude()
    st = _initial_state((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    t, q, worst, finite = 0.0, _attitudes(rng, 1)[0], 0.0, 0
    for _ in range(200):
        t += rng.choice([0.0, -0.01, rng.uniform(0.001, 0.05)], p=[0.1, 0.1, 0.8])
        q = _near(q, rng, 3.0)
        want = rate.update(q, t)
        _attitude_rate(st, q, t)
        got = st[L._RATE_W : L._RATE_W + 3]
        assert np.array_equal(np.isnan(got), np.isnan(want))
        if np.all(np.isfinite(want)):
            worst, finite = max(worst, np.max(np.abs(got - want))), finite + 1
    assert finite > 150 and worst <= 1e-9


#: PID settings of the PID test: each anti-windup mode, with and without the feedforward and
#: the friction compensation, holding or zeroing on invalid estimates, torque limits that bind.
PIDS = [
    {},
    {"anti_windup": "conditional", "feedforward": False, "friction_compensation_Nm": 0.002,
     "invalid_command": "zero", "torque_limit_Nm": 0.02, "crossover_rad_s": 30.0},
    {"anti_windup": "none", "torque_limit_Nm": 0.01},
    {"anti_windup": "back_calculation", "torque_limit_Nm": 0.005, "tracking_time_s": 0.05},
]


@pytest.mark.parametrize("settings", PIDS, ids=range(len(PIDS)))
def test_pid_is_the_pid_controller(settings):
    """Eighty estimates (random attitudes within 10° of a random reference, jittered frame
    times, 15 % invalid) with a random reference rate and acceleration: the torques of
    ``PIDController.command`` to 1e-12 of the torque limit (the same law with a few small
    products ordered differently, rounding of a few eps of each term, which the integrator
    and the filter sum over the run)."""
    rng = np.random.default_rng(10)
    pid = PIDController(PIDConfig.model_validate(settings), PARAMS)
    ref = _Table(rng)
    st = _initial_state((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    par = np.zeros(L._N_PAR)
    _pid_settings(par, pid)
    worst, saturated = 0.0, 0
    for k in range(80):
        t_exp = k / 36.0 + rng.uniform(0, 0.005)
        t = t_exp + rng.uniform(0.01, 0.03)
        r = ref.sample(t)
        q = _near(r.q, rng, 10.0)
        valid = rng.random() > 0.15
        est = Estimate(t_exposure=t_exp, t_available=t, q=q, euler_zyz=np.zeros(3),
                       marker_px=np.zeros((2, 2)), covariance=np.zeros((3, 3)), valid=valid)
        want = pid.command(est, ref, t)
        got = _pid(st, par, valid, q, t_exp, r.q, r.omega, r.alpha)
        worst = max(worst, np.max(np.abs(got - want)))
        saturated += pid.last_saturated
    assert worst <= 1e-12 * pid.torque_limit
    assert saturated > 0 or not settings


@pytest.fixture(scope="module")
def mpc_controller():
    return MPCController(MPCConfig(compute_latency_s=0.004), PARAMS)


def test_mpc_record_keeps_the_mpcs_history(mpc_controller):
    """Commands at random increasing times (gaps up to 1.5 s, so old ones are forgotten):
    the same history (times and torques) as ``MPCController.record_command`` keeps, bit for
    bit (copies and comparisons)."""
    rng = np.random.default_rng(11)
    ctrl = mpc_controller
    ctrl.reset()
    mst, mhist = np.zeros(16), np.zeros((400, 4))
    t = 0.0
    for _ in range(300):
        t += rng.choice([rng.uniform(0, 0.05), rng.uniform(0.5, 1.5)], p=[0.9, 0.1])
        torque = rng.normal(0, 0.01, 3)
        ctrl.record_command(t, torque)
        _mpc_record(mst, mhist, t, torque, ctrl.N * ctrl.h + 1.0)
        kept = mhist[int(mst[_M_HIST_FIRST]) : int(mst[_M_HIST_END])]
        assert np.array_equal(kept, [(tc, *T) for tc, T in ctrl._history])


needs_cc = pytest.mark.skipif(codegen.compiler() is None, reason="no C compiler")


def _mpc_loop(config: dict, seed: int = 0):
    return build_loop(Scenario.model_validate({
        "duration_s": 1.0, "seed": seed, "observer": {"kind": "solver"},
        "controller": {"kind": "mpc", "config": config},
        "reference": {"kind": "cone", "args": {"tilt_deg": 6.0, "yaw_rate_rad_s": 3.0}}}))


@needs_cc
def test_mpc_predict_is_the_mpcs_prediction():
    """Random states, histories of commands and horizons (0 to 60 ms, across commands): the
    state of ``MPCController.predict`` to 1e-12 (the same RK4 chunk, generated C against
    CasADi's compiled function, the same steps)."""
    rng = np.random.default_rng(12)
    loop = _mpc_loop({})
    ctrl = loop.controller
    args = _mpc_arrays(loop, np.zeros(1), np.full(1, L._RELEASE), np.zeros(1, np.int64), 1)
    mpar, mst, calls, r_in, r_out = args[0], args[6], args[8], args[11], args[12]
    mhist = np.zeros((8, 4))  # room for the commands below (``_mpc_arrays``: one per frame)
    worst = 0.0
    for _ in range(30):
        ctrl.reset()
        mst[:], t = 0.0, 0.0
        for _ in range(rng.integers(0, 6)):
            t += rng.uniform(0.005, 0.03)
            torque = rng.normal(0, 0.01, 3)
            ctrl.record_command(t, torque)
            _mpc_record(mst, mhist, t, torque, ctrl.N * ctrl.h + 1.0)
        x = np.r_[_attitudes(rng, 1)[0], rng.normal(0, 2, 3)]
        t_from = rng.uniform(0, t + 0.01)
        t_to = t_from + rng.uniform(0, 0.06)
        want = ctrl.predict(x, t_from, t_to)
        got = _mpc_predict(x, t_from, t_to, mpar, mst, mhist, calls[1], r_in, r_out)
        worst = max(worst, np.max(np.abs(got - want)))
    assert worst <= 1e-12


#: MPC settings of the MPC test: the default (delay-aware, previewing, holding), no preview
#: with zero torque on invalid estimates, not delay-aware.
MPCS = [{}, {"reference_preview": False, "invalid_command": "zero"}, {"delay_aware": False}]


@needs_cc
@pytest.mark.parametrize("settings", MPCS, ids=range(len(MPCS)))
def test_mpc_is_the_mpc_controller(settings):
    """Twenty-five releases of estimates (within 1° of the reference, either sign, 20 %
    invalid, random latencies) on a cone: the torques of ``MPCController.command`` to 1e-9 N·m
    (its solver is the same SQP written out as C, the same iterates to rounding:
    tests/test_compiled_mpc.py holds the solves to 1e-9), with the reference's parameters
    sampled beforehand (``_mpc_arrays``), its warm starts and its delay compensation."""
    rng = np.random.default_rng(13)
    loop = _mpc_loop({"compute_latency_s": 0.004, **settings})
    ctrl = loop.controller
    ctrl.reset()
    # frames at 36 frames/s released in order after random latencies (pipelined): some
    # releases within half the MPC's step of the one before (a warm start not shifted)
    t_exp = np.arange(25) / 36.0
    t_rel = np.maximum.accumulate(t_exp + rng.uniform(0.005, 0.045, 25))
    assert np.sum(np.diff(t_rel) < 0.5 * ctrl.h) >= 3
    kinds, rows = np.full(25, L._RELEASE), np.arange(25)
    args = _mpc_arrays(loop, t_rel, kinds, rows, 25)
    st = _initial_state((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    worst, n_valid = 0.0, 0
    for k in range(25):
        q = _near(loop.reference.sample(t_exp[k]).q, rng, 1.0) * rng.choice([-1.0, 1.0])
        valid = k == 0 or rng.random() > 0.2
        est = Estimate(t_exposure=t_exp[k], t_available=t_rel[k], q=q, euler_zyz=np.zeros(3),
                       marker_px=np.zeros((2, 2)), covariance=np.zeros((3, 3)), valid=valid)
        want = ctrl.command(est, loop.reference, t_rel[k])
        got = _mpc(st, valid, q, t_exp[k], t_rel[k], k, args)
        worst, n_valid = max(worst, np.max(np.abs(got - want))), n_valid + valid
    assert worst <= 1e-9 and 10 < n_valid < 25 and ctrl.failures == ctrl.unconverged == 0


# --- the allocation ---------------------------------------------------------------------------
def test_torque_map_is_the_torque_map():
    """Random attitudes over the workspace: K(q) of ``TorqueMap`` to 1e-12 of its largest
    entry (the same sums over the magnets, compiled with LLVM's reassociation licences:
    18 terms summed in another order, a few eps each)."""
    body, tm, _, gain = _plant_parts(PARAMS)
    coils, magnets = body[4], body[5]
    cos_cut = np.cos(np.deg2rad(PARAMS.motor.cutoff_deg))
    worst = 0.0
    for q in _attitudes(np.random.default_rng(14), 300, 25.0):
        want = tm(q)
        worst = max(worst, np.max(np.abs(_torque_map(q, coils, magnets, gain, cos_cut) - want))
                    / np.max(np.abs(want)))
    assert worst <= 1e-12


def test_least_norm_is_allocate_within_the_limits():
    """Random attitudes and torques whose least-norm currents stay within the limits: the
    currents and the delivered torque of ``allocate`` to 1e-9 relative (K Kᵀ, 3 x 3 and
    well conditioned over the workspace, solved by elimination against LAPACK: the same
    solution rounded in another order, eps times its condition number)."""
    rng = np.random.default_rng(15)
    tm, i_max = TorqueMap(PARAMS.motor), PARAMS.motor.i_max_A
    worst, compared = 0.0, 0
    for q in _attitudes(rng, 300, 25.0):
        K, T = tm(q), rng.normal(0, 0.005, 3)
        currents, delivered, solved = _least_norm(K, T)
        assert solved
        if np.max(np.abs(currents)) > 0.99 * i_max:  # the LP's case: not mirrored
            continue
        want = allocate(T, K, i_max)
        worst = max(worst, np.max(np.abs(currents - want.currents)) / np.max(np.abs(currents)),
                    np.max(np.abs(delivered - want.delivered)) / np.max(np.abs(T)))
        compared += 1
    assert compared > 200 and worst <= 1e-9


# --- the rotor between events ---------------------------------------------------------------
def test_advance_is_advance_segment():
    """A rotor at a random attitude and rate, with the coils' lag, under random held currents,
    advanced over random spans (whole steps, a shortened last one, across grid points, onto the
    tilt stop): the state and the steps table's rows of ``latency.segments._advance_segment`` on a
    ``MujocoPlant`` and ``_StepLog.write_rows`` to 1e-12 (the same compiled step; the compiled
    run loop keeps the pair lists across steps, tests/test_rigid_body.py: the same pairs),
    the tilt-stop flags equal."""
    rng = np.random.default_rng(16)
    params = PARAMS.model_copy(update={"motor": PARAMS.motor.model_copy(
        update={"coil_time_constant_s": 0.0015})})  # the coils' lag on (none by default)
    h = params.physics_dt_s
    body = _plant_parts(params)[0]
    n_steps = 400
    par = np.zeros(L._N_PAR)
    par[L._P_H], par[L._P_TAU_L] = h, params.motor.coil_time_constant_s
    par[L._P_N_STEPS] = n_steps
    par[L._P_COS_STOP] = np.cos(np.deg2rad(params.rotor.tilt_stop_deg))
    q0, w0 = _attitudes(rng, 1, params.rotor.tilt_stop_deg - 1)[0], rng.normal(0, 2, 3)
    plant = MujocoPlant(params, q0, w0)
    st = _initial_state(q0, w0)
    st[L._K] = 0
    # the held command, delivered torque, estimate and saturation flag that the rows show
    st[L._TCMD : L._TCMD + 3], st[L._TDEL : L._TDEL + 3] = rng.normal(size=(2, 3))
    st[L._EST : L._EST + 4], st[L._SAT] = _attitudes(rng, 1)[0], 1.0
    ref_grid = _attitudes(rng, n_steps + 1)
    log, evs = np.full((n_steps + 1, _StepLog.WIDTH), np.nan), np.zeros((100, 6))
    want = _StepLog(n_steps + 1)
    pairs = _pair_lists(body[5].shape[0], body[4].shape[0], PAIR_REUSE_RAD)
    t, k, stop, worst = 0.0, 0, False, 0.0
    while t < 0.3:
        cmd = rng.normal(0, 0.5, N_COILS)
        target = t + rng.uniform(0.2, 8.0) * h
        st[L._CMD : L._CMD + N_COILS] = cmd
        seg = _advance_segment(plant, Advance(cmd, t, target, k), h, n_steps, False)
        _advance(st, target, ref_grid, log, evs, par, *body, pairs)
        n = len(seg.q)
        if n:
            flags = tilt_stop_contact(seg.q, params)
            want.write_rows(k + 1, (k + 1 + np.arange(n)) * h, seg, ref_grid[k + 1 : k + 1 + n],
                            st[L._TCMD : L._TCMD + 3], st[L._TDEL : L._TDEL + 3],
                            st[L._EST : L._EST + 4], st[L._SAT],
                            np.r_[stop, flags[:-1]])
            stop = bool(flags[-1])
        t, k = seg.t_s, k + n
        assert (st[L._T], int(st[L._K])) == (t, k)
        worst = max(worst, np.max(np.abs(st[L._Q : L._Q + 4] - plant.q)),
                    np.max(np.abs(st[L._W : L._W + 3] - plant.omega)),
                    np.max(np.abs(st[L._CUR : L._CUR + N_COILS] - plant.currents)))
    rows = slice(1, k + 1)
    assert k > 100
    assert np.array_equal(np.isnan(log[rows, :40]), np.isnan(want.a[rows, :40]))
    assert np.nanmax(np.abs(log[rows, :40] - want.a[rows, :40])) <= 1e-12 and worst <= 1e-12


# --- the event handlers: whole runs -----------------------------------------------------------
#: Short runs through the kernel and the event loop: the pixel Kalman filters behind dropouts,
#: outliers, a search window and random latencies; the PID onto its torque limit and the motor's
#: current limits (the allocation's LP), pipelined.
RUNS = {
    "filters, losses": Scenario.model_validate({
        "duration_s": 0.5, "seed": 3, "observer": {"kind": "pixel_kalman"},
        "measurement": {"dropout_prob": 0.2, "outlier_prob": 0.1,
                        "loss": {"kind": "search_window", "search_radius_px": 25.0}},
        "reference": {"kind": "cone", "args": {"tilt_deg": 10.0, "yaw_rate_rad_s": 6.0}},
        "pipeline": {"observer": {"kind": "gamma", "shape_k": 9.0, "scale_theta_s": 0.003}},
        "controller_latency": {"kind": "uniform", "low_s": 0.001, "high_s": 0.004}}),
    "saturation": Scenario.model_validate({
        "duration_s": 0.5, "seed": 2, "observer": {"kind": "solver"},
        "controller": {"kind": "pid", "config": {"crossover_rad_s": 50.0,
                                                 "torque_limit_Nm": 2.0}},
        "reference": {"kind": "tilt_step", "tilt_deg": 15.0, "t_step_s": 0.05},
        "pipeline": {"observer": {"kind": "constant", "value_s": 0.005}, "mode": "pipelined"}}),
}
#: The runs' trajectories: within 1e-9 rad of each other (the kernel's arithmetic of a few
#: small products is ordered differently, rounding of 1e-16 that the loop carries along;
#: tests/test_batched.py bounds every summary metric by this distance).
RUN_TOL_RAD = 1e-9
#: Pixels of attitudes ``RUN_TOL_RAD`` apart: the markers sit within 40 mm of the CoR,
#: 250 mm from the camera, at a focal length below 1e4 px: under 2e3 px/rad, plus ``PX_TOL``.
RUN_TOL_PX = 2e3 * RUN_TOL_RAD + PX_TOL


@pytest.fixture(scope="module")
def runs():
    out = {}
    for name, s in RUNS.items():
        assert compiled.coverage(build_loop(s)).path == "compiled"
        out[name] = (build_loop(s).run(), compiled.run(build_loop(s)))
    return out


@pytest.mark.parametrize("case", list(RUNS))
def test_on_frame_is_the_event_loops(runs, case):
    """The frames' timing, true and measured pixels (``RUN_TOL_PX``), loss flags and centre
    errors, and the loss, reacquisition, drop and divergence events, as the event loop's."""
    ev, ct = runs[case]
    assert list(ev.frames.columns) == list(ct.frames.columns)
    exact = ["frame", "t_exposure_s", "t_release_s", "dropped", "lost"]
    assert ev.frames[exact].equals(ct.frames[exact])
    px = [c for c in ev.frames.columns if c.endswith("_px")]
    a, b = ev.frames[px].to_numpy(float), ct.frames[px].to_numpy(float)
    assert len(px) == 9 and np.array_equal(np.isnan(a), np.isnan(b))
    assert np.nanmax(np.abs(a - b)) <= RUN_TOL_PX
    kinds = {"tracking_loss", "reacquisition", "frame_dropped", "divergence"}
    mine = [(t, k, d) for t, k, d in ct.events.itertuples(index=False) if k in kinds]
    theirs = [(t, k, d) for t, k, d in ev.events.itertuples(index=False) if k in kinds]
    assert [x[1:] for x in mine] == [x[1:] for x in theirs]
    assert np.allclose([x[0] for x in mine], [x[0] for x in theirs], rtol=0, atol=1e-12)


@pytest.mark.parametrize("case", list(RUNS))
def test_on_release_is_the_event_loops(runs, case):
    """The released estimates (attitudes within ``RUN_TOL_RAD``), their validity, reasons and
    latencies, and the invalid-estimate events, as the event loop's."""
    ev, ct = runs[case]
    q = ["est_qw", "est_qx", "est_qy", "est_qz"]
    rel = ev.frames.est_qw.notna().to_numpy()
    assert np.array_equal(rel, ct.frames.est_qw.notna().to_numpy()) and rel.sum() > 10
    d = A.geodesic_angle(ev.frames[q].to_numpy(float)[rel], ct.frames[q].to_numpy(float)[rel])
    assert np.max(d) <= RUN_TOL_RAD
    for col in ("est_valid", "est_reason"):
        assert ev.frames[col].tolist() == ct.frames[col].tolist()
    assert np.allclose(ev.frames.latency_s, ct.frames.latency_s, rtol=0, atol=1e-12,
                       equal_nan=True)
    invalid = [(r.events.kind == "invalid_estimate").sum() for r in (ev, ct)]
    assert invalid[0] == invalid[1]


@pytest.mark.parametrize("case", list(RUNS))
def test_on_command_is_the_event_loops(runs, case):
    """The commanded and delivered torques (1e-9 of the largest: the same laws on estimates
    ``RUN_TOL_RAD`` apart, the loop's gains are below 1 N·m/rad), the commanded currents'
    effect, the saturation flags and events, as the event loop's."""
    ev, ct = runs[case]
    for kind in ("cmd", "delivered"):
        cols = [f"torque_{kind}_{c}_Nm" for c in "xyz"]
        a, b = ev.steps[cols].to_numpy(), ct.steps[cols].to_numpy()
        assert np.max(np.abs(a - b)) <= 1e-9 * max(np.max(np.abs(a)), 1e-3)
    assert ev.steps.saturated.equals(ct.steps.saturated)
    assert (ev.events.kind == "saturation").sum() == (ct.events.kind == "saturation").sum()
    if case == "saturation":
        assert ev.steps.saturated.any()


@pytest.mark.parametrize("case", list(RUNS))
def test_run_events_is_the_timeline(runs, case):
    """The steps table (attitudes within ``RUN_TOL_RAD``, the same rows and flags) and the
    events (kinds in order) of the whole run, as the event loop's."""
    ev, ct = runs[case]
    q = ["qw", "qx", "qy", "qz"]
    assert len(ev.steps) == len(ct.steps) > 100
    assert np.max(A.geodesic_angle(ev.steps[q].to_numpy(), ct.steps[q].to_numpy())) <= RUN_TOL_RAD
    assert ev.steps.tilt_stop.equals(ct.steps.tilt_stop)
    assert ev.events.kind.tolist() == ct.events.kind.tolist()
