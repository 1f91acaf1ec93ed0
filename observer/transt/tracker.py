"""TransT tracking as the published tracker does it (an ``observer.tracking.SingleObjectTracker``).

``TransTTracker.initialize(frame_rgb, box_image_px)`` crops the template (context factor 2, the
frame's mean colour outside it), ImageNet-normalises it and caches its backbone tokens.
``track(frame_rgb, search_centre_image_px=None) -> TrackResult`` then, per frame
(Chen et al., "Transformer Tracking", CVPR 2021, §3.4 "Tracking with TransT"):

1. crops the search region (context factor 4 of the current box size) around the previous box
   centre, or around ``search_centre_image_px`` when given (GK-TransT places it at the pixel
   Kalman prediction, seed 000 §3.2.1);

   with ``search_size`` smaller than the configuration's (our addition, for a caller whose
   search centre is a good prediction), only the centre of that region is cropped, at the same
   image scale: ``search_size`` of the configuration's ``search_size`` pixels. The network then
   sees the centre of a trained-size crop (``TransTNet.search_position``): its boxes are
   fractions of the trained-size region, and the window is the centre of the trained one;
2. runs the network: a target probability and a box for each of the H x W search-feature cells;
3. adds a Hanning window to the probabilities, ``p' = (1 - w) p + w hann``, with TransT's window
   influence w = 0.49, and takes the box of the cell with the largest p';
4. maps that box from crop fractions to image pixels and makes it the new state (TransT replaces
   the size outright, learning rate 1), clipped to the frame.

With ``hold_below_score`` set (our addition; None, the published tracker's rule, by default), a
frame whose chosen cell scores at or below it leaves the state as it was and reports the held
box: the network did not find the target there, and its box regression on a frame without the
target is meaningless. The published rule takes that box anyway; with our small network a
marker hidden under a large occluder then moved the box away or grew it to the whole frame,
and the track was gone for about a hundred frames (docs/tracking.md, the unseen source's
occlusion case; there too, why the dual TransT keeps the published rule by default).

The returned score is the network's target probability at the chosen cell (in [0, 1], before
the window). ``compute_time_s`` is the wall-clock time of the whole ``track`` call
(``time.perf_counter``: checks, crop, network, decoding), and ``last`` holds the
``TransTStep`` of the last call (with the search crop used).

Frames are RGB uint8 (H, W, 3) as the renderers produce them; boxes are (x, y, w, h) in image
pixels of that frame (pixel-centre convention, centre = (x + w/2, y + h/2), see
``observer.transt.crop``). Bad input never raises in ``track``: an unusable frame (see
``observer.gk.hsv_gate.check_frame``: not RGB uint8, a shape other than the init frame's, or
featureless), search centre or network output gives a failed result (NaN box, score 0.0, not
valid) saying why, and the tracker state stays as it was, so the next good frame continues the
track. ``initialize`` raises ``ValueError`` for a frame or box it cannot start from.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

from observer.gk.hsv_gate import UNIFORM_PTP_DN, check_frame, check_rgb_image
from observer.tracking import TrackResult
from observer.transt.crop import context_side, crop_square, crop_to_box, normalise
from observer.transt.network import TransTConfig, TransTNet, build_transt
from observer.transt.service import Backend, NetworkService, shared_service
from observer.transt.weights import SMALL_WEIGHTS, WeightsError, load_weights

#: Our choice: the smallest box side the tracker keeps, image px (TransT clips at 10 px of
#: full-resolution video; our binned frames show the 8 mm marker at about 48 px).
MIN_BOX_PX = 4.0
# A search region (the part of the frame under the search crop) whose pixel values span at most
# UNIFORM_PTP_DN holds no target (an all-black or blank frame); track() then reports a failure
# without running the network. The same test refuses a blank template in initialize().

#: Backend preference of ``TransTTracker.small()`` when none is given: ONNX Runtime was the
#: fastest here (benchmarks/bench_transt.py: track-step median 6.1 ms against 9.6 ms with
#: torch.compile and 12.5 ms eager, see docs/transt.md); without the optional onnxruntime / onnx
#: packages, or if the export fails, eager PyTorch.
DEFAULT_BACKEND: Backend = "onnx"


@dataclass(frozen=True)
class TransTStep:
    """One ``track`` call in detail (``TransTTracker.last``).

    Attributes
    ----------
    box_image_px : (4,) box (x, y, w, h), image px; NaN when ``ok`` is False.
    score : target probability of the chosen cell in [0, 1]; 0.0 when ``ok`` is False.
    compute_time_s : wall-clock time of the ``track`` call, s.
    ok : False when the frame, the search centre or the network output was unusable.
    status : "ok" or why the result is a failure.
    search_centre_image_px : (2,) centre of the search crop used, image px.
    search_side_px : side of the search crop, image px.
    """

    box_image_px: NDArray[np.float64]
    score: float
    compute_time_s: float
    ok: bool
    status: str
    search_centre_image_px: NDArray[np.float64]
    search_side_px: float


def hanning_window(n: int) -> NDArray[np.float32]:
    """TransT's cosine window over an n x n score map, flattened row-major (np.hanning outer)."""
    h = np.hanning(n)
    return np.outer(h, h).astype(np.float32).reshape(-1)


class _Runner:
    """The per-frame part of the network for one target: search crop -> (logits (L, 2),
    boxes (L, 4)) against this target's template tokens, through a ``NetworkService`` (the
    process's shared one for the shipped weights, so that runs can be batched)."""

    def __init__(self, service: NetworkService) -> None:
        self.service = service
        self._z: NDArray[np.float32] | None = None

    def set_template(self, template: NDArray[np.float32]) -> None:
        self._z = self.service.template_tokens(template)

    def __call__(self, search: NDArray[np.float32]) -> tuple[np.ndarray, np.ndarray]:
        assert self._z is not None
        return self.service.evaluate(search, self._z)


class TransTTracker:
    """Single-object TransT tracker (Chen et al., CVPR 2021) on RGB frames.

    Parameters
    ----------
    net : the network; put in eval mode here.
    backend : "eager" (PyTorch), "compile" (``torch.compile``) or "onnx" (ONNX Runtime; needs
        the optional ``onnxruntime`` and ``onnx`` packages).
    service : the ``NetworkService`` that runs ``net`` (default: one of this tracker's own in
        ``backend``); ``small()`` passes the process's shared service of the shipped weights.
    window_influence : weight of the Hanning window (default: the configuration's, 0.49 as in
        TransT).
    min_box_px : smallest box side kept, image px (our choice, ``MIN_BOX_PX``).
    search_size : side of the search crop fed to the network, px (default: the configuration's
        ``search_size``); smaller, the centre of the usual search region at the same scale
        (module docstring). It must differ from the configuration's by a multiple of 16 px
        (a centred block of feature cells); ``ValueError`` otherwise.

    Attributes
    ----------
    compute_time_s : wall-clock time of the last ``init`` or ``track`` call, s.
    last : the ``TransTStep`` of the last ``track`` call (None before).
    centre_image_px, size_image_px : the current state (box centre and size), image px.
    search_size : the search crop's side, px of the network input (see the module docstring).
    hold_below_score : as the parameter.
    """

    def __init__(
        self,
        net: TransTNet,
        backend: Backend = "eager",
        window_influence: float | None = None,
        min_box_px: float = MIN_BOX_PX,
        service: NetworkService | None = None,
        search_size: int | None = None,
        hold_below_score: float | None = None,
    ) -> None:
        self.net = net.eval()
        self.config: TransTConfig = net.config
        self.backend = backend
        self.window_influence = (
            self.config.window_influence if window_influence is None else float(window_influence)
        )
        if not 0.0 <= self.window_influence <= 1.0:
            raise ValueError(f"window_influence must be in [0, 1], got {self.window_influence}")
        self.min_box_px = float(min_box_px)
        self.hold_below_score = hold_below_score
        if service is not None and (service.net is not net or service.backend != backend):
            raise ValueError("service must run the same network in the same backend")
        self._runner = _Runner(service or NetworkService(self.net, backend))
        #: Hanning windows by search-crop side (those ``prepare`` has made ready).
        self._windows: dict[int, NDArray[np.float32]] = {}
        self.search_size = self.config.search_size if search_size is None else search_size
        self.prepare(self.search_size)
        self.centre_image_px: NDArray[np.float64] | None = None
        self._frame_shape: tuple[int, ...] | None = None
        self.size_image_px: NDArray[np.float64] | None = None
        self._pad: NDArray[np.float64] | None = None
        self.compute_time_s = 0.0
        self.last: TransTStep | None = None

    @property
    def hold_below_score(self) -> float | None:
        """The score at or below which a frame leaves the state as it was (None: never)."""
        return self._hold_below_score

    @hold_below_score.setter
    def hold_below_score(self, value: float | None) -> None:
        if value is not None and not 0.0 <= value < 1.0:
            raise ValueError(f"hold_below_score must be None or in [0, 1), got {value}")
        self._hold_below_score = None if value is None else float(value)

    # --- constructors ---------------------------------------------------------------------------
    @classmethod
    def small(
        cls,
        weights: str | Path = SMALL_WEIGHTS,
        backend: Backend | None = None,
        expected_sha256: str | None = None,
        search_size: int | None = None,
    ) -> TransTTracker:
        """The shipped ``small`` network (``weights/transt_small.pt``), SHA-256 checked, with
        search crops of ``search_size`` px (default: the configuration's, 128).

        ``backend=None`` takes ``DEFAULT_BACKEND`` (ONNX Runtime) and falls back to eager
        PyTorch, with one warning, when that is unavailable or its session for
        ``search_size`` cannot be built; ``tracker.backend`` says which one runs.

        The network is loaded and exported once per process and shared by every tracker built
        here (``observer.transt.service.shared_service``); an ``expected_sha256`` other than
        the recorded digest builds a network of this tracker's own.

        Raises ``observer.transt.weights.WeightsError`` (naming the file and the command that
        rebuilds it) when the file is missing or corrupt.
        """
        if expected_sha256 is not None:
            net, _ = load_weights(weights, expected_sha256)
            return cls(net, backend=backend or "eager", search_size=search_size)
        if backend is not None:
            service = shared_service(weights, backend)
            return cls(service.net, backend=backend, service=service, search_size=search_size)
        try:
            service = shared_service(weights, DEFAULT_BACKEND)
            service.prepare(service.net.config.search_size if search_size is None
                            else search_size)
        except WeightsError:
            raise
        except Exception as exc:  # optional ONNX packages missing or export failed
            warnings.warn(f"ONNX Runtime backend unavailable ({exc}); running eager PyTorch, "
                          "which gives the same results more slowly", stacklevel=2)
            service = shared_service(weights, "eager")
        return cls(service.net, backend=service.backend, service=service,
                   search_size=search_size)

    @classmethod
    def from_config(
        cls, config: TransTConfig | str, seed: int = 0, backend: Backend = "eager"
    ) -> TransTTracker:
        """A tracker with randomly initialised weights (seeded), e.g. to time ``transt50``."""
        torch.manual_seed(seed)
        return cls(build_transt(config), backend=backend)

    def _search_size_error(self, search_size: object) -> str:
        """"" if ``search_size`` is a usable search-crop side, else why not."""
        full, cell = self.config.search_size, self.config.stride
        if isinstance(search_size, int) and 2 * cell <= search_size <= full \
                and (full - search_size) % (2 * cell) == 0:
            return ""
        return (f"search_size must be an int of at most {full} px whose difference from {full} "
                f"is a multiple of {2 * cell} (a centred block of feature cells), got "
                f"{search_size!r}")

    def prepare(self, search_size: int) -> None:
        """Make search crops of ``search_size`` px ready (the backend's session of that size
        and the window: the centre of the trained-size one), so that the first ``track`` with
        it does not pay for them; ``ValueError`` naming ``search_size`` if it is not usable
        (see ``__init__``)."""
        why = self._search_size_error(search_size)
        if why:
            raise ValueError(why)
        if search_size not in self._windows:
            self._runner.service.prepare(search_size)
            n, m = self.config.search_feature_size, search_size // self.config.stride
            o = (n - m) // 2
            # the centre of the trained-size window, flattened row-major like the score map
            self._windows[search_size] = np.ascontiguousarray(
                hanning_window(n).reshape(n, n)[o:o + m, o:o + m]).reshape(-1)

    # --- the seam ---------------------------------------------------------------------------------
    @property
    def initialised(self) -> bool:
        """Whether ``initialize`` has set a target to track."""
        return self.centre_image_px is not None

    def initialize(self, frame_rgb: NDArray[np.uint8], box_image_px: ArrayLike) -> None:
        """Start tracking the target in ``box_image_px`` (x, y, w, h), image px, of
        ``frame_rgb`` (RGB uint8, (H, W, 3)).

        Raises ``ValueError`` for an unusable frame (wrong type, dtype or shape, empty), a box
        that is not finite with w, h > 0, a box whose centre lies outside the frame, or a
        uniform template region (an all-black frame).
        """
        t0 = time.perf_counter()
        why = check_rgb_image(frame_rgb)
        if why:
            raise ValueError(f"TransTTracker.initialize: {why}")
        box = np.asarray(box_image_px, dtype=float)
        if box.shape != (4,) or not np.all(np.isfinite(box)) or box[2] <= 0 or box[3] <= 0:
            raise ValueError(
                "TransTTracker.initialize: box_image_px must be a finite (x, y, w, h) with "
                f"w, h > 0, got {box_image_px!r}"
            )
        h_img, w_img = frame_rgb.shape[:2]
        centre = box[:2] + box[2:] / 2.0
        if not (-0.5 <= centre[0] <= w_img - 0.5 and -0.5 <= centre[1] <= h_img - 0.5):
            raise ValueError(
                f"TransTTracker.initialize: the box centre {centre.tolist()} lies outside the "
                f"{w_img} x {h_img} frame"
            )
        pad = frame_rgb.reshape(-1, 3).mean(axis=0)
        side = context_side(box[2:], self.config.template_factor)
        crop = crop_square(frame_rgb, centre, side, self.config.template_size, pad)
        if int(crop.max()) - int(crop.min()) <= UNIFORM_PTP_DN:
            raise ValueError(
                "TransTTracker.initialize: the template region is uniform (an all-black or blank "
                "frame?); nothing to track"
            )
        self._runner.set_template(normalise(crop[None]))
        self._pad = pad
        self._frame_shape = frame_rgb.shape
        self.centre_image_px = centre
        self.size_image_px = box[2:].copy()
        self.last = None
        self.compute_time_s = time.perf_counter() - t0

    def track(
        self,
        frame_rgb: NDArray[np.uint8],
        search_centre_image_px: ArrayLike | None = None,
        search_size: int | None = None,
    ) -> TrackResult:
        """Box (x, y, w, h), image px, and score of the target in the next frame.

        ``search_centre_image_px`` (2,), image px, places the search crop there instead of at
        the previous box centre; ``search_size`` (px, default ``self.search_size``) crops only
        the centre of the search region for this frame (module docstring; made ready by
        ``prepare`` on first use). A failure (bad frame, centre or search size, a frame shape
        other than the init frame's, a featureless frame or search region, non-finite network
        output, not initialised) returns a NaN box and score 0.0 and leaves the state
        unchanged; ``last.status`` says why.
        """
        t0 = time.perf_counter()
        size = self.search_size if search_size is None else search_size
        why = self._search_size_error(size)
        if why:
            res = (np.full(4, np.nan), 0.0, why, np.full(2, np.nan), 0.0)
        else:
            self.prepare(size)
            res = self._track(frame_rgb, search_centre_image_px, size)
        self.compute_time_s = time.perf_counter() - t0
        self.last = TransTStep(
            res[0], res[1], self.compute_time_s, res[2] == "ok", res[2], res[3], res[4]
        )
        ok = self.last.ok
        return TrackResult(self.last.box_image_px.copy(), self.last.score, ok,
                           "" if ok else self.last.status, self.compute_time_s, ok)

    def _track(
        self, frame: object, search_centre: ArrayLike | None, search_size: int
    ) -> tuple[NDArray[np.float64], float, str, NDArray[np.float64], float]:
        nan_box = np.full(4, np.nan)
        if self.centre_image_px is None or self.size_image_px is None:
            return nan_box, 0.0, "not initialised: call initialize first", np.full(2, np.nan), 0.0
        # the trained-size search region (the boxes' unit) and the part of it cropped
        full_side = context_side(self.size_image_px, self.config.search_factor)
        side = full_side * search_size / self.config.search_size
        centre = self.centre_image_px
        # The init frame's shape is required: in a frame of another size the box and search
        # centre would be read in the wrong pixels.
        why = check_frame(frame, init_shape=self._frame_shape) or None
        if why is None and search_centre is not None:
            try:
                sc = np.asarray(search_centre, dtype=float).reshape(2)
            except (TypeError, ValueError):
                sc = np.full(2, np.nan)
            if not np.all(np.isfinite(sc)):
                why = f"search_centre_image_px is not a finite (2,) point: {search_centre!r}"
            else:
                centre = sc
        if why is not None:
            return nan_box, 0.0, why, centre.copy(), side
        assert isinstance(frame, np.ndarray)
        h_img, w_img = frame.shape[:2]
        x0, y0 = (max(int(np.floor(v - side / 2.0)), 0) for v in centre)
        x1 = min(int(np.ceil(centre[0] + side / 2.0)) + 1, w_img)
        y1 = min(int(np.ceil(centre[1] + side / 2.0)) + 1, h_img)
        if x1 <= x0 or y1 <= y0:
            return nan_box, 0.0, "search region outside the frame", centre.copy(), side
        region = frame[y0:y1, x0:x1]
        if int(region.max()) - int(region.min()) <= UNIFORM_PTP_DN:
            return nan_box, 0.0, "uniform search region (blank frame)", centre.copy(), side
        crop = crop_square(frame, centre, side, search_size, self._pad)
        logits, boxes = self._runner(normalise(crop[None]))
        if not (np.all(np.isfinite(logits)) and np.all(np.isfinite(boxes))):
            return nan_box, 0.0, "network output not finite", centre.copy(), side
        z = logits - logits.max(axis=1, keepdims=True)
        e = np.exp(z)
        prob = e[:, 0] / e.sum(axis=1)
        w = self.window_influence
        best = int(np.argmax(prob * (1.0 - w) + self._windows[search_size] * w))
        score = float(prob[best])
        if self.hold_below_score is not None and score <= self.hold_below_score:
            held = np.r_[self.centre_image_px - self.size_image_px / 2.0, self.size_image_px]
            return held, score, "ok", centre.copy(), side
        box = crop_to_box(boxes[best], centre, full_side)
        c = box[:2] + box[2:] / 2.0
        c = np.clip(c, [-0.5, -0.5], [w_img - 0.5, h_img - 0.5])
        size = np.clip(box[2:], self.min_box_px, [w_img, h_img])
        self.centre_image_px, self.size_image_px = c, size
        return np.r_[c - size / 2.0, size], score, "ok", centre.copy(), side
