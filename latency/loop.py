"""The timed closed loop: plant, camera, observer and controller on one event timeline.

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
current saturation, contact with the tilt stop, and divergence (the run stops early and says
so).

Event times are exact: the physics advances to each event with a shortened last step
(``MujocoPlant.advance``), so delays are not rounded to the physics grid.
"""

from __future__ import annotations

import heapq
import itertools
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator
from tqdm import tqdm

from controller.base import Controller, Reference
from latency.frontends import Capture, FrontEnd
from latency.models import Constant, LatencyModel
from latency.pipeline import FrameScheduler, PipelineConfig
from observer.pixel_observer import PixelObserver
from plant import attitude
from plant.dynamics import MujocoPlant
from plant.estimate import Estimate
from plant.params import PlantParams
from plant.torque import N_COILS


class LoopConfig(BaseModel):
    """Settings of one closed-loop run."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    duration_s: float = Field(gt=0.0)
    pipeline: PipelineConfig = Field(default_factory=PipelineConfig)
    controller_latency: LatencyModel | Literal["measured"] = Field(
        default_factory=lambda: Constant(value_s=0.0),
        description="Controller compute latency: a model (reproducible) or 'measured' (the "
        "wall-clock time of each command() call).",
    )
    observer_latency: Literal["model", "measured"] = Field(
        "model",
        description="Observer processing latency from pipeline.observer (reproducible) "
        "or the front end's measured compute time on this machine.",
    )
    controller_rate_hz: float | None = Field(
        None,
        gt=0.0,
        description="None: the controller runs on each new estimate (event-driven). A rate: "
        "it runs on a fixed clock from t = 0, each time on the latest released estimate (a "
        "safe command while there is none or it is invalid), Hz.",
    )
    allocate_with: Literal["estimate", "truth"] = Field(
        "estimate", description="Attitude used for K(q) in the current allocation."
    )
    loss_threshold_px: float = Field(
        20.0, gt=0.0, description="Seed 000 §4.2: centre error threshold, sensor px."
    )
    divergence_deg: float = Field(
        60.0,
        gt=0.0,
        description="Our choice: the run stops when the geodesic error between "
        "truth and reference exceeds this.",
    )
    disturbance_psd_Nm2s: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="Body-frame white disturbance torque intensity per axis, "
        "(N·m)²·s (E w(t) w(s) = q δ(t - s)); 0 = none. Drawn per physics step as N(0, q/h)."
    )
    mujoco_sensor_delay_s: float | None = Field(
        None,
        ge=0.0,
        description="Cross-check: give the plant MuJoCo's native delayed ballquat sensor with "
        "this delay (s); the steps table then has its reading (mj_delayed_q*), which describes "
        "the attitude at t - physics step - delay (MuJoCo evaluates sensors before it "
        "integrates).",
    )
    seed: int = 0
    q0: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    omega0_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _latency_fits(self) -> LoopConfig:
        mean = self.pipeline.observer.mean_s
        if mean >= self.duration_s:
            raise ValueError(
                f"pipeline.observer latency (mean {mean} s) is not shorter than duration_s "
                f"({self.duration_s} s): no estimate would arrive"
            )
        return self


@dataclass
class LoopResult:
    """What a run returns.

    Attributes
    ----------
    steps : one row per physics step: truth, reference, errors, torques, currents.
    frames : one row per camera frame: timing, true and measured pixels, estimate.
    events : one row per event (time, kind, detail).
    summary : scalar metrics (see ``summarize``).
    config : the run's configuration as a dict.
    """

    steps: pd.DataFrame
    frames: pd.DataFrame
    events: pd.DataFrame
    summary: dict[str, float]
    config: dict = field(default_factory=dict)

    def save(self, folder: str | Path) -> Path:
        """Write ``steps.parquet``, ``frames.parquet``, ``events.parquet`` and
        ``summary.json`` into ``folder``."""
        import json

        out = Path(folder)
        out.mkdir(parents=True, exist_ok=True)
        self.steps.to_parquet(out / "steps.parquet")
        self.frames.to_parquet(out / "frames.parquet")
        self.events.to_parquet(out / "events.parquet")
        (out / "summary.json").write_text(json.dumps(self.summary, indent=1, default=str))
        return out


@dataclass
class _Run:
    """The state of one run, shared by the event handlers of ``ClosedLoop``.

    ``queue`` holds the pending events (time s, order, kind, payload); ``frames`` and
    ``events`` are the rows of the result's tables. The rest is what the plant currently
    receives (coil currents A, commanded and delivered torque N·m) and the flags whose changes
    are events.
    """

    plant: MujocoPlant
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
    """

    def __init__(
        self,
        params: PlantParams,
        controller: Controller,
        reference: Reference,
        front_end: FrontEnd,
        observer: PixelObserver,
        config: LoopConfig,
    ) -> None:
        self.params = params
        self.controller = controller
        self.reference = reference
        self.front_end = front_end
        self.observer = observer
        self.config = config

    # --- the run ---------------------------------------------------------------------------
    def run(self, progress: bool = False) -> LoopResult:
        c, p = self.config, self.params
        rng = np.random.default_rng(c.seed)
        rng_pipe, rng_ctrl, rng_dist = (
            np.random.default_rng(s) for s in rng.integers(2**32, size=3)
        )
        plant = MujocoPlant(p, c.q0, c.omega0_rad_s, sensor_delay_s=c.mujoco_sensor_delay_s)
        native = c.mujoco_sensor_delay_s is not None
        psd = np.asarray(c.disturbance_psd_Nm2s)
        if np.any(psd > 0):
            plant.disturbance = lambda h: rng_dist.normal(size=3) * np.sqrt(psd / h)
        self.controller.reset()
        self.front_end.reset()
        self.observer.reset(c.q0, 0.0)
        run = _Run(plant, FrameScheduler(c.pipeline, rng_pipe), rng_ctrl)
        h = p.physics_dt_s
        n_steps = int(np.floor(c.duration_s / h + 1e-9))

        log = _StepLog(n_steps + 1)
        run.push(0.5 * c.pipeline.exposure_s, "frame")
        if c.controller_rate_hz is not None:
            run.push(0.0, "tick", 0)
        t, k_log = 0.0, 0
        stopped = ""
        bar = tqdm(total=n_steps, disable=not progress, desc="closed loop", unit="step")

        def record(t_now: float) -> None:
            q_ref = self.reference.sample(t_now).q
            est = run.estimate
            log.write(
                k_log,
                t_now,
                plant.q,
                plant.omega,
                q_ref,
                run.torque_cmd,
                run.delivered,
                plant.currents,
                est.q if est is not None else None,
                run.saturated,
                run.stop,
                plant.delayed_q() if native else None,
            )

        record(0.0)
        queue = run.queue
        while True:
            t_next_event = queue[0][0] if queue else np.inf
            t_next_grid = (k_log + 1) * h
            t_target = min(t_next_event, t_next_grid, c.duration_s)
            if t_target > t:
                plant.advance(run.currents, t_target - t)
                t = t_target
            if abs(t - t_next_grid) < 1e-12 and k_log + 1 <= n_steps:
                k_log += 1
                record(t)
                bar.update(1)
                stop_now = plant.tilt_stop_active()
                if stop_now != run.stop:
                    run.events.append(
                        (t, "tilt_stop_contact" if stop_now else "tilt_stop_release", "")
                    )
                    run.stop = stop_now
            if run.diverged:
                stopped = run.diverged
                run.events.append((t, "divergence", stopped))
                break
            if t >= c.duration_s - 1e-12:
                break
            if not queue or queue[0][0] > t + 1e-12:
                continue
            _, _, kind, payload = heapq.heappop(queue)
            if kind == "frame":
                self._on_frame(run, t)
            elif kind == "release":
                self._on_release(run, t, payload)
            elif kind == "command":
                self._on_command(run, t, payload)
            elif kind == "tick":
                run.push((payload + 1) / c.controller_rate_hz, "tick", payload + 1)
                est = run.estimate if run.estimate is not None else _no_estimate(t)
                self._control(run, t, est, None)
        bar.close()

        steps = log.frame(k_log + 1, native)
        frames_df = pd.DataFrame(run.frames)
        events_df = pd.DataFrame(run.events, columns=["t_s", "kind", "detail"])
        summary = summarize(steps, frames_df, events_df, c.duration_s, stopped)
        return LoopResult(steps, frames_df, events_df, summary, c.model_dump(mode="json"))

    # --- event handlers --------------------------------------------------------------------
    def _on_frame(self, run: _Run, t: float) -> None:
        """A frame's mid-exposure: measure (unless the frame is dropped), schedule release."""
        c, plant = self.config, run.plant
        err = attitude.geodesic_angle(plant.q, self.reference.sample(t).q)
        if not np.isfinite(err) or np.degrees(err) > c.divergence_deg:
            run.diverged = f"divergence: geodesic error {np.degrees(err):.1f} deg"
            return
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
        run.frames.append(row)
        run.push(timing.t_release, "release", (len(run.frames) - 1, cap, t))

    def _on_release(self, run: _Run, t: float, payload: tuple[int, Capture, float]) -> None:
        """An estimate becomes available: the observer fuses the frame's measurement (at its
        exposure time) and hands over its estimate; compute the command, schedule it."""
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
        t0 = time.perf_counter()
        torque = np.asarray(self.controller.command(est, self.reference, t), dtype=float)
        ctrl_time = time.perf_counter() - t0
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
        """Apply a torque command: allocate currents within the limits, hold them."""
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


def _no_estimate(t: float) -> Estimate:
    """An invalid estimate for a controller clock tick before the first release."""
    nan = np.full(4, np.nan)
    return Estimate(t_exposure=t, t_available=t, q=nan, euler_zyz=np.full(3, np.nan),
                    marker_px=np.zeros((0, 2)), covariance=np.full((3, 3), np.nan), valid=False,
                    reason="no estimate released yet")


class _StepLog:
    """Preallocated per-step arrays (faster than a list of dicts)."""

    def __init__(self, n: int) -> None:
        self.a = np.full((n, 48), np.nan)

    def write(self, k, t, q, w, q_ref, T_cmd, T_del, currents, q_est, sat, stop,
              q_native=None) -> None:
        row = self.a[k]
        row[0] = t
        row[1:5] = q
        row[5:8] = w
        row[8:12] = q_ref
        row[12:15] = T_cmd
        row[15:18] = T_del
        row[18:34] = currents
        if q_est is not None:
            row[34:38] = q_est
        row[38] = sat
        row[39] = stop
        if q_native is not None:
            row[40:44] = q_native

    def frame(self, n: int, native: bool = False) -> pd.DataFrame:
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
        df = pd.DataFrame(a[:, : len(cols)], columns=cols)
        df["saturated"] = df["saturated"].astype(bool)
        df["tilt_stop"] = df["tilt_stop"].astype(bool)
        q = df[["qw", "qx", "qy", "qz"]].to_numpy()
        qr = df[["ref_qw", "ref_qx", "ref_qy", "ref_qz"]].to_numpy()
        df["error_deg"] = np.degrees(attitude.geodesic_angle(q, qr))
        zyz = np.degrees(attitude.to_zyz_array(q))
        zyz_ref = np.degrees(attitude.to_zyz_array(qr))
        for i, name in enumerate(("spin", "tilt", "yaw")):
            df[f"{name}_deg"] = zyz[:, i]
            df[f"ref_{name}_deg"] = zyz_ref[:, i]
        return df


def summarize(
    steps: pd.DataFrame,
    frames: pd.DataFrame,
    events: pd.DataFrame,
    duration_s: float,
    stopped: str = "",
) -> dict[str, float]:
    """Scalar metrics of a run.

    * ``rms_error_deg``, ``max_error_deg``: geodesic attitude error truth vs reference;
    * ``rms_{spin,tilt,yaw}_error_deg``, ``max_{spin,tilt,yaw}_error_deg``: per seed angle,
      wrapped; spin and yaw only where the reference tilt is above 1° (below it Z-Y-Z spin and
      yaw are not separable);
    * ``settling_time_s``: time after the reference's last change until the geodesic error stays
      within 2 % of that change (or 0.05°, whichever is larger); NaN if it never settles;
    * ``overshoot_pct``: peak error on the far side of the target after the last change, in % of
      the change (measured along the change's rotation axis);
    * ``control_effort_N2m2s``: ∫ |T_delivered|² dt; ``rms_torque_Nm``;
    * ``lost_frame_fraction``: lost / processed frames; ``dropped_frame_fraction``;
    * ``mean_latency_s``; ``diverged`` (1.0 if the run stopped early).
    """
    t = steps["t_s"].to_numpy()
    dt = np.diff(t, prepend=t[0])
    err = steps["error_deg"].to_numpy()
    out: dict[str, float] = {
        "duration_s": float(duration_s),
        "simulated_s": float(t[-1]),
        "rms_error_deg": float(np.sqrt(np.mean(err**2))),
        "max_error_deg": float(np.max(err)),
        "diverged": float(bool(stopped)),
    }
    tilt_ok = (steps["ref_tilt_deg"].to_numpy() > 1.0) & (steps["tilt_deg"].to_numpy() > 1.0)
    for name in ("spin", "tilt", "yaw"):
        d = attitude.wrap_angle(np.radians(steps[f"{name}_deg"] - steps[f"ref_{name}_deg"]))
        mask = np.ones_like(tilt_ok) if name == "tilt" else tilt_ok
        out[f"rms_{name}_error_deg"] = (
            float(np.degrees(np.sqrt(np.mean(d[mask] ** 2)))) if mask.any() else float("nan")
        )
        out[f"max_{name}_error_deg"] = (
            float(np.degrees(np.max(np.abs(d[mask])))) if mask.any() else float("nan")
        )
    T = steps[[f"torque_delivered_{c}_Nm" for c in "xyz"]].to_numpy()
    out["control_effort_N2m2s"] = float(np.sum(np.sum(T**2, axis=1) * dt))
    out["rms_torque_Nm"] = float(np.sqrt(np.mean(np.sum(T**2, axis=1))))
    out.update(_step_metrics(steps))
    if len(frames):
        processed = frames[~frames["dropped"]]
        out["dropped_frame_fraction"] = float(frames["dropped"].mean())
        out["lost_frame_fraction"] = (
            float(processed["lost"].mean()) if len(processed) and "lost" in processed else 0.0
        )
        out["mean_latency_s"] = (
            float(processed["latency_s"].mean()) if "latency_s" in processed else float("nan")
        )
    out["n_events"] = float(len(events))
    return out


def _step_metrics(steps: pd.DataFrame) -> dict[str, float]:
    nan = {"settling_time_s": float("nan"), "overshoot_pct": float("nan")}
    qr = steps[["ref_qw", "ref_qx", "ref_qy", "ref_qz"]].to_numpy()
    changes = np.flatnonzero(attitude.geodesic_angle(qr[:-1], qr[1:]) > 1e-9)
    if len(changes) == 0:
        return nan
    i0 = changes[-1] + 1
    t = steps["t_s"].to_numpy()
    q = steps[["qw", "qx", "qy", "qz"]].to_numpy()
    q_from, q_to = q[i0 - 1], qr[i0]
    size = attitude.geodesic_angle(q_from, q_to)
    if size < 1e-6:
        return nan
    axis = attitude.to_rotvec(attitude.multiply(attitude.conjugate(q_from), q_to)) / size
    # Progress along the step's rotation axis (1.0 = on target); overshoot = how far above 1.
    rel = attitude.multiply(attitude.conjugate(q_from), q[i0:])
    rel = rel * np.sign(rel[:, :1] + 1e-300)
    s_half = np.linalg.norm(rel[:, 1:], axis=1)
    angle = 2.0 * np.arctan2(s_half, rel[:, 0])
    rotvec = rel[:, 1:] * np.where(s_half > 1e-12, angle / np.maximum(s_half, 1e-300), 2.0)[:, None]
    prog = rotvec @ axis / size
    err = np.degrees(attitude.geodesic_angle(q[i0:], q_to))
    band = max(0.02 * np.degrees(size), 0.05)
    outside = np.flatnonzero(err > band)
    if len(outside) == 0:
        settle = 0.0
    elif outside[-1] == len(err) - 1:
        settle = float("nan")
    else:
        settle = float(t[i0 + outside[-1] + 1] - t[i0])
    return {
        "settling_time_s": settle,
        "overshoot_pct": float(max(0.0, 100.0 * (prog.max() - 1.0))),
        "step_size_deg": float(np.degrees(size)),
    }
