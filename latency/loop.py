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
(the controller then falls back to zero torque or holds its last command), current saturation,
contact with the tilt stop, and divergence (the run stops early and says so).

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
from pydantic import BaseModel, ConfigDict, Field, model_validator
from tqdm import tqdm

from controller.base import Controller, Reference
from latency.frontends import FrontEnd
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
    on_invalid: Literal["zero", "hold"] = Field(
        "hold", description="Safe command when the estimate is invalid."
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


def _zyz_deg(q: np.ndarray) -> tuple[float, float, float]:
    a, b, g = attitude.to_zyz(q)
    return float(np.degrees(a)), float(np.degrees(b)), float(np.degrees(g))


class ClosedLoop:
    """One closed-loop run: ``ClosedLoop(...).run()`` returns a ``LoopResult``.

    Parameters
    ----------
    params : PlantParams
    controller : Controller
    reference : Reference
    front_end : FrontEnd (``MeasurementFrontEnd`` or ``ImageFrontEnd``)
    observer : PixelObserver (e.g. ``observer.pixel_observer.FilterObserver``)
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
        scheduler = FrameScheduler(c.pipeline, rng_pipe)
        h = p.physics_dt_s
        n_steps = int(np.floor(c.duration_s / h + 1e-9))

        log = _StepLog(n_steps + 1)
        frames: list[dict] = []
        events: list[tuple[float, str, str]] = []
        queue: list[tuple[float, int, str, object]] = []
        order = itertools.count()

        def push(t: float, kind: str, payload: object = None) -> None:
            heapq.heappush(queue, (t, next(order), kind, payload))

        state = {
            "currents": np.zeros(N_COILS),
            "torque_cmd": np.zeros(3),
            "delivered": np.zeros(3),
            "saturated": False,
            "lost": False,
            "stop": False,
            "estimate": None,
            "last_ctrl_time": np.nan,
        }
        push(0.5 * c.pipeline.exposure_s, "frame")
        if c.controller_rate_hz is not None:
            push(0.0, "tick", 0)
        t, k_log = 0.0, 0
        stopped = ""
        bar = tqdm(total=n_steps, disable=not progress, desc="closed loop", unit="step")

        def record(t_now: float) -> None:
            q_ref = self.reference.sample(t_now).q
            est = state["estimate"]
            log.write(
                k_log,
                t_now,
                plant.q,
                plant.omega,
                q_ref,
                state["torque_cmd"],
                state["delivered"],
                plant.currents,
                est.q if est is not None else None,
                state["saturated"],
                state["stop"],
                plant.delayed_q() if native else None,
            )

        record(0.0)
        while True:
            t_next_event = queue[0][0] if queue else np.inf
            t_next_grid = (k_log + 1) * h
            t_target = min(t_next_event, t_next_grid, c.duration_s)
            if t_target > t:
                plant.advance(state["currents"], t_target - t)
                t = t_target
            if abs(t - t_next_grid) < 1e-12 and k_log + 1 <= n_steps:
                k_log += 1
                record(t)
                bar.update(1)
                stop_now = plant.tilt_stop_active()
                if stop_now != state["stop"]:
                    events.append((t, "tilt_stop_contact" if stop_now else "tilt_stop_release", ""))
                    state["stop"] = stop_now
            if state.get("diverged"):
                stopped = state["diverged"]
                events.append((t, "divergence", stopped))
                break
            if t >= c.duration_s - 1e-12:
                break
            if not queue or queue[0][0] > t + 1e-12:
                continue
            _, _, kind, payload = heapq.heappop(queue)
            if kind == "frame":
                self._on_frame(t, plant, scheduler, push, frames, events, state)
            elif kind == "release":
                self._on_release(t, payload, push, frames, events, state, rng_ctrl)
            elif kind == "command":
                self._on_command(t, payload, plant, events, state)
            elif kind == "tick":
                push((payload + 1) / c.controller_rate_hz, "tick", payload + 1)
                est = state["estimate"]
                if est is None:
                    est = _no_estimate(t)
                self._control(t, est, None, push, frames, events, state, rng_ctrl)
        bar.close()

        steps = log.frame(k_log + 1, native)
        frames_df = pd.DataFrame(frames)
        events_df = pd.DataFrame(events, columns=["t_s", "kind", "detail"])
        summary = summarize(steps, frames_df, events_df, c.duration_s, stopped)
        return LoopResult(steps, frames_df, events_df, summary, c.model_dump(mode="json"))

    # --- event handlers --------------------------------------------------------------------
    def _on_frame(self, t, plant, scheduler, push, frames, events, state) -> None:
        """A frame's mid-exposure: measure (unless the frame is dropped), schedule release."""
        c = self.config
        err = attitude.geodesic_angle(plant.q, self.reference.sample(t).q)
        if not np.isfinite(err) or np.degrees(err) > c.divergence_deg:
            state["diverged"] = f"divergence: geodesic error {np.degrees(err):.1f} deg"
            return
        captured: dict = {}

        def measure(k: int) -> float:
            cap = self.front_end.capture(plant.q, plant.omega, t)
            captured["cap"] = cap
            if c.observer_latency == "measured":
                return cap.compute_time_s
            return c.pipeline.observer.sample(scheduler.rng)

        timing = scheduler.next_frame(measure)
        t_next = (timing.index + 1) * c.pipeline.frame_period_s + 0.5 * c.pipeline.exposure_s
        push(t_next, "frame")
        row = {
            "frame": timing.index,
            "t_exposure_s": timing.t_exposure,
            "t_release_s": timing.t_release,
            "dropped": timing.dropped,
        }
        if timing.dropped:
            events.append((t, "frame_dropped", f"frame {timing.index}"))
            frames.append(row)
            return
        cap = captured["cap"]
        pixels = isinstance(cap.marker_px, np.ndarray) and cap.marker_px.shape == (2, 2)
        if pixels and np.all(np.isfinite(cap.true_px)):
            err = np.linalg.norm(cap.marker_px - cap.true_px, axis=1)
        else:  # no marker truth (e.g. a textured rotor): the front end's own verdict only
            err = np.full(2, np.nan if cap.lost else 0.0)
        lost = bool(cap.lost or not np.all(err <= c.loss_threshold_px))
        if lost != state["lost"]:
            detail = cap.reason or f"centre error {np.nanmax(err):.1f} px"
            events.append((t, "tracking_loss" if lost else "reacquisition", detail))
            state["lost"] = lost
        meas = cap.marker_px if pixels else np.full((2, 2), np.nan)
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
        frames.append(row)
        push(timing.t_release, "release", (len(frames) - 1, cap, t))

    def _on_release(self, t, payload, push, frames, events, state, rng_ctrl) -> None:
        """An estimate becomes available: the observer fuses the frame's pixels (at their
        exposure time) and hands over its estimate; compute the command, schedule it."""
        c = self.config
        frame_row, cap, t_exposure = payload
        self.observer.process(cap.marker_px, t_exposure, cap.lost, cap.reason, cap.compute_time_s)
        est: Estimate = self.observer.release(t)
        state["estimate"] = est
        if est.valid:
            self.front_end.tilt_hint(attitude.tilt(est.q))
        frames[frame_row].update(
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
        if c.controller_rate_hz is None:
            self._control(t, est, frame_row, push, frames, events, state, rng_ctrl)
        elif not est.valid:
            events.append((t, "invalid_estimate", est.reason))

    def _control(self, t, est, frame_row, push, frames, events, state, rng_ctrl) -> None:
        """Run the controller on ``est`` at ``t`` (or the safe command) and schedule the
        command after the controller latency. ``frame_row`` (None on a clock tick) gets the
        measured compute time."""
        c = self.config
        overridden = not est.valid
        if not est.valid:
            if frame_row is not None:
                events.append((t, "invalid_estimate", est.reason))
            torque = np.zeros(3) if c.on_invalid == "zero" else state["torque_cmd"]
            ctrl_time = 0.0
        else:
            t0 = time.perf_counter()
            torque = np.asarray(self.controller.command(est, self.reference, t), dtype=float)
            ctrl_time = time.perf_counter() - t0
            if torque.shape != (3,) or not np.all(np.isfinite(torque)):
                events.append((t, "invalid_command", f"controller returned {torque!r}"))
                torque = np.zeros(3) if c.on_invalid == "zero" else state["torque_cmd"]
                overridden = True
        if frame_row is not None:
            frames[frame_row]["controller_compute_s"] = ctrl_time
        latency = (
            ctrl_time
            if c.controller_latency == "measured"
            else c.controller_latency.sample(rng_ctrl)
        )
        push(t + latency, "command", (torque, est, overridden))

    def _on_command(self, t, payload, plant, events, state) -> None:
        """Apply a torque command: allocate currents within the limits, hold them."""
        torque, est, overridden = payload
        if overridden and hasattr(self.controller, "record_command"):
            self.controller.record_command(t, torque)  # e.g. the MPC's delay compensation
        q_alloc = plant.q if self.config.allocate_with == "truth" or not est.valid else est.q
        alloc = plant.allocate(torque, q_alloc)
        if alloc.saturated != state["saturated"]:
            if alloc.saturated:
                events.append(
                    (
                        t,
                        "saturation",
                        f"delivered {np.linalg.norm(alloc.delivered):.3g}"
                        f" of {np.linalg.norm(torque):.3g} N·m",
                    )
                )
            state["saturated"] = alloc.saturated
        state["currents"] = alloc.currents
        state["torque_cmd"] = torque
        state["delivered"] = alloc.delivered
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
