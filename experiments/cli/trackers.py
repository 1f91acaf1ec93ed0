"""``pmspm`` commands on trackers and cameras: latency profiles, loss calibration, the tracking
benchmark, tracking a recording, the camera mount and the camera calibration."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer
from pydantic import ValidationError

from experiments.cli.common import (
    OutOption,
    _config_error,
    _fail,
    _interrupted,
    _names,
    _new_folder,
    _writable_folder,
    app,
)
from observer.trackers import TRACKERS


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
        help="Reference seeds per held-out point (>= 1).")] = 3,
    duration_s: Annotated[float, typer.Option(help="Simulated time per run, s (> 0.5).")] = 4.0,
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
    _check_bench_options(tracker_list, stand_in, torch_threads)
    new_folder = out is None
    out = _new_folder(_writable_folder(Path("runs")), "bench-trackers") if new_folder else (
        _writable_folder(out))
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
    command = "pmspm bench-trackers " + " ".join(
        [f"--seeds {seeds}", f"--frames {frames}", f"--cases {','.join(case_list)}",
         f"--trackers {','.join(tracker_list)}"] + (["--stand-in"] if stand_in else [])
    )
    _bench_report(out, report, command, stand_in)


def _check_bench_options(tracker_list: list[str], stand_in: bool, torch_threads: int) -> None:
    """Exit with status 2 for bad options (TransT rows without the shipped network fail here,
    not omitted silently); set torch's threads for the TransT rows."""
    from experiments import tracking_bench as tb

    if torch_threads < 1:
        _fail(f"--torch-threads must be >= 1, got {torch_threads}")
    try:
        tb.tracker_factories(tracker_list, stand_in, require_transt=True)
    except ValueError as exc:
        _config_error(exc, "options")
    if not stand_in and any(t.startswith(("gk_transt", "dual_transt")) for t in tracker_list):
        import torch

        torch.set_num_threads(torch_threads)


def _bench_report(out: Path, report, command: str, stand_in: bool) -> None:  # noqa: ANN001
    """Write the tracking benchmark's report.md and print its tables and checks."""
    from experiments import tracking_bench as tb

    title = "# Tracking benchmark (seed 000 §4)"
    if stand_in:
        title += " [numpy-KCF stand-in for the TransT network]"
    (out / "report.md").write_text(f"{title}\n\n`{command}`\n\n{report.notes}\n")
    typer.echo(tb.markdown_table(report.table1[["algorithm", "fps", "latency_median_ms",
                                                "seed_latency_ms"]], ".2f"))
    typer.echo(tb.markdown_table(report.summary[["tracker", "case", "main_precision_20px",
                                                 "aux_precision_20px"]]))
    for line in report.checks:
        typer.echo(f"- {line}")
    typer.echo(f"results: {out}")



@app.command()
def track(
    source: Annotated[str, typer.Argument(help="Video file, image folder, camera index or URL.")],
    out: OutOption = Path("track_run"),
    tracker: Annotated[str, typer.Option(help="Pair tracker: " + "; ".join(
        f"{p.name} = {p.summary}" for p in TRACKERS) + ".")] = "gk_transt",
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
    from observer.trackers import make_pair_tracker

    try:
        tracker = TRACKERS.canonical(tracker)
    except ValueError as exc:
        _config_error(exc, "--tracker")
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
    from plant.user_files import load_setup

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
    from observer.trackers import make_pair_tracker

    try:
        tracker = TRACKERS.canonical(tracker)
    except ValueError as exc:
        _config_error(exc, "--tracker")
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
