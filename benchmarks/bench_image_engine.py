"""The batched image engine: frames per second and real-time factor against the event loop and
against the tracker networks' own limit.

For GK-TransT and the dual TransT (PID, per-frame solver, random references at 3 rad/s, the
seed's latency of the tracker, analytic renderer):

* the event loop's image mode: ``ClosedLoop.run`` one run after the other in this process, the
  network already built (as every run after a process's first), on the first 16 of the
  engine's B = 64 runs (the same references and frames);
* the engine (``latency.image_engine.run_images``, 2 worker processes) at B = 1, 8 and 64 runs:
  aggregate frames per second and real-time factor (simulated seconds per wall second), the
  workers' start included, with the engine's default runs per batch (``RUNS_PER_BATCH``) and,
  at B = 64, with each worker's 32 runs in one batch (a thread per run, network calls
  batched);
* the engine at B = 64 on a warm ``ImagePool`` (its 2 workers started and through a first
  call): ``<tracker>_B64_warm_pool_*``, like for like with the event loop's figure, which is
  also timed after the network is built;
* the *network limit*: frames per second of the tracker's networks alone on search crops, at
  the best of 1 or 2 ONNX Runtime threads and batch sizes 1-64, measured just before and just
  after the engine's B = 64 run and averaged (``_before`` and ``_after`` keys: each alone; one
  network call per frame for GK-TransT on its steady 96 px crop, which it searches on all but
  its first frames and re-acquisitions; two per frame for the dual TransT on 128 px crops;
  1-thread figures scaled by the two cores, an upper bound);
* where a run's time goes: a profile of one event-loop run (the code an engine run executes),
  by part (render, network, GK and trackers, physics, control, the rest), library calls
  charged to the part that made them.

Keys: ``<tracker>_B<B>_realtime_factor``, ``<tracker>_B<B>_frames_per_s``,
``<tracker>_B64_fraction_of_network_limit``, ``<tracker>_B64_ratio_to_event_loop``,
``<tracker>_network_limit_frames_per_s``, ``<tracker>_event_loop_realtime_factor``,
``<tracker>_B64_one_batch_per_worker_realtime_factor`` (and ``_frames_per_s``),
``<tracker>_ceiling_ratio_to_event_loop`` (the network limit over the event loop's frames/s:
the most any engine could reach against the event loop),
``<tracker>_time_fraction_<part>``, ``network_s_per_sample_search<px>_threads<T>_B<B>``.

Run on an idle machine: ``python benchmarks/bench_image_engine.py`` (``--quick``: a smoke run
with small batches and short runs, printed only).
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import numpy as np

from latency import Scenario, build_loop
from latency.image_engine import RUNS_PER_BATCH, run_images
from latency.models import SEED_LATENCY_S
from observer.trackers.registry import STEADY_SEARCH_PX

#: tracker: (registry name, network calls per frame, search crop of most frames in px; None:
#: the network's configured size)
TRACKERS = {"gk_transt": ("gk_transt", 1, STEADY_SEARCH_PX),
            "dual_transt": ("dual_transt", 2, None)}
PARTS = {"render": ("plant/render", "plant/scene"), "network": ("onnxruntime",),
         "gk_and_trackers": ("observer/gk", "observer/trackers", "observer/transt",
                             "observer/tracking", "observer/opencv", "cv2"),
         "physics": ("plant/dynamics", "plant/rigid_body", "plant/torque"),
         "control": ("controller/", "observer/cor_", "observer/pixel_observer")}


def _scenarios(tracker: str, n: int, duration_s: float, first_seed: int = 0) -> list[Scenario]:
    name = TRACKERS[tracker][0]
    return [Scenario.model_validate({
        "mode": "image", "tracker": name, "duration_s": duration_s, "seed": s,
        "observer": {"kind": "solver"},
        "reference": {"kind": "random", "args": {"max_rate_rad_s": 3.0, "seed": s}},
        "pipeline": {"observer": {"kind": "constant", "value_s": SEED_LATENCY_S[tracker]}},
    }) for s in range(first_seed, first_seed + n)]


def _frames(results) -> int:
    return int(sum((~r.frames["dropped"].astype(bool)).sum() for r in results))


#: Every figure's runs start at this seed, so they share references and frames: the event loop
#: runs the first ``EVENT_LOOP_RUNS`` of the engine's B = 64 runs.
FIRST_SEED = 300
#: Runs of the event loop's figure.
EVENT_LOOP_RUNS = 16


def event_loop(tracker: str, n: int, duration_s: float) -> tuple[float, float]:
    """(real-time factor, frames/s) of the event loop on the first ``n`` of the engine's runs,
    network built beforehand."""
    build_loop(_scenarios(tracker, 1, 0.2)[0]).run()  # builds and exports the network
    loops = [build_loop(s) for s in _scenarios(tracker, n, duration_s, first_seed=FIRST_SEED)]
    t0 = time.perf_counter()
    res = [lp.run() for lp in loops]
    wall = time.perf_counter() - t0
    return n * duration_s / wall, _frames(res) / wall


def engine(tracker: str, B: int, duration_s: float, one_batch: bool = False
           ) -> tuple[float, float]:
    """(real-time factor, frames/s) of the engine on B runs, 2 workers, start included; with
    its default runs per batch, or (``one_batch``) each worker's runs in one batch (a thread
    per run, the network calls batched)."""
    specs = _scenarios(tracker, B, duration_s, first_seed=FIRST_SEED)
    rpb = max(1, -(-B // 2)) if one_batch else RUNS_PER_BATCH
    t0 = time.perf_counter()
    res = run_images(build_loop, specs, workers=2, runs_per_batch=rpb)
    wall = time.perf_counter() - t0
    return B * duration_s / wall, _frames(res) / wall


def engine_warm(tracker: str, B: int, duration_s: float) -> tuple[float, float]:
    """(real-time factor, frames/s) of the engine on B runs, 2 workers already started and
    warm (an ``ImagePool`` that has run a call before): what every call after a pool's first
    gets, like for like with ``event_loop`` (which times runs after the network is built)."""
    from latency.image_engine import ImagePool

    specs = _scenarios(tracker, B, duration_s, first_seed=FIRST_SEED)
    with ImagePool(2) as pool:
        run_images(build_loop, _scenarios(tracker, 4, 0.2, first_seed=400), pool=pool)
        t0 = time.perf_counter()
        res = run_images(build_loop, specs, pool=pool)
        wall = time.perf_counter() - t0
    return B * duration_s / wall, _frames(res) / wall


def network_costs(batches: tuple[int, ...], repeats: int,
                  search_size: int | None) -> tuple[int, dict[tuple[int, int], float]]:
    """The crop's side (px) and the median seconds per crop of the shipped network (ONNX
    Runtime) on search crops of ``search_size`` px (None: its configured size) per (threads,
    batch)."""
    from observer.transt.export import onnx_session
    from observer.transt.weights import SMALL_WEIGHTS, load_weights

    net, _ = load_weights(SMALL_WEIGHTS)
    c = net.config
    rng = np.random.default_rng(0)
    out = {}
    for threads in (1, 2):
        session = onnx_session(net, num_threads=threads, search_size=search_size)
        side = search_size or c.search_size
        for B in batches:
            x = rng.normal(size=(B, 3, side, side)).astype(np.float32)
            z = rng.normal(size=(B, c.template_feature_size ** 2, c.d_model)).astype(np.float32)
            session.run(None, {"search": x, "z": z})
            walls = []
            for _ in range(max(3, repeats // B)):
                t0 = time.perf_counter()
                session.run(None, {"search": x, "z": z})
                walls.append(time.perf_counter() - t0)
            out[(threads, B)] = float(np.median(walls)) / B
    return side, out


def _part_of(path: str, func: str) -> str | None:
    """The ``PARTS`` entry a profiled function belongs to, None if none names it."""
    where = f"{path}:{func}"
    return next((part for part, keys in PARTS.items() if any(k in where for k in keys)), None)


def time_split(tracker: str, duration_s: float) -> dict[str, float]:
    """Fractions of one run's time by part (see ``PARTS``): the event loop's run, profiled in
    this thread, network built beforehand (an engine run executes the same code; the engine's
    threads are not seen by the profiler of this one). A library function that no part names
    (a numpy or OpenCV call, a ufunc) is charged to its callers in proportion to the time each
    call took, up the call chain until a part names the caller; what still has none (the
    loop's own bookkeeping, the interpreter) is ``rest``."""
    build_loop(_scenarios(tracker, 1, 0.2)[0]).run()  # builds and exports the network
    loop = build_loop(_scenarios(tracker, 1, duration_s, first_seed=200)[0])
    prof = cProfile.Profile()
    prof.enable()
    loop.run()
    prof.disable()
    stats = pstats.Stats(prof).stats  # type: ignore[attr-defined]
    parts = dict.fromkeys([*PARTS, "rest"], 0.0)
    memo: dict[tuple, dict[str, float]] = {}

    def shares(key: tuple, chain: frozenset) -> dict[str, float]:
        """How ``key``'s own time splits over the parts (its callers' shares, recursively)."""
        part = _part_of(key[0], key[2])
        if part is not None:
            return {part: 1.0}
        callers = stats[key][4] if key in stats else {}
        if not callers or key in chain:
            return {"rest": 1.0}
        if key not in memo:
            by_caller = sum(c[2] for c in callers.values())
            out: dict[str, float] = {}
            for caller, c in callers.items():
                w = c[2] / by_caller if by_caller > 0 else 1.0 / len(callers)
                for p, f in shares(caller, chain | {key}).items():
                    out[p] = out.get(p, 0.0) + w * f
            memo[key] = out
        return memo[key]

    for key, (_, _, tottime, _, _) in stats.items():
        for p, f in shares(key, frozenset()).items():
            parts[p] += tottime * f
    total = sum(parts.values())
    return {k: v / total for k, v in parts.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small batches, short runs")
    args = ap.parse_args()
    duration = 0.6 if args.quick else 2.0
    sizes = (1, 4) if args.quick else (1, 8, 64)
    batches = (1, 4) if args.quick else (1, 2, 4, 8, 16, 32, 64)
    figures: dict[str, float] = {}
    repeats = 8 if args.quick else 64
    for tracker, (_, calls, search_size) in TRACKERS.items():
        # The network's costs just before and just after the engine's largest run, averaged:
        # the machine's speed drifts by tens of per cent within minutes, and the fraction of
        # the limit compares the two.
        top = max(sizes)
        side, before = network_costs(batches, repeats, search_size)
        rt_top, fps_top = engine(tracker, top, duration)
        after = network_costs(batches, repeats, search_size)[1]
        costs = {key: 0.5 * (before[key] + after[key]) for key in before}
        for (threads, B), s in costs.items():
            figures[f"network_s_per_sample_search{side}_threads{threads}_B{B}"] = s
        for name, c in (("before", before), ("after", after), ("", costs)):
            # the best frames/s of the networks on two cores: 1 thread in each of 2
            # processes, or 2 threads in one
            per_crop = min(min(s / 2.0 for (t, _), s in c.items() if t == 1),
                           min(s for (t, _), s in c.items() if t == 2))
            figures[f"{tracker}_network_limit{'_' + name if name else ''}_frames_per_s"] = \
                1.0 / (calls * per_crop)
        limit = figures[f"{tracker}_network_limit_frames_per_s"]
        rt_ev, fps_ev = event_loop(tracker, 4 if args.quick else EVENT_LOOP_RUNS, duration)
        figures[f"{tracker}_event_loop_realtime_factor"] = rt_ev
        figures[f"{tracker}_event_loop_frames_per_s"] = fps_ev
        # an engine that did nothing but the network calls would run at the limit: the most
        # any engine can reach against the event loop
        figures[f"{tracker}_ceiling_ratio_to_event_loop"] = limit / fps_ev
        for B in sizes:
            rt, fps = (rt_top, fps_top) if B == top else engine(tracker, B, duration)
            figures[f"{tracker}_B{B}_realtime_factor"] = rt
            figures[f"{tracker}_B{B}_frames_per_s"] = fps
        rt, fps = engine(tracker, top, duration, one_batch=True)
        figures[f"{tracker}_B{top}_one_batch_per_worker_realtime_factor"] = rt
        figures[f"{tracker}_B{top}_one_batch_per_worker_frames_per_s"] = fps
        rt, fps = engine_warm(tracker, top, duration)
        figures[f"{tracker}_B{top}_warm_pool_realtime_factor"] = rt
        figures[f"{tracker}_B{top}_warm_pool_frames_per_s"] = fps
        figures[f"{tracker}_B{top}_warm_pool_ratio_to_event_loop"] = rt / rt_ev
        figures[f"{tracker}_B{top}_warm_pool_fraction_of_network_limit"] = fps / limit
        figures[f"{tracker}_B{top}_fraction_of_network_limit"] = \
            figures[f"{tracker}_B{top}_frames_per_s"] / limit
        figures[f"{tracker}_B{top}_ratio_to_event_loop"] = \
            figures[f"{tracker}_B{top}_realtime_factor"] / rt_ev
        for part, frac in time_split(tracker, duration).items():
            figures[f"{tracker}_time_fraction_{part}"] = frac

    if args.quick:  # a smoke run: printed, not recorded
        for k, v in figures.items():
            print(f"{k:>50s}  {v:.4g}")
        return
    from _report import record

    record("bench_image_engine",
           "Batched image engine: frames/s against the event loop and the network limit",
           figures,
           notes=f"Runs of {duration:g} s at 36 frames/s, PID, per-frame solver, random "
                 "references at 3 rad/s, each tracker at its seed latency; engine with 2 "
                 f"worker processes, {RUNS_PER_BATCH} run(s) per batch unless the key says "
                 "one batch per worker, the workers' start included except in the warm_pool "
                 "keys (an ImagePool through a first call). The network limit assumes "
                 "one network call per GK-TransT frame on its steady 96 px crop and two per "
                 "dual-TransT frame on 128 px crops.")


if __name__ == "__main__":
    main()
