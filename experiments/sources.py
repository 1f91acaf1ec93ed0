"""Frame sources for ``pmspm track`` and ``pmspm calibrate``: a video file, a folder of images or
a live camera behind OpenCV's ``VideoCapture`` interface, and the live camera's frame schedule.

A live camera delivers a frame every ``1/fps`` s. When the consumer is slower, the frames
delivered while it was busy are grabbed (taken off the camera without decoding) and dropped, and
only the newest is processed, so no backlog builds up (``LiveSchedule``). The capture object and
the clock are injectable: tests drive the schedule on a simulated clock.

**Frame rate** (``open_source``; a frame's capture time is its index / rate): ``--fps`` when
given; else for a folder of images the camera file's ``frame_rate_hz`` (the rate the images were
captured at); for a video or a live camera its own rate, checked against the camera file's (a
warning names both when they differ by more than ``RATE_TOLERANCE``); without either, the
default camera's 36 Hz (seed 000 §5). ``Source.fps_origin`` says which, for the report. A rate
that is zero, negative or not finite is refused.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from experiments.cvat import list_frames
from plant.params import PlantParams

Clock = Callable[[], float]


class UserInputError(ValueError):
    """The user's input cannot be tracked (unreadable video, bad boxes, mismatched files)."""


class Capture(Protocol):
    """The part of ``cv2.VideoCapture`` a run uses: frames in OpenCV's BGR order."""

    def read(self) -> tuple[bool, NDArray[np.uint8] | None]:
        """The next frame (grab + decode)."""
        ...

    def grab(self) -> bool:
        """Take the next frame off the source without decoding it."""
        ...

    def release(self) -> None:
        """Close the source."""
        ...

    def isOpened(self) -> bool:  # noqa: N802 - OpenCV's name
        """The source is open."""
        ...

    def get(self, prop_id: int) -> float:
        """A property (``cv2.CAP_PROP_*``; 0 when unknown)."""
        ...


class FolderCapture:
    """A folder of images as a ``Capture`` (name order, ``experiments.cvat.list_frames``)."""

    def __init__(self, folder: Path | str) -> None:
        try:
            self.files = list_frames(folder)
        except ValueError as exc:
            raise UserInputError(str(exc)) from exc
        self.index = 0

    def __len__(self) -> int:
        return len(self.files)

    def grab(self) -> bool:
        """Advance to the next image as ``cv2.VideoCapture.grab`` does; False past the last one."""
        self.index += 1
        return self.index <= len(self.files)

    def read(self) -> tuple[bool, NDArray[np.uint8] | None]:
        """The next image (BGR uint8, as ``cv2.imread``) and whether it could be read;
        ``(False, None)`` past the last one."""
        if self.index >= len(self.files):
            return False, None
        img = cv2.imread(str(self.files[self.index]), cv2.IMREAD_COLOR)
        self.index += 1
        return img is not None, img

    def release(self) -> None:
        """Close the source: every later ``read`` returns ``(False, None)``."""
        self.index = len(self.files)

    def isOpened(self) -> bool:  # noqa: N802 - OpenCV's name
        """Whether images are left to read (``cv2.VideoCapture.isOpened``)."""
        return self.index < len(self.files)

    def get(self, prop_id: int) -> float:
        """The number of images for ``cv2.CAP_PROP_FRAME_COUNT``, 0 for any other property."""
        return float(len(self.files)) if prop_id == cv2.CAP_PROP_FRAME_COUNT else 0.0


@dataclass
class Source:
    """An opened frame source.

    Attributes
    ----------
    capture : the frames.
    kind : ``"video"``, ``"folder"`` or ``"live"``.
    fps : frame rate, Hz (the video's, or the camera's nominal rate).
    n_frames : frames in a recording (None for a live camera or when the container omits it).
    name : what was opened.
    fps_origin : where ``fps`` came from (module docstring), for the report.
    warnings : what the user should check (e.g. a video rate differing from the camera file's).
    """

    capture: Capture
    kind: str
    fps: float
    n_frames: int | None
    name: str
    fps_origin: str = "the caller"
    warnings: list[str] = field(default_factory=list)


#: Relative difference between a video's own rate and the camera file's beyond which a warning
#: names both (our choice: 1 %, above the rounding of container rates such as 29.97 Hz).
RATE_TOLERANCE = 0.01


def check_rate(name: str, rate_hz: float) -> float:
    """``rate_hz`` as a float, or ``UserInputError`` naming ``name`` unless finite and > 0."""
    r = float(rate_hz)
    if not (math.isfinite(r) and r > 0.0):
        raise UserInputError(f"{name} must be a finite frame rate > 0 Hz, got {rate_hz}")
    return r


def _choose_rate(own_hz: float, fps: float | None, camera_rate_hz: float | None,
                 camera_origin: str, kind: str) -> tuple[float, str, list[str]]:
    """(rate, where it came from, warnings) by the rule of the module docstring; ``own_hz`` is
    the source's own rate (0 when it has none)."""
    if fps is not None:
        return check_rate("--fps", fps), "--fps", []
    cam = None if camera_rate_hz is None else check_rate(camera_origin, camera_rate_hz)
    has_own = math.isfinite(own_hz) and own_hz > 0.0
    if has_own:
        warnings = []
        if cam is not None and abs(own_hz - cam) > RATE_TOLERANCE * cam:
            warnings.append(f"the {kind}'s own frame rate is {own_hz:g} Hz but {camera_origin} "
                            f"is {cam:g} Hz: using the {kind}'s; pass --fps to choose")
        return own_hz, f"the {kind}'s own rate", warnings
    if cam is not None:
        return cam, camera_origin, []
    return PlantParams().camera.frame_rate_hz, "the default camera's rate (seed 000 §5)", []


def open_source(spec: str, fps: float | None = None,
                capture_factory: Callable[[int | str], Capture] | None = None,
                camera_rate_hz: float | None = None,
                camera_origin: str = "the camera file's frame_rate_hz") -> Source:
    """Open ``spec``: a folder of images, a video file, a camera index (``"0"``) or a URL.

    The frame rate (Hz) follows the module docstring's rule: ``fps`` (the ``--fps`` option)
    overrides; ``camera_rate_hz`` is the camera file's ``frame_rate_hz`` (None: no camera
    file), named ``camera_origin`` in the report and the warnings. ``capture_factory``
    (default ``cv2.VideoCapture``) opens files, indices and URLs. Raises ``UserInputError``
    when the source cannot be opened or a rate is zero, negative or not finite.
    """
    factory = capture_factory or cv2.VideoCapture
    path = Path(spec)
    if path.is_dir():
        cap = FolderCapture(path)
        rate, origin, warnings = _choose_rate(0.0, fps, camera_rate_hz, camera_origin, "folder")
        return Source(cap, "folder", rate, len(cap), str(path), origin, warnings)
    live = spec.isdigit() or "://" in spec
    if not live and not path.is_file():
        raise UserInputError(f"{spec}: no such file, folder or camera")
    cap = factory(int(spec) if spec.isdigit() else spec)
    if not cap.isOpened():
        raise UserInputError(f"{spec}: cannot open (unreadable video or camera)")
    kind = "live" if live else "video"
    rate, origin, warnings = _choose_rate(float(cap.get(cv2.CAP_PROP_FPS)), fps, camera_rate_hz,
                                          camera_origin, "camera" if live else kind)
    count = 0 if live else int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    return Source(cap, kind, rate, count if count > 0 else None, spec, origin, warnings)


class LiveSchedule:
    """Which frame of a live camera to process next: the newest one delivered by now.

    The camera delivers frame k at ``t0 + k / fps`` on ``clock`` (``t0``: when frame 0 was in
    hand), at its nominal rate. Frames delivered while the tracker was busy (including while it
    started), except the newest, are grabbed and discarded; the frame after that is waited for.
    """

    def __init__(self, fps: float, clock: Clock, t0: float) -> None:
        self.period_s = 1.0 / fps
        self.clock = clock
        self.t0 = t0
        self.last = 0
        self.dropped = 0

    def skip_stale(self, capture: Capture) -> bool:
        """Discard the stale frames; False when the source ends."""
        # the 1e-9 keeps a frame due exactly now (up to round-off of the clock) in
        newest = math.floor((self.clock() - self.t0) / self.period_s + 1e-9)
        stale = max(newest - self.last - 1, 0)
        for _ in range(stale):
            if not capture.grab():
                return False
        self.dropped += stale
        self.last += stale + 1
        return True


def read_first(source: Source) -> NDArray[np.uint8]:
    """The source's first frame (BGR); ``UserInputError`` if there is none."""
    ok, frame = source.capture.read()
    if not ok or frame is None or frame.size == 0:
        raise UserInputError(f"{source.name}: no frame could be read (empty or unreadable)")
    return frame
