"""Rendered validation tracking sequences for the TransT network and their ground-truth boxes.

``validation_sequence`` renders a smooth motion of the rotor with the analytic renderer from a
seed that never generates training data; the training command tracks three of them after
training (``train.evaluate_sequences``) and the tests and ``benchmarks/bench_transt.py`` use
others. ``marker_box_image`` / ``red_box_image`` give a frame's true marker boxes in image px.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from plant import attitude
from plant.camera import sensor_to_image
from plant.params import PlantParams
from plant.render_analytic import AnalyticRenderer, AnalyticRenderOptions
from plant.scene import Frame

#: Seeds of the validation tracking sequences the training command tracks (never used for
#: training data), and their length in frames.
VALIDATION_SEQUENCE_SEEDS = (1001, 1002, 1003)
VALIDATION_SEQUENCE_FRAMES = 150


def validation_sequence(
    seed: int,
    n_frames: int = 120,
    params: PlantParams | None = None,
    options: AnalyticRenderOptions | None = None,
) -> list:
    """A rendered tracking sequence (list of ``plant.scene.Frame``) for validation.

    Smooth motion drawn from ``seed`` (our choice): tilt β(τ) = β0 + A sin(2π τ/T1 + φ1) within
    0-15°, yaw turning at a random rate (up to 2π per 90 frames), spin wandering by up to
    ±0.4 rad, τ in frames at the camera's 36 frames/s; the markers move up to about 10 sensor px
    a frame. Read noise 2 DN, the frame's motion blur from the body rate, random highlights and
    colour distractor; ``options`` replaces these renderer options (e.g.
    ``plant.appearance.heldout_options``).
    Seeds used for reported numbers are never used to generate training data (training scenes
    come from ``render_scene`` with its own seed streams).
    """
    p = params or PlantParams()
    rng = np.random.default_rng([seed, 7919])
    opts = AnalyticRenderOptions(
        noise_sigma_dn=2.0,
        n_highlights=int(rng.integers(0, 4)),
        colour_distractor=("none", "red", "yellow")[int(rng.integers(3))],
    )
    opts = options or opts
    r = AnalyticRenderer(p, options=opts, seed=int(rng.integers(1 << 31)))
    fps = p.camera.frame_rate_hz
    b0 = rng.uniform(3.0, 11.0)
    amp = rng.uniform(1.0, min(b0, 15.0 - b0))
    t1, ph1 = rng.uniform(40, 150), rng.uniform(0, 2 * np.pi)
    yaw_rate = rng.uniform(-1.0, 1.0) * 2 * np.pi / 90.0
    spin_amp, t2 = rng.uniform(0.0, 0.4), rng.uniform(80, 300)

    def q_of(tau: float) -> NDArray[np.float64]:
        beta = math.radians(b0 + amp * math.sin(2 * math.pi * tau / t1 + ph1))
        yaw = yaw_rate * tau
        spin = spin_amp * math.sin(2 * math.pi * tau / t2)
        return attitude.from_zyz(spin - yaw, beta, yaw)

    frames = []
    for k in range(n_frames):
        q, q_next = q_of(k), q_of(k + 0.01)
        omega = attitude.to_rotvec(attitude.multiply(attitude.conjugate(q), q_next)) * fps / 0.01
        frames.append(r.render(q, k / fps, omega=omega))
    return frames


def marker_box_image(frame: Frame, marker: int = 0) -> NDArray[np.float64]:
    """Ground-truth box (x, y, w, h) in image px of ``frame`` (at its binning) of marker 0
    (the red disc) or 1 (the yellow one)."""
    b = np.asarray(frame.boxes_px[marker], dtype=float)
    lo = sensor_to_image(b[:2], frame.binning)
    return np.r_[lo, b[2:] / frame.binning]


def red_box_image(frame: Frame) -> NDArray[np.float64]:
    """The red disc's ground-truth box (x, y, w, h) in image px of ``frame`` (its binning)."""
    return marker_box_image(frame, 0)
