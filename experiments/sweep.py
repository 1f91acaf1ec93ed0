"""The sweep runner: many runs, one table, resumable, on this machine or on a Dask cluster.

* Each run is a JSON-able config (a dict). Its id is a hash of the canonical JSON of that config
  (seed included), so the same run always has the same id and a changed config a new one.
* Each run's result is one row, written atomically (temporary file, then rename) as
  ``<out>/runs/<id>.parquet``. The sweep's table is the union of those files.
* A restarted sweep skips every id whose file exists: an interrupted sweep (Ctrl-C, a killed
  worker, a crashed run) recomputes nothing that finished and loses nothing.
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
import os
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


def table(out_dir: str | Path) -> pd.DataFrame:
    """The sweep's table: the union of the finished runs' rows, sorted by run id."""
    files = sorted((Path(out_dir) / "runs").glob("*.parquet"))
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
        (``execute_batch``) and gets up to this many configs at a time, spread evenly over the
        workers.
    """
    _resolve(target)  # fail early on a bad target
    out = str(out_dir)
    Path(out).mkdir(parents=True, exist_ok=True)
    todo = pending(configs, out)
    n_workers = workers or os.cpu_count() or 1
    bar = tqdm(total=len(todo), desc="sweep", unit="run", disable=not progress)
    if not todo:
        bar.close()
        return table(out)
    if batch_size is None:
        jobs = [(execute, target, c, out) for c in todo]
    else:
        n_chunks = max(n_workers, -(-len(todo) // batch_size))
        jobs = [(execute_batch, target, list(chunk), out)
                for chunk in np.array_split(np.array(todo, dtype=object), n_chunks) if len(chunk)]
    if scheduler is None:
        with ProcessPoolExecutor(max_workers=n_workers) as pool:
            futures = {pool.submit(*job): job for job in jobs}
            for f in as_completed(futures):
                f.result()
                bar.update(_n_runs(futures[f][2]))
    else:
        from dask.distributed import Client, LocalCluster
        from dask.distributed import as_completed as dask_completed

        cluster = None
        if scheduler == "local":
            cluster = LocalCluster(
                n_workers=n_workers, threads_per_worker=1, processes=True, dashboard_address=None
            )
            client = Client(cluster)
        else:
            client = Client(scheduler)
        try:
            futures = {client.submit(*job, pure=False): job for job in jobs}
            for f in dask_completed(list(futures)):
                f.result()
                bar.update(_n_runs(futures[f][2]))
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    bar.close()
    return table(out)


def _n_runs(job_configs: dict | list[dict]) -> int:
    return len(job_configs) if isinstance(job_configs, list) else 1
