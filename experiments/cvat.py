"""CVAT "for video 1.1" XML annotations of the marker pair: export, import, and the benchmark on a
folder of recorded frames.

Seed 000 §4.1 annotated its recordings frame by frame in CVAT. A user's recording can go through
the same benchmark as our rendered sequences: annotate the red and yellow markers as box tracks
with labels ``red`` and ``yellow`` in a CVAT task made from the frames, export "CVAT for video
1.1", and call ``benchmark_cvat_folder(frames_folder, annotations_xml, ...)``.

**Format** (CVAT's XML annotation format, version 1.1, interpolation mode): ``<annotations>`` with
``<version>1.1</version>``, a ``<meta><task>`` block (``size``, ``mode``, ``start_frame``,
``stop_frame``, ``labels``, ``original_size``) and one ``<track id label>`` per object holding
``<box frame outside occluded keyframe xtl ytl xbr ybr z_order>`` elements. Import rules:

* frames are numbered from ``start_frame`` (0 when absent);
* a track's boxes between two listed frames are linearly interpolated, as CVAT does between
  keyframes; from a box with ``outside="1"`` until the next listed box the object is absent
  (NaN); before its first and after its last listed box the track is absent;
* when one label has several tracks, a frame takes the first track that has a visible box;
* other shapes, tracks of other labels and attributes are ignored.

**Validation.** A file that breaks these rules raises ``CvatError`` (a ``ValueError``) naming the
file, the line and the element, before any per-frame array is allocated: a box whose ``frame``
is missing or not an integer, lies before ``start_frame`` or beyond the frame count (the
frames given, else the task's ``size``, else ``stop_frame``, else ``MAX_UNDECLARED_FRAMES``); a
box with a missing or non-finite coordinate; a box with a negative width or height (or an empty
one that is not ``outside``).

**Coordinates.** CVAT measures boxes from the top-left *corner* of the image (the first pixel
spans [0, 1]); this package uses OpenCV's pixel-*centre* convention (the first pixel's centre is
0). So ``x_ours = xtl - 0.5`` and ``xbr = x_ours + w + 0.5``, in pixels of the annotated frames;
frames binned by ``b`` then convert to full-sensor px with ``observer.gk.hsv_gate``'s
``box_image_to_sensor``.

Frame order: the task's frames are the image files of the folder in sorted (lexicographic) order,
CVAT's default sorting method; name files with zero-padded numbers.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from xml.parsers import expat

import numpy as np
from numpy.typing import ArrayLike, NDArray

from experiments.sequences import TrackingSequence
from observer.gk.hsv_gate import box_image_to_sensor, box_sensor_to_image
from plant.params import PlantParams

LABELS = ("red", "yellow")
LABEL_COLOURS = {"red": "#ff0000", "yellow": "#ffd700"}
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
#: Our choice: the largest frame count accepted from a file that declares none (no ``size`` or
#: ``stop_frame``): 10⁶ frames (7.7 h at 36 fps) of two labels are 64 MB of boxes.
MAX_UNDECLARED_FRAMES = 1_000_000
#: Our choice: the largest frame count a file may declare (``size``, ``stop_frame``): 10⁷
#: frames (77 h at 36 fps); the boxes of two labels are then 640 MB, and an absurd count (10¹²)
#: is refused instead of allocated.
MAX_DECLARED_FRAMES = 10_000_000
#: Our choice: the largest image side accepted in ``original_size``, px (sensors stop near
#: 20,000 px a side).
MAX_IMAGE_SIDE_PX = 100_000


class CvatError(ValueError):
    """A CVAT XML file that cannot be read as the annotation of the marker pair; the message
    names the file, and the line and element where there is one."""


@dataclass
class CvatTracks:
    """Per-frame boxes of the labelled tracks, in image px of the annotated frames (OpenCV
    pixel-centre convention).

    Attributes
    ----------
    boxes_px : label -> (N, 4) boxes (x, y, w, h), NaN where the object is outside.
    occluded : label -> (N,) CVAT's ``occluded`` flag.
    width, height : frame size from ``original_size`` (0 when absent).
    name : the task name.
    """

    boxes_px: dict[str, NDArray[np.float64]]
    occluded: dict[str, NDArray[np.bool_]]
    width: int = 0
    height: int = 0
    name: str = ""
    start_frame: int = 0
    extra_labels: list[str] = field(default_factory=list)

    @property
    def n_frames(self) -> int:
        """Number of frames: the longest track's length (0 without tracks)."""
        return max((len(b) for b in self.boxes_px.values()), default=0)


# --- export -------------------------------------------------------------------------------------
def _fmt(v: float) -> str:
    return f"{v:.2f}"


def export_cvat_xml(
    path: Path | str,
    boxes_image_px: dict[str, ArrayLike],
    width: int,
    height: int,
    occluded: dict[str, ArrayLike] | None = None,
    task_name: str = "pmspm markers",
) -> Path:
    """Write a CVAT for video 1.1 XML with one box track per label.

    ``boxes_image_px[label]`` is (N, 4) (x, y, w, h) in image px of the frames (pixel-centre
    convention; NaN rows are written as ``outside="1"``); ``occluded[label]`` optional (N,) flags.
    Every frame is a keyframe (the boxes are per-frame ground truth, not interpolated).
    """
    labels = list(boxes_image_px)
    arrays = {lab: np.asarray(boxes_image_px[lab], dtype=float).reshape(-1, 4) for lab in labels}
    n = max(len(a) for a in arrays.values())
    root = ET.Element("annotations")
    ET.SubElement(root, "version").text = "1.1"
    task = ET.SubElement(ET.SubElement(root, "meta"), "task")
    for tag, text in (("id", "0"), ("name", task_name), ("size", str(n)),
                      ("mode", "interpolation"), ("overlap", "0"), ("bugtracker", ""),
                      ("flipped", "False"), ("start_frame", "0"), ("stop_frame", str(n - 1)),
                      ("frame_filter", "")):
        ET.SubElement(task, tag).text = text
    lab_el = ET.SubElement(task, "labels")
    for lab in labels:
        le = ET.SubElement(lab_el, "label")
        ET.SubElement(le, "name").text = lab
        ET.SubElement(le, "color").text = LABEL_COLOURS.get(lab, "#808080")
        ET.SubElement(le, "type").text = "rectangle"
        ET.SubElement(le, "attributes")
    size = ET.SubElement(task, "original_size")
    ET.SubElement(size, "width").text = str(int(width))
    ET.SubElement(size, "height").text = str(int(height))
    for tid, lab in enumerate(labels):
        tr = ET.SubElement(root, "track", id=str(tid), label=lab, source="manual")
        occ = np.zeros(n, bool) if occluded is None or lab not in occluded else \
            np.asarray(occluded[lab], dtype=bool).reshape(-1)
        prev_out = False
        for k, b in enumerate(arrays[lab]):
            out = not np.all(np.isfinite(b))
            if out and prev_out:
                continue
            if out:  # CVAT marks the frame where the object leaves; keep the last box's shape
                b = arrays[lab][k - 1] if k > 0 else np.zeros(4)
                if not np.all(np.isfinite(b)):
                    b = np.zeros(4)
            ET.SubElement(tr, "box", frame=str(k), keyframe="1", outside="1" if out else "0",
                          occluded="1" if bool(occ[k]) else "0",
                          xtl=_fmt(b[0] + 0.5), ytl=_fmt(b[1] + 0.5),
                          xbr=_fmt(b[0] + b[2] + 0.5), ybr=_fmt(b[1] + b[3] + 0.5),
                          z_order="0")
            prev_out = out
    ET.indent(root, space="  ")
    out_path = Path(path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    ET.ElementTree(root).write(out_path, encoding="utf-8", xml_declaration=True)
    return out_path


def export_sequence(seq: TrackingSequence, path: Path | str) -> Path:
    """Export a sequence's ground truth (red, yellow boxes) as CVAT for video 1.1 XML, in image
    px of its frames; the occluded frames are flagged ``occluded``."""
    boxes = {lab: np.array([box_sensor_to_image(b, seq.binning) for b in seq.boxes_px[:, m]])
             for m, lab in enumerate(LABELS)}
    occ = {lab: seq.occluded for lab in LABELS}
    h, w = seq.images.shape[1:3]
    return export_cvat_xml(path, boxes, w, h, occ, task_name=seq.name)


# --- import -------------------------------------------------------------------------------------
def _element_lines(data: bytes) -> list[int]:
    """Line of each element's start tag, in document order (ElementTree keeps no lines)."""
    lines: list[int] = []
    parser = expat.ParserCreate()
    parser.StartElementHandler = lambda name, attrs: lines.append(parser.CurrentLineNumber)
    parser.Parse(data, True)
    return lines


def _box(
    b: ET.Element, start: int, limit: tuple[int, str], where: str
) -> tuple[int, NDArray, bool, bool]:
    """(frame index from ``start_frame``, box (x, y, w, h), outside, occluded) of a ``<box>``;
    ``CvatError`` (with ``where``) if it breaks the rules of the module docstring. ``limit`` is
    the frame count and how the message names it."""
    try:
        frame = int(b.get("frame", ""))
    except ValueError:
        raise CvatError(f"{where}: frame={b.get('frame')!r} is not an integer") from None
    if frame < start:
        raise CvatError(f"{where}: frame {frame} is before start_frame {start}")
    if frame - start >= limit[0]:
        raise CvatError(f"{where}: frame {frame} is beyond the {limit[1]}")
    coords = []
    for name in ("xtl", "ytl", "xbr", "ybr"):
        try:
            v = float(b.get(name, ""))
        except ValueError:
            v = float("nan")
        if not np.isfinite(v):
            raise CvatError(f"{where}: coordinate {name}={b.get(name)!r} is missing or not a "
                            "finite number")
        coords.append(v)
    xtl, ytl, xbr, ybr = coords
    outside = b.get("outside", "0") == "1"
    w, h = xbr - xtl, ybr - ytl
    if w < 0 or h < 0 or (not outside and (w == 0 or h == 0)):
        raise CvatError(f"{where}: width {w:g} and height {h:g} px (xbr - xtl, ybr - ytl) "
                        "must be positive")
    return frame - start, np.array([xtl - 0.5, ytl - 0.5, w, h]), outside, \
        b.get("occluded", "0") == "1"


def read_cvat_xml(path: Path | str, labels: Sequence[str] = LABELS,
                  n_frames: int | None = None) -> CvatTracks:
    """Read the box tracks of ``labels`` from a CVAT for video 1.1 XML (see the module
    docstring). ``n_frames`` (the frames annotated, e.g. the files of a folder) bounds the
    frame numbers; without it the task's declared size does. Raises ``CvatError`` (a
    ``ValueError``) if the file is not CVAT XML, has no track of a label or has a bad box."""
    root, line_of = _parse(path)
    task = root.find("meta/task")
    if task is None:
        task = root.find("meta/job")
    start, size, stop, width, height = _task_numbers(task, path, line_of)
    name = (task.findtext("name") or "") if task is not None else ""
    limit = _frame_limit(n_frames, start, size, stop)
    tracks = root.findall("track")
    if not tracks and root.findall("image"):
        raise CvatError(f"{path}: this is a 'CVAT for images' export; export 'CVAT for video'")
    per_label: dict[str, list[list[tuple[int, NDArray, bool, bool]]]] = {lab: [] for lab in labels}
    last = -1
    extra: list[str] = []
    for tr in tracks:
        lab = tr.get("label", "")
        items = []
        for b in tr.findall("box"):
            where = (f"{path}, line {line_of[id(b)]}: <box frame={b.get('frame')!r}> of track "
                     f"{tr.get('id')!r} ({lab})")
            items.append(_box(b, start, limit, where))
            last = max(last, items[-1][0])
        if lab in per_label:
            per_label[lab].append(sorted(items, key=lambda it: it[0]))
        elif lab not in extra:
            extra.append(lab)
    missing = [lab for lab in labels if not per_label[lab]]
    if missing:
        raise CvatError(f"{path}: no box track with label(s) {missing}; found labels "
                        f"{sorted({t.get('label', '') for t in tracks})}")
    n = n_frames if n_frames is not None else max(size, last + 1)
    boxes, occluded = _merged_tracks(per_label, n)
    return CvatTracks(boxes, occluded, width, height, name, start, extra)


def _parse(path: Path | str) -> tuple[ET.Element, dict[int, int]]:
    """The root ``<annotations>`` element of the file and the line of each element (by
    ``id``); ``CvatError`` for a file that cannot be read, is not XML, or is not CVAT XML 1.x."""
    try:
        data = Path(path).read_bytes()
        root = ET.fromstring(data)
        lines = _element_lines(data)
    except (ET.ParseError, expat.ExpatError) as exc:
        raise CvatError(f"{path}: not an XML file ({exc})") from exc
    except OSError as exc:
        raise CvatError(f"{path}: cannot read the file ({exc.strerror or exc})") from exc
    line_of = dict(zip(map(id, root.iter()), lines, strict=True))
    if root.tag != "annotations":
        raise CvatError(f"{path}: root element is <{root.tag}>, expected <annotations>")
    version = (root.findtext("version") or "").strip()
    if version and not version.startswith("1."):
        raise CvatError(f"{path}: CVAT XML version {version!r}; this reader knows 1.x")
    return root, line_of


def _task_numbers(task: ET.Element | None, path: Path | str,
                  line_of: dict[int, int]) -> tuple[int, int, int, int, int]:
    """The task's start frame, size, stop frame (-1 when not declared) and original image
    width and height, px (0 when not declared); ``CvatError`` naming the element and its line
    for a value that is not an integer in range, or a stop frame declaring too many frames."""
    def meta(tag: str, default: int, low: int, high: int) -> int:
        """The integer of ``task``'s element ``tag`` in [low, high], or ``default`` when the
        file has none; ``CvatError`` naming the element and its line otherwise."""
        el = task.find(tag) if task is not None else None
        if el is None or not (el.text or "").strip():
            return default
        where = f"{path}, line {line_of[id(el)]}: <{tag}>"
        try:
            v = int(el.text.strip())
        except ValueError:
            raise CvatError(f"{where} is {el.text.strip()!r}, not an integer") from None
        if not low <= v <= high:
            raise CvatError(f"{where} is {v}, outside [{low}, {high}]")
        return v

    start = meta("start_frame", 0, 0, MAX_DECLARED_FRAMES)
    size = meta("size", 0, 0, MAX_DECLARED_FRAMES)
    stop = meta("stop_frame", -1, 0, 2 * MAX_DECLARED_FRAMES)
    if stop - start + 1 > MAX_DECLARED_FRAMES:
        raise CvatError(f"{path}: stop_frame {stop} declares {stop - start + 1} frames, more "
                        f"than {MAX_DECLARED_FRAMES}")
    width = meta("original_size/width", 0, 1, MAX_IMAGE_SIDE_PX)
    height = meta("original_size/height", 0, 1, MAX_IMAGE_SIDE_PX)
    return start, size, stop, width, height


def _frame_limit(n_frames: int | None, start: int, size: int, stop: int) -> tuple[int, str]:
    """How many frames a box's frame number may reach, and where that bound comes from: the
    frames given, else the task's size, else its stop frame, else ``MAX_UNDECLARED_FRAMES``."""
    if n_frames is not None:
        return n_frames, f"{n_frames} frames given"
    if size > 0:
        return size, f"task's size of {size} frames"
    if stop >= start:
        return stop - start + 1, f"task's stop_frame {stop}"
    return (MAX_UNDECLARED_FRAMES, f"{MAX_UNDECLARED_FRAMES} frames accepted from a file "
            "that declares no size or stop_frame")


def _merged_tracks(
    per_label: dict[str, list[list[tuple[int, NDArray, bool, bool]]]], n: int,
) -> tuple[dict[str, NDArray[np.float64]], dict[str, NDArray[np.bool_]]]:
    """Per label, the boxes (n, 4) (x, y, w, h; NaN where no track has one) and occluded
    flags (n,) of its tracks expanded to every frame; where tracks overlap, the first wins."""
    boxes: dict[str, NDArray[np.float64]] = {}
    occluded: dict[str, NDArray[np.bool_]] = {}
    for lab, tracks in per_label.items():
        bx = np.full((n, 4), np.nan)
        oc = np.zeros(n, bool)
        for items in tracks:
            tb, to = _expand_track(items, n)
            free = ~np.all(np.isfinite(bx), axis=1) & np.all(np.isfinite(tb), axis=1)
            bx[free], oc[free] = tb[free], to[free]
        boxes[lab], occluded[lab] = bx, oc
    return boxes, occluded


def _expand_track(
    items: list[tuple[int, NDArray, bool, bool]], n: int
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Per-frame boxes (n, 4) and occluded flags of one track: linear interpolation between
    listed boxes, absent from an ``outside`` box to the next listed one. The frame indices of
    ``items`` are in [0, n) (``read_cvat_xml`` checked them)."""
    bx = np.full((n, 4), np.nan)
    oc = np.zeros(n, bool)
    for i, (k, box, outside, occ) in enumerate(items):
        if outside:
            continue
        bx[k], oc[k] = box, occ
        if i + 1 < len(items):
            k2, box2, _, _ = items[i + 1]
            for j in range(k + 1, k2):
                a = (j - k) / (k2 - k)
                bx[j] = (1.0 - a) * box + a * box2
                oc[j] = occ
    return bx, oc


def list_frames(folder: Path | str) -> list[Path]:
    """Image files of ``folder`` in CVAT's default (lexicographic) order."""
    files = sorted(p for p in Path(folder).iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise ValueError(f"{folder}: no image files ({', '.join(IMAGE_SUFFIXES)})")
    return files


def load_cvat_sequence(
    folder: Path | str,
    xml_path: Path | str,
    params: PlantParams | None = None,
    binning: int | None = None,
    fps: float | None = None,
    name: str | None = None,
) -> TrackingSequence:
    """A ``TrackingSequence`` from a folder of frames and their CVAT for video 1.1 XML.

    The frames must be sensor size / ``binning`` of ``params``' camera (``binning`` defaults to
    sensor width / frame width). Ground-truth centres are the centres of the annotated boxes;
    frames where a marker is outside have NaN truth and are not scored. Raises ``ValueError``
    with the reason for mismatched sizes or counts.
    """
    import cv2

    p = params or PlantParams()
    files = list_frames(folder)
    tracks = read_cvat_xml(xml_path, n_frames=len(files))
    first = cv2.imread(str(files[0]), cv2.IMREAD_COLOR)
    if first is None:
        raise ValueError(f"cannot read {files[0]}")
    h, w = first.shape[:2]
    if tracks.width and (tracks.width, tracks.height) != (w, h):
        raise ValueError(f"frames are {w} x {h} px but the XML's original_size is "
                         f"{tracks.width} x {tracks.height}")
    cam = p.camera
    b = binning if binning is not None else cam.sensor_width_px // max(w, 1)
    if (cam.sensor_width_px // b, cam.sensor_height_px // b) != (w, h):
        raise ValueError(f"frames of {w} x {h} px are not the sensor ({cam.sensor_width_px} x "
                         f"{cam.sensor_height_px}) binned by {b}; pass PlantParams whose camera "
                         "matches the recording")
    images = np.empty((len(files), h, w, 3), np.uint8)
    for k, f in enumerate(files):
        img = first if k == 0 else cv2.imread(str(f), cv2.IMREAD_COLOR)
        if img is None or img.shape[:2] != (h, w):
            raise ValueError(f"{f}: unreadable or not {w} x {h} px")
        images[k] = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    n = len(files)
    boxes = np.full((n, 2, 4), np.nan)
    for m, lab in enumerate(LABELS):
        for k in range(n):
            bi = tracks.boxes_px[lab][k]
            if np.all(np.isfinite(bi)):
                boxes[k, m] = box_image_to_sensor(bi, b)
    centres = boxes[:, :, :2] + 0.5 * boxes[:, :, 2:]
    occluded = tracks.occluded["red"] | tracks.occluded["yellow"]
    return TrackingSequence(name or tracks.name or Path(folder).name, images, centres, boxes, b,
                            fps or cam.frame_rate_hz, "recorded", occluded, np.zeros(n, bool),
                            p, None, np.full(n, np.nan))


def benchmark_cvat_folder(
    folder: Path | str,
    xml_path: Path | str,
    trackers: Iterable[str] = ("gk_transt", "dual_transt", "kcf", "csrt", "k2cf"),
    params: PlantParams | None = None,
    binning: int | None = None,
    out_dir: Path | str | None = None,
    transt_factory=None,
):
    """Run the tracking benchmark (``experiments.tracking_bench``) on a user's recording.

    ``folder`` holds the frames, ``xml_path`` their CVAT for video 1.1 annotation (labels
    ``red`` and ``yellow``). Trackers are named as in ``observer.trackers.make_pair_tracker``.
    The first frame must show both markers (the trackers start on its annotated boxes). Returns
    (per-run metrics, Table-1 latency table); with ``out_dir`` also writes the CSV tables and the
    precision and error plots there.
    """
    from experiments.tracking_plots import plot_error_curves, plot_precision_curves
    from experiments.tracking_runs import run_benchmark, table1
    from observer.trackers import make_pair_tracker

    seq = load_cvat_sequence(folder, xml_path, params, binning)
    if not np.all(np.isfinite(seq.boxes_px[0])):
        raise ValueError("both markers must be annotated (not outside) in the first frame")
    p = seq.params
    factories = {name: (lambda name=name: make_pair_tracker(name, p,
                                                            transt_factory=transt_factory))
                 for name in trackers}
    metrics, runs, seqs = run_benchmark(factories, [seq])
    t1 = table1(runs)
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        metrics.to_csv(out / f"{seq.name}_metrics.csv", index=False)
        t1.to_csv(out / f"{seq.name}_table1.csv", index=False)
        plot_precision_curves(runs, seqs, seq.case).savefig(
            out / f"{seq.name}_precision.png", dpi=110)
        plot_error_curves(runs, seq).savefig(out / f"{seq.name}_errors.png", dpi=110)
    return metrics, t1
