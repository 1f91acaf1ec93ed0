"""Latency models: how long one stage of the vision loop takes, in seconds.

Each model draws one latency per call of ``sample(rng)`` from a ``numpy.random.Generator`` (same
seed, same numbers) and knows its mean. Kinds:

* ``Constant``: a fixed latency.
* ``seed_profile(name)``: the per-frame latencies of seed 000 Table 1 (RTX 4060 laptop GPU):
  GK-TransT 16.33 ms, dual TransT 31.23 ms, KCF 10.86 ms, CSRT 67.62 ms. The seed reports means
  only, so a profile is a constant unless a jitter model is added.
* ``Empirical``: latencies measured here by running a real observer (resampled with
  replacement), saved to and loaded from disk with the facts of the measurement.
* ``Normal`` (truncated at zero), ``Gamma``, ``Uniform``: distributions with jitter.

All models are pydantic objects with a ``kind`` (the tag a scenario file names) and the shape of
``LatencyDistribution``: a negative latency or an impossible parameter raises an error that names
the field. A new kind is one such class added to the ``LatencyModel`` union.
"""

from __future__ import annotations

import json
import platform
from datetime import datetime
from pathlib import Path
from typing import Annotated, Literal, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, field_validator, model_validator

from plant.registry import Registry

#: Seed 000 Table 1: mean per-frame latency (s) of each tracker on an RTX 4060 laptop GPU. The
#: one copy of these figures in the code: everything else reads them from here.
SEED_LATENCY_S = {
    "gk_transt": 16.33e-3,
    "dual_transt": 31.23e-3,
    "kcf": 10.86e-3,
    "csrt": 67.62e-3,
}
#: Seed 000 Table 1: frame rate (frames/s) of the same trackers.
SEED_FPS = {"gk_transt": 61.23, "dual_transt": 32.02, "kcf": 92.05, "csrt": 14.79}


def seed_latency_ms(name: str) -> float:
    """``SEED_LATENCY_S[name]`` in ms, to the seed's two decimals (16.33 for ``gk_transt``)."""
    return round(1e3 * SEED_LATENCY_S[name], 2)


class LatencyDistribution(Protocol):
    """What every latency model offers: a draw (s) and the mean (s)."""

    def sample(self, rng: np.random.Generator) -> float:
        """One latency, s, drawn with ``rng``."""
        ...

    @property
    def mean_s(self) -> float:
        """The mean latency, s."""
        ...


class _Model(BaseModel):
    """A latency model's settings: unknown fields and numbers that are not finite raise
    ``ValueError`` naming the field."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Constant(_Model):
    """A fixed latency ``value_s`` (s)."""

    kind: Literal["constant"] = "constant"
    value_s: float = Field(ge=0.0, description="The latency, s.")

    def sample(self, rng: np.random.Generator) -> float:
        """``value_s``, every time."""
        return self.value_s

    @property
    def mean_s(self) -> float:
        """``value_s``."""
        return self.value_s


class Normal(_Model):
    """Normal latency with mean ``mean_value_s`` and std ``std_s`` (s), truncated at zero by
    redrawing (the mean then sits slightly above ``mean_value_s`` when std is large)."""

    kind: Literal["normal"] = "normal"
    mean_value_s: float = Field(ge=0.0, description="Mean before truncation, s.")
    std_s: float = Field(ge=0.0, description="Standard deviation before truncation, s.")

    def sample(self, rng: np.random.Generator) -> float:
        """A draw of N(mean_value_s, std_s²), s, redrawn while negative (0 after 1,000
        negative draws)."""
        for _ in range(1000):
            x = rng.normal(self.mean_value_s, self.std_s)
            if x >= 0.0:
                return float(x)
        return 0.0

    @property
    def mean_s(self) -> float:
        """``mean_value_s`` (before truncation)."""
        return self.mean_value_s


class Gamma(_Model):
    """Gamma-distributed latency: ``offset_s`` plus Gamma(shape k, scale theta_s)."""

    kind: Literal["gamma"] = "gamma"
    shape_k: float = Field(gt=0.0, description="Gamma shape k (dimensionless).")
    scale_theta_s: float = Field(gt=0.0, description="Gamma scale theta, s.")
    offset_s: float = Field(0.0, ge=0.0, description="Fixed part added to the gamma "
                            "draw, s.")

    def sample(self, rng: np.random.Generator) -> float:
        """``offset_s`` plus a Gamma(k, θ) draw, s."""
        return float(self.offset_s + rng.gamma(self.shape_k, self.scale_theta_s))

    @property
    def mean_s(self) -> float:
        """``offset_s + k·θ``, s."""
        return self.offset_s + self.shape_k * self.scale_theta_s


class Uniform(_Model):
    """Latency uniform on [low_s, high_s] (s)."""

    kind: Literal["uniform"] = "uniform"
    low_s: float = Field(ge=0.0, description="Lower end, s.")
    high_s: float = Field(ge=0.0, description="Upper end, s.")

    @model_validator(mode="after")
    def _ordered(self) -> Uniform:
        if self.high_s < self.low_s:
            raise ValueError(f"high_s ({self.high_s}) must be >= low_s ({self.low_s})")
        return self

    def sample(self, rng: np.random.Generator) -> float:
        """A uniform draw on [low_s, high_s], s."""
        return float(rng.uniform(self.low_s, self.high_s))

    @property
    def mean_s(self) -> float:
        """The midpoint, s."""
        return 0.5 * (self.low_s + self.high_s)


class Empirical(_Model):
    """Latencies measured by running a real stage here; ``sample`` resamples them.

    Attributes
    ----------
    samples_s : the measured latencies, s.
    source : what was measured (observer, settings).
    machine : where; ``measured_at`` : when (ISO 8601).
    """

    kind: Literal["empirical"] = "empirical"
    samples_s: tuple[float, ...] = Field(min_length=1, description="The measured "
                                         "latencies, s.")
    source: str = Field("", description="What was measured (stage, tracker).")
    machine: str = Field("", description="Where it was measured.")
    measured_at: str = Field("", description="When it was measured (ISO 8601).")

    @field_validator("samples_s")
    @classmethod
    def _non_negative(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        a = np.asarray(v, dtype=float)
        if not np.all(np.isfinite(a)) or np.any(a < 0):
            raise ValueError("samples_s must be finite and non-negative")
        return v

    @classmethod
    def from_measurements(cls, samples_s: list[float] | np.ndarray, source: str) -> Empirical:
        """Wrap freshly measured latencies (s) with this machine's description and the time."""
        return cls(
            samples_s=tuple(float(x) for x in samples_s),
            source=source,
            machine=f"{platform.machine()} {platform.processor()} {platform.python_version()}",
            measured_at=datetime.now().isoformat(timespec="seconds"),
        )

    def sample(self, rng: np.random.Generator) -> float:
        """One of the measured samples, drawn uniformly with replacement, s."""
        return float(self.samples_s[rng.integers(len(self.samples_s))])

    @property
    def mean_s(self) -> float:
        """The samples' mean, s."""
        return float(np.mean(self.samples_s))

    def save(self, path: str | Path) -> None:
        """Write the profile as JSON."""
        Path(path).write_text(json.dumps(self.model_dump(), indent=1) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> Empirical:
        """Read a profile written by ``save``."""
        return cls.model_validate(json.loads(Path(path).read_text()))


LatencyModel = Annotated[
    Constant | Normal | Gamma | Uniform | Empirical, Field(discriminator="kind")
]
_adapter: TypeAdapter = TypeAdapter(LatencyModel)


def _as_model(spec: Constant | Normal | Gamma | Uniform | Empirical) -> LatencyDistribution:
    """A latency model's settings are the model: they draw its samples (``sample``)."""
    return spec


LATENCY_MODELS = Registry(
    "latency",
    "a stage's latency distribution: the pipeline's stages, the controller, the observer",
    "(spec) -> LatencyDistribution",
    "pipeline.<stage>, controller_latency: {kind: NAME, ...}",
)
for _cls, _summary in ((Constant, "a fixed latency"),
                       (Normal, "a normal latency, truncated at zero"),
                       (Gamma, "an offset plus a gamma-distributed latency"),
                       (Uniform, "a latency uniform on [low_s, high_s]"),
                       (Empirical, "latencies measured here, resampled")):
    LATENCY_MODELS.register(_cls.model_fields["kind"].default, _summary, _as_model, _cls)


def parse_latency(data: dict) -> Constant | Normal | Gamma | Uniform | Empirical:
    """Build a latency model from a config mapping with a ``kind`` field."""
    return _adapter.validate_python(data)


def seed_profile(name: str) -> Constant:
    """The constant latency of a tracker from seed 000 Table 1 (``gk_transt``, ``dual_transt``,
    ``kcf``, ``csrt``)."""
    try:
        return Constant(value_s=SEED_LATENCY_S[name])
    except KeyError:
        raise ValueError(
            f"unknown seed profile {name!r}; choose one of {sorted(SEED_LATENCY_S)}"
        ) from None
