"""Measure an observer's latency profile on a rendered sequence: one call, one ``Empirical``.

The sequence is rendered with the analytic renderer from a seed (a slow cone in the workspace,
with motion blur), the locator (tracker + GK assistance) is started on the first frame's true
box, and the wall-clock time of each ``locate`` call is recorded. The first ``warmup`` frames are
not recorded (caches, lazy initialisation). Rendering is not timed.
"""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from latency.models import Empirical
from observer.frame_observer import MarkerLocator
from plant import attitude
from plant.params import PlantParams


def cone_attitude(t: float, tilt_rad: float = np.deg2rad(8.0), rate_rad_s: float = 1.5):
    """A cone: ``tilt_rad`` toward an azimuth turning at ``rate_rad_s`` (no turn about the
    shaft). Returns the attitude and the body rate (rad/s)."""
    g = rate_rad_s * t
    q = attitude.from_zyz(-g, tilt_rad, g)
    R = attitude.to_matrix(q)
    omega_body = R.T @ (rate_rad_s * (np.array([0.0, 0.0, 1.0]) - R[:, 2]))
    return q, omega_body


def measure_locator_latency(
    params: PlantParams,
    locator: MarkerLocator,
    n_frames: int = 200,
    warmup: int = 5,
    seed: int = 0,
    source: str = "",
    progress: bool = False,
) -> Empirical:
    """Per-frame compute time (s) of ``locator`` on ``n_frames`` rendered frames.

    Returns an ``Empirical`` latency profile (save it with ``.save(path)``; the timed loop takes
    it as ``PipelineConfig.observer``). Frames whose markers are lost still count: the time is
    what the observer spends.
    """
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
            locator.start(frame.image, frame.binning, frame.boxes_px[0])
        located = locator.locate(frame.image, frame.binning)
        if k >= warmup:
            times.append(located.compute_time_s)
    name = source or f"{type(locator.tracker).__name__} + GK assistance"
    return Empirical.from_measurements(times, source=f"{name}, {n_frames} analytic frames")
