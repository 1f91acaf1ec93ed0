"""The front door: run closed-loop scenarios.

``simulate(scenario)`` runs one ``latency.scenario.Scenario`` and returns its
``latency.loop.LoopResult``; ``simulate_many(scenarios)`` runs many, in order, each on the
engine that computes it fastest with the same result, and logs why a run does not take the
faster engine:

* ``"batched"``: measurement-model runs advance together in ``latency.batched`` (its compiled
  run loop where ``latency.compiled.coverage`` covers the run, else lockstep rounds); image runs
  advance together in ``latency.image_engine``, their network calls batched. Run by run the
  results equal the event loop's.
* ``"event"``: the timed event loop, ``ClosedLoop.run``, one run at a time; it alone measures
  compute latencies (``controller_latency: measured``, ``observer_latency: measured``) and runs
  the ORB observers.

``engine="auto"`` (the default) picks ``"batched"`` for measurement-model runs and for image
runs when there are several that it can take, ``"event"`` otherwise. ``build_loop`` is the
composition root: it builds each part from its family's registry.

    >>> from latency import Scenario, simulate
    >>> result = simulate(Scenario(duration_s=0.5))  # doctest: +SKIP
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Literal, get_args

from pydantic import ValidationError

from controller.registry import build_controller
from latency import compiled
from latency.batched import run_batched
from latency.frontends import FRONT_ENDS, orb_reference
from latency.image_engine import check_workers, run_images
from latency.loop import ClosedLoop
from latency.loop_config import LoopResult
from latency.scenario import Scenario
from observer.registry import build_observer
from plant.renderers import RENDERERS

_log = logging.getLogger(__name__)

#: The engines: ``"auto"`` chooses per run (see the module docstring).
Engine = Literal["auto", "batched", "event"]


def front_end_name(s: Scenario) -> str:
    """The scenario's front end in ``latency.frontends.FRONT_ENDS``."""
    if s.observer.is_orb:
        return "orb"
    return s.mode


def build_loop(s: Scenario, clock: Callable[[], float] = time.perf_counter) -> ClosedLoop:
    """The closed loop of a scenario, each part built by its family's registry.

    ``clock`` (seconds, default ``time.perf_counter``) times every measured compute time: the
    observer's front end and back end, the controller's calls and the loop's timer around them.
    Tests inject a stand-in so that the ``measured`` latencies do not depend on machine load.
    """
    p = s.plant
    renderer = (RENDERERS.get(s.renderer).build(p, s.texture, s.seed, s.camera_effects)
                if s.mode == "image" else None)
    reference_view = None
    if s.observer.is_orb:  # the textured rotor: rendered frames matched to a reference view
        reference_view = orb_reference(p, renderer, s.texture, config=s.observer.orb)
    observer = build_observer(s.observer, p, clock, reference_view)
    front = FRONT_ENDS.get(front_end_name(s)).build(s, renderer, observer, clock)
    latency = s.controller_latency
    controller = build_controller(s.controller, p, clock,
                                  None if latency == "measured" else latency.mean_s)
    return ClosedLoop(p, controller, s.reference.build(), front, observer, s.loop_config(), clock)


def event_only_reason(s: Scenario) -> str | None:
    """Why ``s`` can run only on the event loop (None if the batched engines take it)."""
    if s.mode == "image" and s.observer.is_orb:
        return "the batched image engine runs marker trackers, not the ORB observer"
    if s.mode == "image" and "measured" in (s.observer_latency, s.controller_latency):
        return ("the batched image engine needs model latencies (it charges each run the "
                "model's latency, not the batched wall time); a measured latency needs the "
                "event loop's own clock")
    return None


def _batchable_image_runs(scenarios: Sequence[Scenario]) -> int:
    """How many of ``scenarios`` are image runs the batched image engine can take."""
    return sum(s.mode == "image" and event_only_reason(s) is None for s in scenarios)


def choose_engine(s: Scenario, engine: Engine = "auto", n_image_runs: int = 1
                  ) -> tuple[Literal["batched", "event"], str]:
    """The engine that runs ``s`` and why, for ``engine`` and a call with ``n_image_runs``
    image runs; ``ValueError`` if the engine asked for cannot run it."""
    reason = event_only_reason(s)
    if engine == "batched" and reason is not None:
        raise ValueError(f"scenario {s.name!r}: {reason}; use engine='event'")
    if engine != "auto":
        return engine, f"engine {engine!r} asked for"
    if reason is not None:
        return "event", reason
    if s.mode == "image" and n_image_runs < 2:
        return "event", "a single image run gains nothing from the batched image engine"
    return "batched", ("measurement-model runs advance together" if s.mode == "measurement"
                       else "image runs advance together, their network calls batched")


def describe_path(s: Scenario, engine: Engine = "auto", n_image_runs: int = 1) -> str:
    """Which engine and, on the batched engine, which path computes ``s`` in a call with
    ``n_image_runs`` image runs, with the reason when it is not the compiled run loop
    (``latency.compiled.coverage``), in words."""
    e, why = choose_engine(s, engine, n_image_runs)
    if e == "event":
        return f"engine: event loop ({why})"
    if s.mode == "image":
        return "engine: batched image engine"
    cov = compiled.coverage(build_loop(s))
    if cov.path == "compiled":
        return "engine: batched, compiled run loop"
    return f"engine: batched, not the compiled run loop ({cov.reason})"


def describe_paths(scenarios: Sequence[Scenario], engine: Engine = "auto") -> dict[str, int]:
    """``describe_path`` of every scenario, with its number of runs. The path does not depend
    on a run's seed, name, reference or duration, so one loop is built per group of scenarios
    that differ only there (building an MPC costs about 0.3 s; a sweep has thousands of runs)."""
    n_image = _batchable_image_runs(scenarios)
    paths: dict[str, int] = {}
    described: dict[str, str] = {}
    for s in scenarios:
        key = s.model_dump_json(exclude={"seed", "name", "reference", "duration_s"})
        if key not in described:
            described[key] = describe_path(s, engine, n_image)
        paths[described[key]] = paths.get(described[key], 0) + 1
    return paths


def simulate(scenario: Scenario | Mapping, engine: Engine = "auto",
             progress: bool = False) -> LoopResult:
    """Run one scenario (a ``Scenario`` or its fields as a mapping, e.g. a scenario file's
    content; see ``simulate_many`` for ``engine``); its result, with the steps, frames and
    events tables."""
    return simulate_many([scenario], engine, progress)[0]


def _scenario(s: Scenario | Mapping, k: int) -> Scenario:
    """``s`` as a ``Scenario`` (a mapping is validated); ``TypeError`` for anything else."""
    if isinstance(s, Scenario):
        return s
    if isinstance(s, Mapping):
        return Scenario.model_validate(s)
    raise TypeError(f"scenario {k}: expected a latency.Scenario or a mapping of its fields, "
                    f"got {type(s).__name__}")


def simulate_many(scenarios: Iterable[Scenario | Mapping], engine: Engine = "auto",
                  progress: bool = False, tables: bool = True, workers: int = 1
                  ) -> list[LoopResult]:
    """Run scenarios and return their results in order.

    Parameters
    ----------
    scenarios : the runs: ``Scenario`` objects or mappings of their fields (validated here).
    engine : ``"auto"`` (each run on the fastest engine that takes it, the reason logged at
        INFO on ``latency.simulation`` when that is the event loop), ``"batched"`` (every run
        batched; ``ValueError`` for one it cannot take) or ``"event"``.
    progress : show progress bars.
    tables : False returns results without their steps, frames and events tables where the
        batched engine can skip them (only the summaries are wanted).
    workers : processes for the image runs on the batched image engine; 1 (the default) runs
        them in this process. More start that many processes, each in about 5-10 s (spawned:
        a script that asks for them must guard its top level with
        ``if __name__ == "__main__":``), which pays from a few dozen runs of seconds on.
        Measurement-model runs stay in this process (a sweep spreads those over its own
        workers).
    """
    if engine not in get_args(Engine):
        raise ValueError(f"engine must be one of {', '.join(get_args(Engine))}, got {engine!r}")
    check_workers(workers)
    if isinstance(scenarios, Scenario | Mapping | str):
        raise TypeError("simulate_many takes a sequence of scenarios; for one, use simulate")
    scenarios = [_scenario(s, k) for k, s in enumerate(scenarios)]
    n_image = _batchable_image_runs(scenarios)
    choices = [choose_engine(s, engine, n_image) for s in scenarios]
    for reason in sorted({why for e, why in choices if e == "event" and engine == "auto"}):
        _log.info("event loop: %s", reason)
    out: list[LoopResult | None] = [None] * len(scenarios)
    batched = [i for i, (e, _) in enumerate(choices) if e == "batched"]
    measured = [i for i in batched if scenarios[i].mode == "measurement"]
    images = [i for i in batched if scenarios[i].mode == "image"]
    for i, res in zip(measured, run_batched([build_loop(scenarios[i]) for i in measured],
                                            progress, tables), strict=True):
        out[i] = res
    for i, res in zip(images, run_images(build_loop, [scenarios[i] for i in images],
                                         workers=workers, progress=progress), strict=True):
        out[i] = res
    for i, (e, _) in enumerate(choices):
        if e == "event":
            out[i] = build_loop(scenarios[i]).run(progress=progress)
    return [r for r in out if r is not None]


def run_summary(config: dict) -> dict:
    """Sweep entry point: run the scenario given as a dict on the event loop, return its
    summary metrics."""
    return simulate(Scenario.model_validate(config), engine="event").summary


def run_summaries(configs: list[dict]) -> list[dict | Exception]:
    """Batched sweep entry point: the summaries of the scenarios given as dicts, together
    (``simulate_many`` with ``engine="auto"``); an invalid config gives its exception in its
    place."""
    scenarios: list[Scenario] = []
    out: list[dict | Exception] = []
    for c in configs:
        try:
            scenarios.append(Scenario.model_validate(c))
            out.append({})
        except ValidationError as exc:
            out.append(exc)
    results = iter(simulate_many(scenarios, tables=False))
    return [o if isinstance(o, Exception) else next(results).summary for o in out]
