"""``pmspm`` commands that choose settings: the Kalman Q/R tuning and the co-design search."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from pydantic import ValidationError

from experiments.cli.common import (
    EngineChoice,
    EngineOption,
    OutOption,
    _check_storage,
    _check_workers_and_scheduler,
    _config_error,
    _fail,
    _interrupted,
    _load_yaml,
    _number,
    _writable_folder,
    app,
)


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
    engine: EngineOption = EngineChoice.auto,
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
            engine=engine.value,
        )
    except KeyboardInterrupt:
        _interrupted()
    typer.echo("\n".join(result.summary_lines()))
    typer.echo(f"results: {out}")



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
