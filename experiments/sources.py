"""Frame sources for ``pmspm track`` and ``pmspm calibrate``: a video file, a folder of images or
a live camera behind OpenCV's ``VideoCapture`` interface, and the live camera's frame schedule.

A live camera delivers a frame every ``1/fps`` s. When the consumer is slower, the frames
delivered while it was busy are grabbed (taken off the camera without decoding) and dropped, and
only the newest is processed, so no backlog builds up (``LiveSchedule``). The capture object and
the clock are injectable: tests drive the schedule on a simulated clock.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
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
        self.index += 1
        return self.index <= len(self.files)

    def read(self) -> tuple[bool, NDArray[np.uint8] | None]:
        if self.index >= len(self.files):
            return False, None
        img = cv2.imread(str(self.files[self.index]), cv2.IMREAD_COLOR)
        self.index += 1
        return img is not None, img

    def release(self) -> None:
        self.index = len(self.files)

    def isOpened(self) -> bool:  # noqa: N802 - OpenCV's name
        return self.index < len(self.files)

    def get(self, prop_id: int) -> float:
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
    """

    capture: Capture
    kind: str
    fps: float
    n_frames: int | None
    name: str


def open_source(spec: str, fps: float | None = None,
                capture_factory: Callable[[int | str], Capture] | None = None) -> Source:
    """Open ``spec``: a folder of images, a video file, a camera index (``"0"``) or a URL.

    ``fps`` overrides the frame rate (default: the video's, else 36 Hz, seed 000 §5).
    ``capture_factory`` (default ``cv2.VideoCapture``) opens files, indices and URLs.
    Raises ``UserInputError`` when the source cannot be opened.
    """
    factory = capture_factory or cv2.VideoCapture
    default_fps = PlantParams().camera.frame_rate_hz
    path = Path(spec)
    if path.is_dir():
        cap = FolderCapture(path)
        return Source(cap, "folder", fps or default_fps, len(cap), str(path))
    live = spec.isdigit() or "://" in spec
    if not live and not path.is_file():
        raise UserInputError(f"{spec}: no such file, folder or camera")
    cap = factory(int(spec) if spec.isdigit() else spec)
    if not cap.isOpened():
        raise UserInputError(f"{spec}: cannot open (unreadable video or camera)")
    rate = float(cap.get(cv2.CAP_PROP_FPS))
    count = 0 if live else int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    return Source(cap, "live" if live else "video", fps or (rate if rate > 0 else default_fps),
                  count if count > 0 else None, spec)


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
