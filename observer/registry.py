"""The observer family: every attitude back end a scenario can name, with its settings
(pydantic) and its builder (``plant.registry``).

Marker rotor: ``aekf``/``ekf`` (the quaternion filter of ``observer.aekf``, optionally
predicting across the latency), ``solver`` (per-frame least squares), ``pixel_kalman`` (the
seed's pixel Kalman filter on each marker, then the solver). Textured rotor (image mode only):
``orb`` (ORB alone, a direct solve per frame), ``orb_ekf`` and ``orb_aekf`` (the quaternion
EKF/AEKF on the matched points, seed 001). A scenario's ``observer`` is one of ``ObserverSpec``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from observer.aekf import AEKFConfig
from observer.cor_model import CorModel
from observer.cor_solver import CorSolver
from observer.gk.pixel_kalman import R_MIN_PX2, PixelKalmanConfig
from observer.orb import OrbConfig, OrbReference
from observer.orb_observer import OrbObserver, orb_filter_config
from observer.pixel_observer import (
    FilterObserver,
    PixelKalmanObserver,
    PixelObserver,
    SolverObserver,
)
from plant.params import PlantParams
from plant.registry import Registry


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class FilterObserverSpec(_Model):
    """The quaternion filter on the marker pixels: ``aekf`` (adaptive) or ``ekf``."""

    kind: Literal["aekf", "ekf"] = "aekf"
    compensate_delay: bool = Field(True, description="Predict to the release time (our "
                                   "choice: on).")
    aekf: AEKFConfig = Field(default_factory=AEKFConfig, description="Filter settings (its "
                             "adaptive flag is set by the kind).")
    #: Whether the kind needs the textured rotor and its ORB front end.
    is_orb: ClassVar[bool] = False


class SolverObserverSpec(_Model):
    """The per-frame least-squares solve on the marker centres."""

    kind: Literal["solver"] = "solver"
    #: Whether the kind needs the textured rotor and its ORB front end.
    is_orb: ClassVar[bool] = False


class PixelKalmanObserverSpec(_Model):
    """The seed's pixel Kalman filter on each marker centre, then the per-frame solve."""

    kind: Literal["pixel_kalman"] = "pixel_kalman"
    pixel_q_scale: float = Field(0.01, gt=0.0, description="Q = q·I4; seed 000 §3.2.1: 0.01.")
    pixel_r_scale: float = Field(
        0.1, ge=R_MIN_PX2, description="R = r·I2, at least "
        "``observer.gk.pixel_kalman.R_MIN_PX2``; seed 000 §3.2.1: 0.1."
    )
    #: Whether the kind needs the textured rotor and its ORB front end.
    is_orb: ClassVar[bool] = False


class OrbObserverSpec(_Model):
    """ORB features on the textured rotor: ``orb`` (a direct solve per frame), ``orb_ekf`` or
    ``orb_aekf`` (the quaternion EKF/AEKF on the matched points, seed 001)."""

    kind: Literal["orb", "orb_ekf", "orb_aekf"] = "orb_aekf"
    compensate_delay: bool = Field(True, description="orb_ekf/orb_aekf: predict to the "
                                   "release time (our choice: on).")
    aekf: AEKFConfig = Field(
        default_factory=orb_filter_config,
        description="Filter settings: seed 001's ϑ = 0.8, window N = 10, each point's σ from "
        "the front end (observer.orb_observer.orb_filter_config).",
    )
    orb: OrbConfig = Field(default_factory=OrbConfig, description="Keypoints, matching, "
                           "RANSAC.")
    orb_max_coast_s: float = Field(
        0.5, gt=0.0, description="The estimate is invalid after this long without an "
        "accepted measurement, s (our choice, OrbObserver's default).",
    )
    is_orb: ClassVar[bool] = True


ObserverSpec = Annotated[
    FilterObserverSpec | SolverObserverSpec | PixelKalmanObserverSpec | OrbObserverSpec,
    Field(discriminator="kind"),
]
#: The ORB kinds -> ``OrbObserver``'s method.
ORB_METHODS = {"orb": "orb", "orb_ekf": "ekf", "orb_aekf": "aekf"}


def _filter(spec: FilterObserverSpec, plant: PlantParams, clock: Callable[[], float],
            orb_reference: OrbReference | None) -> PixelObserver:
    """``FilterObserver`` with the kind's adaptive flag."""
    cfg = spec.aekf.model_copy(update={"adaptive": spec.kind == "aekf"})
    return FilterObserver(plant, cfg, compensate_delay=spec.compensate_delay)


def _solver(spec: SolverObserverSpec, plant: PlantParams, clock: Callable[[], float],
            orb_reference: OrbReference | None) -> PixelObserver:
    """``SolverObserver`` on the nominal marker model."""
    return SolverObserver(CorSolver(CorModel.nominal(plant)))


def _pixel_kalman(spec: PixelKalmanObserverSpec, plant: PlantParams,
                  clock: Callable[[], float], orb_reference: OrbReference | None
                  ) -> PixelObserver:
    """``PixelKalmanObserver`` with Q = q·I4 and R = r·I2."""
    pk = PixelKalmanConfig(Q=(spec.pixel_q_scale * np.eye(4)).tolist(),
                           R=(spec.pixel_r_scale * np.eye(2)).tolist())
    return PixelKalmanObserver(CorSolver(CorModel.nominal(plant)), pk)


def _orb(spec: OrbObserverSpec, plant: PlantParams, clock: Callable[[], float],
         orb_reference: OrbReference | None) -> OrbObserver:
    """``OrbObserver`` matching to ``orb_reference`` (the textured rotor's reference view)."""
    if orb_reference is None:
        raise ValueError(f"observer {spec.kind!r} needs the textured rotor's reference view")
    return OrbObserver(plant, orb_reference, method=ORB_METHODS[spec.kind],  # type: ignore
                       orb_config=spec.orb, filter_config=spec.aekf,
                       compensate_delay=spec.compensate_delay,
                       max_coast_s=spec.orb_max_coast_s, clock=clock)


OBSERVERS = Registry(
    "observer",
    "the attitude back end: marker centres (or ORB matches) in, attitude estimate out",
    "(spec, plant, clock, orb_reference) -> observer",
    "observer: {kind: NAME, ...}",
)
OBSERVERS.register("aekf", "adaptive quaternion EKF on the marker pixels, predicting across "
                   "the latency", _filter, FilterObserverSpec)
OBSERVERS.register("ekf", "quaternion EKF on the marker pixels, predicting across the "
                   "latency", _filter, FilterObserverSpec)
OBSERVERS.register("solver", "per-frame least-squares solve on the two marker centres",
                   _solver, SolverObserverSpec)
OBSERVERS.register("pixel_kalman", "the seed's pixel Kalman filter on each marker, then the "
                   "solve (seed 000 §3.2.1)", _pixel_kalman, PixelKalmanObserverSpec)
OBSERVERS.register("orb", "ORB on the textured rotor, a direct solve per frame (image mode)",
                   _orb, OrbObserverSpec)
OBSERVERS.register("orb_ekf", "quaternion EKF on the ORB matches (seed 001; image mode)",
                   _orb, OrbObserverSpec)
OBSERVERS.register("orb_aekf", "adaptive quaternion EKF on the ORB matches (seed 001; image "
                   "mode)", _orb, OrbObserverSpec)


def build_observer(spec: FilterObserverSpec | SolverObserverSpec | PixelKalmanObserverSpec
                   | OrbObserverSpec, plant: PlantParams, clock: Callable[[], float],
                   orb_reference: OrbReference | None = None) -> PixelObserver | OrbObserver:
    """The observer of ``spec`` (``OBSERVERS``); the ORB kinds need ``orb_reference``."""
    return OBSERVERS.get(spec.kind).build(spec, plant, clock, orb_reference)
