"""The ``pmspm`` command line (typer). ``pmspm --help`` lists the commands; every command's
``--help`` shows an example. Configuration errors exit with status 2 and a message that names
the field, without a traceback."""

from __future__ import annotations

import itertools
import json
import os
from pathlib import Path
from typing import Annotated

import typer
import yaml
from pydantic import ValidationError

os.environ.setdefault("MUJOCO_GL", "egl")  # before anything imports mujoco

app = typer.Typer(
    help="Closed-loop co-design toolkit for a vision-measured spherical motor.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

OutOption = Annotated[Path, typer.Option(help="Folder for the results.")]


def _config_error(exc: ValidationError | ValueError, source: str) -> None:
    """Print a configuration error naming the field(s) and exit with status 2."""
    typer.secho(f"invalid configuration in {source}:", fg=typer.colors.RED, err=True)
    if isinstance(exc, ValidationError):
        for e in exc.errors():
            where = ".".join(str(p) for p in e["loc"]) or "(top level)"
            typer.echo(f"  {where}: {e['msg']}", err=True)
    else:
        typer.echo(f"  {exc}", err=True)
    raise typer.Exit(code=2)


def _load_yaml(path: Path) -> dict:
    if not path.exists():
        typer.secho(f"no such file: {path}", fg=typer.colors.RED, err=True)
        raise typer.Exit(code=2)
    with open(path) as fh:
        data = yaml.safe_load(fh) or {}
    if not isinstance(data, dict):
        typer.secho(f"{path}: expected a mapping at the top level", fg=typer.colors.RED, err=True)
        raise typer.Exit(code=2)
    return data


@app.command()
def study(
    out: OutOption = Path("runs"),
    quick: Annotated[bool, typer.Option(help="A small study (a minute) for a smoke test.")] = False,
    workers: Annotated[int | None, typer.Option(help="Local worker processes.")] = None,
    scheduler: Annotated[
        str | None, typer.Option(help="Dask scheduler address, or 'local' for a LocalCluster.")
    ] = None,
) -> None:
    """The headline study: margins, tracking loss and error against vision delay, PID vs MPC.

    Writes runs/<timestamp>-study/ with report.md, report.html, PNG plots and Parquet tables.

    Example: pmspm study --out runs --workers 2
    """
    from experiments.study import DUAL_MS, GK_MS, StudyConfig, run_study

    cfg = StudyConfig(workers=workers, scheduler=scheduler)
    if quick:
        cfg = cfg.model_copy(
            update={"delays_ms": (GK_MS, DUAL_MS), "max_rates_rad_s": (3.0,), "duration_s": 1.5,
                    "latency_frames": 10}
        )
    folder = run_study(out, cfg)
    typer.echo(f"report: {folder / 'report.html'}")


@app.command()
def demo(out: OutOption = Path("runs")) -> None:
    """Tilt step of the simulated motor under a PD law on the true state, with rendered frames.

    Example: pmspm demo --out runs
    """
    from experiments.demo import run_demo

    folder = run_demo(out)
    typer.echo(f"report: {folder / 'report.md'}")


@app.command()
def simulate(
    scenario: Annotated[Path, typer.Argument(help="Scenario YAML (experiments.scenario).")],
    out: OutOption = Path("runs"),
) -> None:
    """One closed-loop run: writes its tables (Parquet) and a plot, prints the summary.

    Example: pmspm simulate examples/scenario.yaml --out runs
    """
    from experiments.scenario import Scenario, run

    try:
        s = Scenario.model_validate(_load_yaml(scenario))
    except (ValidationError, ValueError) as exc:
        _config_error(exc, str(scenario))
    result = run(s, progress=True)
    folder = result.save(Path(out) / f"simulate-{s.name}")
    _plot_run(result.steps, folder / "run.png", s.name)
    for k, v in result.summary.items():
        typer.echo(f"{k:>28s}  {v:.6g}")
    typer.echo(f"tables: {folder}")


def _plot_run(steps, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
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
    plt.close(fig)


@app.command()
def margins(
    crossover_rad_s: Annotated[float, typer.Option(help="PID crossover, rad/s.")] = 10.0,
    frame_rate_hz: Annotated[float, typer.Option(help="Observer update rate, Hz.")] = 36.0,
    delay_ms: Annotated[float, typer.Option(help="Vision delay for Bode/Nyquist, ms.")] = 16.33,
    out: OutOption = Path("runs"),
) -> None:
    """Margins of the per-axis PID loop with the exact delay; Bode and Nyquist plots and the
    margins against delay 0–60 ms.

    Example: pmspm margins --crossover-rad-s 10 --delay-ms 31.23
    """
    import matplotlib

    matplotlib.use("Agg")
    from controller.pid import PIDConfig, PIDController
    from latency.margins import (
        attitude_delay_sweep,
        attitude_margins,
        attitude_plant,
        loop_model,
        plot_bode,
        plot_nyquist,
    )
    from plant.params import PlantParams

    try:
        cfg = PIDConfig(crossover_rad_s=crossover_rad_s)
    except ValidationError as exc:
        _config_error(exc, "options")
    if frame_rate_hz <= 0 or delay_ms < 0:
        _config_error(ValueError("frame_rate_hz must be > 0 and delay_ms >= 0"), "options")
    p = PlantParams()
    pid = PIDController(cfg, p)
    J, b, T = float(pid.J[1]), p.rotor.viscous_Nms_per_rad, 1.0 / frame_rate_hz
    tau = 0.5 * p.camera.exposure_s + delay_ms / 1e3
    m = attitude_margins(
        pid.transfer_function(1), inertia_kgm2=J, damping_Nms_per_rad=b, frame_period_s=T,
        delay_s=tau,
    )
    folder = Path(out) / f"margins-{crossover_rad_s:g}rad_s-{delay_ms:g}ms"
    folder.mkdir(parents=True, exist_ok=True)
    typer.echo(m.summary())
    model = loop_model(
        attitude_plant(J, b), pid.transfer_function(1), sample_period_s=T, delay_s=tau
    )
    plot_bode(model, m).savefig(folder / "bode.png", dpi=110)
    plot_nyquist(model, m).savefig(folder / "nyquist.png", dpi=110)
    sweep = attitude_delay_sweep(
        pid.transfer_function(1), inertia_kgm2=J, damping_Nms_per_rad=b, frame_period_s=T
    )
    sweep.to_parquet(folder / "margins_vs_delay.parquet")
    typer.echo(f"plots and table: {folder}")


def _expand(base: dict, grid: dict) -> list[dict]:
    """All combinations of ``grid`` (dotted paths -> lists of values) applied to ``base``."""
    keys = list(grid)
    out = []
    for values in itertools.product(*(grid[k] for k in keys)):
        cfg = json.loads(json.dumps(base))
        for key, value in zip(keys, values, strict=True):
            node = cfg
            *parents, leaf = key.split(".")
            for p in parents:
                node = node.setdefault(p, {})
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
) -> None:
    """A grid of scenarios, resumable (finished runs are skipped), local or on Dask.

    The YAML has a 'base' scenario and a 'grid' mapping dotted field paths to lists, e.g.

    grid:
      pipeline.observer.value_s: [0.01633, 0.03123]
      controller.kind: \\[pid, mpc]
      seed: [0, 1]

    Example: pmspm sweep examples/sweep.yaml --out runs/sweep --scheduler tcp://host:8786
    """
    from experiments.scenario import Scenario
    from experiments.sweep import run_sweep

    data = _load_yaml(spec)
    unknown = set(data) - {"base", "grid"}
    if unknown:
        _config_error(ValueError(f"unknown top-level keys {sorted(unknown)}; use base, grid"),
                      str(spec))
    configs = _expand(data.get("base", {}), data.get("grid", {}))
    for c in configs:
        try:
            Scenario.model_validate(c)
        except ValidationError as exc:
            _config_error(exc, str(spec))
    df = run_sweep("experiments.scenario:run_summary", configs, out, scheduler, workers)
    df.to_parquet(Path(out) / "sweep.parquet")
    failed = int((df.error != "").sum()) if "error" in df else 0
    typer.echo(f"{len(df)} runs ({failed} failed): {Path(out) / 'sweep.parquet'}")


@app.command("measure-latency")
def measure_latency(
    tracker: Annotated[
        str,
        typer.Option(
            help="kcf or csrt (GK assistance on top), or orb (the textured rotor's ORB-AEKF)."
        ),
    ] = "kcf",
    frames: Annotated[int, typer.Option(help="Frames to time.")] = 200,
    out: Annotated[Path, typer.Option(help="Profile JSON to write.")] = Path("latency.json"),
) -> None:
    """Measure the observer's per-frame latency on a rendered sequence; writes an empirical
    latency profile that a scenario can load (as pipeline.observer).

    Example: pmspm measure-latency --tracker csrt --frames 200 --out csrt.json
    """
    import numpy as np

    from latency.profile import measure_locator_latency, measure_orb_latency
    from observer.frame_observer import MarkerLocator
    from observer.opencv_trackers import OpenCVTracker
    from plant.params import PlantParams

    if tracker not in ("kcf", "csrt", "orb") or frames < 1:
        _config_error(ValueError("tracker must be kcf, csrt or orb and frames >= 1"), "options")
    p = PlantParams()
    if tracker == "orb":
        prof = measure_orb_latency(p, "aekf", n_frames=frames, progress=True)
        label = "ORB-AEKF"
    else:
        locator = MarkerLocator(p, OpenCVTracker(tracker))
        prof = measure_locator_latency(p, locator, n_frames=frames, progress=True)
        label = f"{tracker}+GK"
    prof.save(out)
    s = np.asarray(prof.samples_s) * 1e3
    typer.echo(f"{label}: median {np.median(s):.2f} ms, p95 {np.percentile(s, 95):.2f} ms")
    typer.echo(f"profile: {out}")


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
    report.md (Table 1 beside the seed's, precision at 20 px, success AUC, issue 4's targets).
    The same code path as benchmarks/bench_tracking.py.

    Example: pmspm bench-trackers --seeds 1 --cases clean --trackers gk_transt,kcf --stand-in
    """
    import datetime as dt

    # Before torch loads its OpenMP runtime: idle threads sleep instead of spinning
    # (docs/tracking.md; as benchmarks/bench_tracking.py).
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    from tqdm import tqdm

    from experiments import tracking_bench as tb
    from experiments.sequences import CASES

    case_list = _names(cases) or list(CASES)
    tracker_list = _names(trackers) or list(tb.DEFAULT_TRACKERS)
    if not stand_in and any(t.startswith(("gk_transt", "dual_transt")) for t in tracker_list):
        try:
            import torch

            torch.set_num_threads(max(1, torch_threads))
        except ImportError:
            pass
    if out is None:
        stamp = dt.datetime.now().strftime("%Y%m%d-%H%M%S")
        out = Path("runs") / f"{stamp}-bench-trackers"
        out.mkdir(parents=True, exist_ok=False)  # a new folder, never a previous run's
    bar = tqdm(total=seeds * len(case_list) * max(frames - 1, 0), desc="bench-trackers",
               unit="frame")
    try:
        report = tb.run_tracking_benchmark(
            out, seeds=seeds, frames=frames, cases=case_list, trackers=tracker_list,
            stand_in=stand_in, progress=lambda msg: bar.set_postfix_str(msg, refresh=True),
            on_step=lambda: bar.update(1),
        )
    except ValueError as exc:
        bar.close()
        _config_error(exc, "options")
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
    grid_points: Annotated[int, typer.Option(help="Grid points per axis (log q x log r).")] = 5,
    trials: Annotated[int, typer.Option(help="Optuna TPE trials per delay.")] = 20,
    duration_s: Annotated[float, typer.Option(help="Simulated time per run, s.")] = 3.0,
    workers: Annotated[int | None, typer.Option(help="Local worker processes.")] = None,
    scheduler: Annotated[
        str | None, typer.Option(help="Dask scheduler address, or 'local'.")
    ] = None,
    storage: Annotated[
        str | None, typer.Option(help="Optuna storage URL (default: SQLite in the output).")
    ] = None,
) -> None:
    """Tune the pixel Kalman filter's Q/R against closed-loop cost (not pixel error), grid +
    optuna, and compare with the seed's Q = 0.01·I4, R = 0.1·I2 on held-out seeds, with the phase
    margin of each loop.

    Example: pmspm tune-kalman --delays-ms 16.33 --delays-ms 31.23 --trials 20 --workers 2
    """
    from experiments.tuning import tune_kalman

    if grid_points < 2 or trials < 0 or duration_s <= 0:
        _config_error(
            ValueError("need grid_points >= 2, trials >= 0 and duration_s > 0"), "options"
        )
    delays = tuple(d / 1e3 for d in (delays_ms or [16.33, 31.23]))
    result = tune_kalman(
        out,
        delays_s=delays,
        grid_points=grid_points,
        n_trials=trials,
        duration_s=duration_s,
        scheduler=scheduler,
        workers=workers,
        storage=storage,
    )
    typer.echo("\n".join(result.summary_lines()))
    typer.echo(f"results: {out}")


if __name__ == "__main__":
    app()
