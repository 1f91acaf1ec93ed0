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

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from latency.models import SEED_LATENCY_S, Constant, LatencyModel

PipelineMode = Literal["sequential", "pipelined"]


class PipelineConfig(BaseModel):
    """Timing of the camera and the observer."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    frame_rate_hz: float = Field(
        36.0, gt=0.0, description="Seed 000 §5: 90 frames in 2.5 s."
    )
    exposure_s: float = Field(2e-3, gt=0.0, description="Our choice (PlantParams.camera).")
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
        return 1.0 / self.frame_rate_hz


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
        if config.exposure_s > config.frame_period_s:
            raise ValueError(
                f"exposure_s {config.exposure_s} exceeds the frame period "
                f"{config.frame_period_s:.4g} s"
            )
        self.config = config
        self.rng = rng
        self._k = 0
        self._busy_until = -np.inf
        self._last_release = -np.inf

    def next_frame(self, measure: Callable[[int], float] | None = None) -> FrameTiming:
        """Timing of the next frame.

        ``measure``, if given, is called with the frame index only for a frame that is not
        dropped, and returns the processing latency (s) to use instead of the model's: for an
        observer whose compute time is measured while the loop runs.
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
