"""The batched image-in-the-loop engine: many image-mode runs of the timed loop together.

Each run is a ``latency.loop.ClosedLoop`` with an ``ImageFrontEnd`` (its own seed, renderer,
tracker, delays, controller and reference), built in the process that runs it by a picklable
``build(spec)`` (e.g. ``latency.simulation.build_loop`` on ``Scenario`` objects). The engine

* spreads the runs over ``workers`` processes (one per core by default), in batches of
  ``runs_per_batch`` runs; an ``ImagePool`` keeps its processes for the next call, so a caller
  that runs in several calls pays the workers' start once;
* in each process builds the tracker networks once (``observer.transt.service.shared_service``:
  the shipped weights are read, checked and exported to ONNX once per process, not per run);
* advances a batch's runs together, one thread per run, each on the event loop's own timeline
  (``ClosedLoop.run``), so a run computes exactly what the event loop computes for it: the same
  frames from the same renderer and seed, the same tracker and GK code, the same physics and
  control (by default a batch is one run, ``RUNS_PER_BATCH``, which the worker runs in its own
  thread with the network unbatched: exactly the event loop's run);
* evaluates the network on the crops of all runs of the batch that are waiting for it in one
  call (``NetworkService.batching``: a call takes every run's crop once all of the batch's runs
  are waiting on the network or done, at most ``max_network_batch`` crops). A crop's result does
  not depend on the other crops in the call, so the tracker outputs equal the event loop's to the
  rounding of the batched products (tests/test_image_engine.py).

Timing: a run's tracker latency is the loop's latency *model* (``pipeline.observer``), e.g. the
distribution of the tracker's per-frame latency measured unbatched on this machine
(``pmspm measure-latency``, ``latency.profile``), as a single camera would see it, never the wall
time of a batched call. Runs that ask for measured latencies (``observer_latency: measured`` or
``controller_latency: measured``) are refused: threads of a batch share the cores, so a time
measured there says nothing about one camera.

Where an image run's time goes, and what this engine does not do: docs/closed_loop.md.
"""

from __future__ import annotations

import multiprocessing
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import ExitStack
from typing import TypeVar

from tqdm import tqdm

from latency.frontends import ImageFrontEnd
from latency.loop import ClosedLoop
from latency.loop_config import LoopResult

Spec = TypeVar("Spec")

#: Runs advanced together in one process, by measurement (docs/closed_loop.md, the image
#: engine): on this two-core CPU one network call costs about as much per crop alone as in a
#: batch (6.5 against 6.0 ms), while a batch's threads wait for each other and share one
#: interpreter, so one run at a time per worker was 35-40 % faster for GK-TransT (48 runs) and
#: as fast for the dual TransT. Raise it where the network's cost per crop falls with the batch
#: (a GPU).
RUNS_PER_BATCH = 1
#: Our choice: most crops in one network call (the per-crop cost measured flat from 8 to 64,
#: benchmarks/results/bench_image_engine.json).
MAX_NETWORK_BATCH = 16


def check_workers(workers: int) -> None:
    """``ValueError`` unless ``workers`` (a count of processes) is an integer >= 1."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")


def check_image_loop(loop: ClosedLoop) -> None:
    """``ValueError`` unless ``loop`` is an image-mode run the engine can batch: an
    ``ImageFrontEnd`` and model latencies only (see the module docstring)."""
    c = loop.config
    if not isinstance(loop.front_end, ImageFrontEnd):
        raise ValueError(
            f"the image engine runs image-mode marker runs; this run's front end is "
            f"{type(loop.front_end).__name__} (measurement-model runs go to latency.batched)"
        )
    if c.observer_latency == "measured" or c.controller_latency == "measured":
        raise ValueError(
            "the image engine needs model latencies (observer_latency: model and a "
            "controller_latency model): runs that share the cores cannot measure one "
            "camera's latency; measure it unbatched with `pmspm measure-latency` and use that "
            "profile as pipeline.observer"
        )


def run_batch(loops: Sequence[ClosedLoop], max_network_batch: int = MAX_NETWORK_BATCH
              ) -> list[LoopResult]:
    """Run the image-mode ``loops`` together in this process (one thread each, their network
    calls batched; see the module docstring) and return their results in order. An exception in
    a run is raised here after the others have finished. A lone loop runs as the event loop runs
    it, in this thread (a thread and the batching would cost it about 6 % for nothing)."""
    for lp in loops:
        check_image_loop(lp)
    if len(loops) == 1:  # nothing to batch: the event loop's run itself, in this thread
        return [loops[0].run()]
    # imported here: the network services bring in torch, which only image runs need (and
    # every sweep worker would otherwise import, about 2 s a process)
    from observer.transt.service import shared_services

    results: list[LoopResult | BaseException | None] = [None] * len(loops)
    services = shared_services()

    def one(i: int) -> None:
        with ExitStack() as stack:
            for s in services:
                stack.enter_context(s.client())
            try:
                results[i] = loops[i].run()
            except BaseException as exc:  # noqa: BLE001 - raised in the caller's thread
                results[i] = exc

    with ExitStack() as stack:
        for s in services:
            stack.enter_context(s.batching(max_network_batch))
        threads = [threading.Thread(target=one, args=(i,), name=f"image-run-{i}")
                   for i in range(len(loops))]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
    for r in results:
        if isinstance(r, BaseException):
            raise r
    return [r for r in results if isinstance(r, LoopResult)]


def _run_specs(build: Callable[[Spec], ClosedLoop], specs: Sequence[Spec],
               max_network_batch: int) -> list[LoopResult]:
    """A worker's batch: build the loops here (networks from this process's services), run."""
    return run_batch([build(s) for s in specs], max_network_batch)


def _worker_init() -> None:
    """One core per worker: torch's and OpenCV's own thread pools off."""
    import cv2
    import torch

    torch.set_num_threads(1)
    cv2.setNumThreads(1)


class ImagePool:
    """Worker processes for image runs that serve several ``run_images`` calls.

    A worker's start costs seconds (spawning, importing torch and OpenCV, loading the network
    and the compiled kernels: about 6 s of CPU on the two-core machine) before its first frame;
    a caller that runs its runs in several calls (``pmspm calibrate-loss``'s batches) keeps one
    pool open across them and pays it once. Use as a context manager; the processes end when it
    closes.

    Parameters
    ----------
    workers : processes (spawned, started on the first call that needs them; torch and OpenCV
        held to one thread each).
    """

    def __init__(self, workers: int = 2) -> None:
        check_workers(workers)
        self.workers = workers
        self._closed = False
        self._executor = ProcessPoolExecutor(
            workers, mp_context=multiprocessing.get_context("spawn"), initializer=_worker_init)

    def __enter__(self) -> ImagePool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """End the workers (after the runs they are running; queued runs are dropped)."""
        self._closed = True
        self._executor.shutdown(cancel_futures=True)

    def run(self, build: Callable[[Spec], ClosedLoop], chunks: list[list[Spec]],
            max_network_batch: int, bar: tqdm) -> list[list[LoopResult]]:
        """Each chunk's results (``_run_specs`` in a worker), in the order of ``chunks``; on a
        failure the chunks not yet started are dropped and the failure is raised."""
        if self._closed:
            raise ValueError("this ImagePool is closed: open a new one")
        out: list[list[LoopResult] | None] = [None] * len(chunks)
        futures = {self._executor.submit(_run_specs, build, chunk, max_network_batch): k
                   for k, chunk in enumerate(chunks)}
        try:
            for fut in as_completed(futures):
                k = futures[fut]
                out[k] = fut.result()
                bar.update(len(chunks[k]))
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise
        return [chunk for chunk in out if chunk is not None]


def run_images(
    build: Callable[[Spec], ClosedLoop],
    specs: Sequence[Spec],
    *,
    workers: int | None = None,
    pool: ImagePool | None = None,
    runs_per_batch: int = RUNS_PER_BATCH,
    max_network_batch: int = MAX_NETWORK_BATCH,
    progress: bool = False,
) -> list[LoopResult]:
    """Run image-mode closed loops and return their results, in the order of ``specs``.

    Parameters
    ----------
    build : picklable callable spec -> ``ClosedLoop`` (an image-mode run), called in the worker
        that runs the spec (trackers hold network sessions that do not cross processes).
    specs : what ``build`` takes, one per run (e.g. ``latency.Scenario``).
    workers : processes (default 2, or ``pool``'s; 1 without a pool: in this process). With
        more than one, the processes are spawned: a script that calls this must guard its top
        level with ``if __name__ == "__main__":``.
    pool : an open ``ImagePool`` to run on (its workers stay for the next call); default a pool
        of ``workers`` for this call alone.
    runs_per_batch : runs advanced together in one process.
    max_network_batch : most crops per network call.
    progress : a progress bar over the runs.
    """
    if pool is not None and workers not in (None, pool.workers):
        raise ValueError(f"workers={workers} differs from the pool's {pool.workers}")
    n_workers = pool.workers if pool is not None else (2 if workers is None else workers)
    check_workers(n_workers)
    if runs_per_batch < 1:
        raise ValueError(f"runs_per_batch must be >= 1, got {runs_per_batch}")
    # Batches no larger than an even share, so that every worker has runs.
    size = max(1, min(runs_per_batch, -(-len(specs) // n_workers)))
    chunks = [list(specs[i : i + size]) for i in range(0, len(specs), size)]
    bar = tqdm(total=len(specs), disable=not progress, desc="image runs", unit="run")
    try:
        if pool is not None:
            out = pool.run(build, chunks, max_network_batch, bar)
        elif n_workers == 1 or len(chunks) == 1:
            out = []
            for chunk in chunks:
                out.append(_run_specs(build, chunk, max_network_batch))
                bar.update(len(chunk))
        else:
            with ImagePool(min(n_workers, len(chunks))) as own:
                out = own.run(build, chunks, max_network_batch, bar)
    finally:
        bar.close()
    return [r for chunk in out for r in chunk]
