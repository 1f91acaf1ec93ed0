"""The settings of one closed-loop run (``LoopConfig``) and what a run returns (``LoopResult``).

``latency.loop.ClosedLoop`` runs with a ``LoopConfig``; the engines that compute the same run
faster (``latency.batched``, ``latency.compiled``) take the same settings and return the same
``LoopResult``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pandas as pd
from pydantic import BaseModel, ConfigDict, Field, model_validator

from latency.models import Constant, LatencyModel
from latency.pipeline import PipelineConfig


class LoopConfig(BaseModel):
    """Settings of one closed-loop run. Numbers must be finite (an infinite rate or latency
    cannot run)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

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
        description="Our choice: a divergence event when the geodesic error between truth and "
        "reference exceeds this (the run continues, so every run covers its duration).",
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
    seed: int = Field(0, ge=0, description="Random seed (numpy needs it >= 0).")
    step_metrics: bool = Field(
        True,
        description="The reference is piecewise constant (steps): the summary measures the "
        "step after its last change (overshoot, settling time, steady-state error). False for "
        "a smooth reference (random, ramp, cone): those metrics are NaN (latency.metrics).",
    )
    q0: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    omega0_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _latency_fits(self) -> LoopConfig:
        """Settings that would run without a single estimate or command, or that the camera
        cannot do (the frame scheduler would stop the run at its first frame)."""
        pipe = self.pipeline
        mean = pipe.observer.mean_s
        if mean >= self.duration_s:
            raise ValueError(
                f"pipeline.observer latency (mean {mean} s) is not shorter than duration_s "
                f"({self.duration_s} s): no estimate would arrive"
            )
        if self.controller_latency != "measured":
            total = mean + self.controller_latency.mean_s
            if total >= self.duration_s:
                raise ValueError(
                    f"pipeline.observer latency plus controller_latency (means, {total:g} s) "
                    f"is not shorter than duration_s ({self.duration_s} s): no command would "
                    "take effect"
                )
        if pipe.exposure_s > pipe.frame_period_s:
            raise ValueError(
                f"pipeline.frame_rate_hz = {pipe.frame_rate_hz:g} is more than the camera can "
                f"reach with pipeline.exposure_s = {pipe.exposure_s:g} s (at most "
                f"{1.0 / pipe.exposure_s:g} Hz: each frame is exposed within its period)"
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
        out = Path(folder)
        out.mkdir(parents=True, exist_ok=True)
        self.steps.to_parquet(out / "steps.parquet")
        self.frames.to_parquet(out / "frames.parquet")
        self.events.to_parquet(out / "events.parquet")
        (out / "summary.json").write_text(json.dumps(self.summary, indent=1, default=str))
        return out
