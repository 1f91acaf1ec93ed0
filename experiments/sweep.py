"""The sweep runner: many runs, one table, resumable, on this machine or on a Dask cluster.

* Each run is a JSON-able config (a dict). Its id is a hash of the canonical JSON of that config
  (seed included), so the same run always has the same id and a changed config a new one.
* Each run's result is one row, written atomically (temporary file, then rename) as
  ``<out>/runs/<id>.parquet``.
* A sweep (a list of configs) has its own id, the hash of its sorted run ids, and a manifest
  ``<out>/sweeps/<sweep id>.json`` listing its run ids. Its table is the union of exactly those
  runs' files: several sweeps may share a folder and reuse each other's finished runs (same
  content, same id), but no sweep's table shows another sweep's runs.
* A restarted sweep skips every id whose file exists: an interrupted sweep (Ctrl-C, a killed
  worker, a crashed run) recomputes nothing that finished and loses nothing.
* Local pool workers end when the sweep's process dies, even by SIGKILL (they watch their
  parent), and ignore Ctrl-C (SIGINT), which the sweep's process handles: it ends the workers
  (the runs in flight are recomputed on resume) and re-raises ``KeyboardInterrupt``. Dask
  LocalCluster workers ignore SIGINT the same way; the cluster is closed.
* A run that raises records its error and traceback in its row; the sweep goes on.
* Backends: a local process pool over this machine's cores (default), or Dask distributed
  (``scheduler="tcp://host:8786"``, or ``"local"`` for a ``LocalCluster``): the same function,
  the same files, the same table.

The run function must be importable by name (``"package.module:function"``) so that worker
processes and Dask workers can find it; it takes the config dict and returns a flat dict of
scalars.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import math
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm


def run_id(config: dict) -> str:
    """Content-derived id of a run: the first 16 hex digits of SHA-256 of its canonical JSON."""
    canonical = json.dumps(config, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(canonical.encode()).hexdigest()[:16]


#: How long to try to connect to a Dask scheduler before giving up, s (our choice).
SCHEDULER_TIMEOUT_S = 10.0


class SchedulerUnreachable(ConnectionError):
    """The Dask scheduler given by address did not answer; nothing has run."""


def sweep_id(configs: Iterable[dict]) -> str:
    """Content-derived id of a sweep: the first 16 hex digits of SHA-256 of its sorted, unique
    run ids (the order of the configs and repeated configs do not change it)."""
    ids = sorted({run_id(c) for c in configs})
    return hashlib.sha256(",".join(ids).encode()).hexdigest()[:16]


def write_manifest(configs: list[dict], out_dir: str | Path) -> Path:
    """Write ``<out_dir>/sweeps/<sweep id>.json`` (the sweep's run ids, in order, duplicates
    removed) atomically and return its path."""
    ids = list(dict.fromkeys(run_id(c) for c in configs))
    folder = Path(out_dir) / "sweeps"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{sweep_id(configs)}.json"
    tmp = folder / f".{path.stem}.{os.getpid()}.tmp"
    tmp.write_text(json.dumps({"run_ids": ids}, indent=1))
    os.replace(tmp, path)
    return path


#: How often a pool worker checks that the sweep's process is still alive, s (our choice).
PARENT_POLL_S = 0.2
_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def _watch_parent(parent_pid: int) -> None:
    """Pool worker initialiser: ignore SIGINT (the sweep's process handles Ctrl-C) and end this
    worker when the sweep's process dies. On Linux the kernel sends SIGKILL at the parent's
    death (``prctl(PR_SET_PDEATHSIG)``); everywhere, a daemon thread polls the parent pid."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)

    def poll() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    if os.getppid() != parent_pid:  # the parent died before the kernel watch was set
        os._exit(1)
    threading.Thread(target=poll, daemon=True, name="watch-parent").start()


def _resolve(target: str) -> Callable[[dict], dict]:
    module, _, name = target.partition(":")
    if not name:
        raise ValueError(f"run function must be 'package.module:function', got {target!r}")
    return getattr(importlib.import_module(module), name)


def _flatten(prefix: str, value, out: dict) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f"{prefix}.{k}" if prefix else str(k), v, out)
    elif isinstance(value, list | tuple):
        out[prefix] = json.dumps(value)
    else:
        out[prefix] = value


def execute(target: str, config: dict, out_dir: str) -> str:
    """Run one config and write its row atomically. Returns the run id. Never raises for an
    error inside the run: the row then carries ``error`` and ``traceback``."""
    try:
        result: dict | Exception = _resolve(target)(config)
    except Exception as exc:  # noqa: BLE001 (a failed run is data, not a crash of the sweep)
        result = exc
    return _write_row(config, result, out_dir)


def execute_batch(target: str, configs: list[dict], out_dir: str) -> list[str]:
    """Run configs together with a batch run function (configs -> one result dict, or the
    exception, per config, in order) and write each row as ``execute`` does. If the batch
    function itself raises, every config of the batch gets that error."""
    try:
        results: list[dict | Exception] = list(_resolve(target)(configs))
    except Exception as exc:  # noqa: BLE001
        results = [exc] * len(configs)
    return [_write_row(c, r, out_dir) for c, r in zip(configs, results, strict=True)]


def _write_row(config: dict, result: dict | Exception, out_dir: str) -> str:
    rid = run_id(config)
    row: dict = {"run_id": rid}
    _flatten("config", config, row)
    if isinstance(result, Exception):
        row["error"] = f"{type(result).__name__}: {result}"
        row["traceback"] = "".join(traceback.format_exception(result))
    else:
        row.update({f"result.{k}": v for k, v in result.items()})
        row["error"] = ""
        row["traceback"] = ""
    folder = Path(out_dir) / "runs"
    folder.mkdir(parents=True, exist_ok=True)
    tmp = folder / f".{rid}.{os.getpid()}.tmp"
    pd.DataFrame([row]).to_parquet(tmp)
    os.replace(tmp, folder / f"{rid}.parquet")
    return rid


def table(out_dir: str | Path, run_ids: Iterable[str] | None = None) -> pd.DataFrame:
    """The finished rows of the runs ``run_ids`` (a sweep's, ``sweep_id``), or of every run in
    the folder when None, sorted by run id."""
    folder = Path(out_dir) / "runs"
    if run_ids is None:
        files = sorted(folder.glob("*.parquet"))
    else:
        files = [f for f in (folder / f"{r}.parquet" for r in sorted(set(run_ids))) if f.exists()]
    if not files:
        return pd.DataFrame()
    df = pd.concat([pd.read_parquet(f) for f in files], ignore_index=True)
    return df.sort_values("run_id").reset_index(drop=True)


def pending(configs: Iterable[dict], out_dir: str | Path) -> list[dict]:
    """The configs whose result file does not exist yet (duplicates removed)."""
    done = {p.stem for p in (Path(out_dir) / "runs").glob("*.parquet")}
    seen, todo = set(), []
    for c in configs:
        rid = run_id(c)
        if rid not in done and rid not in seen:
            seen.add(rid)
            todo.append(c)
    return todo


def run_sweep(
    target: str,
    configs: list[dict],
    out_dir: str | Path,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = True,
    batch_size: int | None = None,
) -> pd.DataFrame:
    """Run every config not yet done and return the sweep's table.

    Parameters
    ----------
    target : "package.module:function" of the run function.
    configs : the runs (JSON-able dicts).
    out_dir : folder of the sweep (``runs/`` inside holds one Parquet file per run).
    scheduler : None for a local process pool; ``"local"`` for a Dask ``LocalCluster``; or a
        Dask scheduler address such as ``"tcp://host:8786"``.
    workers : local processes or LocalCluster workers (default: this machine's cores).
    batch_size : None: ``target`` runs one config. A number: ``target`` is a batch run function
        (``execute_batch``) and gets up to this many configs at a time, in a number of batches
        that is a multiple of the workers, of sizes differing by at most one.

    Returns
    -------
    The table of exactly these configs' runs (``table`` of their ids), whichever sweep of the
    same folder computed them; ``<out_dir>/sweeps/<sweep_id>.json`` lists them.
    """
    _resolve(target)  # fail early on a bad target
    out = str(out_dir)
    Path(out).mkdir(parents=True, exist_ok=True)
    write_manifest(configs, out)
    ids = [run_id(c) for c in configs]
    todo = pending(configs, out)
    n_workers = workers or os.cpu_count() or 1
    bar = tqdm(total=len(todo), desc="sweep", unit="run", disable=not progress)
    if not todo:
        bar.close()
        return table(out, ids)
    if batch_size is None:
        jobs = [(execute, target, c, out) for c in todo]
    else:
        # a multiple of the workers, so that each runs as many batches and none waits alone
        # through the last one
        per_worker = math.ceil(math.ceil(len(todo) / batch_size) / n_workers)
        n_chunks = per_worker * n_workers
        jobs = [(execute_batch, target, list(chunk), out)
                for chunk in np.array_split(np.array(todo, dtype=object), n_chunks) if len(chunk)]
    if scheduler is None:
        _run_in_processes(jobs, n_workers, bar)
    else:
        _run_on_dask(jobs, scheduler, n_workers, bar)
    bar.close()
    return table(out, ids)


def _run_in_processes(jobs: list[tuple], n_workers: int, bar: tqdm) -> None:
    """Run ``jobs`` (function and arguments) in a local pool of ``n_workers`` processes that
    end with this one, counting the finished runs on ``bar``; on Ctrl-C or a failure the
    workers are ended at once (the runs in flight are recomputed on resume)."""
    pool = ProcessPoolExecutor(
        max_workers=n_workers, initializer=_watch_parent, initargs=(os.getpid(),)
    )
    try:
        futures = {pool.submit(*job): job for job in jobs}
        for f in as_completed(futures):
            f.result()
            bar.update(_n_runs(futures[f][2]))
    except BaseException:
        # Ctrl-C or a failure of the pool: stop now; the runs in flight are lost and
        # recomputed on resume. (Python < 3.14 has no public way to end the workers.)
        workers = list((pool._processes or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for worker in workers:
            worker.terminate()
        raise
    pool.shutdown()


def _run_on_dask(jobs: list[tuple], scheduler: str, n_workers: int, bar: tqdm) -> None:
    """Run ``jobs`` (function and arguments) on Dask: a ``LocalCluster`` of ``n_workers``
    processes for ``scheduler="local"``, else the scheduler at that address
    (``SchedulerUnreachable`` within ``SCHEDULER_TIMEOUT_S``), counting the finished runs on
    ``bar``; the client (and a local cluster) is closed at the end."""
    from dask.distributed import Client, LocalCluster
    from dask.distributed import as_completed as dask_completed

    cluster = None
    if scheduler == "local":
        # The worker processes inherit an ignored SIGINT: a Ctrl-C reaches this process
        # only, which closes the cluster, instead of every worker printing a traceback.
        handler = signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            cluster = LocalCluster(
                n_workers=n_workers, threads_per_worker=1, processes=True,
                dashboard_address=None,
            )
        finally:
            signal.signal(signal.SIGINT, handler)
        client = Client(cluster)
    else:
        try:
            client = Client(scheduler, timeout=SCHEDULER_TIMEOUT_S)
        except OSError as exc:  # distributed raises OSError (or TimeoutError) on failure
            bar.close()
            raise SchedulerUnreachable(
                f"cannot reach the Dask scheduler {scheduler!r} within "
                f"{SCHEDULER_TIMEOUT_S:g} s ({exc})"
            ) from None
    try:
        futures = {client.submit(*job, pure=False): job for job in jobs}
        for f in dask_completed(list(futures)):
            f.result()
            bar.update(_n_runs(futures[f][2]))
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _n_runs(job_configs: dict | list[dict]) -> int:
    return len(job_configs) if isinstance(job_configs, list) else 1
