"""Measure an observer's latency profile on a rendered sequence: one call, one ``Empirical``.

The sequence is rendered with the analytic renderer from a seed (a slow cone in the workspace,
with motion blur) and the wall-clock time of each frame's processing is recorded. The first
``warmup`` frames are not recorded (caches, lazy initialisation). Rendering is not timed.

* ``measure_locator_latency``: the marker rotor; a pair tracker (``observer.tracking.PairTracker``,
  e.g. a tracker inside the GK assistance, GK-TransT or the dual TransT) started on the first
  frame's true boxes, timed per ``step`` call by the tracker's own clock.
  ``measure_pair_tracker_latency`` is the same measurement, named after the tracker.
* ``measure_orb_latency``: the textured rotor; an ``OrbObserver`` (ORB alone, ORB-EKF
  or ORB-AEKF) on a reference view at rest, timed per frame over its front end (ORB, matching,
  RANSAC, refinement) and back end (solve or filter update), as ``OrbObserver.update`` reports.

A profile saved with ``.save(path)`` goes into a scenario as ``pipeline.observer`` (with
``observer_latency: model``): a reproducible stand-in for the latency measured in the loop.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from latency.models import Empirical
from observer.tracking import PairTracker
from plant import attitude
from plant.params import PlantParams
from plant.texture import TextureParams

if TYPE_CHECKING:
    from plant.scene import Frame


def cone_attitude(t: float, tilt_rad: float = np.deg2rad(8.0), rate_rad_s: float = 1.5):
    """A cone: ``tilt_rad`` toward an azimuth turning at ``rate_rad_s`` (no turn about the
    shaft). Returns the attitude and the body rate (rad/s)."""
    g = rate_rad_s * t
    q = attitude.from_zyz(-g, tilt_rad, g)
    R = attitude.to_matrix(q)
    omega_body = R.T @ (rate_rad_s * (np.array([0.0, 0.0, 1.0]) - R[:, 2]))
    return q, omega_body


def _time_frames(
    params: PlantParams,
    start: Callable[[Frame], None],
    step: Callable[[Frame], float],
    n_frames: int,
    warmup: int,
    seed: int,
    progress: bool,
) -> list[float]:
    """Render the cone sequence; ``start`` on the first frame, ``step`` on every frame
    (returning its compute time, s); the times after ``warmup`` frames."""
    if n_frames < 1 or warmup < 0:
        raise ValueError(f"need n_frames >= 1 and warmup >= 0, got {n_frames}, {warmup}")
    from plant.render_analytic import AnalyticRenderer

    renderer = AnalyticRenderer(params, seed=seed)
    period = 1.0 / params.camera.frame_rate_hz
    times = []
    for k in tqdm(range(n_frames + warmup), disable=not progress, desc="latency", unit="frame"):
        t = k * period
        q, omega = cone_attitude(t)
        frame = renderer.render(q, t_exposure=t, omega=omega)
        if k == 0:
            start(frame)
        dt = step(frame)
        if k >= warmup:
            times.append(dt)
    return times


def measure_locator_latency(
    params: PlantParams,
    locator: PairTracker,
    n_frames: int = 200,
    warmup: int = 5,
    seed: int = 0,
    source: str = "",
    progress: bool = False,
) -> Empirical:
    """Per-frame compute time (s) of ``locator`` on ``n_frames`` rendered frames.

    Returns an ``Empirical`` latency profile (save it with ``.save(path)``; the timed loop takes
    it as ``PipelineConfig.observer``). Frames whose markers are lost still count: the time is
    what the observer spends, as the locator's ``clock`` measures it.
    """
    times = _time_frames(
        params,
        lambda f: locator.start(f.image, f.boxes_px, f.binning),
        lambda f: locator.step(f.image).compute_time_s,
        n_frames, warmup, seed, progress,
    )
    name = source or locator.name
    return Empirical.from_measurements(times, source=f"{name}, {n_frames} analytic frames")


def measure_pair_tracker_latency(
    params: PlantParams,
    tracker: PairTracker,
    n_frames: int = 200,
    warmup: int = 5,
    seed: int = 0,
    progress: bool = False,
) -> Empirical:
    """Per-frame compute time (s) of a marker-pair tracker (e.g. GK-TransT or the dual TransT
    of seed 000 §3.2, ``observer.trackers.make_pair_tracker``) on ``n_frames`` rendered frames,
    started on the first frame's true boxes; timed per ``step`` as the tracker reports it
    (``measure_locator_latency`` with the profile named after the tracker)."""
    return measure_locator_latency(params, tracker, n_frames, warmup, seed, progress=progress)


def measure_orb_latency(
    params: PlantParams,
    method: str = "aekf",
    texture: TextureParams | None = None,
    n_frames: int = 200,
    warmup: int = 5,
    seed: int = 0,
    progress: bool = False,
    clock: Callable[[], float] = time.perf_counter,
) -> Empirical:
    """Per-frame compute time (s) of the ORB observer (``"orb"``, ``"ekf"`` or ``"aekf"``,
    ``observer.orb_observer.OrbObserver``) on ``n_frames`` rendered frames of the textured
    rotor (``texture``, default ``TextureParams()``), matched against a reference view rendered
    at rest. Each frame's time is the observer's own measurement (``Estimate.compute_time_s``:
    front end + back end, timed by ``clock``; tests inject a stand-in). Frames it cannot use
    still count. Returns an ``Empirical`` profile."""
    names = {"orb": "ORB alone", "ekf": "ORB-EKF", "aekf": "ORB-AEKF"}
    if method not in names:
        raise ValueError(f"method must be 'orb', 'ekf' or 'aekf', got {method!r}")
    if n_frames < 1 or warmup < 0:
        raise ValueError(f"need n_frames >= 1 and warmup >= 0, got {n_frames}, {warmup}")
    from latency.frontends import orb_reference
    from observer.orb_observer import OrbObserver
    from plant.render_analytic import AnalyticRenderer, AnalyticRenderOptions

    tex = texture or TextureParams()
    renderer = AnalyticRenderer(params, options=AnalyticRenderOptions(texture=tex), seed=seed)
    observer = OrbObserver(params, orb_reference(params, renderer, tex), method=method, clock=clock)
    period = 1.0 / params.camera.frame_rate_hz
    times = []
    for k in tqdm(range(n_frames + warmup), disable=not progress, desc="latency", unit="frame"):
        t = k * period
        q, omega = cone_attitude(t)
        estimate = observer.update(renderer.render(q, t_exposure=t, omega=omega), t)
        if k >= warmup:
            times.append(estimate.compute_time_s)
    return Empirical.from_measurements(
        times, source=f"{names[method]} (texture seed {tex.seed}), {n_frames} analytic frames"
    )
