"""Track the marker pair on a recorded video, a folder of images or a live camera, and turn the
centres into attitudes and a latency profile (``pmspm track``).

Per frame: read (and decode) the frame, ``PairTracker.step`` (``observer.trackers``), the
attitude from the two centres, and an annotated copy for the MP4. The attitude back end
(``observer``): ``solver``, the centre-of-rotation least squares
(``observer.cor_solver.CorSolver``, seed 002 §2.4) warm-started from the previous frame; or
``aekf``, the quaternion AEKF (``observer.pixel_observer.FilterObserver``, seed 001) fusing the
centres at each frame's capture time with no torque input (the recording's motor currents are
unknown: its rate random walk carries the motion), released at the capture time.
Outputs in the run folder:

* ``frames.parquet``: one row per processed frame: frame index, capture time (s; frame index /
  fps: a live camera's frame k is taken as delivered at k / fps after the first), the time the
  frame was in hand (s after the first frame, on the run's clock), both centres
  (sensor px), lost flags and reasons, the tracker's own ``red_measured`` / ``yellow_measured``
  flags (the centre was measured in this frame, not predicted), ``attitude_source`` (what the
  attitude rests on: "both measured", "one predicted", "both predicted"), the attitude
  (quaternion; spin, tilt, yaw in deg) and the per-stage compute times (read, tracker step, of
  which inside the single-object trackers or networks, solver; s);
* ``annotated.mp4``: the frames with boxes, centres and the attitude;
* ``latency_profile.json``: an ``latency.models.Empirical`` profile of tracker + back-end time
  (``solver_time_s`` is the back end's time, solver or AEKF),
  the format ``pipeline.observer`` of a scenario (``pmspm simulate``) takes;
* ``report.md`` with ``attitude.png`` (stretches whose attitude does not rest on two measured
  markers shaded) and ``latency.png``.

The back ends receive only the markers the tracker measured (``observer.tracking.attitude_input``,
the boundary rule of docs/architecture.md): with one marker measured the least-squares solve has
too few markers and gives no attitude, the AEKF fuses the one marker; with none the frame is lost.
Accuracy summaries (``score``, ``experiments.track_accuracy``) count the frames whose markers were
measured unless asked otherwise, and say how many predicted frames they left out.

Sources (``experiments.sources``): a folder of images, a video file, or a live camera (an
integer or a URL). Recorded sources are processed frame by frame; a live camera in real time,
dropping (not queueing) the frames that arrive while the tracker is busy; the number dropped is
reported. The capture and the clock are injectable, so the timing logic runs in tests on a
simulated clock. Ctrl-C stops the run; everything processed until then is written.

Bad input raises ``UserInputError`` with the reason (the CLI exits with status 2).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from experiments.cvat import read_cvat_xml
from experiments.sources import Clock, LiveSchedule, Source, UserInputError, read_first
from experiments.tracking_metrics import PRECISION_PX, centre_errors, precision_at
from latency.models import Empirical
from observer.aekf import AEKFConfig
from observer.cor_model import CorModel
from observer.cor_solver import CorSolver
from observer.gk.hsv_gate import (
    RED,
    YELLOW,
    box_image_to_sensor,
    box_sensor_to_image,
    colour_mask,
)
from observer.pixel_observer import FilterObserver
from observer.tracking import (
    ATTITUDE_SOURCES,
    AttitudeInput,
    PairResult,
    PairTracker,
    attitude_input,
)
from observer.types import SolverResult
from plant import attitude
from plant.camera import Camera, image_to_sensor, sensor_to_image
from plant.user_files import UserSetup


def parse_boxes(text: str) -> NDArray[np.float64]:
    """``"x,y,w,h;x,y,w,h"`` (red then yellow, image px of the frames) -> (2, 4) array."""
    try:
        rows = [[float(v) for v in part.split(",")] for part in text.split(";")]
        boxes = np.array(rows, dtype=float)
    except ValueError as exc:
        raise UserInputError(f"--boxes {text!r}: expected 'x,y,w,h;x,y,w,h' ({exc})") from exc
    if boxes.shape != (2, 4):
        raise UserInputError(f"--boxes {text!r}: expected two boxes of four numbers "
                              "(red;yellow), image px")
    return boxes


#: Auto initialisation: smallest colour blob taken for a marker, image px (our choice: a disc of
#: about 5 px diameter), and how much larger the biggest blob of a colour must be than the next
#: for the choice to be unambiguous.
AUTO_MIN_AREA_PX = 20
AUTO_DOMINANCE = 2.0


def auto_boxes(bgr: NDArray[np.uint8]) -> NDArray[np.float64]:
    """First-frame boxes (2, 4), red then yellow (x, y, w, h, image px), from colour: the
    bounding box of the largest blob of each marker colour (the HSV ranges of seed 000 §3.2.1,
    ``observer.gk.hsv_gate``). Raises ``UserInputError`` when a colour has no blob of
    ``AUTO_MIN_AREA_PX`` or two of similar size (pass the boxes by hand then)."""
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    boxes = []
    for name, hsv_range in (("red", RED), ("yellow", YELLOW)):
        n, _, stats, _ = cv2.connectedComponentsWithStats(colour_mask(rgb, hsv_range))
        areas = stats[1:, cv2.CC_STAT_AREA]
        order = np.argsort(areas)[::-1]
        if n < 2 or areas[order[0]] < AUTO_MIN_AREA_PX:
            raise UserInputError(f"auto boxes: no {name} marker found in the first frame; "
                                 "give --boxes")
        if n > 2 and areas[order[0]] < AUTO_DOMINANCE * areas[order[1]]:
            raise UserInputError(f"auto boxes: several {name} blobs of similar size in the "
                                 "first frame; give --boxes")
        x, y, w, h = stats[1 + order[0], :4]
        boxes.append([x, y, w, h])
    return np.array(boxes, dtype=float)


def check_boxes(boxes_image_px: ArrayLike, width: int, height: int) -> NDArray[np.float64]:
    """Both first-frame boxes (2, 4), image px, must be finite, non-empty and inside the
    ``width`` x ``height`` frame; returns them as an array."""
    boxes = np.asarray(boxes_image_px, dtype=float).reshape(2, 4)
    for name, (x, y, w, h) in zip(("red", "yellow"), boxes, strict=True):
        if not (np.all(np.isfinite([x, y, w, h])) and w > 0 and h > 0):
            raise UserInputError(f"{name} box {[x, y, w, h]} must be finite with w, h > 0")
        if x < -0.5 or y < -0.5 or x + w > width - 0.5 or y + h > height - 0.5:
            raise UserInputError(f"{name} box {[x, y, w, h]} (x, y, w, h) is outside the "
                                  f"{width} x {height} px image")
    return boxes


@dataclass
class GroundTruth:
    """Annotated centres (N, 2, 2), image px of the frames, NaN where a marker is absent."""

    centres_image_px: NDArray[np.float64]
    first_boxes_image_px: NDArray[np.float64]


def load_ground_truth(xml_path: Path | str, width: int, height: int,
                      n_frames: int | None) -> GroundTruth:
    """CVAT for video 1.1 boxes of a recording of ``width`` x ``height`` px and ``n_frames``
    frames (None: unknown). Raises ``UserInputError`` if the file belongs to another video
    (other size or frame count) or lacks the first frame's boxes."""
    try:
        tracks = read_cvat_xml(xml_path)
    except (ValueError, OSError) as exc:
        raise UserInputError(str(exc)) from exc
    if tracks.width and (tracks.width, tracks.height) != (width, height):
        raise UserInputError(f"{xml_path}: annotated frames are {tracks.width} x "
                              f"{tracks.height} px, the video's are {width} x {height} px "
                              "(a CVAT file for another video?)")
    if n_frames is not None and tracks.n_frames != n_frames:
        raise UserInputError(f"{xml_path}: annotates {tracks.n_frames} frames, the video has "
                              f"{n_frames} (a CVAT file for another video?)")
    boxes = np.stack([tracks.boxes_px["red"], tracks.boxes_px["yellow"]], axis=1)
    if not np.all(np.isfinite(boxes[0])):
        raise UserInputError(f"{xml_path}: both markers must be annotated in the first frame")
    return GroundTruth(boxes[:, :, :2] + 0.5 * boxes[:, :, 2:], boxes[0])


def cor_model(setup: UserSetup) -> CorModel:
    """The attitude solver's model (``CorModel.nominal``): the setup's camera (its calibrated
    intrinsics when the camera file has them, ``CameraFile.params``, and its mount's offset),
    its markers and the CoR depth R + h_c from its plant. It works in the camera-aligned frame
    (``plant.camera``): ``run_track`` turns its attitudes by the mount's roll into the stator
    frame."""
    return CorModel.nominal(setup.params, markers_m=setup.markers_m)


#: The attitude back ends of ``run_track``.
TRACK_OBSERVERS = ("solver", "aekf")
#: The AEKF's rate random walk on a recording, rad²/s³ (our choice): the motor's torque is
#: unknown here, so the rate must be free to change by about 0.5 rad/s (one sigma) within a
#: frame at 36 frames/s. The closed loop's default (0.1, ``AEKFConfig``) assumes the torque
#: is known; on the rendered 8° cone it coasts and rejects every measurement from the third
#: frame, while 1 to 100 rad²/s³ all track it to 0.04°.
TRACK_Q_OMEGA_RAD2_PER_S3 = 10.0


def attitude_filter(setup: UserSetup) -> FilterObserver:
    """The AEKF back end (``AEKFConfig`` with the rate random walk
    ``TRACK_Q_OMEGA_RAD2_PER_S3``; no delay compensation: the estimate is at the frame's
    capture time), restarted from the setup's least-squares solve after a loss. Its
    measurement model draws the markers from the motor's VFC, so a motor file whose explicit
    marker layout differs from that is refused (``UserInputError``)."""
    if not setup.motor.markers_follow_vfc():
        raise UserInputError("--observer aekf models the markers of the motor file's vfc "
                             "(leg_mm, marker_diameter_mm) and rotor.radius_m; its explicit "
                             "markers layout differs: use --observer solver")
    config = AEKFConfig(q_omega_rad2_per_s3=TRACK_Q_OMEGA_RAD2_PER_S3)
    return FilterObserver(setup.params, config, compensate_delay=False,
                          solver=CorSolver(cor_model(setup)))


def filter_step(filt: FilterObserver, model: CorModel, given: AttitudeInput, reason: str,
                t_capture_s: float) -> SolverResult:
    """Fuse one frame's measured centres (``attitude_input``) into the AEKF at its capture
    time (s) and release the estimate there, as a ``SolverResult`` (residual: the measured
    centres against the estimate's projection through ``model``, sensor px); ``reason`` is the
    tracker's."""
    filt.process(given.marker_px, t_capture_s, lost=given.lost, reason=reason)
    est = filt.release(t_capture_s)
    if not est.valid:
        return SolverResult.invalid(est.reason or "filter estimate invalid")
    d = np.asarray(given.marker_px, float) - model.project(est.q)
    seen = np.all(np.isfinite(d), axis=1)
    rms = float(np.sqrt(np.mean(d[seen] ** 2))) if seen.any() else np.nan
    return SolverResult(q=est.q, covariance=est.covariance, reason=est.reason,
                        residual_rms_px=rms)


@dataclass
class TrackOutcome:
    """What a run produced.

    Attributes
    ----------
    table : the per-frame table (also ``frames.parquet``).
    out_dir : the run folder.
    dropped : live frames discarded because the tracker was busy.
    interrupted : the run was stopped by Ctrl-C.
    metrics : precision at 20 px and centre errors per marker (with ground truth), else empty.
    start_boxes_image_px : (2, 4) the first-frame boxes the tracker started on, image px.
    observer : the attitude back end (``TRACK_OBSERVERS``).
    """

    table: pd.DataFrame
    out_dir: Path
    start_boxes_image_px: NDArray[np.float64]
    dropped: int = 0
    interrupted: bool = False
    metrics: dict[str, float] = field(default_factory=dict)
    observer: str = "solver"

    def summary_lines(self) -> list[str]:
        """Human-readable lines for the terminal and the report."""
        t = self.table
        ok = t["attitude_valid"].to_numpy(bool) if len(t) else np.zeros(0, bool)
        boxes = "; ".join(",".join(f"{v:.1f}" for v in b) for b in self.start_boxes_image_px)
        lines = [f"first-frame boxes (red; yellow, x,y,w,h image px): {boxes}",
                 f"frames processed: {len(t)}, dropped (live): {self.dropped}"
                 + (" (stopped by Ctrl-C)" if self.interrupted else ""),
                 f"attitude ({self.observer}) valid on {int(ok.sum())} of {len(t)} frames; "
                 "markers lost on "
                 f"{int(t['lost'].sum()) if len(t) else 0}"]
        if len(t):
            counts = t["attitude_source"].value_counts()
            lines.append("attitude rests on: " + ", ".join(
                f"{src} {int(counts.get(src, 0))}" for src in ATTITUDE_SOURCES) + " frames")
            total = (t["tracker_time_s"] + t["solver_time_s"]).to_numpy() * 1e3
            lines.append(f"tracker + {self.observer} time: median {np.median(total):.2f} ms, "
                         f"p95 {np.percentile(total, 95):.2f} ms")
        for k, v in self.metrics.items():
            lines.append(f"{k}: {int(v)}" if k.endswith("left out") else f"{k}: {v:.3f}")
        return lines


def _annotate(bgr: NDArray[np.uint8], res: PairResult, binning: int,
              text: str) -> NDArray[np.uint8]:
    """Boxes, centres and a text line drawn on a copy of a BGR frame."""
    out = bgr.copy()
    colours = ((0, 0, 255), (0, 215, 255))  # red, yellow in BGR
    for box, centre, lost, colour in zip(res.boxes_px, res.marker_px,
                                         (res.red_lost, res.yellow_lost), colours, strict=True):
        if np.all(np.isfinite(box)):
            x, y, w, h = box_sensor_to_image(box, binning)
            cv2.rectangle(out, (round(x), round(y)), (round(x + w), round(y + h)), colour,
                          1 if lost else 2)
        if np.all(np.isfinite(centre)):
            u, v = sensor_to_image(centre, binning)
            cv2.drawMarker(out, (round(u), round(v)), (255, 255, 0), cv2.MARKER_CROSS, 8, 1)
    cv2.putText(out, text, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1,
                cv2.LINE_AA)
    return out


def run_track(
    source: Source,
    tracker: PairTracker,
    out_dir: Path | str,
    boxes_image_px: ArrayLike | str | None = None,
    ground_truth: Path | str | None = None,
    setup: UserSetup | None = None,
    max_frames: int | None = None,
    clock: Clock = time.perf_counter,
    write_video: bool = True,
    observer: str = "solver",
) -> TrackOutcome:
    """Track ``source`` and write the outputs of the module docstring into ``out_dir``.

    Parameters
    ----------
    source : from ``open_source``.
    tracker : a pair tracker (``observer.trackers.make_pair_tracker``) built with ``params``.
    boxes_image_px : (2, 4) first-frame boxes, red then yellow (x, y, w, h), image px, or
        ``"auto"`` (``auto_boxes``: found by colour; check them in the report and the video);
        may be omitted when ``ground_truth`` gives them.
    ground_truth : a CVAT for video 1.1 XML of the recording: its first-frame boxes start the
        tracker (unless ``boxes_image_px`` is given) and its centres score the run (precision at
        20 px and centre errors, ``experiments.tracking_bench``).
    setup : the user's motor and camera (``plant.user_files.load_setup``; default the
        seed's motor and the default camera); the camera's image size must be the frames'.
    max_frames : stop after this many processed frames.
    clock : seconds, monotonic; times the stages and paces a live source.
    write_video : write ``annotated.mp4``.
    observer : the attitude back end, ``TRACK_OBSERVERS`` (module docstring).
    """
    setup = setup or UserSetup()
    if observer not in TRACK_OBSERVERS:
        raise UserInputError(f"observer must be one of {TRACK_OBSERVERS}, got {observer!r}")
    cam = setup.camera
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    first = read_first(source)
    t0 = clock()  # the first frame is in hand: a live camera's frame clock starts here
    h, w = first.shape[:2]
    if (w, h) != cam.image_size:
        raise UserInputError(f"the camera file's image size is {cam.image_size[0]} x "
                              f"{cam.image_size[1]} px (sensor / binning) but the frames are "
                              f"{w} x {h} px")
    truth = None if ground_truth is None else load_ground_truth(
        ground_truth, w, h, source.n_frames if source.kind != "live" else None)
    boxes = _first_boxes(boxes_image_px, first, truth)
    b = cam.camera.binning
    try:
        tracker.start(cv2.cvtColor(first, cv2.COLOR_BGR2RGB),
                      np.array([box_image_to_sensor(x, b) for x in boxes]), b)
    except ValueError as exc:
        raise UserInputError(f"cannot start the tracker: {exc}") from exc
    model = cor_model(setup)
    camera = Camera.from_plant(setup.params)
    solver = CorSolver(model)
    filt = attitude_filter(setup) if observer == "aekf" else None
    writer = cv2.VideoWriter(str(out / "annotated.mp4"), cv2.VideoWriter_fourcc(*"mp4v"),
                             source.fps, (w, h)) if write_video else None
    live = LiveSchedule(source.fps, clock, t0) if source.kind == "live" else None
    rows, interrupted = _track_frames(source, tracker, _Backend(solver, filt, model, camera),
                                      first, clock=clock, t0=t0, writer=writer, live=live,
                                      max_frames=max_frames, binning=b)
    table = pd.DataFrame(rows)
    outcome = TrackOutcome(table, out, boxes, live.dropped if live else 0, interrupted,
                           observer=observer)
    if truth is not None:
        outcome.metrics = score(table, truth, b)
    write_outputs(outcome, source, tracker)
    return outcome


@dataclass(frozen=True)
class _Backend:
    """The attitude back end of a tracking run: the CoR model and its per-frame solver, the
    filter (None for the per-frame solve) and the camera (camera-aligned to stator frame)."""

    solver: CorSolver
    filt: FilterObserver | None
    model: CorModel
    camera: Camera


def _track_frames(
    source: Source, tracker: PairTracker, backend: _Backend, first: NDArray[np.uint8], *,
    clock: Clock, t0: float, writer: cv2.VideoWriter | None, live: LiveSchedule | None,
    max_frames: int | None, binning: int,
) -> tuple[list[dict], bool]:
    """Track the frames of ``source`` from ``first`` (BGR) until the source ends, a frame of
    another size comes, ``max_frames`` are done or the user interrupts: per frame the
    tracker's step, the attitude, the table row (times from ``clock`` less ``t0``, s) and the
    annotated video frame; a live source skips stale frames. The source and the video are
    released at the end. Returns the rows and whether the user interrupted."""
    h, w = first.shape[:2]
    rows: list[dict] = []
    q_prev = None
    frame, read_s, index = first, 0.0, 0
    interrupted = False
    try:
        while frame is not None and (max_frames is None or len(rows) < max_frames):
            t_received = clock() - t0
            res = tracker.step(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB))
            ts = clock()
            sol = _solve(backend, res, q_prev, not rows, index / source.fps)
            solver_s = clock() - ts
            q_prev = sol.q if sol.valid else q_prev
            # the tracker's geometry and drift checks read the latest attitude and residual
            tracker.residual_hint_px = sol.residual_rms_px
            if sol.valid:
                tracker.tilt_hint_rad = attitude.tilt(sol.q)
            # the back ends work in the camera-aligned frame; the table is in the stator frame
            stator = replace(sol, q=backend.camera.stator_attitude(sol.q)) if sol.valid else sol
            row = _frame_row(index, source.fps, t_received, res, stator, read_s, solver_s)
            rows.append(row)
            if writer is not None:
                text = (f"#{index} tilt {row['tilt_deg']:.2f} yaw {row['yaw_deg']:.1f} spin "
                        f"{row['spin_deg']:.1f} deg" if sol.valid else f"#{index} no attitude")
                writer.write(_annotate(frame, res, binning, text))
            if live is not None and not live.skip_stale(source.capture):
                break
            tr = clock()
            ok, frame = source.capture.read()
            read_s = clock() - tr
            frame = frame if ok and frame is not None and frame.shape[:2] == (h, w) else None
            index = live.last if live is not None else index + 1
    except KeyboardInterrupt:
        interrupted = True
    finally:
        source.capture.release()
        if writer is not None:
            writer.release()
    return rows, interrupted


def _first_boxes(boxes_image_px: ArrayLike | str | None, first: NDArray[np.uint8],
                 truth: GroundTruth | None) -> NDArray[np.float64]:
    """The checked first-frame boxes (2, 4), image px: those given, those found by colour in
    the first frame ``first`` (BGR) for ``"auto"``, or the ground truth's first boxes when
    none are given; ``UserInputError`` when there are none or they do not fit the frame."""
    h, w = first.shape[:2]
    if isinstance(boxes_image_px, str) and boxes_image_px == "auto":
        boxes_image_px = auto_boxes(first)
    elif boxes_image_px is None:
        if truth is None:
            raise UserInputError("give the first-frame boxes (--boxes) or a CVAT file")
        boxes_image_px = truth.first_boxes_image_px
    return check_boxes(boxes_image_px, w, h)


def _solve(backend: _Backend, res: PairResult, q_prev: NDArray[np.float64] | None, first: bool,
           t_s: float) -> SolverResult:
    """The attitude of one frame from the tracker's result ``res``: the per-frame solve
    (from ``q_prev``), or with a filter the filter's step at time ``t_s`` (s), the filter
    started from the frame's solve on the ``first`` frame."""
    solver, filt, model = backend.solver, backend.filt, backend.model
    given = attitude_input(res)
    if filt is None:
        return solver.solve(given.marker_px, q_prev) if not given.lost else \
            SolverResult.invalid("no marker measured in this frame")
    if first:
        filt.reset(_first_attitude(solver, given), t_s)
    return filter_step(filt, model, given, res.reason, t_s)


def _first_attitude(solver: CorSolver, given: AttitudeInput) -> NDArray[np.float64]:
    """The AEKF's starting attitude: the least-squares solve of the first frame's measured
    centres, else rest."""
    sol = solver.solve(given.marker_px)
    return sol.q if sol.valid else np.array([1.0, 0.0, 0.0, 0.0])


def _frame_row(index: int, fps: float, received_s: float, res: PairResult, sol: SolverResult,
               read_s: float, solver_s: float) -> dict[str, object]:
    """One row of ``frames.parquet`` (see the module docstring)."""
    q = sol.q if sol.valid else np.full(4, np.nan)
    angles = np.rad2deg(attitude.to_zyz_array(q[None])[0]) if sol.valid else np.full(3, np.nan)
    return {
        "frame_index": index, "capture_time_s": index / fps, "received_time_s": received_s,
        "red_u_px": res.red_px[0], "red_v_px": res.red_px[1],
        "yellow_u_px": res.yellow_px[0], "yellow_v_px": res.yellow_px[1],
        "lost": res.lost, "red_lost": res.red_lost, "yellow_lost": res.yellow_lost,
        "red_measured": res.red_measured, "yellow_measured": res.yellow_measured,
        "attitude_source": attitude_input(res).source, "reason": res.reason,
        "q_w": q[0], "q_x": q[1], "q_y": q[2], "q_z": q[3],
        "spin_deg": angles[0], "tilt_deg": angles[1], "yaw_deg": angles[2],
        "attitude_valid": sol.valid, "attitude_reason": sol.reason,
        "residual_rms_px": sol.residual_rms_px,
        "read_time_s": read_s, "tracker_time_s": res.compute_time_s,
        "network_time_s": res.tracker_time_s, "solver_time_s": solver_s,
    }


def score(table: pd.DataFrame, truth: GroundTruth, binning: int,
          include_predicted: bool = False) -> dict[str, float]:
    """Precision at 20 px and mean / median centre errors (sensor px, as the benchmark) of each
    marker against the annotated centres of the processed frames: the frames in which the
    tracker measured that marker, unless ``include_predicted``; ``"<marker> predicted frames
    left out"`` counts the others."""
    idx = table["frame_index"].to_numpy(int)
    keep = idx < len(truth.centres_image_px)
    idx = idx[keep]
    metrics: dict[str, float] = {}
    for m, name in enumerate(("red", "yellow")):
        pred = table[[f"{name}_u_px", f"{name}_v_px"]].to_numpy()[keep]
        true = image_to_sensor(truth.centres_image_px[idx, m], binning)
        e = centre_errors(pred, true)
        predicted = ~table[f"{name}_measured"].to_numpy(bool)[keep]
        if not include_predicted:
            e[predicted] = np.nan  # not scored
        metrics[f"{name} predicted frames left out"] = \
            0.0 if include_predicted else float(predicted.sum())
        scored = e[~np.isnan(e)]
        metrics[f"{name} precision@{PRECISION_PX:g}px"] = precision_at(e)
        metrics[f"{name} mean centre error px"] = float(np.mean(scored)) if scored.size else np.nan
        metrics[f"{name} median centre error px"] = float(np.median(scored)) if scored.size \
            else np.nan
    return metrics


def write_outputs(outcome: TrackOutcome, source: Source, tracker: PairTracker) -> None:
    """The Parquet table, the latency profile, the plots and ``report.md``."""
    from matplotlib.figure import Figure

    out, t = outcome.out_dir, outcome.table
    t.to_parquet(out / "frames.parquet", index=False)
    name = tracker.name
    if len(t):
        total = (t["tracker_time_s"] + t["solver_time_s"]).to_numpy()
        Empirical.from_measurements(
            total, source=f"{name} + {outcome.observer}, {len(t)} frames of {source.name}"
        ).save(out / "latency_profile.json")
    fig = Figure(figsize=(7, 3.5))
    ax = fig.subplots()
    for col in ("tilt_deg", "yaw_deg", "spin_deg"):
        if len(t):
            ax.plot(t["capture_time_s"], t[col], label=col.replace("_deg", ""))
    if len(t):
        _shade_predicted(ax, t)
    ax.set_xlabel("capture time, s")
    ax.set_ylabel("angle, deg")
    ax.legend()
    ax.set_title("attitude (ZYZ spin, tilt, yaw); shaded: a marker predicted")
    fig.tight_layout()
    fig.savefig(out / "attitude.png", dpi=100)
    fig = Figure(figsize=(7, 3.5))
    ax = fig.subplots()
    for col in ("read_time_s", "tracker_time_s", "solver_time_s"):
        if len(t):
            ax.plot(t["capture_time_s"], t[col] * 1e3, label=col.replace("_time_s", ""))
    ax.set_xlabel("capture time, s")
    ax.set_ylabel("compute time, ms")
    ax.legend()
    ax.set_title("per-stage compute time")
    fig.tight_layout()
    fig.savefig(out / "latency.png", dpi=100)
    lines = [f"# Tracking run: {source.name}", "",
             f"Source: {source.kind}, {source.fps:g} frames/s (from {source.fps_origin}); "
             f"tracker: {name}; attitude: {outcome.observer}.", "",
             *[f"**Warning:** {w}" for w in source.warnings],
             *([""] if source.warnings else []),
             *[f"- {s}" for s in outcome.summary_lines()], "",
             "![attitude](attitude.png)", "", "![latency](latency.png)", "",
             "Files: `frames.parquet` (per frame), `annotated.mp4`, `latency_profile.json` "
             "(a scenario's `pipeline.observer`).", ""]
    (out / "report.md").write_text("\n".join(lines))


#: Shading of the attitude plot's stretches per ``attitude_source`` (None: not shaded).
_SHADES = {ATTITUDE_SOURCES[1]: "#f5c26b", ATTITUDE_SOURCES[2]: "#b0b0b0"}


def predicted_stretches(table: pd.DataFrame) -> list[tuple[float, float, str]]:
    """(start, end, attitude_source) of each run of consecutive rows whose attitude does not
    rest on two measured markers; times are capture times (s), each row covering half a frame
    period on either side."""
    times = table["capture_time_s"].to_numpy(float)
    sources = table["attitude_source"].to_numpy(str)
    half = 0.5 * float(np.median(np.diff(times))) if len(times) > 1 else 0.5
    out: list[tuple[float, float, str]] = []
    for k, (t, src) in enumerate(zip(times, sources, strict=True)):
        if src == ATTITUDE_SOURCES[0]:
            continue
        if out and out[-1][2] == src and sources[k - 1] == src:
            out[-1] = (out[-1][0], t + half, src)
        else:
            out.append((t - half, t + half, src))
    return out


def _shade_predicted(ax, table: pd.DataFrame) -> None:
    """Shade the attitude plot where a marker was predicted (one: orange, both: grey)."""
    labelled: set[str] = set()
    for t0, t1, src in predicted_stretches(table):
        ax.axvspan(t0, t1, color=_SHADES[src], alpha=0.4, lw=0,
                   label=None if src in labelled else src)
        labelled.add(src)
