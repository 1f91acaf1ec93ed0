"""What every ``pmspm`` command shares: the typer application, the engine and output options,
and the checks that turn a mistake into a message and exit status 2 (``_config_error``) before
any expensive work starts.

Importing this module sets ``MUJOCO_GL=egl`` and one BLAS thread (see below) before anything
imports mujoco or numpy.
"""

from __future__ import annotations

import datetime as dt
import math
import os
import re
import tempfile
from enum import Enum
from pathlib import Path
from typing import Annotated, NoReturn

os.environ.setdefault("MUJOCO_GL", "egl")  # before anything imports mujoco
# One BLAS thread, before anything imports numpy: the toolkit's linear algebra is on 3x3 to
# 20x20 matrices, where OpenBLAS's thread hand-off costs more than the work (a 3x3 ``expm``,
# called tens of thousands of times by the margins tables, took 24 ms with the default threads
# on a loaded 2-core machine and 0.08 ms with one). Sweep workers inherit it.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import typer  # noqa: E402
from pydantic import ValidationError  # noqa: E402

from plant.config_files import ConfigFileError, load_mapping  # noqa: E402

app = typer.Typer(
    help="Closed-loop co-design toolkit for a vision-measured spherical motor.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

OutOption = Annotated[Path, typer.Option(help="Folder for the results.")]


class EngineChoice(str, Enum):
    """The closed-loop engine (``latency.simulation.Engine``)."""

    auto = "auto"
    batched = "batched"
    event = "event"


EngineOption = Annotated[
    EngineChoice,
    typer.Option(help="auto (each run on the fastest engine that takes it: measurement-model "
                 "runs and groups of image runs batched, the rest on the event loop), batched "
                 "(runs advanced together: measurement-model runs in the compiled engine, "
                 "image runs with their network calls batched) or event (one run at a time; "
                 "image runs that measure their latency need it)."),
]
#: Runs per batch of the batched engine in a sweep (our choice: past the knee of the engine's
#: throughput curve, benchmarks/bench_engine.py).
SWEEP_BATCH = 256


def _config_error(exc: ValidationError | ValueError, source: str) -> NoReturn:
    """Print a configuration error naming the field(s) and exit with status 2."""
    typer.secho(f"invalid configuration in {source}:", fg=typer.colors.RED, err=True)
    if isinstance(exc, ValidationError):
        from latency.scenario import field_path

        for e in exc.errors():
            where = field_path(e["loc"]) or "(top level)"
            typer.echo(f"  {where}: {e['msg'].removeprefix('Value error, ')}", err=True)
    else:
        typer.echo(f"  {exc}", err=True)
    raise typer.Exit(code=2)


def _fail(message: str) -> NoReturn:
    """Print one error line and exit with status 2 (a usage error, as click's own)."""
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def _warn(message: str) -> None:
    typer.secho(f"warning: {message}", fg=typer.colors.YELLOW, err=True)


def _load_yaml(path: Path) -> dict:
    try:
        return load_mapping(path)
    except ConfigFileError as exc:
        _fail(str(exc))


def _number(
    name: str, value: float | None, *, low: float = 0.0, strict: bool = False,
    high: float = math.inf, why: str = "",
) -> None:
    """Exit with a message unless ``value`` (an option) is finite, above ``low`` (``> low``
    when ``strict``, else ``>= low``) and at most ``high``; None passes (the option's
    default). ``why`` explains the bounds in the message."""
    if value is None:
        return
    ok = math.isfinite(value) and (value > low if strict else value >= low) and value <= high
    if not ok:
        upper = f" and <= {high:g}" if math.isfinite(high) else ""
        _fail(f"{name} must be a finite number {'>' if strict else '>='} {low:g}{upper}, got "
              f"{value}{why}")


def _writable_folder(out: Path, option: str = "--out") -> Path:
    """Create ``out`` (a folder) if needed and check that a file can be written in it, before
    any work; exit with a message otherwise."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except (OSError, ValueError) as exc:
        reason = getattr(exc, "strerror", None) or str(exc)
        _fail(f"{option} {out}: cannot write results there ({reason})")
    return out


def _new_folder(root: Path, label: str) -> Path:
    """A new folder ``<root>/<timestamp>-<label>`` (``-2``, ``-3``... if that exists): a run
    never writes into an earlier run's folder."""
    name = f"{dt.datetime.now().strftime('%Y%m%d-%H%M%S')}-{label}"
    folder, n = root / name, 1
    while True:
        try:
            folder.mkdir(parents=True, exist_ok=False)
            return folder
        except FileExistsError:
            n += 1
            folder = root / f"{name}-{n}"


#: A Dask scheduler address: [protocol://]host:port (or 'local' for a LocalCluster).
_SCHEDULER = re.compile(r"((tcp|tls|ucx|ws|wss)://)?([A-Za-z0-9_.-]+|\[[0-9A-Fa-f:]+\]):(\d{1,5})")


def _check_workers_and_scheduler(workers: int | None, scheduler: str | None) -> None:
    if workers is not None and workers < 1:
        _fail(f"--workers must be >= 1, got {workers}")
    if scheduler is None or scheduler == "local":
        return
    m = _SCHEDULER.fullmatch(scheduler)
    if m is None or not 0 < int(m.group(4)) < 65536:
        _fail(
            f"--scheduler {scheduler!r} is neither 'local' nor a Dask scheduler address "
            "[protocol://]host:port such as tcp://127.0.0.1:8786"
        )


def _check_storage(url: str) -> None:
    """Exit with a message unless ``url`` is a database URL that optuna can open (a known
    SQLAlchemy dialect whose driver is installed; for SQLite, a folder that exists)."""
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError, NoSuchModuleError

    try:
        parsed = make_url(url)
        parsed.get_dialect()
    except (ArgumentError, NoSuchModuleError, ValueError) as exc:
        _fail(f"--storage {url!r} is not a database URL optuna can use, such as "
              f"sqlite:///runs/optuna.db ({str(exc).splitlines()[0]})")
    except ImportError as exc:
        _fail(f"--storage {url!r}: the database driver is not installed ({exc})")
    if parsed.get_backend_name() == "sqlite" and parsed.database not in (None, "", ":memory:"):
        folder = Path(parsed.database).parent
        if not folder.is_dir():
            _fail(f"--storage {url!r}: the folder {folder} of the SQLite file does not exist")


def _interrupted() -> NoReturn:
    typer.secho(
        "interrupted: the runs that finished are kept; run the same command to resume",
        fg=typer.colors.YELLOW, err=True,
    )
    raise typer.Exit(code=130)



def _names(values: list[str] | None) -> list[str] | None:
    """Option values given repeated or comma-separated (``--cases clean,blur``)."""
    if not values:
        return None
    return [v.strip() for value in values for v in value.split(",") if v.strip()]

