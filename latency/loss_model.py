"""Per-tracker tracking-loss models calibrated from image-in-the-loop runs.

A real tracker loses the markers for reasons a hand-set search window does not describe. This
module holds the *calibrated* alternative used by the measurement front end
(``latency.frontends.MeasurementFrontEnd`` with ``loss: {kind: calibrated, tracker: NAME}``): a
two-state (tracked / lost) Markov model whose transition probabilities depend on what the
front end knows about each frame, fitted by ``pmspm calibrate-loss``
(``experiments.loss_calibration``) on frames rendered and tracked by the tracker itself in
closed loop (``latency.image_engine``).

Per processed frame k, from the true marker centres and the front end's own constant-velocity
prediction (``latency.frontends.MarkerPrediction``, advanced by the frames it measured):

* ``offset_px``: the prediction's miss, max over both markers of |truth - prediction|, sensor px
  (0 before the first measurement); it grows with the loop's acceleration and the frames since
  the last measurement;
* ``blur_px``: the largest marker travel during the exposure, sensor px
  (``blur_travel_px``);
* ``frames_lost``: processed frames lost in a row before this one.

Frame k is lost (no measurement, or a centre more than 20 px from the truth, seed 000 §4.2)

    after a tracked frame:   P = σ(h0 + h1 log(1 + offset_px) + h2 log(1 + blur_px))
    after a lost frame:      P = σ(r0 + r1 log(1 + offset_px) + r2 log(1 + blur_px)
                                   + r3 log(1 + frames_lost))

with σ the logistic function (``hazard`` and ``persistence`` coefficients); a tracked frame's
centres are the truth plus Gaussian noise of ``noise_sigma_px`` per coordinate (the robust
spread of the tracker's centre error on its tracked frames). Logistic regression is our
choice: two transition probabilities that are monotone in a few named conditions, fitted by
maximum likelihood with a light ridge (``fit_logistic``), each coefficient readable.

Files: ``latency/loss_models/<tracker>.json`` (``LossModelFile``), versioned
(``FORMAT_VERSION``) and stamped with the digest of the network weights they were calibrated
with, so a file from another format or other weights is refused with the command that
rewrites it.
"""

from __future__ import annotations

import functools
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field
from scipy.optimize import minimize

from plant import attitude
from plant.camera import marker_pixels
from plant.params import PlantParams

#: The scene appearance the intercepts describe; the others carry offsets (``scene_offsets``).
BASELINE_SCENE = "nominal"
#: Version of the file layout; files of another version are refused.
FORMAT_VERSION = 2
#: Where the shipped calibrations live.
MODELS_DIR = Path(__file__).resolve().parent / "loss_models"
#: Trackers that can be calibrated (``observer.trackers.make_pair_tracker`` names).
CALIBRATABLE = ("gk_transt", "dual_transt", "kcf_gk", "k2cf")
#: Trackers whose behaviour depends on the shipped TransT weights.
NETWORK_TRACKERS = ("gk_transt", "dual_transt")
HAZARD_FEATURES = ("log1p_offset_px", "log1p_blur_px")
PERSISTENCE_FEATURES = ("log1p_offset_px", "log1p_blur_px", "log1p_frames_lost")


class LossModelError(ValueError):
    """A calibration file is missing, of another format or stale; says how to rewrite it."""


def calibrate_command(tracker: str) -> str:
    """The command that (re)writes the calibration of ``tracker``."""
    return f"pmspm calibrate-loss --tracker {tracker}"


class LossModelFile(BaseModel):
    """A calibrated loss model as written to ``<tracker>.json``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    format_version: int = Field(description="FORMAT_VERSION of the writer.")
    tracker: str = Field(description="The pair tracker it describes (make_pair_tracker name).")
    weights_sha256: str | None = Field(
        description="SHA-256 of the TransT weights the tracker ran with; None for trackers "
        "without a network.")
    hazard: tuple[float, ...] = Field(
        description="h0, h1, h2: logit of P(lost | tracked before), see the module docstring.")
    persistence: tuple[float, ...] = Field(
        description="r0 .. r3: logit of P(lost | lost before).")
    noise_sigma_px: float = Field(ge=0.0, description="Per-coordinate centre noise of tracked "
                                  "frames, sensor px (1.4826 x the median absolute error).")
    n_frames: int = Field(ge=0, description="Frames the fit used.")
    n_runs: int = Field(ge=0, description="Image-mode runs the fit used.")
    design: dict = Field(description="The calibration design (rates, delays, seeds, length).")
    scene_offsets: dict[str, tuple[float, float]] = Field(
        default_factory=dict, description="Per scene appearance of the calibration other than "
        "BASELINE_SCENE: the offsets (hazard, persistence) added to the intercepts h0 and r0.")
    lost_by_condition: list[dict] = Field(
        default_factory=list, description="The fit's lost-frame fraction per camera (frame "
        "rate, exposure) and per scene appearance (experiments.loss_calibration).")
    validation: list[dict] = Field(
        default_factory=list, description="Held-out agreement rows (experiments.loss_calibration).")
    created_utc: str = Field(description="When it was written.")


def sigmoid(x: NDArray[np.float64] | float) -> NDArray[np.float64] | float:
    """The logistic function 1 / (1 + exp(-x)), evaluated without overflow."""
    return 0.5 * (1.0 + np.tanh(0.5 * np.asarray(x, dtype=float)))


class LossModel:
    """A loaded calibration: the loss probability of a frame (module docstring) in one of the
    calibration's scene appearances (``scene``; its offsets added to both intercepts)."""

    def __init__(self, data: LossModelFile, scene: str = BASELINE_SCENE) -> None:
        self.data = data
        self.scene = scene
        self.hazard = np.asarray(data.hazard, dtype=float)
        self.persistence = np.asarray(data.persistence, dtype=float)
        if self.hazard.shape != (1 + len(HAZARD_FEATURES),) or \
                self.persistence.shape != (1 + len(PERSISTENCE_FEATURES),):
            raise LossModelError(f"calibration of {data.tracker!r} has coefficients of the wrong "
                                 f"length; rewrite it with `{calibrate_command(data.tracker)}`")
        if scene != BASELINE_SCENE:
            if scene not in data.scene_offsets:
                raise LossModelError(
                    f"the calibration of {data.tracker!r} has no scene {scene!r}; choose one of "
                    f"{', '.join(self.scenes)}")
            dh, dr = data.scene_offsets[scene]
            self.hazard[0] += dh
            self.persistence[0] += dr

    @property
    def scenes(self) -> tuple[str, ...]:
        """The scene appearances this calibration describes (``BASELINE_SCENE`` first)."""
        return (BASELINE_SCENE, *self.data.scene_offsets)

    @property
    def noise_sigma_px(self) -> float:
        """Per-coordinate noise of the tracked marker centres, sensor px (from the fitted data)."""
        return self.data.noise_sigma_px

    def p_lost(self, offset_px: float, blur_px: float, frames_lost: int) -> float:
        """Probability that a frame is lost given its conditions (module docstring).

        Mirrored in ``latency.compiled.frontend._p_lost``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        a, b = math.log1p(offset_px), math.log1p(blur_px)
        if frames_lost <= 0:
            h = self.hazard
            return float(sigmoid(h[0] + h[1] * a + h[2] * b))
        r = self.persistence
        return float(sigmoid(r[0] + r[1] * a + r[2] * b + r[3] * math.log1p(frames_lost)))


def model_path(tracker: str, folder: Path | None = None) -> Path:
    """The calibration file of ``tracker``."""
    return (folder or MODELS_DIR) / f"{tracker}.json"


def current_weights_sha256(tracker: str) -> str | None:
    """The digest of the shipped TransT weights for the network trackers, else None."""
    if tracker not in NETWORK_TRACKERS:
        return None
    from observer.transt.weights import SMALL_WEIGHTS, sha256_of

    return sha256_of(SMALL_WEIGHTS)


def check_tracker(tracker: str) -> None:
    """``LossModelError`` naming the known trackers for an unknown name."""
    if tracker not in CALIBRATABLE:
        raise LossModelError(f"unknown tracker {tracker!r} for a calibrated loss model; "
                             f"choose one of {', '.join(CALIBRATABLE)}")


@functools.lru_cache(maxsize=16)
def _load(path: str, mtime_ns: int, tracker: str) -> LossModel:
    try:
        raw = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise LossModelError(f"cannot read the calibration {path}: {exc}; rewrite it with "
                             f"`{calibrate_command(tracker)}`") from exc
    version = raw.get("format_version") if isinstance(raw, dict) else None
    if version != FORMAT_VERSION:
        raise LossModelError(
            f"the calibration {path} has format version {version!r}, this version reads "
            f"{FORMAT_VERSION}; rewrite it with `{calibrate_command(tracker)}`")
    data = LossModelFile.model_validate(raw)
    if data.tracker != tracker:
        raise LossModelError(f"the calibration {path} describes {data.tracker!r}, not "
                             f"{tracker!r}; rewrite it with `{calibrate_command(tracker)}`")
    return LossModel(data)


def load_loss_model(tracker: str, folder: Path | None = None,
                    scene: str = BASELINE_SCENE) -> LossModel:
    """The calibrated loss model of ``tracker`` in the scene appearance ``scene``;
    ``LossModelError`` for an unknown tracker or scene, a missing file, a file of another format
    version, or a file calibrated with other network weights than the shipped ones (each naming
    the command that rewrites it)."""
    check_tracker(tracker)
    p = model_path(tracker, folder)
    if not p.is_file():
        raise LossModelError(f"no calibrated loss model for {tracker!r} ({p} is missing); "
                             f"write it with `{calibrate_command(tracker)}`")
    model = _load(str(p), p.stat().st_mtime_ns, tracker)
    want = current_weights_sha256(tracker)
    if want is not None and model.data.weights_sha256 != want:
        raise LossModelError(
            f"the calibration {p} was made with other TransT weights (SHA-256 "
            f"{model.data.weights_sha256}, shipped {want}): it is stale; rewrite it with "
            f"`{calibrate_command(tracker)}`")
    return model if scene == BASELINE_SCENE else LossModel(model.data, scene)


def write_loss_model(data: LossModelFile, folder: Path | None = None) -> Path:
    """Write ``data`` to its file atomically (a temporary file in the same folder, renamed)."""
    p = model_path(data.tracker, folder)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=p.parent, prefix=f".{p.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(data.model_dump_json(indent=1) + "\n")
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return p


# --- features ------------------------------------------------------------------------------
def blur_travel_px(params: PlantParams, q: ArrayLike, omega: ArrayLike) -> float:
    """Largest marker travel (sensor px) over the camera's exposure at body rate ``omega``
    (rad/s) about mid-exposure attitude ``q``: the two markers projected half an exposure
    either side.

    Mirrored in ``latency.compiled.frontend._blur_travel_px``; keep both in step
    (tests/test_compiled_mirror.py checks them equal)."""
    half = 0.5 * params.camera.exposure_s
    w = np.asarray(omega, dtype=float)
    ends = [marker_pixels(params, attitude.multiply(q, attitude.from_rotvec(s * half * w)))
            for s in (-1.0, 1.0)]
    return float(np.max(np.linalg.norm(ends[1] - ends[0], axis=1)))


def prediction_offset_px(truth_px: NDArray[np.float64],
                         predicted_px: NDArray[np.float64] | None) -> float:
    """Max over the markers of |truth - prediction| (sensor px); 0 without a prediction.

    Mirrored in ``latency.compiled.frontend._p_lost``; keep both in step
    (tests/test_compiled_mirror.py checks them equal)."""
    if predicted_px is None:
        return 0.0
    return float(np.max(np.linalg.norm(truth_px - predicted_px, axis=1)))


def design_matrices(offset_px: ArrayLike, blur_px: ArrayLike, frames_lost: ArrayLike
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The features of ``HAZARD_FEATURES`` and ``PERSISTENCE_FEATURES`` (n, 2) and (n, 3)."""
    a = np.log1p(np.asarray(offset_px, dtype=float))
    b = np.log1p(np.asarray(blur_px, dtype=float))
    c = np.log1p(np.asarray(frames_lost, dtype=float))
    return np.column_stack([a, b]), np.column_stack([a, b, c])


def fit_logistic(X: ArrayLike, y: ArrayLike, ridge: float = 0.05) -> NDArray[np.float64]:
    """Maximum-likelihood logistic regression with an intercept: coefficients (1 + p,) of
    P(y = 1 | x) = σ(c0 + c·x), with a ridge penalty ``ridge`` · |c|² on the standardised
    slopes (not the intercept). Solved by L-BFGS (``scipy.optimize.minimize``) on the
    standardised features, then mapped back to the raw ones.

    The penalty is a fixed amount, not one that grows with the number of frames: it is a
    Gaussian prior of standard deviation 1 / sqrt(2 ridge) (about 3 for the default) on each
    standardised slope, which keeps a slope finite when a feature separates the classes
    perfectly and otherwise vanishes against the likelihood. A penalty scaled by the frame
    count would stay as strong as the data and flatten the steep, threshold-like hazards the
    trackers have (a loss floor at slow motion where they lose nothing)."""
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float)
    if X.ndim != 2 or y.shape != (X.shape[0],) or X.shape[0] == 0:
        raise ValueError(f"X must be (n, p) and y (n,) with n > 0, got {X.shape}, {y.shape}")
    mu, sd = X.mean(axis=0), X.std(axis=0)
    sd[sd == 0] = 1.0
    Z = np.column_stack([np.ones(len(X)), (X - mu) / sd])

    def nll(c: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        s = Z @ c
        # log(1 + exp(s)) - y s, stable for both signs of s
        loss = np.sum(np.logaddexp(0.0, s) - y * s) + ridge * np.sum(c[1:] ** 2)
        g = Z.T @ (sigmoid(s) - y)
        g[1:] += 2.0 * ridge * c[1:]
        return float(loss), g

    p0 = np.clip(y.mean(), 1e-6, 1 - 1e-6)
    c0 = np.zeros(Z.shape[1])
    c0[0] = math.log(p0 / (1 - p0))
    res = minimize(nll, c0, jac=True, method="L-BFGS-B")
    c = res.x
    slopes = c[1:] / sd
    return np.r_[c[0] - slopes @ mu, slopes]
