"""Tracking sequences rendered deterministically from seeds, with the seed's synthetic cases.

**Motion** (seed 000 §4.1: the rotor "was manually manipulated" and recorded continuously; the
seed gives no trajectory, so the model is our choice): a hand moves the rotor from one pose to
the next and pauses. The pose is (spin ψ about the shaft, tilt β, tilt azimuth γ) with the
attitude ``q = from_zyz(ψ - γ, β, γ)`` (``docs/plant.md``: a pure tilt toward γ is
``from_zyz(-γ, β, γ)``, so ψ is the turn about the shaft). Each move changes the spin, the tilt
(with its azimuth), or both, towards a random target (|Δψ| ≤ 90°, β ∈ [0, 15°] the mechanical
range of seed 000 §2.4, |Δγ| ≤ 120°) along a minimum-jerk profile lasting 0.6-2.0 s (a brisk
hand: up to about 300°/s at the peak of a short spin move), followed by a dwell of 0-0.8 s; a
small hand tremor (0.05° per angle, 3-8 Hz) rides on top. Frames at 36 frames/s (seed 000 §5).

**Rendering**: ``plant.render_analytic.AnalyticRenderer`` (default camera, 612 x 512 at binning
4), with the body rate from the trajectory for the exposure blur, and per-sequence illumination
0.85-1.15, 0-2 stationary highlights and read noise 1.5-3 DN drawn from the seed (our choices,
for variety between sequences). Ground truth: ``Frame.marker_px`` (2, 2) and ``Frame.boxes_px``
(2, 4), full-sensor px, red then yellow.

**Cases** on top of the same underlying motion:

* ``clean``: frame k shows trajectory frame k.
* ``occlusion`` (seed 000 §4.3.1): frames 100-110 get a black (0) rectangle over both markers'
  boxes plus a 20 px margin (sensor px; converted to image px, every pixel the rectangle touches).
  The ground truth is kept.
* ``blur`` (seed 000 §4.3.2): frames 130-160 advance the trajectory K = 5 frames each
  (τ = 130 + 5 (k - 130)), so the markers move five times faster, and each is the mean of
  M = 6 consecutive trajectory frames τ-5 … τ (linear superposition). Ground truth of a blurred
  frame: the mean of those six centres (the centre of the smear) and the mean box. After frame 160
  the trajectory continues at normal speed (τ = k + 120).

**Hard cases** (our choice) disturb frames ``HARD_FRAMES`` (100-140) of the same motion, ramped
in and out over 12 frames (``disturb``): ``occluder_<colour>`` a finger (a capsule 2.6 marker
radii wide, colour family of ``plant.appearance``) sliding over the red marker until it is
hidden, staying and withdrawing (frames with at least half the red disc hidden are flagged
``occluded``; the truth is kept); ``highlight`` a white glare on each marker; ``distractor_red``
/ ``distractor_yellow`` a disc of marker size and colour beside the pair; ``fast`` the
trajectory at ``K_FAST`` = 3 times the speed; ``dark`` the brightness down to 30 % and back.
``heldout_pattern`` / ``heldout_lighting`` render the whole sequence in an appearance family
the TransT network never saw in training (``plant.appearance.heldout_options``), and
``occluder_purple`` uses the held-out occluder colour.

**Seeds**. Validation sequences use seeds ``VALIDATION_SEED_BASE + i`` (7,000,000 + i); they are
for reported numbers only, never for training or tuning. Development and tuning use
``DEVELOPMENT_SEED_BASE + i`` (6,000,000 + i). The TransT network is trained on renderer data from
the training script's own seeds (``observer/transt``), which stay below 6,000,000; keep it so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from plant import attitude
from plant.appearance import heldout_options, occluder_rgb
from plant.camera import sensor_to_image
from plant.mjcf import RED_RGB, YELLOW_RGB
from plant.params import PlantParams
from plant.render_analytic import AnalyticRenderer, AnalyticRenderOptions

Case = Literal[
    "clean", "occlusion", "blur",
    "occluder_skin", "occluder_red_brown", "occluder_dark", "occluder_blue", "occluder_purple",
    "highlight", "distractor_red", "distractor_yellow", "fast", "dark",
    "heldout_pattern", "heldout_lighting",
]
Source = Literal["analytic", "unseen"]
#: The seed's cases (000 §4.3).
CASES: tuple[Case, ...] = ("clean", "occlusion", "blur")
#: Hard cases (our choice, see the module docstring): disturbances during ``HARD_FRAMES``.
HARD_CASES: tuple[Case, ...] = (
    "occluder_skin", "occluder_red_brown", "occluder_dark", "occluder_blue", "highlight",
    "distractor_red", "distractor_yellow", "fast", "dark",
)
#: Appearance families held out from the network's training (``plant.appearance``): the
#: held-out rotor pattern, the held-out lighting, and occluders of the held-out colour.
HELDOUT_CASES: tuple[Case, ...] = ("heldout_pattern", "heldout_lighting", "occluder_purple")
ALL_CASES: tuple[Case, ...] = CASES + HARD_CASES + HELDOUT_CASES
#: Cases drawn over the frames by ``disturb`` besides the occluders and distractors.
DRAWN_CASES = ("highlight", "dark")
#: Frames of the hard cases' disturbances (inclusive start, exclusive stop).
HARD_FRAMES = range(100, 141)

#: Seed 000 §4.3.1: occluded frames 100-110 (inclusive) and the occluder's margin, sensor px.
OCCLUSION_FRAMES = range(100, 111)
OCCLUSION_MARGIN_SENSOR_PX = 20.0
#: Seed 000 §4.3.2: blurred frames 130-160 (inclusive), temporal downsampling K, frames averaged M.
BLUR_FRAMES = range(130, 161)
K_DOWNSAMPLE = 5
M_AVERAGE = 6
#: The ``fast`` case: trajectory frames advanced per output frame during ``HARD_FRAMES``.
K_FAST = 3

#: Seed ranges (see the module docstring). Training data must use seeds below both.
VALIDATION_SEED_BASE = 7_000_000
DEVELOPMENT_SEED_BASE = 6_000_000


def validation_seeds(n: int) -> list[int]:
    """The first ``n`` validation seeds (reported numbers only; never train or tune on them)."""
    return [VALIDATION_SEED_BASE + i for i in range(int(n))]


def development_seeds(n: int) -> list[int]:
    """The first ``n`` development seeds (for tuning and tests)."""
    return [DEVELOPMENT_SEED_BASE + i for i in range(int(n))]


class ManualMotionConfig(BaseModel):
    """The hand-moved trajectory (all our choices, see the module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    tilt_max_deg: float = Field(15.0, gt=0.0, le=15.0, description="Seed 000 §2.4: 0-15°.")
    spin_step_deg: float = Field(90.0, ge=0.0, description="Largest spin change of one move.")
    azimuth_step_deg: float = Field(120.0, ge=0.0, description="Largest azimuth change of a "
                                    "move.")
    move_s: tuple[float, float] = Field((0.6, 2.0), description="Duration range of a move, s.")
    dwell_s: tuple[float, float] = Field((0.0, 0.8), description="Pause range after a move, s.")
    tremor_deg: float = Field(0.05, ge=0.0, description="Hand tremor amplitude per angle, deg.")
    tremor_hz: tuple[float, float] = Field((3.0, 8.0), description="Tremor frequency range, Hz.")


class SequenceSpec(BaseModel):
    """What to render: seed, length, case and motion."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    seed: int = Field(..., ge=0, description="Seed of the motion, the scene variations and noise.")
    case: Case = "clean"
    n_frames: int = Field(300, ge=1, description="Frames in the sequence (seed cases need 161).")
    fps: float = Field(36.0, gt=0.0, description="Seed 000 §5: 36 frames/s.")
    motion: ManualMotionConfig = ManualMotionConfig()
    binning: int | None = Field(None, description="Renderer binning (default: the camera's).")
    source: Source = Field(
        "analytic", description="Image source: ``analytic`` (``plant.render_analytic``, the "
        "renderer the TransT network was trained on) or ``unseen`` (``plant.render_unseen``: "
        "MuJoCo in a look and through a sensor drawn from the seed, never used for training).")

    @property
    def name(self) -> str:
        """The sequence's name, ``s<seed>_<case>`` (with ``_unseen`` for the evaluation-only
        source)."""
        return f"s{self.seed}_{self.case}" + ("_unseen" if self.source == "unseen" else "")


@dataclass
class TrackingSequence:
    """Frames with ground truth for the tracking benchmark.

    Attributes
    ----------
    name : identifier (e.g. ``s7000000_blur`` or a CVAT task name).
    images : (N, H, W, 3) uint8 RGB frames, binned by ``binning``.
    marker_px : (N, 2, 2) true centres, red then yellow, full-sensor px (NaN where unknown).
    boxes_px : (N, 2, 4) true boxes (x, y, w, h), full-sensor px (NaN where unknown).
    binning : sensor px per image px.
    fps : frame rate, frames/s.
    case : "clean", "occlusion", "blur" or "recorded".
    occluded, blurred : (N,) flags of the synthetic disturbances (or CVAT's ``occluded``).
    params : the plant/camera parameters the frames belong to.
    seed : the spec's seed (None for recordings).
    tilt_rad : (N,) true tilt at each frame (NaN where unknown).
    """

    name: str
    images: NDArray[np.uint8]
    marker_px: NDArray[np.float64]
    boxes_px: NDArray[np.float64]
    binning: int
    fps: float
    case: str
    occluded: NDArray[np.bool_]
    blurred: NDArray[np.bool_]
    params: PlantParams = field(default_factory=PlantParams)
    seed: int | None = None
    tilt_rad: NDArray[np.float64] | None = None

    @property
    def n_frames(self) -> int:
        """Number of frames N (the first axis of ``images``)."""
        return int(self.images.shape[0])

    def __post_init__(self) -> None:
        n = self.images.shape[0]
        if self.images.ndim != 4 or self.images.shape[3] != 3 or self.images.dtype != np.uint8:
            raise ValueError(f"images must be (N, H, W, 3) uint8, got {self.images.shape} "
                             f"{self.images.dtype}")
        for name, arr, shape in (("marker_px", self.marker_px, (n, 2, 2)),
                                 ("boxes_px", self.boxes_px, (n, 2, 4)),
                                 ("occluded", self.occluded, (n,)),
                                 ("blurred", self.blurred, (n,))):
            if np.shape(arr) != shape:
                raise ValueError(f"{name} must have shape {shape}, got {np.shape(arr)}")


# --- motion ------------------------------------------------------------------------------------
def _min_jerk(s: NDArray[np.float64]) -> NDArray[np.float64]:
    """Minimum-jerk profile 10 s³ - 15 s⁴ + 6 s⁵ on s ∈ [0, 1]."""
    return s**3 * (10.0 - 15.0 * s + 6.0 * s * s)


def manual_motion(
    rng: np.random.Generator, n_frames: int, fps: float, cfg: ManualMotionConfig
) -> NDArray[np.float64]:
    """(n_frames, 3) angles (spin ψ, tilt β, azimuth γ) in rad at t = k / fps (see the module
    docstring)."""
    t = np.arange(n_frames) / fps
    # tremor first, so that the motion of the first frames does not depend on n_frames
    trem_f = rng.uniform(*cfg.tremor_hz, size=(3, 3))
    trem_ph = rng.uniform(0.0, 2.0 * math.pi, size=(3, 3))
    pose = np.array([rng.uniform(-math.pi, math.pi),
                     rng.uniform(0.0, math.radians(cfg.tilt_max_deg)),
                     rng.uniform(-math.pi, math.pi)])
    knots_t, knots_p = [0.0], [pose.copy()]
    t_now = 0.0
    while t_now < t[-1] + 1.0:
        kind = rng.choice(["spin", "tilt", "both"], p=[0.35, 0.35, 0.30])
        target = pose.copy()
        if kind in ("spin", "both"):
            target[0] += math.radians(rng.uniform(-cfg.spin_step_deg, cfg.spin_step_deg))
        if kind in ("tilt", "both"):
            target[1] = rng.uniform(0.0, math.radians(cfg.tilt_max_deg))
            target[2] += math.radians(rng.uniform(-cfg.azimuth_step_deg, cfg.azimuth_step_deg))
        dur = rng.uniform(*cfg.move_s)
        dwell = rng.uniform(*cfg.dwell_s)
        knots_t += [t_now + dur, t_now + dur + dwell]
        knots_p += [target, target.copy()]
        pose, t_now = target, t_now + dur + dwell
    angles = np.empty((n_frames, 3))
    kt = np.array(knots_t)
    kp = np.array(knots_p)
    idx = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, len(kt) - 2)
    span = np.maximum(kt[idx + 1] - kt[idx], 1e-12)
    s = _min_jerk(np.clip((t - kt[idx]) / span, 0.0, 1.0))
    angles[:] = kp[idx] + s[:, None] * (kp[idx + 1] - kp[idx])
    if cfg.tremor_deg > 0.0:
        for j in range(3):
            f, ph = trem_f[j], trem_ph[j]
            trem = np.sin(2.0 * math.pi * f[:, None] * t[None, :] + ph[:, None]).sum(axis=0)
            angles[:, j] += math.radians(cfg.tremor_deg) * trem / math.sqrt(1.5)
    tmax = math.radians(cfg.tilt_max_deg)
    angles[:, 1] = np.clip(np.abs(angles[:, 1]), 0.0, tmax)
    return angles


def attitudes(angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 4) quaternions from (spin ψ, tilt β, azimuth γ) rows: from_zyz(ψ - γ, β, γ)."""
    return np.array([attitude.from_zyz(a[0] - a[2], a[1], a[2]) for a in angles])


def body_rates(qs: NDArray[np.float64], fps: float) -> NDArray[np.float64]:
    """(N, 3) body-frame angular velocity, rad/s, by central differences of the attitudes."""
    rv = np.array([attitude.to_rotvec(attitude.multiply(attitude.conjugate(qs[k]), qs[k + 1]))
                   for k in range(len(qs) - 1)]) * fps
    if len(rv) == 0:
        return np.zeros((len(qs), 3))
    w = np.empty((len(qs), 3))
    w[0], w[-1] = rv[0], rv[-1]
    w[1:-1] = 0.5 * (rv[:-1] + rv[1:])
    return w


def trajectory_index(k: int, case: Case) -> int:
    """Trajectory frame τ shown by output frame k (the blur and fast cases' time warps)."""
    frames, K = {"blur": (BLUR_FRAMES, K_DOWNSAMPLE), "fast": (HARD_FRAMES, K_FAST)}.get(
        case, (None, 1))
    if frames is None or k < frames.start:
        return k
    if k in frames:
        return frames.start + K * (k - frames.start)
    return k + (K - 1) * (len(frames) - 1)


# --- hard cases --------------------------------------------------------------------------------
def _ramp(k: int) -> float:
    """0 before ``HARD_FRAMES``, rising linearly to 1 over its first 12 frames, 1 until its last
    12, falling back to 0 at its end."""
    a, b = HARD_FRAMES.start, HARD_FRAMES.stop - 1
    return float(np.clip(min((k - a) / 12.0, (b - k) / 12.0), 0.0, 1.0)) if a <= k <= b else 0.0


@dataclass(frozen=True)
class _Disturbance:
    """A hard case's draws (from the sequence seed): occluder direction and colour, highlight
    offsets, distractor direction."""

    angle: float
    rgb: tuple[int, int, int]
    offsets: NDArray[np.float64]


def _draw_disturbance(case: str, rng: np.random.Generator) -> _Disturbance:
    family = case.removeprefix("occluder_")
    rgb = occluder_rgb(rng, family) if case.startswith("occluder_") else (0, 0, 0)
    return _Disturbance(float(rng.uniform(-np.pi / 6, np.pi / 6) + np.pi / 2 * rng.choice([-1, 1])),
                        rgb, rng.uniform(-0.5, 0.5, size=(2, 2)))


def disturb(
    case: str, k: int, image: NDArray[np.uint8], marker_img: NDArray[np.float64],
    radius_img: float, d: _Disturbance,
) -> float:
    """Apply hard case ``case`` to frame ``k`` (image px, in place) and return the covered
    fraction of the red disc (0-1).

    ``marker_img`` (2, 2): true red and yellow centres, image px; ``radius_img``: marker radius,
    image px. Occluders are a finger (a capsule 2.6 marker radii wide) coming from a direction
    about perpendicular to the red→yellow line; its tip slides from 3 radii outside the red
    marker to 1.3 radii past its centre over the first 12 frames, stays, and withdraws over
    the last 12. ``highlight``: a white Gaussian glare (sigma 0.45 radii, peak 255 DN) on each
    marker, off-centre by up to half a radius. ``distractor_*``: a disc of the marker's size
    and colour 2.5 diameters from the red marker, beside the pair. ``dark``: the frame's
    brightness drops to 30 % and recovers (``_ramp``).
    """
    s = _ramp(k)
    if s == 0.0:
        return 0.0
    red, yellow = marker_img
    axis = (yellow - red) / max(float(np.hypot(*(yellow - red))), 1e-9)
    rot = np.array([[np.cos(d.angle), -np.sin(d.angle)], [np.sin(d.angle), np.cos(d.angle)]])
    side = rot @ axis  # about perpendicular to the pair
    r = radius_img
    if case == "dark":
        f = image.astype(np.float32) * np.float32(1.0 - 0.7 * s)
        image[...] = np.clip(np.rint(f), 0, 255).astype(np.uint8)
        return 0.0
    if case == "highlight":
        h, w = image.shape[:2]
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        acc = np.zeros((h, w), np.float32)
        for c, off in zip(marker_img, d.offsets, strict=True):
            cc = c + off * r
            acc += np.exp(-((xx - cc[0]) ** 2 + (yy - cc[1]) ** 2) / (2 * (0.45 * r) ** 2))
        f = image.astype(np.float32) + 255.0 * s * acc[..., None]
        image[...] = np.clip(np.rint(f), 0, 255).astype(np.uint8)
        return 0.0
    if case.startswith("distractor_"):
        rgb = RED_RGB if case == "distractor_red" else YELLOW_RGB
        c = red + 5.0 * r * side
        colour = tuple(float(255.0 * v * 0.95) for v in rgb)
        cv2.circle(image, tuple(int(round(v * 16)) for v in c), int(round(r * 16)), colour, -1,
                   cv2.LINE_AA, 4)
        return 0.0
    # occluder: a capsule from outside the frame to its tip
    tip = red + side * r * (3.0 - 4.3 * s)
    far = tip + side * 4.0 * max(image.shape[:2])
    mask = np.zeros(image.shape[:2], np.uint8)
    cv2.line(mask, tuple(int(round(v * 16)) for v in tip), tuple(int(round(v * 16)) for v in far),
             255, int(round(2.6 * r)), cv2.LINE_AA, 4)
    alpha = mask.astype(np.float32)[..., None] / 255.0
    image[...] = np.clip(np.rint(image * (1 - alpha) + alpha * np.asarray(d.rgb, np.float32)),
                         0, 255).astype(np.uint8)
    disc = np.zeros_like(mask)
    cv2.circle(disc, tuple(int(round(v * 16)) for v in red), int(round(r * 16)), 255, -1,
               cv2.LINE_8, 4)
    inside = disc > 0
    return float(np.mean(mask[inside] > 127)) if inside.any() else 0.0


# --- rendering ---------------------------------------------------------------------------------
def occluder_pixels(
    boxes_sensor_px: NDArray[np.float64], binning: int, width: int, height: int,
    margin_sensor_px: float = OCCLUSION_MARGIN_SENSOR_PX,
) -> tuple[slice, slice]:
    """Rows and columns of the occluder (seed 000 §4.3.1): the union of the boxes (k, 4) plus
    ``margin_sensor_px`` on each side (sensor px), as every pixel of a ``width`` x ``height``
    frame binned by ``binning`` that the rectangle touches."""
    lo = np.min(boxes_sensor_px[:, :2], axis=0) - margin_sensor_px
    hi = np.max(boxes_sensor_px[:, :2] + boxes_sensor_px[:, 2:], axis=0) + margin_sensor_px
    lo_i = (lo + 0.5) / binning - 0.5
    hi_i = (hi + 0.5) / binning - 0.5
    c0, r0 = (max(int(math.ceil(v - 0.5)), 0) for v in lo_i)
    c1 = min(int(math.floor(hi_i[0] + 0.5)), width - 1)
    r1 = min(int(math.floor(hi_i[1] + 0.5)), height - 1)
    return slice(r0, r1 + 1), slice(c0, c1 + 1)


def render_sequence(spec: SequenceSpec, params: PlantParams | None = None) -> TrackingSequence:
    """Render the sequence of ``spec`` (deterministic: same spec, same frames)."""
    p = params or PlantParams()
    n = spec.n_frames
    n_traj = n + (K_DOWNSAMPLE - 1) * (len(BLUR_FRAMES) - 1)  # the same motion for every case
    angles = manual_motion(np.random.default_rng([spec.seed, 0x7A3C]), n_traj, spec.fps,
                           spec.motion)
    qs = attitudes(angles)
    omegas = body_rates(qs, spec.fps)
    rng = np.random.default_rng([spec.seed, 0x0B7])
    options = AnalyticRenderOptions(
        illumination=float(rng.uniform(0.85, 1.15)),
        n_highlights=int(rng.integers(0, 3)),
        noise_sigma_dn=float(rng.uniform(1.5, 3.0)),
    )
    if spec.case in ("heldout_pattern", "heldout_lighting"):
        p, options = heldout_options(spec.seed, spec.case.removeprefix("heldout_"))
    dist = _draw_disturbance(spec.case, np.random.default_rng([spec.seed, 0xD15]))
    noise_rng = np.random.default_rng([spec.seed, 0x51D])
    if spec.source == "unseen":
        from plant.render_unseen import UnseenRenderer, draw_look

        look = draw_look(np.random.default_rng([spec.seed, 0x5EE]))
        renderer = UnseenRenderer(p, look, noise_rng, spec.binning)
    else:
        renderer = AnalyticRenderer(p, binning=spec.binning, options=options, seed=noise_rng)
    b = renderer.binning
    images = np.empty((n, renderer.height, renderer.width, 3), np.uint8)
    marker = np.empty((n, 2, 2))
    boxes = np.empty((n, 2, 4))
    tilt = np.empty(n)
    occluded = np.zeros(n, bool)
    blurred = np.zeros(n, bool)
    for k in range(n):
        tau = trajectory_index(k, spec.case)
        if spec.case == "blur" and k in BLUR_FRAMES:
            taus = list(range(tau - M_AVERAGE + 1, tau + 1))
            blurred[k] = True
        else:
            taus = [tau]
        frames = [renderer.render(qs[j], j / spec.fps, omega=omegas[j]) for j in taus]
        if len(frames) == 1:
            images[k] = frames[0].image
        else:
            acc = np.mean([f.image.astype(np.float32) for f in frames], axis=0)
            images[k] = np.clip(np.rint(acc), 0, 255).astype(np.uint8)
        marker[k] = np.mean([f.marker_px for f in frames], axis=0)
        boxes[k] = np.mean([f.boxes_px for f in frames], axis=0)
        tilt[k] = attitude.tilt(qs[tau])
        if spec.case == "occlusion" and k in OCCLUSION_FRAMES:
            rows, cols = occluder_pixels(boxes[k], b, renderer.width, renderer.height)
            images[k][rows, cols] = 0
            occluded[k] = True
        elif spec.case.startswith(("occluder_", "distractor_")) or spec.case in DRAWN_CASES:
            covered = disturb(spec.case, k, images[k], sensor_to_image(marker[k], b),
                              float(np.mean(boxes[k, 0, 2:])) / (2 * b), dist)
            occluded[k] = covered >= 0.5
    return TrackingSequence(spec.name, images, marker, boxes, b, spec.fps, spec.case, occluded,
                            blurred, p, spec.seed, tilt)


def validation_suite(
    n_seeds: int = 2, cases: tuple[Case, ...] = CASES, n_frames: int = 300
) -> list[SequenceSpec]:
    """Specs of the validation sequences: ``n_seeds`` seeds x ``cases``."""
    return [SequenceSpec(seed=s, case=c, n_frames=n_frames)
            for s in validation_seeds(n_seeds) for c in cases]
