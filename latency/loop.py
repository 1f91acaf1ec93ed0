"""The timed closed loop: plant, camera, observer and controller on one event timeline.

The event handlers, the timeline and the run's tables share one run's state (event queue,
frame scheduler, logs), so they live together here; a run's settings (``LoopConfig``) and what
it returns (``LoopResult``) are in ``latency.loop_config``.

Simulated time only (s). Per run:

* **physics** (``plant.dynamics.MujocoPlant``) at ``params.physics_dt_s`` (1 kHz by default),
  the coil currents held between commands (zero-order hold);
* **frames** exposed at the camera's rate (``latency.pipeline``); the front end measures the
  markers at mid-exposure (rendered with motion blur in image mode, ground truth plus noise in
  measurement-model mode); the observer fuses them, at their exposure time, when it releases
  the frame's estimate (so a pipelined observer with several frames in flight never uses a
  frame before its processing has finished);
* **estimates** released at ``t_exposure + exposure/2 + readout + observer latency``; dropped frames
  (sequential pipeline) are never processed;
* **commands** computed on each released estimate and applied after the controller's latency
  (a model, or its measured wall-clock time); the torque is allocated to coil currents with the
  current limits at the *estimated* attitude (or the true one, ``allocate_with="truth"``).

Events are recorded with their times: tracking loss (the front end says so, or a centre is more
than 20 px from the truth, seed 000 §4.2) and re-acquisition, dropped frames, invalid estimates
(the controller answers them by its ``invalid_command``: zero torque or its last command, see
``controller.base``), invalid commands (a torque that is not finite: zero torque instead),
current saturation, contact with the tilt stop, and divergence (noted; the run still covers its
whole duration, so the metrics of every run cover the same time).

Event times are exact: the physics advances to each event with a shortened last step
(``MujocoPlant.advance``), so delays are not rounded to the physics grid.

A run's events live in a generator (``ClosedLoop.timeline``) that asks for the physics between
events (``Advance``) and gets the states at the grid points back (``Segment``): ``run`` serves it
with one ``MujocoPlant``, ``latency.batched`` serves many runs' requests together.
"""

from __future__ import annotations

import heapq
import itertools
import time
from collections.abc import Callable, Generator
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray
from tqdm import tqdm

from controller.base import Controller, Reference
from latency.frontends import Capture, FrontEnd
from latency.loop_config import LoopConfig, LoopResult
from latency.metrics import summarize
from latency.pipeline import FrameScheduler
from latency.segments import Advance, KernelAdvance, Segment, _advance_segment
from observer.pixel_observer import PixelObserver
from observer.tracking import attitude_source
from plant import attitude
from plant.dynamics import MujocoPlant
from plant.estimate import Estimate
from plant.params import PlantParams
from plant.rigid_body import tilt_stop_contact
from plant.torque import N_COILS, Allocation


class PlantState(Protocol):
    """What a run's timeline reads and sets on its plant (``plant.dynamics.MujocoPlant``, or a
    run of the batched engine): the state, the allocation at an attitude and the disturbance
    hook. ``delayed_q`` only for ``mujoco_sensor_delay_s``."""

    disturbance: Callable[[float], NDArray[np.float64]] | None

    @property
    def q(self) -> NDArray[np.float64]:
        """Current attitude (4,), unit quaternion (w, x, y, z), rotor to stator."""

    @property
    def omega(self) -> NDArray[np.float64]:
        """Current body rate (3,), rad/s."""

    @property
    def currents(self) -> NDArray[np.float64]:
        """Current coil currents (16,), A."""

    def allocate(self, torque: ArrayLike, q: ArrayLike | None = None) -> Allocation:
        """The coil currents that make ``torque`` (3,), N·m, stator frame, at attitude ``q`` (4,)
        (default: the current one)."""

    def delayed_q(self) -> NDArray[np.float64]:
        """The attitude MuJoCo's delayed sensor reports now (only with
        ``mujoco_sensor_delay_s``)."""


@dataclass
class _Run:
    """The state of one run, shared by the event handlers of ``ClosedLoop``.

    ``queue`` holds the pending events (time s, order, kind, payload); ``frames`` and
    ``events`` are the rows of the result's tables. The rest is what the plant currently
    receives (coil currents A, commanded and delivered torque N·m) and the flags whose changes
    are events.
    """

    plant: PlantState
    scheduler: FrameScheduler
    rng_ctrl: np.random.Generator
    queue: list[tuple[float, int, str, object]] = field(default_factory=list)
    order: itertools.count = field(default_factory=itertools.count)
    frames: list[dict] = field(default_factory=list)
    events: list[tuple[float, str, str]] = field(default_factory=list)
    currents: NDArray[np.float64] = field(default_factory=lambda: np.zeros(N_COILS))
    torque_cmd: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    delivered: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    saturated: bool = False
    lost: bool = False
    stop: bool = False
    estimate: Estimate | None = None
    diverged: str = ""

    def push(self, t: float, kind: str, payload: object = None) -> None:
        """Schedule an event of ``kind`` at ``t`` (s); ties run in the order pushed."""
        heapq.heappush(self.queue, (t, next(self.order), kind, payload))


class ClosedLoop:
    """One closed-loop run: ``ClosedLoop(...).run()`` returns a ``LoopResult``.

    Parameters
    ----------
    params : PlantParams
    controller : Controller
    reference : Reference
    front_end : FrontEnd (``MeasurementFrontEnd`` or ``ImageFrontEnd``)
    observer : the back end that fuses the front end's ``Capture.measurement``: a PixelObserver
        (e.g. ``observer.pixel_observer.FilterObserver``) for marker pixels, an
        ``observer.orb_observer.OrbObserver`` for ORB matches
    config : LoopConfig
    clock : callable returning seconds, default ``time.perf_counter``
        Times each ``controller.command`` call (``controller_compute_s``; the latency with
        ``controller_latency: measured``). Tests inject a stand-in so that the loop's
        bookkeeping does not depend on machine load.
    """

    def __init__(
        self,
        params: PlantParams,
        controller: Controller,
        reference: Reference,
        front_end: FrontEnd,
        observer: PixelObserver,
        config: LoopConfig,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.params = params
        self.controller = controller
        self.reference = reference
        self.front_end = front_end
        self.observer = observer
        self.config = config
        self.clock = clock

    # --- the run ---------------------------------------------------------------------------
    def run(self, progress: bool = False) -> LoopResult:
        """Run the loop for ``config.duration_s`` on a fresh ``MujocoPlant`` and return its
        ``LoopResult`` (steps, frames, commands and estimates); ``progress`` shows a bar."""
        c = self.config
        plant = MujocoPlant(
            self.params, c.q0, c.omega0_rad_s, sensor_delay_s=c.mujoco_sensor_delay_s
        )
        h, n_steps = self.params.physics_dt_s, self.n_steps
        native = c.mujoco_sensor_delay_s is not None
        timeline = self.timeline(plant, progress)
        try:
            req = next(timeline)  # the run's start: sets the disturbance hook
            if native or plant.disturbance is not None:
                while True:
                    req = timeline.send(_advance_segment(plant, req, h, n_steps, native))
            advance = KernelAdvance(plant, n_steps)
            while True:
                req = timeline.send(advance(req))
        except StopIteration as done:
            return done.value

    @property
    def n_steps(self) -> int:
        """Physics steps in the run (rows of the steps table after the first)."""
        return int(np.floor(self.config.duration_s / self.params.physics_dt_s + 1e-9))

    def timeline(
        self, plant: PlantState, progress: bool = False
    ) -> Generator[Advance, Segment, LoopResult]:
        """The run's events on ``plant`` (state at t = 0, the config's ``q0`` and
        ``omega0_rad_s``), as a generator. Between events it yields an ``Advance``: the physics
        must move from ``t_s`` to the next event at ``t_target_s`` with the currents held,
        stopping at every physics grid point on the way; it is sent back the ``Segment`` (the
        time reached and the state at each grid point passed). It returns the ``LoopResult``.
        ``run`` advances a ``MujocoPlant`` (``_advance_segment``); ``latency.batched``
        advances many runs at once.

        Mirrored in ``latency.compiled.kernel._run_events``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        c = self.config
        native = c.mujoco_sensor_delay_s is not None
        run, log, q_ref_grid = self._start(plant)
        t, k_log = 0.0, 0
        stopped = ""
        bar = tqdm(total=self.n_steps, disable=not progress, desc="closed loop", unit="step")
        self._record(run, log, q_ref_grid, 0, Segment(
            0.0, plant.q[None], plant.omega[None], plant.currents[None],
            plant.delayed_q()[None] if native else None))
        queue = run.queue
        while True:
            t_next_event = queue[0][0] if queue else np.inf
            t_target = min(t_next_event, c.duration_s)
            if t_target > t:
                seg = yield Advance(run.currents, t, t_target, k_log)
                t = seg.t_s
                if len(seg.q):
                    self._record(run, log, q_ref_grid, k_log + 1, seg)
                    k_log += len(seg.q)
                    bar.update(len(seg.q))
            if t >= c.duration_s - 1e-12:
                break
            if not queue or queue[0][0] > t + 1e-12:
                continue
            _, _, kind, payload = heapq.heappop(queue)
            self._dispatch(run, t, kind, payload)
            if run.diverged and not stopped:
                stopped = run.diverged  # noted once; the run goes on to its full duration
                run.events.append((t, "divergence", stopped))
        bar.close()
        return self._result(run, log.frame(k_log + 1, native), stopped)

    def _start(self, plant: PlantState) -> tuple[_Run, _StepLog, NDArray[np.float64]]:
        """A run's start on ``plant``: its random streams, the disturbance hook, the
        controller, front end and observer reset, the first frame and controller tick
        queued, an empty steps log, and the reference's attitudes on the whole physics grid
        (one array call, not one per step), (n_steps + 1, 4)."""
        c, p = self.config, self.params
        rng_pipe, rng_ctrl, rng_dist = run_streams(c.seed)
        psd = np.asarray(c.disturbance_psd_Nm2s)
        if np.any(psd > 0):
            plant.disturbance = lambda h: rng_dist.normal(size=3) * np.sqrt(psd / h)
        self.controller.reset()
        self.front_end.reset()
        self.observer.reset(c.q0, 0.0)
        run = _Run(plant, FrameScheduler(c.pipeline, rng_pipe), rng_ctrl)
        n_steps = self.n_steps
        log = _StepLog(n_steps + 1)
        q_ref_grid = self.reference.sample_many(np.arange(n_steps + 1) * p.physics_dt_s).q
        run.push(0.5 * c.pipeline.exposure_s, "frame")
        if c.controller_rate_hz is not None:
            run.push(0.0, "tick", 0)
        return run, log, q_ref_grid

    def _record(self, run: _Run, log: _StepLog, q_ref_grid: NDArray[np.float64], k0: int,
                seg: Segment) -> None:
        """Rows k0, k0 + 1, ... of the steps table from the states at the grid points;
        tilt-stop contact and release events where the flag changes (each row shows the
        flag of the row before)."""
        p = self.params
        n = len(seg.q)
        times = (k0 + np.arange(n)) * p.physics_dt_s
        q_ref = q_ref_grid[k0 : k0 + n]
        stop = tilt_stop_contact(seg.q, p)
        before = np.concatenate(([run.stop], stop[:-1]))
        est = run.estimate
        log.write_rows(k0, times, seg, q_ref, run.torque_cmd, run.delivered,
                       est.q if est is not None else None, run.saturated, before)
        for k in np.flatnonzero(stop != before):
            run.events.append((float(times[k]),
                               "tilt_stop_contact" if stop[k] else "tilt_stop_release", ""))
        run.stop = bool(stop[-1])

    def _dispatch(self, run: _Run, t: float, kind: str, payload: object) -> None:
        """Handle the event of ``kind`` due at ``t`` (s): a frame, a release, a command, or a
        tick of the controller's clock (which queues the next tick and controls on the latest
        released estimate)."""
        if kind == "frame":
            self._on_frame(run, t)
        elif kind == "release":
            self._on_release(run, t, payload)
        elif kind == "command":
            self._on_command(run, t, payload)
        elif kind == "tick":
            run.push((payload + 1) / self.config.controller_rate_hz, "tick", payload + 1)
            est = run.estimate if run.estimate is not None else _no_estimate(t)
            self._control(run, t, est, None)

    def _result(self, run: _Run, steps: pd.DataFrame, stopped: str) -> LoopResult:
        """The run's ``LoopResult`` from its steps table and its frames and events, with the
        summary metrics (``stopped``: the divergence noted, if any)."""
        c = self.config
        frames_df = pd.DataFrame(run.frames)
        events_df = pd.DataFrame(run.events, columns=["t_s", "kind", "detail"])
        summary = summarize(steps, frames_df, events_df, c.duration_s, stopped,
                            c.step_metrics)
        return LoopResult(steps, frames_df, events_df, summary, c.model_dump(mode="json"))

    # --- event handlers --------------------------------------------------------------------
    def _on_frame(self, run: _Run, t: float) -> None:
        """A frame's mid-exposure: measure (unless the frame is dropped), schedule release.

        Mirrored in ``latency.compiled.kernel._on_frame``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        c, plant = self.config, run.plant
        err = attitude.geodesic_angle(plant.q, self.reference.sample(t).q)
        far = not np.isfinite(err) or np.degrees(err) > c.divergence_deg
        if far and not run.diverged:
            run.diverged = f"divergence: geodesic error {np.degrees(err):.1f} deg"
        captured: dict = {}

        def measure(k: int) -> float:
            cap = self.front_end.capture(plant.q, plant.omega, t)
            captured["cap"] = cap
            if c.observer_latency == "measured":
                return cap.compute_time_s
            return c.pipeline.observer.sample(run.scheduler.rng)

        timing = run.scheduler.next_frame(measure)
        t_next = (timing.index + 1) * c.pipeline.frame_period_s + 0.5 * c.pipeline.exposure_s
        run.push(t_next, "frame")
        row = {
            "frame": timing.index,
            "t_exposure_s": timing.t_exposure,
            "t_release_s": timing.t_release,
            "dropped": timing.dropped,
        }
        if timing.dropped:
            run.events.append((t, "frame_dropped", f"frame {timing.index}"))
            run.frames.append(row)
            return
        cap: Capture = captured["cap"]
        if np.all(np.isfinite(cap.true_px)):
            err = np.linalg.norm(cap.marker_px - cap.true_px, axis=1)
        else:  # no marker truth (e.g. a textured rotor): the front end's own verdict only
            err = np.full(2, np.nan if cap.lost else 0.0)
        lost = bool(cap.lost or not np.all(err <= c.loss_threshold_px))
        if lost != run.lost:
            detail = cap.reason or f"centre error {np.nanmax(err):.1f} px"
            run.events.append((t, "tracking_loss" if lost else "reacquisition", detail))
            run.lost = lost
        meas = cap.marker_px
        row.update(
            {
                "true_red_u_px": cap.true_px[0, 0],
                "true_red_v_px": cap.true_px[0, 1],
                "true_yellow_u_px": cap.true_px[1, 0],
                "true_yellow_v_px": cap.true_px[1, 1],
                "meas_red_u_px": meas[0, 0],
                "meas_red_v_px": meas[0, 1],
                "meas_yellow_u_px": meas[1, 0],
                "meas_yellow_v_px": meas[1, 1],
                "centre_error_px": float(np.nanmax(err)) if np.any(np.isfinite(err)) else np.nan,
                "lost": lost,
                "observer_compute_s": cap.compute_time_s,
            }
        )
        if cap.red_measured is not None:  # a pair tracker's own flags (image mode)
            row.update({"red_measured": bool(cap.measured[0]),
                        "yellow_measured": bool(cap.measured[1]),
                        "attitude_source": attitude_source(*cap.measured)})
        run.frames.append(row)
        run.push(timing.t_release, "release", (len(run.frames) - 1, cap, t))

    def _on_release(self, run: _Run, t: float, payload: tuple[int, Capture, float]) -> None:
        """An estimate becomes available: the observer fuses the frame's measurement (at its
        exposure time) and hands over its estimate; compute the command, schedule it.

        Mirrored in ``latency.compiled.kernel._on_release``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        frame_row, cap, t_exposure = payload
        self.observer.process(cap.measurement, t_exposure, cap.lost, cap.reason,
                              cap.compute_time_s)
        est: Estimate = self.observer.release(t)
        run.estimate = est
        if est.valid:
            self.front_end.tilt_hint(attitude.tilt(est.q))
        run.frames[frame_row].update(
            {
                "est_qw": est.q[0],
                "est_qx": est.q[1],
                "est_qy": est.q[2],
                "est_qz": est.q[3],
                "est_valid": est.valid,
                "est_reason": est.reason,
                "latency_s": est.latency_s,
            }
        )
        if self.config.controller_rate_hz is None:
            self._control(run, t, est, frame_row)
        elif not est.valid:
            run.events.append((t, "invalid_estimate", est.reason))

    def _control(self, run: _Run, t: float, est: Estimate, frame_row: int | None) -> None:
        """Run the controller on ``est`` at ``t`` (an invalid estimate gets the controller's
        ``invalid_command``) and schedule the command after the controller latency. A torque
        that is not finite (3,) is replaced by zero torque. ``frame_row`` (None on a clock
        tick) gets the measured compute time."""
        c = self.config
        if not est.valid and frame_row is not None:
            run.events.append((t, "invalid_estimate", est.reason))
        t0 = self.clock()
        torque = np.asarray(self.controller.command(est, self.reference, t), dtype=float)
        ctrl_time = self.clock() - t0
        overridden = torque.shape != (3,) or not np.all(np.isfinite(torque))
        if overridden:
            run.events.append((t, "invalid_command", f"controller returned {torque!r}"))
            torque = np.zeros(3)
        if frame_row is not None:
            run.frames[frame_row]["controller_compute_s"] = ctrl_time
        latency = (
            ctrl_time
            if c.controller_latency == "measured"
            else c.controller_latency.sample(run.rng_ctrl)
        )
        run.push(t + latency, "command", (torque, est, overridden))

    def _on_command(self, run: _Run, t: float,
                    payload: tuple[NDArray[np.float64], Estimate, bool]) -> None:
        """Apply a torque command: allocate currents within the limits, hold them.

        Mirrored in ``latency.compiled.kernel._on_command``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        torque, est, overridden = payload
        if overridden:
            self.controller.record_command(t, torque)  # e.g. the MPC's delay compensation
        plant = run.plant
        q_alloc = plant.q if self.config.allocate_with == "truth" or not est.valid else est.q
        alloc = plant.allocate(torque, q_alloc)
        if alloc.saturated != run.saturated:
            if alloc.saturated:
                run.events.append(
                    (
                        t,
                        "saturation",
                        f"delivered {np.linalg.norm(alloc.delivered):.3g}"
                        f" of {np.linalg.norm(torque):.3g} N·m",
                    )
                )
            run.saturated = alloc.saturated
        run.currents = alloc.currents
        run.torque_cmd = torque
        run.delivered = alloc.delivered
        self.observer.record_torque(t, alloc.delivered)


def run_streams(seed: int) -> tuple[np.random.Generator, ...]:
    """A run's random streams, one Generator per purpose, spawned from ``LoopConfig.seed``:
    the pipeline's latencies, the controller's latencies and the disturbance. Each stream is
    consumed only by its purpose, so its numbers do not depend on the order of the events
    (``latency.compiled`` draws the latencies of a whole run before it starts)."""
    rng = np.random.default_rng(seed)
    rng_pipe, rng_ctrl, rng_dist = (np.random.default_rng(s) for s in rng.integers(2**32, size=3))
    return rng_pipe, rng_ctrl, rng_dist


def _no_estimate(t: float) -> Estimate:
    """An invalid estimate for a controller clock tick before the first release."""
    nan = np.full(4, np.nan)
    return Estimate(t_exposure=t, t_available=t, q=nan, euler_zyz=np.full(3, np.nan),
                    marker_px=np.zeros((0, 2)), covariance=np.full((3, 3), np.nan), valid=False,
                    reason="no estimate released yet")


class _StepLog:
    """Preallocated per-step arrays (faster than a list of dicts)."""

    #: Columns of a row (``columns`` names the first 40, 44 with the MuJoCo sensor).
    WIDTH = 48

    def __init__(self, n: int) -> None:
        self.a = np.full((n, self.WIDTH), np.nan)

    def write_rows(self, k0, t, seg, q_ref, T_cmd, T_del, q_est, sat, stop) -> None:
        """Rows k0 ... k0 + n - 1: times t (n,), the states of ``seg``, the references
        q_ref (n, 4), the held command, estimate and flags, the stop flags (n,).

        Mirrored in ``latency.compiled.steps._record``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        rows = self.a[k0 : k0 + len(t)]
        rows[:, 0] = t
        rows[:, 1:5] = seg.q
        rows[:, 5:8] = seg.omega
        rows[:, 8:12] = q_ref
        rows[:, 12:15] = T_cmd
        rows[:, 15:18] = T_del
        rows[:, 18:34] = seg.currents
        if q_est is not None:
            rows[:, 34:38] = q_est
        rows[:, 38] = sat
        rows[:, 39] = stop
        if seg.q_native is not None:
            rows[:, 40:44] = seg.q_native

    def frame(self, n: int, native: bool = False) -> pd.DataFrame:
        """The steps table of rows 0 ... n - 1 (``columns`` as a frame)."""
        return pd.DataFrame(self.columns(n, native))

    def columns(self, n: int, native: bool = False) -> dict[str, NDArray]:
        """The steps table's columns (rows 0 ... n - 1), with the derived errors and angles."""
        a = self.a[:n]
        cols = (
            ["t_s", "qw", "qx", "qy", "qz", "omega_x_rad_s", "omega_y_rad_s", "omega_z_rad_s"]
            + ["ref_qw", "ref_qx", "ref_qy", "ref_qz"]
            + [f"torque_cmd_{c}_Nm" for c in "xyz"]
            + [f"torque_delivered_{c}_Nm" for c in "xyz"]
            + [f"current_{i:02d}_A" for i in range(N_COILS)]
            + ["est_qw", "est_qx", "est_qy", "est_qz", "saturated", "tilt_stop"]
            + (["mj_delayed_qw", "mj_delayed_qx", "mj_delayed_qy", "mj_delayed_qz"]
               if native else [])
        )
        # Every column as an array first, one DataFrame at the end (inserting columns one by
        # one into a wide frame cost more than the rest of a short run's bookkeeping).
        data: dict[str, NDArray] = {name: a[:, k] for k, name in enumerate(cols)}
        data["saturated"] = data["saturated"].astype(bool)
        data["tilt_stop"] = data["tilt_stop"].astype(bool)
        q, qr = a[:, 1:5], a[:, 8:12]
        data["error_deg"] = np.degrees(attitude.geodesic_angle(q, qr))
        zyz = np.degrees(attitude.to_zyz_array(q))
        zyz_ref = np.degrees(attitude.to_zyz_array(qr))
        for i, name in enumerate(("spin", "tilt", "yaw")):
            data[f"{name}_deg"] = zyz[:, i]
            data[f"ref_{name}_deg"] = zyz_ref[:, i]
        return data
