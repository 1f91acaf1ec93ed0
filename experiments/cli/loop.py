"""``pmspm`` commands on the closed loop: the headline study, one run, margins, sweeps, and
the registered parts."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path
from typing import Annotated

import typer
from pydantic import ValidationError

from experiments.cli.common import (
    SWEEP_BATCH,
    EngineChoice,
    EngineOption,
    OutOption,
    _check_workers_and_scheduler,
    _config_error,
    _fail,
    _interrupted,
    _load_yaml,
    _new_folder,
    _number,
    _warn,
    _writable_folder,
    app,
)
from latency.models import seed_latency_ms


@app.command()
def study(
    out: OutOption = Path("runs"),
    quick: Annotated[bool, typer.Option(
        help="A small study (a minute) for a smoke test: 2 delays, 2 seeds, 1.5 s runs, "
        "margins every 5 ms.")] = False,
    workers: Annotated[int | None, typer.Option(help="Local worker processes.")] = None,
    scheduler: Annotated[
        str | None, typer.Option(help="Dask scheduler address, or 'local' for a LocalCluster.")
    ] = None,
    n_seeds: Annotated[
        int | None,
        typer.Option(help="Seeds per closed-loop point (default 10; --quick: 2)."),
    ] = None,
    engine: EngineOption = EngineChoice.auto,
    motor_file: Annotated[
        Path | None, typer.Option(help="Motor YAML (examples/motor.yaml); default the seed's.")
    ] = None,
    camera_file: Annotated[
        Path | None, typer.Option(help="Camera YAML (pmspm calibrate, examples/camera.yaml).")
    ] = None,
    full: Annotated[
        bool, typer.Option(help="Every point at 32 reference seeds: the sweep (instead of 10, "
                           "unless --n-seeds says otherwise) and the image-engine section "
                           "(instead of 8), GK-TransT and the dual TransT each at both of the "
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
    from experiments.study_config import FULL_STUDY

    _check_workers_and_scheduler(workers, scheduler)
    _writable_folder(out)
    try:
        extra = dict(FULL_STUDY) if full else {}
        if n_seeds is not None:
            extra["n_seeds"] = n_seeds
        if engine != EngineChoice.auto:
            extra["engine"] = engine.value
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
                    "image_loop_duration_s": 1.5, "margin_step_ms": 5.0}
        )
    try:
        folder = run_study(out, cfg)
    except KeyboardInterrupt:
        _interrupted()
    typer.echo(f"report: {folder / 'report.html'}")


@app.command()
def simulate(
    scenario: Annotated[Path, typer.Argument(help="Scenario YAML (latency.scenario).")],
    out: OutOption = Path("runs"),
    engine: EngineOption = EngineChoice.auto,
) -> None:
    """One closed-loop run: writes its tables (Parquet) and a plot into a new folder
    <out>/<timestamp>-simulate-<name>/, prints the summary.

    Example: pmspm simulate examples/scenario.yaml --out runs --engine event
    """
    import latency
    from latency.simulation import choose_engine, describe_path

    try:
        s = latency.Scenario.model_validate(_load_yaml(scenario))
        choose_engine(s, engine.value)
    except (ValidationError, ValueError) as exc:
        _config_error(exc, str(scenario))
    for reason in s.reach_warnings():
        _warn(reason)
    _writable_folder(out)
    typer.echo(describe_path(s, engine.value))
    try:
        result = latency.simulate(s, engine.value, progress=True)
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
    engine: EngineOption = EngineChoice.auto,
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
    from experiments.sweep import SchedulerUnreachable, run_sweep, sweep_id
    from latency import Scenario
    from latency.simulation import choose_engine, describe_paths

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
            choose_engine(scenarios[-1], engine.value)
        except (ValidationError, ValueError) as exc:
            _config_error(exc, f"{spec} (run {i + 1} of {len(configs)})")
    for reason in dict.fromkeys(r for s in scenarios for r in s.reach_warnings()):
        _warn(reason)
    for path, n in describe_paths(scenarios, engine.value).items():
        typer.echo(f"{path}: {n} run{'s' if n > 1 else ''}")
    _writable_folder(out)
    try:
        if engine == EngineChoice.event:
            df = run_sweep("latency.simulation:run_summary", configs, out, scheduler, workers)
        else:
            df = run_sweep("latency.simulation:run_summaries", configs, out, scheduler,
                           workers, batch_size=SWEEP_BATCH)
    except SchedulerUnreachable as exc:
        _fail(str(exc))
    except KeyboardInterrupt:
        _interrupted()
    path = Path(out) / f"sweep-{sweep_id(configs)}.parquet"
    df.to_parquet(path)
    failed = int((df.error != "").sum()) if "error" in df else 0
    typer.echo(f"{len(df)} runs ({failed} failed): {path}")


@app.command()
def parts(
    family: Annotated[str | None, typer.Argument(help="One family (e.g. tracker, controller); "
                                                 "default every family.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable JSON.")] = False,
    markdown: Annotated[bool, typer.Option(help="The Markdown of docs/parts.md.")] = False,
) -> None:
    """List every registered part (front ends, trackers, renderers, loss models, observers,
    controllers, references, latency models) with its options and defaults.

    Example: pmspm parts tracker; pmspm parts --json
    """
    from latency.parts import FAMILIES, parts_data, parts_markdown
    from latency.parts import family as family_of

    try:
        families = FAMILIES if family is None else (family_of(family),)
    except ValueError as exc:
        _config_error(exc, "FAMILY")
    if as_json:
        typer.echo(json.dumps(parts_data(families), indent=1))
        return
    if markdown:
        typer.echo(parts_markdown(families))
        return
    for r in families:
        typer.secho(f"{r.family}: {r.description} ({r.selected_by})", bold=True)
        for p in r:
            typer.echo(f"  {p.name:<14s} {p.summary}")
            for o in p.options():
                typer.echo(f"      {o.name} = {o.default}")
