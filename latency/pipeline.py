"""When each camera frame is exposed, processed and released: the vision pipeline's timing.

Stages of one frame k (all times in s of simulated time):

* exposure from ``k T_f`` to ``k T_f + t_exp``; its measurement belongs to mid-exposure
  ``t_exposure = k T_f + t_exp/2`` (docs/architecture.md, "Conventions");
* readout: the frame is in memory at ``t_ready = k T_f + t_exp + t_readout``;
* processing by the observer, with a latency drawn from its model; released at ``t_release``.

Two explicit semantics:

* ``sequential`` (one observer thread, the seed's host loop): the observer takes a frame only when
  it is idle; frames that become ready while it is busy are dropped. A 31 ms tracker at a 27.8 ms
  frame period therefore processes every second frame.
* ``pipelined``: every frame is processed (as by parallel workers) and released in order,
  ``t_release_k = max(t_ready_k + latency_k, t_release_{k-1})``. No frame is dropped.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from latency.models import SEED_LATENCY_S, Constant, LatencyModel
from plant.params import CameraParams

PipelineMode = Literal["sequential", "pipelined"]


class PipelineConfig(BaseModel):
    """Timing of the camera and the observer."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    frame_rate_hz: float = Field(
        CameraParams.model_fields["frame_rate_hz"].default,
        gt=0.0,
        description="The camera's, PlantParams.camera.frame_rate_hz (a scenario checks that "
        "they agree).",
    )
    exposure_s: float = Field(
        CameraParams.model_fields["exposure_s"].default,
        gt=0.0,
        description="The camera's, PlantParams.camera.exposure_s (a scenario checks that "
        "they agree).",
    )
    readout_s: float = Field(
        0.0, ge=0.0, description="Our choice: transfer to host memory; 0 = counted in the "
        "observer's latency, as seed 000 Table 1's per-frame figures are end to end."
    )
    observer: LatencyModel = Field(
        default_factory=lambda: Constant(value_s=SEED_LATENCY_S["gk_transt"]),
        description="Observer processing latency; default seed 000 Table 1, GK-TransT.",
    )
    mode: PipelineMode = "sequential"

    @property
    def frame_period_s(self) -> float:
        """Time between frames, s (1 / ``frame_rate_hz``)."""
        return 1.0 / self.frame_rate_hz

    @classmethod
    def from_camera(
        cls, camera: CameraParams, observer: LatencyModel | None = None,
        mode: PipelineMode = "sequential", readout_s: float = 0.0,
    ) -> PipelineConfig:
        """The pipeline of ``camera`` (its frame rate and exposure) with this observer."""
        extra = {} if observer is None else {"observer": observer}
        return cls(frame_rate_hz=camera.frame_rate_hz, exposure_s=camera.exposure_s,
                   readout_s=readout_s, mode=mode, **extra)

    def timing(
        self, controller_compute_s: float = 0.0, vision_delay_s: float | None = None
    ) -> LoopTiming:
        """:func:`loop_timing` of this pipeline with the observer's mean latency, or with
        ``vision_delay_s`` (s) in its place."""
        d = self.observer.mean_s if vision_delay_s is None else vision_delay_s
        return loop_timing(
            d, mode=self.mode, frame_rate_hz=self.frame_rate_hz,
            exposure_s=self.exposure_s, readout_s=self.readout_s,
            controller_compute_s=controller_compute_s,
        )


@dataclass(frozen=True)
class LoopTiming:
    """The loop's constant delay and update period for one observer latency.

    Attributes
    ----------
    vision_delay_s : float
        Observer processing latency (s).
    mode : {"sequential", "pipelined"}
        Observer semantics.
    frames_per_update : int
        Camera frames per processed frame (1, or more when a sequential observer drops frames).
    update_period_s : float
        Interval between processed frames (s): the period at which the observer and the
        controller run.
    delay_s : float
        Mid-exposure to command applied (s): half the exposure, the readout, the observer's
        latency and the controller's compute time.
    """

    vision_delay_s: float
    mode: PipelineMode
    frames_per_update: int
    update_period_s: float
    delay_s: float

    def describe(self) -> str:
        """One line naming the case, e.g. for a command's output."""
        drop = (
            f", 1 frame in {self.frames_per_update} processed"
            if self.frames_per_update > 1 else ", every frame processed"
        )
        return (
            f"{self.mode} observer, vision delay {self.vision_delay_s * 1e3:.2f} ms{drop}: "
            f"update period {self.update_period_s * 1e3:.2f} ms, loop delay "
            f"{self.delay_s * 1e3:.2f} ms"
        )


def loop_timing(
    vision_delay_s: float,
    *,
    mode: PipelineMode,
    frame_rate_hz: float,
    exposure_s: float,
    readout_s: float = 0.0,
    controller_compute_s: float = 0.0,
) -> LoopTiming:
    """Loop delay and update period of the pipeline for a constant observer latency.

    A frame is ready ``exposure + readout`` after its exposure starts. A sequential observer
    busy for ``d`` takes the next frame that is ready once it is idle, i.e. every
    ``m = max(1, ceil(d / T_f))``-th frame (``T_f`` the frame period; :class:`FrameScheduler`
    accepts a frame ready exactly when the observer becomes idle); a pipelined one takes every
    frame. The delay runs from mid-exposure (the measurement's time stamp) to the command:
    ``exposure/2 + readout + d + controller compute``.

    Parameters
    ----------
    vision_delay_s : float
        Observer latency ``d`` (s), >= 0.
    mode : {"sequential", "pipelined"}
    frame_rate_hz : float
        Camera frame rate (Hz).
    exposure_s, readout_s : float
        Exposure and readout times (s).
    controller_compute_s : float
        Controller compute time between the estimate and the command (s).
    """
    if not np.isfinite(vision_delay_s) or vision_delay_s < 0.0:
        raise ValueError(f"vision_delay_s must be finite and >= 0, got {vision_delay_s}")
    if frame_rate_hz <= 0.0:
        raise ValueError(f"frame_rate_hz must be > 0, got {frame_rate_hz}")
    if mode not in ("sequential", "pipelined"):
        raise ValueError(f"mode must be 'sequential' or 'pipelined', got {mode!r}")
    T_f = 1.0 / frame_rate_hz
    m = max(1, math.ceil(vision_delay_s / T_f - 1e-9)) if mode == "sequential" else 1
    delay = 0.5 * exposure_s + readout_s + vision_delay_s + controller_compute_s
    return LoopTiming(float(vision_delay_s), mode, m, m * T_f, float(delay))


@dataclass(frozen=True)
class FrameTiming:
    """Timing of one camera frame (s). ``dropped`` frames have NaN start and release."""

    index: int
    t_exposure: float
    t_ready: float
    t_start: float
    t_release: float
    dropped: bool

    @property
    def latency_s(self) -> float:
        """Release minus mid-exposure, s (NaN when dropped)."""
        return self.t_release - self.t_exposure


class FrameScheduler:
    """Produces ``FrameTiming`` for frames 0, 1, 2, ... on demand, with the latencies drawn
    from the observer's model with ``rng``. Use ``next_frame()`` in a loop, or
    ``schedule(duration_s)`` for the whole timeline of a run."""

    def __init__(self, config: PipelineConfig, rng: np.random.Generator) -> None:
        self.check(config)
        self.config = config
        self.rng = rng
        self._k = 0
        self._busy_until = -np.inf
        self._last_release = -np.inf

    @staticmethod
    def check(config: PipelineConfig) -> None:
        """Raise ``ValueError`` when the frames of ``config`` cannot be timed: an exposure
        longer than the frame period."""
        if config.exposure_s > config.frame_period_s:
            raise ValueError(
                f"exposure_s {config.exposure_s} exceeds the frame period "
                f"{config.frame_period_s:.4g} s"
            )

    def next_frame(self, measure: Callable[[int], float] | None = None) -> FrameTiming:
        """Timing of the next frame.

        ``measure``, if given, is called with the frame index only for a frame that is not
        dropped, and returns the processing latency (s) to use instead of the model's: for an
        observer whose compute time is measured while the loop runs.

        Mirrored in ``latency.compiled.events._event_queue``; keep both in step
        (tests/test_compiled_mirror.py checks them equal).
        """
        c = self.config
        k = self._k
        self._k += 1
        t0 = k * c.frame_period_s
        t_exposure = t0 + 0.5 * c.exposure_s
        t_ready = t0 + c.exposure_s + c.readout_s
        if c.mode == "sequential" and t_ready < self._busy_until:
            return FrameTiming(k, t_exposure, t_ready, np.nan, np.nan, True)
        latency = c.observer.sample(self.rng) if measure is None else measure(k)
        if latency < 0 or not np.isfinite(latency):
            raise ValueError(f"observer latency must be finite and >= 0, got {latency}")
        t_release = t_ready + latency
        if c.mode == "pipelined":
            t_release = max(t_release, self._last_release)
        self._busy_until = t_release
        self._last_release = t_release
        return FrameTiming(k, t_exposure, t_ready, t_ready, t_release, False)

    def schedule(self, duration_s: float) -> list[FrameTiming]:
        """All frames whose exposure starts before ``duration_s``."""
        out = []
        while self._k * self.config.frame_period_s < duration_s:
            out.append(self.next_frame())
        return out
