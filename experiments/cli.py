"""The ``pmspm`` command line (typer). ``pmspm --help`` lists the commands; every command's
``--help`` shows an example. One module of about 860 lines: one typer application, each command a
thin function that checks its arguments and calls the module that does the work.

Every mistake on the command line (a file that is not a YAML mapping, a field out of range, a
combination that cannot run, a non-finite or negative number, an output folder that cannot be
written, an unknown scheduler or storage) exits with status 2 and a message that names the
problem, without a traceback, before any expensive work starts (docs/reliability.md).
Settings that run but are far outside what the plant can do print a warning with the reason.
A Ctrl-C exits with status 130 and says that finished runs are kept.
"""

from __future__ import annotations

import datetime as dt
import itertools
import json
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

from experiments.config_files import ConfigFileError, load_mapping  # noqa: E402
from latency.models import seed_latency_ms  # noqa: E402
from observer.tracking import PAIR_TRACKER_DESCRIPTIONS  # noqa: E402

app = typer.Typer(
    help="Closed-loop co-design toolkit for a vision-measured spherical motor.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

OutOption = Annotated[Path, typer.Option(help="Folder for the results.")]


class EngineChoice(str, Enum):
    """The closed-loop engine (``experiments.scenario.Engine``)."""

    batched = "batched"
    event = "event"


EngineOption = Annotated[
    EngineChoice | None,
    typer.Option(help="batched (runs advanced together: measurement-model runs in the compiled "
                 "engine, image runs with their network calls batched) or event (one run at a "
                 "time; image runs that measure their latency need it). Default: batched for "
                 "measurement-model scenarios, event for image-in-the-loop ones."),
]
#: Runs per batch of the batched engine in a sweep (our choice: past the knee of the engine's
#: throughput curve, benchmarks/bench_engine.py).
SWEEP_BATCH = 256


def _config_error(exc: ValidationError | ValueError, source: str) -> NoReturn:
    """Print a configuration error naming the field(s) and exit with status 2."""
    typer.secho(f"invalid configuration in {source}:", fg=typer.colors.RED, err=True)
    if isinstance(exc, ValidationError):
        for e in exc.errors():
            where = ".".join(str(p) for p in e["loc"]) or "(top level)"
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


@app.command()
def study(
    out: OutOption = Path("runs"),
    quick: Annotated[bool, typer.Option(
        help="A small study (a minute) for a smoke test: 2 delays, 2 seeds, 1.5 s runs.")] = False,
    workers: Annotated[int | None, typer.Option(help="Local worker processes.")] = None,
    scheduler: Annotated[
        str | None, typer.Option(help="Dask scheduler address, or 'local' for a LocalCluster.")
    ] = None,
    n_seeds: Annotated[
        int | None,
        typer.Option(help="Seeds per closed-loop point (default 10; --quick: 2)."),
    ] = None,
    engine: EngineOption = None,
    motor_file: Annotated[
        Path | None, typer.Option(help="Motor YAML (examples/motor.yaml); default the seed's.")
    ] = None,
    camera_file: Annotated[
        Path | None, typer.Option(help="Camera YAML (pmspm calibrate, examples/camera.yaml).")
    ] = None,
    full: Annotated[
        bool, typer.Option(help="The image-engine section at 32 reference seeds per point "
                           "instead of 8, GK-TransT and the dual TransT each at both of the "
                           "seed's latencies (the default: each at its own).")
    ] = False,
    fixed_reference: Annotated[
        bool, typer.Option(help="Fixed-reference mode: every run on the same random reference "
                           "(noise-only spread); default: each run's drawn from its seed.")
    ] = False,
) -> None:
    """The headline study: margins, tracking loss and error against vision delay, PID vs MPC,
    each tracker's loss from its calibrated model and from its own image-in-the-loop runs.

    Writes runs/<timestamp>-study/ with report.md, report.html, PNG plots and Parquet tables.
    With --motor-file / --camera-file the analysis and the sweeps use that motor and camera.

    Example: pmspm study --out runs --workers 2 --motor-file examples/motor.yaml
    """
    from experiments.study import DUAL_MS, GK_MS, StudyConfig, run_study, study_plant

    _check_workers_and_scheduler(workers, scheduler)
    _writable_folder(out)
    try:
        extra = {} if n_seeds is None else {"n_seeds": n_seeds}
        if engine is not None:
            extra["engine"] = engine.value
        if full:
            extra |= {"image_loop_n_seeds": 32, "image_loop_delays": "both"}
        if fixed_reference:
            extra["reference_mode"] = "fixed"
        cfg = StudyConfig(workers=workers, scheduler=scheduler, motor_file=motor_file,
                          camera_file=camera_file, **extra)
        study_plant(cfg)
    except (ValidationError, ValueError) as exc:
        _config_error(exc, "options")
    if quick:
        cfg = cfg.model_copy(
            update={"delays_ms": (GK_MS, DUAL_MS), "max_rates_rad_s": (3.0,), "duration_s": 1.5,
                    "latency_frames": 10, "n_seeds": n_seeds or 2,
                    "image_loop_rates_rad_s": (3.0,), "image_loop_n_seeds": 1,
                    "image_loop_duration_s": 1.5}
        )
    try:
        folder = run_study(out, cfg)
    except KeyboardInterrupt:
        _interrupted()
    typer.echo(f"report: {folder / 'report.html'}")


@app.command()
def simulate(
    scenario: Annotated[Path, typer.Argument(help="Scenario YAML (experiments.scenario).")],
    out: OutOption = Path("runs"),
    engine: EngineOption = None,
) -> None:
    """One closed-loop run: writes its tables (Parquet) and a plot into a new folder
    <out>/<timestamp>-simulate-<name>/, prints the summary.

    Example: pmspm simulate examples/scenario.yaml --out runs --engine event
    """
    from experiments.scenario import Scenario, check_engine, describe_path, run

    try:
        s = Scenario.model_validate(_load_yaml(scenario))
        if engine is not None:
            check_engine(s, engine.value)
    except (ValidationError, ValueError) as exc:
        _config_error(exc, str(scenario))
    for reason in s.reach_warnings():
        _warn(reason)
    _writable_folder(out)
    typer.echo(describe_path(s, None if engine is None else engine.value))
    try:
        result = run(s, progress=True, engine=None if engine is None else engine.value)
    except KeyboardInterrupt:
        _interrupted()
    folder = result.save(_new_folder(out, f"simulate-{s.name}"))
    _plot_run(result.steps, folder / "run.png", s.name)
    for k, v in result.summary.items():
        typer.echo(f"{k:>28s}  {v:.6g}")
    typer.echo(f"tables: {folder}")


def _plot_run(steps, path: Path, title: str) -> None:  # noqa: ANN001 - LoopResult.steps
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 5.5))
    ax = fig.subplots(2, 1, sharex=True)
    ax[0].plot(steps.t_s, steps.tilt_deg, label="tilt")
    ax[0].plot(steps.t_s, steps.ref_tilt_deg, "k--", lw=0.8, label="reference tilt")
    ax[0].set_ylabel("tilt (deg)")
    ax[0].legend()
    ax[1].semilogy(steps.t_s, steps.error_deg)
    ax[1].set_ylabel("geodesic error (deg)")
    ax[1].set_xlabel("time (s)")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


@app.command()
def margins(
    crossover_rad_s: Annotated[float, typer.Option(help="PID crossover, rad/s.")] = 10.0,
    frame_rate_hz: Annotated[
        float | None, typer.Option(help="Camera frame rate, Hz (default: PlantParams.camera).")
    ] = None,
    delay_ms: Annotated[
        float, typer.Option(help="Vision delay for Bode/Nyquist, ms.")
    ] = seed_latency_ms("gk_transt"),
    observer: Annotated[
        str,
        typer.Option(help="sequential (drops frames while busy, as the study) or pipelined."),
    ] = "sequential",
    out: OutOption = Path("runs"),
) -> None:
    """Margins of the per-axis PID loop as it runs (discrete C(z) at the observer's update
    period, exact delay); Bode and Nyquist plots and the margins against delay 0–60 ms.

    Example: pmspm margins --crossover-rad-s 10 --delay-ms 31.23 --observer sequential
    """
    from controller.pid import PIDConfig, PIDController, reach_warnings
    from experiments.study import StudyConfig, margins_table, pid_axis_margins, pid_headroom_s
    from latency.margins import attitude_plant, loop_model, plot_bode, plot_nyquist
    from plant.params import PlantParams

    beyond = " (beyond it the margin computation does not finish)"
    _number("--crossover-rad-s", crossover_rad_s, low=MIN_CROSSOVER_RAD_S,
            high=MAX_CROSSOVER_RAD_S, why=beyond)
    if frame_rate_hz is not None:
        _number("--frame-rate-hz", frame_rate_hz, strict=True)
    _number("--delay-ms", delay_ms, high=MAX_DELAY_MS, why=beyond)
    if observer not in ("sequential", "pipelined"):
        _fail(f"--observer must be sequential or pipelined, got {observer!r}")
    try:
        cfg = PIDConfig(crossover_rad_s=crossover_rad_s)
        p = PlantParams()
        if frame_rate_hz is not None:
            camera = p.camera.model_dump() | {"frame_rate_hz": frame_rate_hz}
            p = PlantParams.model_validate(p.model_dump() | {"camera": camera})
    except ValidationError as exc:
        _config_error(exc, "options")
    folder = _writable_folder(
        Path(out) / f"margins-{crossover_rad_s:g}rad_s-{delay_ms:g}ms-{observer}"
    )
    for reason in reach_warnings(PIDController(cfg, p), p.camera.frame_rate_hz):
        _warn(reason)
    timing, m = pid_axis_margins(p, crossover_rad_s, delay_ms / 1e3, observer)
    typer.echo(f"case: {timing.describe()}")
    typer.echo(m.summary())
    for line in m.crossover_lines():
        typer.echo(f"  {line}")
    pid = PIDController(cfg, p)
    model = loop_model(
        attitude_plant(float(pid.J[1]), p.rotor.viscous_Nms_per_rad),
        pid.discrete_transfer_function(timing.update_period_s, axis=1),
        delay_s=timing.delay_s,
    )
    plot_bode(model, m).savefig(folder / "bode.png", dpi=110)
    plot_nyquist(model, m).savefig(folder / "nyquist.png", dpi=110)
    table = margins_table(p, StudyConfig(crossover_rad_s=crossover_rad_s), modes=(observer,))
    table.to_parquet(folder / "margins_vs_delay.parquet")
    head = pid_headroom_s(p, crossover_rad_s, delay_ms / 1e3, observer)
    if head == head:  # NaN when the loop is already unstable
        typer.echo(
            f"headroom: {1e3 * head:.2f} ms more vision delay before the loop is unstable "
            "(scanned through the pipeline)"
        )
    typer.echo(f"plots and table: {folder}")


#: Most runs in one sweep file (our choice: a grid this large is a typo, and expanding it
#: would take the memory before any run starts).
MAX_SWEEP_RUNS = 100_000


#: Range of ``margins --crossover-rad-s`` and largest ``--delay-ms`` (our choice: the margin
#: computation took up to 10 s at these bounds and did not finish at 1e9 rad/s or 1e300 ms).
MIN_CROSSOVER_RAD_S, MAX_CROSSOVER_RAD_S, MAX_DELAY_MS = 1e-3, 1e4, 1000.0


def _expand(base: dict, grid: dict) -> list[dict]:
    """All combinations of ``grid`` (dotted paths -> lists of values) applied to ``base``.

    Raises ``ValueError`` naming the key for a grid that is not a mapping of non-empty lists,
    a dotted path with an empty part or through a field that is not a mapping, or more than
    ``MAX_SWEEP_RUNS`` runs."""
    if not isinstance(base, dict):
        raise ValueError(f"base must be a mapping of scenario fields, got {type(base).__name__}")
    if not isinstance(grid, dict):
        raise ValueError(f"grid must be a mapping of field paths to lists, got "
                         f"{type(grid).__name__}")
    for key, values in grid.items():
        if not isinstance(key, str) or not all(key.split(".")):
            raise ValueError(f"grid key {key!r} must be a dotted field path such as seed or "
                             "pipeline.frame_rate_hz")
        if not isinstance(values, list) or not values:
            raise ValueError(f"grid.{key} must be a non-empty list of values, got {values!r}")
    n_runs = math.prod(len(v) for v in grid.values())
    if n_runs > MAX_SWEEP_RUNS:
        raise ValueError(f"the grid has {n_runs} runs, more than {MAX_SWEEP_RUNS}")
    keys = list(grid)
    out = []
    for values in itertools.product(*(grid[k] for k in keys)):
        cfg = json.loads(json.dumps(base))
        for key, value in zip(keys, values, strict=True):
            node = cfg
            *parents, leaf = key.split(".")
            for p in parents:
                node = node.setdefault(p, {})
                if not isinstance(node, dict):
                    raise ValueError(f"grid key {key!r}: {p} is not a mapping in the base")
            node[leaf] = value
        out.append(cfg)
    return out


# Help texts are rich markup: "[" before a letter opens a style tag and is swallowed unless
# escaped as "\\[" (as in the sweep example below).
@app.command()
def sweep(
    spec: Annotated[Path, typer.Argument(help="Sweep YAML: 'base' scenario + 'grid' of lists.")],
    out: OutOption = Path("runs/sweep"),
    workers: Annotated[int | None, typer.Option(help="Local worker processes.")] = None,
    scheduler: Annotated[
        str | None, typer.Option(help="Dask scheduler address, or 'local'.")
    ] = None,
    engine: EngineOption = None,
) -> None:
    """A grid of scenarios, resumable (finished runs are skipped), local or on Dask. The table
    <out>/sweep-<id>.parquet holds exactly this grid's runs (the id is the grid's content), also
    when other grids share the folder and its finished runs.

    The YAML has a 'base' scenario and a 'grid' mapping dotted field paths to lists, e.g.

    grid:
      pipeline.observer.value_s: [0.01633, 0.03123]
      controller.kind: \\[pid, mpc]
      seed: [0, 1]

    Example: pmspm sweep examples/sweep.yaml --out runs/sweep --scheduler tcp://host:8786
    """
    from experiments.scenario import Scenario, check_engine
    from experiments.sweep import SchedulerUnreachable, run_sweep, sweep_id

    _check_workers_and_scheduler(workers, scheduler)
    data = _load_yaml(spec)
    unknown = set(data) - {"base", "grid"}
    if unknown:
        _config_error(ValueError(f"unknown top-level keys {sorted(unknown)}; use base, grid"),
                      str(spec))
    try:
        configs = _expand(data.get("base") or {}, data.get("grid") or {})
    except (ValueError, TypeError) as exc:
        _config_error(ValueError(str(exc)), str(spec))
    scenarios = []
    for i, c in enumerate(configs):
        try:
            scenarios.append(Scenario.model_validate(c))
            if engine is not None:
                check_engine(scenarios[-1], engine.value)
        except (ValidationError, ValueError) as exc:
            _config_error(exc, f"{spec} (run {i + 1} of {len(configs)})")
    for reason in dict.fromkeys(r for s in scenarios for r in s.reach_warnings()):
        _warn(reason)
    _writable_folder(out)
    try:
        if engine == EngineChoice.event:
            df = run_sweep("experiments.scenario:run_summary", configs, out, scheduler, workers)
        else:
            df = run_sweep("experiments.scenario:run_summaries", configs, out, scheduler,
                           workers, batch_size=SWEEP_BATCH)
    except SchedulerUnreachable as exc:
        _fail(str(exc))
    except KeyboardInterrupt:
        _interrupted()
    path = Path(out) / f"sweep-{sweep_id(configs)}.parquet"
    df.to_parquet(path)
    failed = int((df.error != "").sum()) if "error" in df else 0
    typer.echo(f"{len(df)} runs ({failed} failed): {path}")


@app.command("measure-latency")
def measure_latency(
    tracker: Annotated[
        str,
        typer.Option(
            help="kcf or csrt (GK assistance on top), gk_transt, dual_transt (the shipped "
            "TransT network), orb (the textured rotor's ORB-AEKF), or all of them."
        ),
    ] = "kcf",
    frames: Annotated[int, typer.Option(help="Frames to time (1 to 100000).")] = 200,
    out: OutOption = Path("runs"),
) -> None:
    """Measure the observer's per-frame latency on a rendered sequence; writes an empirical
    latency profile that a scenario can load (as pipeline.observer) into a new folder
    <out>/<timestamp>-measure-latency-<tracker>/latency.json.

    Example: pmspm measure-latency --tracker all --frames 100 --out runs
    """
    import numpy as np

    from latency.profile import (
        measure_locator_latency,
        measure_orb_latency,
        measure_pair_tracker_latency,
    )
    from observer.trackers import make_pair_tracker
    from plant.params import PlantParams

    names = ("kcf", "csrt", "gk_transt", "dual_transt", "orb")
    if tracker not in (*names, "all"):
        _fail(f"--tracker must be one of {', '.join(names)} or all, got {tracker!r}")
    if not 1 <= frames <= 100_000:
        _fail(f"--frames must be between 1 and 100000, got {frames}")
    _writable_folder(out)
    p = PlantParams()
    folder = _new_folder(out, f"measure-latency-{tracker}")
    for name in names if tracker == "all" else (tracker,):
        try:
            if name == "orb":
                prof = measure_orb_latency(p, "aekf", n_frames=frames, progress=True)
                label = "ORB-AEKF"
            elif name in ("gk_transt", "dual_transt"):
                prof = measure_pair_tracker_latency(p, make_pair_tracker(name, p),
                                                    n_frames=frames, progress=True)
                label = {"gk_transt": "GK-TransT", "dual_transt": "dual TransT"}[name]
            else:
                locator = make_pair_tracker(f"{name}_gk", p)
                prof = measure_locator_latency(p, locator, n_frames=frames, progress=True)
                label = f"{name}+GK"
        except KeyboardInterrupt:
            _interrupted()
        path = folder / ("latency.json" if tracker != "all" else f"latency_{name}.json")
        prof.save(path)
        s = np.asarray(prof.samples_s) * 1e3
        typer.echo(f"{label}: median {np.median(s):.2f} ms, p95 {np.percentile(s, 95):.2f} ms")
        typer.echo(f"profile: {path}")


@app.command("calibrate-loss")
def calibrate_loss(
    tracker: Annotated[str, typer.Option(
        help="gk_transt, dual_transt, kcf_gk (OpenCV KCF inside the GK assistance) or k2cf.")],
    seeds: Annotated[int, typer.Option(help="Reference seeds per fit point (>= 1).")] = 6,
    holdout_seeds: Annotated[int, typer.Option(
        help="Reference seeds per held-out point (>= 1).")] = 4,
    duration_s: Annotated[float, typer.Option(help="Simulated time per run, s (> 0.5).")] = 3.0,
    workers: Annotated[int, typer.Option(help="Worker processes of the image engine.")] = 2,
    work: Annotated[Path | None, typer.Option(
        help="Folder of the resumable records (default runs/calibrate-loss-<tracker>).")] = None,
) -> None:
    """Calibrate a tracker's loss model on its own image-in-the-loop runs and write it as the
    package's latency/loss_models/<tracker>.json (scenarios select it with
    measurement: {loss: {kind: calibrated, tracker: NAME}}). Resumable: run it again with the
    same --work folder to continue. Prints the held-out agreement table.

    Example: pmspm calibrate-loss --tracker gk_transt --seeds 6
    """
    from experiments.loss_calibration import CalibrationDesign, calibrate
    from latency.loss_model import CALIBRATABLE

    if tracker not in CALIBRATABLE:
        _fail(f"--tracker must be one of {', '.join(CALIBRATABLE)}, got {tracker!r}")
    if seeds < 1 or holdout_seeds < 1 or workers < 1 or not duration_s > 0.5:
        _fail("--seeds, --holdout-seeds and --workers must be >= 1 and --duration-s > 0.5")
    design = CalibrationDesign(fit_seeds=seeds, holdout_seeds=holdout_seeds,
                               duration_s=duration_s)
    try:
        path, data = calibrate(tracker, design, work, workers)
    except KeyboardInterrupt:
        _interrupted()
    except ValueError as exc:
        _fail(str(exc))
    typer.echo(f"{tracker}: {data.n_frames} frames from {data.n_runs} runs; "
               f"noise {data.noise_sigma_px:.2f} px; written to {path}")
    for row in data.validation:
        il, ml = row["image_lost_frame_fraction"], row["model_lost_frame_fraction"]
        typer.echo(f"  {row['delay_ms']:6.2f} ms {row['rate_rad_s']:4.1f} rad/s: lost frames "
                   f"image {il[0]:.3f} [{il[1]:.3f}, {il[2]:.3f}] model {ml[0]:.3f} "
                   f"[{ml[1]:.3f}, {ml[2]:.3f}]; {'agree' if row['agree'] else 'DIFFER'}")


def _names(values: list[str] | None) -> list[str] | None:
    """Option values given repeated or comma-separated (``--cases clean,blur``)."""
    if not values:
        return None
    return [v.strip() for value in values for v in value.split(",") if v.strip()]


@app.command("bench-trackers")
def bench_trackers(
    seeds: Annotated[int, typer.Option(help="Validation seeds (7,000,000 + i), >= 1.")] = 2,
    frames: Annotated[
        int,
        typer.Option(help="Frames per sequence; clean >= 2, occlusion >= 116, blur >= 161."),
    ] = 300,
    cases: Annotated[
        list[str] | None,
        typer.Option(help="clean, occlusion, blur (repeat or comma-separate; default all)."),
    ] = None,
    trackers: Annotated[
        list[str] | None,
        typer.Option(
            help="gk_transt, gk_transt_norefine, dual_transt, dual_transt_refine, kcf, csrt, "
            "kcf_numpy, k2cf (repeat or comma-separate; default all)."
        ),
    ] = None,
    stand_in: Annotated[
        bool,
        typer.Option(
            "--stand-in",
            help="numpy KCF in place of the TransT network: a quick plumbing run "
            "(rows gk_standin, dual_standin; not TransT numbers).",
        ),
    ] = False,
    out: Annotated[
        Path | None,
        typer.Option(help="Output folder (default: a new runs/<timestamp>-bench-trackers/)."),
    ] = None,
    torch_threads: Annotated[int, typer.Option(help="torch intra-op threads.")] = 1,
) -> None:
    """The tracking benchmark of seed 000 §4 (GK-TransT, dual TransT, KCF, CSRT, K²CF) on the
    validation sequences, clean and with the seed's occlusion and blur cases; --cases also takes
    the hard cases and held-out appearance families of experiments.sequences (ALL_CASES).

    Writes tracking_metrics.csv (one row per run), precision and error plots per case and
    report.md (Table 1 beside the seed's, precision at 20 px, success AUC, the targets).
    The same code path as benchmarks/bench_tracking.py.

    Example: pmspm bench-trackers --seeds 1 --cases clean --trackers gk_transt,kcf --stand-in
    """
    # Before torch loads its OpenMP runtime: idle threads sleep instead of spinning
    # (docs/tracking.md; as benchmarks/bench_tracking.py).
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    from tqdm import tqdm

    from experiments import tracking_bench as tb
    from experiments.sequences import CASES

    case_list = _names(cases) or list(CASES)
    tracker_list = _names(trackers) or list(tb.DEFAULT_TRACKERS)
    if torch_threads < 1:
        _fail(f"--torch-threads must be >= 1, got {torch_threads}")
    try:  # TransT rows without the shipped network: fail here, not omit them silently
        tb.tracker_factories(tracker_list, stand_in, require_transt=True)
    except ValueError as exc:
        _config_error(exc, "options")
    new_folder = out is None
    out = _new_folder(_writable_folder(Path("runs")), "bench-trackers") if new_folder else (
        _writable_folder(out))
    if not stand_in and any(t.startswith(("gk_transt", "dual_transt")) for t in tracker_list):
        try:
            import torch

            torch.set_num_threads(torch_threads)
        except ImportError:
            pass
    bar = tqdm(total=seeds * len(case_list) * max(frames - 1, 0), desc="bench-trackers",
               unit="frame")
    try:
        report = tb.run_tracking_benchmark(
            out, seeds=seeds, frames=frames, cases=case_list, trackers=tracker_list,
            stand_in=stand_in, progress=lambda msg: bar.set_postfix_str(msg, refresh=True),
            on_step=lambda: bar.update(1), require_transt=True,
        )
    except ValueError as exc:  # the options, checked before any sequence is rendered
        bar.close()
        if new_folder and not any(out.iterdir()):
            out.rmdir()
        _config_error(exc, "options")
    except KeyboardInterrupt:
        bar.close()
        _interrupted()
    bar.close()
    title = "# Tracking benchmark (seed 000 §4)"
    if stand_in:
        title += " [numpy-KCF stand-in for the TransT network]"
    command = "pmspm bench-trackers " + " ".join(
        [f"--seeds {seeds}", f"--frames {frames}", f"--cases {','.join(case_list)}",
         f"--trackers {','.join(tracker_list)}"] + (["--stand-in"] if stand_in else [])
    )
    (out / "report.md").write_text(f"{title}\n\n`{command}`\n\n{report.notes}\n")
    typer.echo(tb.markdown_table(report.table1[["algorithm", "fps", "latency_median_ms",
                                                "seed_latency_ms"]], ".2f"))
    typer.echo(tb.markdown_table(report.summary[["tracker", "case", "main_precision_20px",
                                                 "aux_precision_20px"]]))
    for line in report.checks:
        typer.echo(f"- {line}")
    typer.echo(f"results: {out}")


@app.command("tune-kalman")
def tune_kalman_cmd(
    out: OutOption = Path("runs/tune-kalman"),
    delays_ms: Annotated[
        list[float] | None, typer.Option(help="Vision delays, ms (repeat the option).")
    ] = None,
    grid_points: Annotated[
        int, typer.Option(help="Log-spaced grid points per axis (q, r); the seed's value is added "
                          "when it is not one of them (an even count gets one more).")
    ] = 5,
    trials: Annotated[int, typer.Option(help="Optuna TPE trials per delay.")] = 20,
    duration_s: Annotated[float, typer.Option(help="Simulated time per run, s.")] = 3.0,
    workers: Annotated[int | None, typer.Option(help="Local worker processes.")] = None,
    scheduler: Annotated[
        str | None, typer.Option(help="Dask scheduler address, or 'local'.")
    ] = None,
    storage: Annotated[
        str | None, typer.Option(help="Optuna storage URL (default: SQLite in the output).")
    ] = None,
    engine: EngineOption = None,
) -> None:
    """Tune the pixel Kalman filter's Q/R against closed-loop cost (not pixel error), grid +
    optuna, and compare with the seed's Q = 0.01·I4, R = 0.1·I2 on held-out seeds, with the phase
    margin of each loop.

    Example: pmspm tune-kalman --delays-ms 16.33 --delays-ms 31.23 --trials 20 --workers 2
    """
    from experiments.tuning import (
        DEFAULT_DELAYS_S,
        GRID_DECADES,
        SEED_Q_SCALE,
        SEED_R_SCALE,
        TuningObjective,
        log_grid,
        tune_kalman,
    )

    if not (2 <= grid_points <= 100 and trials >= 0):
        _fail(f"need 2 <= --grid-points <= 100 and --trials >= 0, got {grid_points} and "
              f"{trials}")
    _number("--duration-s", duration_s, strict=True)
    for d in delays_ms or []:
        _number("--delays-ms", d)
    delays = tuple(d / 1e3 for d in delays_ms) if delays_ms else DEFAULT_DELAYS_S
    try:  # the scenarios of the runs, validated here rather than in the workers
        for d in delays:
            TuningObjective(delay_s=d, duration_s=duration_s).configs(SEED_Q_SCALE, SEED_R_SCALE)
    except (ValidationError, ValueError) as exc:
        _config_error(exc, "options")
    _check_workers_and_scheduler(workers, scheduler)
    _writable_folder(out)
    if storage is not None:
        _check_storage(storage)
    nq = len(log_grid(SEED_Q_SCALE, grid_points, GRID_DECADES))
    nr = len(log_grid(SEED_R_SCALE, grid_points, GRID_DECADES))
    typer.echo(
        f"grid: {nq} x {nr} (q, r) points per delay, {len(delays)} delay(s)"
        + (" (the seed's q and r are added to the grid: they are not among the "
           f"{grid_points} log-spaced values)" if (nq, nr) != (grid_points, grid_points) else "")
        + f"; then {trials} optuna trial(s) per delay and the held-out comparison"
    )
    try:
        result = tune_kalman(
            out,
            delays_s=delays,
            grid_points=grid_points,
            n_trials=trials,
            duration_s=duration_s,
            scheduler=scheduler,
            workers=workers,
            storage=storage,
            engine="batched" if engine is None else engine.value,
        )
    except KeyboardInterrupt:
        _interrupted()
    typer.echo("\n".join(result.summary_lines()))
    typer.echo(f"results: {out}")


@app.command()
def track(
    source: Annotated[str, typer.Argument(help="Video file, image folder, camera index or URL.")],
    out: OutOption = Path("track_run"),
    tracker: Annotated[str, typer.Option(help="Pair tracker: " + "; ".join(
        f"{k} = {v}" for k, v in PAIR_TRACKER_DESCRIPTIONS.items()) + ".")] = "gk_transt",
    boxes: Annotated[
        str | None,
        typer.Option(help="First-frame boxes 'x,y,w,h;x,y,w,h' (red;yellow), image px, or "
                     "'auto' (found by colour: check them in the report)."),
    ] = None,
    cvat: Annotated[
        Path | None, typer.Option(help="CVAT for video 1.1 XML: first boxes and ground truth.")
    ] = None,
    camera: Annotated[Path | None, typer.Option(help="Camera YAML (pmspm calibrate).")] = None,
    motor: Annotated[Path | None, typer.Option(help="Motor YAML (markers, rotor radius).")] = None,
    fps: Annotated[float | None, typer.Option(
        help="Frame rate, Hz; overrides the camera file's frame_rate_hz (a folder's rate) and "
             "a video's own rate.")] = None,
    max_frames: Annotated[int | None, typer.Option(help="Stop after this many frames.")] = None,
    observer: Annotated[
        str, typer.Option(help="Attitude back end: solver (CoR least squares) or aekf.")
    ] = "solver",
) -> None:
    """Track the two markers on a recording or a live camera; write the per-frame table, the
    attitudes, an annotated MP4, a latency profile and a report.

    Example: pmspm track lab.mp4 --boxes "196,231,48,48;367,231,48,48" --tracker kcf_gk --out run
    """
    from experiments.sources import UserInputError
    from experiments.track import TRACK_OBSERVERS, parse_boxes, run_track
    from observer.trackers import PAIR_TRACKERS, make_pair_tracker

    if tracker not in PAIR_TRACKERS:
        _config_error(ValueError(f"--tracker must be one of {PAIR_TRACKERS}"), "options")
    if observer not in TRACK_OBSERVERS:
        _config_error(ValueError(f"--observer must be one of {TRACK_OBSERVERS}"), "options")
    try:
        setup, src = _open_recording(source, fps, motor, camera)
        outcome = run_track(src, make_pair_tracker(tracker, setup.params), out,
                            boxes if boxes in (None, "auto") else parse_boxes(boxes), cvat, setup,
                            max_frames, observer=observer)
    except (ValidationError, ValueError) as exc:
        _config_error(exc, "input" if isinstance(exc, UserInputError) else "configuration")
    typer.echo("\n".join(outcome.summary_lines()))
    typer.echo(f"results: {out}")


def _open_recording(source: str, fps: float | None, motor: Path | None, camera: Path | None):
    """The user's setup and the recording's frames, timed at ``--fps``, else the camera file's
    frame rate (a folder) or the video's own (checked against the camera file's); warnings
    printed. ``ValueError`` (``UserInputError`` for the recording) on bad input."""
    from experiments.sources import open_source
    from experiments.user_files import load_setup

    setup = load_setup(motor, camera)
    src = open_source(source, fps, camera_rate_hz=setup.camera.camera.frame_rate_hz
                      if camera is not None else None,
                      camera_origin=f"frame_rate_hz of {camera}")
    for warning in src.warnings:
        typer.echo(f"warning: {warning}", err=True)
    return setup, src


@app.command("calibrate-mount")
def calibrate_mount(
    source: Annotated[str, typer.Argument(help="Video file or image folder of the rotor.")],
    out: OutOption = Path("mount"),
    known: Annotated[Path | None, typer.Option(
        help="CSV of the resting attitudes: first_frame,last_frame,spin_deg,tilt_deg,yaw_deg "
             "(without it: the rotor spinning at zero tilt).")] = None,
    tracker: Annotated[str, typer.Option(help="Pair tracker (see pmspm track --help).")]
    = "kcf_gk",
    boxes: Annotated[str | None, typer.Option(
        help="First-frame boxes 'x,y,w,h;x,y,w,h' (red;yellow), image px, or 'auto'.")]
    = "auto",
    camera: Annotated[Path | None, typer.Option(help="Camera YAML (pmspm calibrate).")] = None,
    motor: Annotated[Path | None, typer.Option(help="Motor YAML (markers, rotor radius).")] = None,
    fps: Annotated[float | None, typer.Option(help="Frame rate, Hz (as pmspm track).")] = None,
    max_frames: Annotated[int | None, typer.Option(help="Stop after this many frames.")] = None,
) -> None:
    """Estimate the camera's roll about its optical axis and its optical centre's offset from
    the rotation axis, with their uncertainties, from a recording of the rotor resting at known
    attitudes (--known) or spinning at zero tilt; write the camera file with the mount.

    Example: pmspm calibrate-mount rest/ --known poses.csv --camera cam.yaml --out mount
    """
    from experiments.mount import run_calibrate_mount
    from experiments.sources import UserInputError
    from experiments.track import parse_boxes
    from observer.trackers import PAIR_TRACKERS, make_pair_tracker

    if tracker not in PAIR_TRACKERS:
        _config_error(ValueError(f"--tracker must be one of {PAIR_TRACKERS}"), "options")
    try:
        setup, src = _open_recording(source, fps, motor, camera)
        est = run_calibrate_mount(src, make_pair_tracker(tracker, setup.params), out,
                                  boxes if boxes in (None, "auto") else parse_boxes(boxes),
                                  setup, known, max_frames)
    except (ValidationError, ValueError) as exc:
        _config_error(exc, "input" if isinstance(exc, UserInputError) else "configuration")
    typer.echo("\n".join(est.summary_lines()))
    typer.echo(f"camera file: {out / 'camera.yaml'}")


@app.command()
def calibrate(
    source: Annotated[str, typer.Argument(help="Folder of images or a video of a chessboard.")],
    out: OutOption = Path("calibration"),
    pattern: Annotated[str, typer.Option(help="Inner corners, columns x rows.")] = "12x9",
    square_mm: Annotated[float, typer.Option(help="Side of one square, mm.")] = 5.0,
    binning: Annotated[int, typer.Option(help="Sensor pixels per frame pixel.")] = 1,
    pixel_size_um: Annotated[float, typer.Option(help="Sensor pixel pitch, µm.")] = 3.45,
    step: Annotated[int, typer.Option(help="Use every step-th frame of a video.")] = 1,
) -> None:
    """Calibrate the camera from chessboard views: intrinsics, distortion, their uncertainties
    and the reprojection error, written as a camera YAML with a report.

    Example: pmspm calibrate board_views/ --pattern 12x9 --square-mm 5 --binning 4 --out cal
    """
    from experiments.calibrate import calibrate_frames, read_frames, write_report
    from plant.params import CameraParams

    try:
        cols, rows = (int(v) for v in pattern.lower().split("x"))
        if cols < 2 or rows < 2 or square_mm <= 0 or pixel_size_um <= 0:
            raise ValueError("need a pattern of at least 2x2 inner corners, square_mm > 0 and "
                             "pixel_size_um > 0")
        cam = CameraParams(binning=binning, pixel_size_m=pixel_size_um * 1e-6)
        cal = calibrate_frames(read_frames(source, step), (cols, rows), square_mm, cam)
    except (ValidationError, ValueError) as exc:
        _config_error(exc, "input")
    path = write_report(cal, out, source)
    typer.echo("\n".join(cal.summary_lines()))
    typer.echo(f"camera file: {path}")


if __name__ == "__main__":
    app()


@app.command()
def codesign(
    spec_file: Annotated[Path, typer.Argument(help="Co-design spec (YAML).")],
    out: OutOption = Path("runs/codesign"),
    trials: Annotated[
        int | None, typer.Option(help="Finished designs the study should have (default: the "
                                 "spec's search.n_trials).")
    ] = None,
    workers: Annotated[int, typer.Option(help="Worker processes sharing the study.")] = 1,
    scheduler: Annotated[
        str | None, typer.Option(help="Dask scheduler address, or 'local'.")
    ] = None,
    image_check: Annotated[
        bool | None, typer.Option(help="Re-run the recommended design on rendered frames "
                                  "(default: the spec's image_check.enabled).")
    ] = None,
) -> None:
    """Choose the camera mode, tracker, observer and controller together (docs/codesign.md):
    an optuna study (SQLite in <out>/<name>, resumed by running the same command again),
    then the report: Pareto front, non-dominated designs, the recommended design beside the
    seed's, and its image-in-the-loop check.

    Example: pmspm codesign examples/codesign.yaml --out runs/codesign
    """
    from experiments.codesign.report import write_report
    from experiments.codesign.search import run_search, trial_records
    from experiments.codesign.spec import CodesignSpec

    data = _load_yaml(spec_file)
    if trials is not None:
        if trials < 1:
            _fail(f"--trials must be >= 1, got {trials}")
        data.setdefault("search", {})
        if isinstance(data["search"], dict):
            data["search"] = {**data["search"], "n_trials": trials}
    try:
        spec = CodesignSpec.model_validate(data)
    except (ValidationError, ValueError) as exc:
        _config_error(exc, str(spec_file))
    _check_workers_and_scheduler(workers, scheduler)
    if spec.search.storage is not None:
        _check_storage(spec.search.storage)
    folder = _writable_folder(out / spec.name)
    try:
        study = run_search(spec, folder, workers=workers, scheduler=scheduler)
        result = write_report(spec, trial_records(study), folder, image_check)
    except KeyboardInterrupt:
        _interrupted()
    rec = result["recommended"]
    typer.echo(f"{result['n_designs']} designs ({result['n_pruned']} pruned, "
               f"{result['n_feasible']} feasible, {result['n_non_dominated']} non-dominated)")
    if rec is None:
        typer.echo("no feasible design: relax the constraints or widen the space")
    else:
        seed = result["seed"]
        typer.echo(f"recommended: mean RMS error {rec['rms_error_deg']:.3g} deg against the "
                   f"seed's {seed['rms_error_deg']:.3g} deg; phase margin "
                   f"{rec['phase_margin_deg']:.3g} against {seed['phase_margin_deg']:.3g} deg")
    typer.echo(f"report: {folder / 'report.md'}")
