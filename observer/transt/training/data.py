"""Training and validation crop pairs for TransT, pre-rendered into a cache (analytic renderer).

Rendering on the fly was too slow for CPU training (docs/transt.md), so the pairs are rendered once,
deterministically from a seed, into a folder of ``.npy`` arrays (``runs/transt_cache/`` by
default, not committed) and read back memory-mapped by ``CropPairs``.

**A scene** (all draws from ``numpy.random.default_rng([seed, scene_index])``, so any scene can
be regenerated alone and the result does not depend on the number of worker processes):

* one of ``N_RENDERERS`` analytic renderers (``plant.render_analytic``), each with its own
  distractors: stationary specular highlights (0-4) and, in some, a red or yellow sticker on the
  rotor (the renderers' read noise is off; noise is added per crop below);
* a template attitude in the workspace: tilt β uniform in [0°, 15°] (seed 000 §2.4), spin and
  yaw uniform in [0, 2π) (free axes);
* ``SEARCHES_PER_SCENE`` search frames, each a short motion away: the attitude turned by a
  random rotation of up to 6°, rendered with motion blur (a random body rate and exposure
  chosen so that the marker smear is none, moderate or up to about 1.2 marker diameters; the
  seed's blur case averages 6 frames at 5x speed, seed 000 §4.3.2), and in 25 % of them a
  black or grey rectangle over 20-60 % of the red marker (partial occlusion).

**Crops** follow TransT's training sampler (Chen et al., CVPR 2021, §4.1 and the released
settings): the template crop (context factor 2) is centred on the red marker's box with a small
jitter (our choice: 5 % of its size, since a user's initial box is not exact); the search crop
(context factor 4) is centred on the search frame's red box moved by up to ±1.5 box sizes
(TransT's centre jitter factor 3) with the box size scaled by exp(0.25 N(0, 1)) (TransT's scale
jitter 0.25). Lighting: each crop is scaled by an illumination factor (log-uniform 0.5-1.6,
the search's correlated with the template's), a ±6 % white-balance change, and Gaussian read
noise of 0-5 DN.

**Labels**: the red disc's ground-truth box of the search frame (``Frame.boxes_px[0]``,
full-sensor px, converted to image px) as (cx, cy, w, h) fractions of the search crop; and the
true red centre (``Frame.marker_px[0]``) in the same fractions, for the centre-error metric.
The target is the red main marker (seed 000 §3.2); with ``PairSpec.yellow_fraction`` > 0 that
fraction of the scenes has the yellow marker as the target instead (labels then from
``boxes_px[1]`` / ``marker_px[1]``), so that the network follows its template rather than the
colour red.

``CropPairs`` adds joint dihedral flips (horizontal, vertical, transpose) of both crops at load
time in training (the disc and the square plate are symmetric under them).

Run ``python -m observer.transt.training.data --out runs/transt_cache/train --pairs 8000
--seed 1``.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import time
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from observer.transt.crop import box_to_crop, context_side, crop_square, normalise
from observer.transt.network import SMALL, TransTConfig
from observer.transt.training.augment import (
    appearance_jitter,
    dihedral_box,
    dihedral_image,
    hide_target,
)
from observer.transt.training.validation import marker_box_image
from plant import attitude
from plant.appearance import (
    TRAIN_LIGHTINGS,
    TRAIN_OCCLUDERS,
    TRAIN_PATTERNS,
    occluder_rgb,
    random_options,
    random_params,
)
from plant.camera import sensor_to_image
from plant.params import PlantParams
from plant.render_analytic import AnalyticRenderer, AnalyticRenderOptions, jpeg_roundtrip

#: Bumped whenever the generator changes what a seed produces.
GENERATOR_VERSION = 1
#: Renderers (distractor layouts) per cache (our choice).
N_RENDERERS = 12
#: Renderers of the randomised pool (``PairSpec.randomise``), each its own appearance.
N_RANDOM_RENDERERS = 48
#: Search frames rendered per template frame (our choice: reuses the template render).
SEARCHES_PER_SCENE = 2
#: Image pixels a marker moves per radian of rotation about a horizontal axis at the default
#: camera (65 mm lever arm, 25 mm lens 0.30 m away, 4x binning: 1812 px focal length).
_PX_PER_RAD = 390.0


class PairSpec(BaseModel):
    """How crop pairs are cut (defaults: TransT's sampler, our choices where noted)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    template_size: int = Field(SMALL.template_size, description="Template crop side, px.")
    search_size: int = Field(SMALL.search_size, description="Search crop side, px.")
    template_factor: float = Field(2.0, description="TransT: template context factor 2.")
    search_factor: float = Field(4.0, description="TransT: search context factor 4.")
    centre_jitter: float = Field(3.0, description="TransT: search centre jitter factor 3.")
    tracking_fraction: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="Our choice: fraction of the searches cut with ``tracking_jitter`` instead "
        "of ``centre_jitter``, the regime of tracking, where the search is centred on a "
        "prediction near the target (0: every search with TransT's jitter).",
    )
    tracking_jitter: float = Field(
        1.0, gt=0.0, description="Search centre jitter factor of the tracking-regime searches: "
        "the target within ±0.5 box sizes of the crop centre.")
    scale_jitter: float = Field(0.25, description="TransT: search scale jitter 0.25.")
    template_jitter: float = Field(0.05, description="Our choice: template centre jitter.")
    occlusion_prob: float = Field(0.25, description="Our choice: partial occlusions.")
    max_tilt_deg: float = Field(15.0, description="Seed 000 §2.4: tilt range 0-15°.")
    yellow_fraction: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="Our choice: fraction of scenes whose target is the yellow marker (0 for "
        "the red main marker only; > 0 teaches the network to follow the template, which the "
        "dual-TransT baseline needs for its yellow tracker).",
    )
    randomise: bool = Field(
        False,
        description="Domain randomisation: scenes from the randomised renderer pool "
        "(training appearance families of ``plant.appearance``), occluders of many colours, "
        "highlights and colour blobs near the target, blur and JPEG compression of the crops.",
    )

    @classmethod
    def for_config(
        cls, config: TransTConfig, yellow_fraction: float = 0.0, randomise: bool = False,
        tracking_fraction: float = 0.0,
    ) -> PairSpec:
        """The default spec for a network ``config`` (its template and search crop sides), with the
        given yellow-target fraction, randomised renderers and tracking-regime fraction."""
        return cls(
            template_size=config.template_size,
            search_size=config.search_size,
            template_factor=config.template_factor,
            search_factor=config.search_factor,
            yellow_fraction=yellow_fraction,
            randomise=randomise,
            occlusion_prob=0.35 if randomise else 0.25,
            tracking_fraction=tracking_fraction,
        )


def _make_renderers(params: PlantParams, randomise: bool = False) -> list[AnalyticRenderer]:
    """The fixed renderer pool (the same for every seed: distractor layouts are scenery); with
    ``randomise``, ``N_RANDOM_RENDERERS`` appearances from the training families."""
    if randomise:
        rng = np.random.default_rng(20241)
        return [
            AnalyticRenderer(
                random_params(rng, params),
                options=random_options(rng, TRAIN_PATTERNS, TRAIN_LIGHTINGS,
                                       noise_sigma_dn=0.0, max_sub_frames=32),
                seed=int(rng.integers(1 << 31)),
            )
            for _ in range(N_RANDOM_RENDERERS)
        ]
    rng = np.random.default_rng(20240)
    out = []
    for i in range(N_RENDERERS):
        distractor = ("none", "none", "red", "yellow")[i % 4]
        opts = AnalyticRenderOptions(
            noise_sigma_dn=0.0,
            n_highlights=int(rng.integers(0, 5)),
            highlight_peak=float(rng.uniform(0.3, 0.9)),
            colour_distractor=distractor,
            max_sub_frames=32,
        )
        out.append(AnalyticRenderer(params, options=opts, seed=int(rng.integers(1 << 31))))
    return out


def _photometric(
    crop: NDArray[np.uint8], illum: float, rng: np.random.Generator
) -> NDArray[np.uint8]:
    """Illumination scale, white-balance change and read noise on a crop."""
    f = crop.astype(np.float32) * np.float32(illum)
    f *= rng.uniform(0.94, 1.06, size=3).astype(np.float32)
    sigma = rng.uniform(0.0, 5.0)
    f += rng.normal(0.0, sigma, size=f.shape).astype(np.float32)
    return np.clip(np.rint(f), 0, 255).astype(np.uint8)


def _photometric_randomised(
    crop: NDArray[np.uint8], illum: float, rng: np.random.Generator
) -> NDArray[np.uint8]:
    """``_photometric`` with a wider white balance (±10 %) and noise (0-8 DN), then Gaussian
    blur (sigma 0.5-2 px) in 25 % and JPEG compression (quality 25-90) in 25 % of crops."""
    f = crop.astype(np.float32) * np.float32(illum)
    f *= rng.uniform(0.9, 1.1, size=3).astype(np.float32)
    f += rng.normal(0.0, rng.uniform(0.0, 8.0), size=f.shape).astype(np.float32)
    if rng.uniform() < 0.25:
        f = cv2.GaussianBlur(f, (0, 0), rng.uniform(0.5, 2.0))
    out = np.clip(np.rint(f), 0, 255).astype(np.uint8)
    quality = int(rng.integers(25, 91)) if rng.uniform() < 0.25 else None
    return jpeg_roundtrip(out, quality)


def _near_target(
    image: NDArray[np.uint8], box: NDArray[np.float64], rng: np.random.Generator
) -> None:
    """In place: a specular highlight (white Gaussian blob) on or next to the target ``box``
    (image px), or a red / yellow / red-brown disc beside it (a distractor of the marker's
    size), or nothing, with probabilities 0.15, 0.15 and 0.7."""
    u = rng.uniform()
    if u >= 0.3:
        return
    x, y, w, h = box
    size = 0.5 * (w + h)
    hh, ww = image.shape[:2]
    yy, xx = np.mgrid[0:hh, 0:ww].astype(np.float32)
    if u < 0.15:
        c = np.array([x + w / 2, y + h / 2]) + rng.normal(0.0, 0.4, 2) * size
        sig = size * rng.uniform(0.15, 0.5)
        blob = np.exp(-((xx - c[0]) ** 2 + (yy - c[1]) ** 2) / (2 * sig * sig))
        f = image.astype(np.float32) + 255.0 * rng.uniform(0.4, 1.2) * blob[..., None]
        image[...] = np.clip(np.rint(f), 0, 255).astype(np.uint8)
        return
    ang = rng.uniform(0.0, 2 * np.pi)
    c = np.array([x + w / 2, y + h / 2]) + rng.uniform(1.3, 3.0) * size * np.array(
        [np.cos(ang), np.sin(ang)]
    )
    colour = ((200, 25, 20), (240, 200, 25), (140, 45, 30))[int(rng.integers(3))]
    r = 0.5 * size * rng.uniform(0.7, 1.3)
    cv2.circle(image, tuple(int(round(v * 16)) for v in c), int(round(r * 16)),
               tuple(int(v * rng.uniform(0.8, 1.1)) for v in colour), -1, cv2.LINE_AA, 4)


def _occlude(
    image: NDArray[np.uint8],
    box: NDArray[np.float64],
    rng: np.random.Generator,
    colour: tuple[int, int, int] | None = None,
) -> None:
    """Cover 20-60 % of ``box`` (image px) from a random side with a rectangle that extends
    beyond the box (in place), of ``colour`` or (None) dark or grey."""
    x, y, w, h = box
    frac = rng.uniform(0.2, 0.6)
    ext = rng.uniform(0.2, 1.5) * max(w, h)
    side = int(rng.integers(4))
    x0, y0, x1, y1 = x - ext, y - ext, x + w + ext, y + h + ext
    if side == 0:
        x1 = x + frac * w
    elif side == 1:
        x0 = x + (1 - frac) * w
    elif side == 2:
        y1 = y + frac * h
    else:
        y0 = y + (1 - frac) * h
    if colour is None:
        colour = (0, 0, 0) if rng.uniform() < 0.7 else tuple([int(rng.integers(40, 200))] * 3)
    hh, ww = image.shape[:2]
    c0, r0 = max(int(round(x0)), 0), max(int(round(y0)), 0)
    c1, r1 = min(int(round(x1)), ww), min(int(round(y1)), hh)
    if c1 > c0 and r1 > r0:
        image[r0:r1, c0:c1] = colour


def _smear_motion(rng: np.random.Generator) -> tuple[NDArray[np.float64], float]:
    """Body rate (rad/s) and exposure (s) for a random marker smear length."""
    u = rng.uniform()
    if u < 0.5:
        smear = rng.uniform(0.0, 2.0)
    elif u < 0.8:
        smear = rng.uniform(2.0, 15.0)
    else:
        smear = rng.uniform(15.0, 60.0)
    exposure = float(np.exp(rng.uniform(np.log(2e-3), np.log(0.17))))
    axis = rng.normal(size=3)
    axis[2] *= 0.5  # spin moves the markers less; keep the smear mostly from tilt / yaw
    axis /= np.linalg.norm(axis)
    rate = smear / (_PX_PER_RAD * exposure)
    return axis * rate, exposure


def _random_attitude(rng: np.random.Generator, max_tilt_deg: float) -> NDArray[np.float64]:
    beta = math.radians(max_tilt_deg) * rng.uniform()
    return attitude.from_zyz(rng.uniform(0, 2 * np.pi), beta, rng.uniform(0, 2 * np.pi))


def render_scene(
    seed: int,
    index: int,
    renderers: list[AnalyticRenderer],
    spec: PairSpec,
) -> list[dict[str, NDArray]]:
    """The ``SEARCHES_PER_SCENE`` crop pairs of scene ``index`` of a cache with ``seed``."""
    rng = np.random.default_rng([seed, index])
    r = renderers[int(rng.integers(len(renderers)))]
    b = r.binning
    q0 = _random_attitude(rng, spec.max_tilt_deg)
    f0 = r.render(q0, exposure_s=2e-3, omega=rng.normal(0.0, 0.3, 3))
    # the target: red, or yellow in a fraction of the scenes (no draw when the fraction is 0,
    # so red-only caches are unchanged by this option)
    m = int(spec.yellow_fraction > 0 and rng.uniform() < spec.yellow_fraction)
    box0 = marker_box_image(f0, m)
    illum0 = float(np.exp(rng.uniform(np.log(0.5), np.log(1.6))))
    tc = box0[:2] + box0[2:] / 2 + rng.normal(0.0, spec.template_jitter, 2) * box0[2:]
    tsize = box0[2:] * np.exp(rng.normal(0.0, 0.05, 2))
    tside = context_side(tsize, spec.template_factor)
    template = crop_square(f0.image, tc, tside, spec.template_size)
    photometric = _photometric_randomised if spec.randomise else _photometric
    template = photometric(template, illum0, rng)
    out = []
    for _ in range(SEARCHES_PER_SCENE):
        for _try in range(20):
            q1 = attitude.multiply(q0, attitude.from_rotvec(rng.normal(size=3) * 0.06))
            if math.degrees(attitude.tilt(q1)) <= spec.max_tilt_deg + 1.0:
                break
        omega, exposure = _smear_motion(rng)
        f1 = r.render(q1, exposure_s=exposure, omega=omega)
        img = f1.image.copy()
        box1 = marker_box_image(f1, m)
        if rng.uniform() < spec.occlusion_prob:
            colour = None
            if spec.randomise:
                colour = occluder_rgb(rng, TRAIN_OCCLUDERS[int(rng.integers(len(TRAIN_OCCLUDERS)))])
            _occlude(img, box1, rng, colour)
        if spec.randomise:
            _near_target(img, box1, rng)
        size = box1[2:] * np.exp(rng.normal(0.0, 1.0, 2) * spec.scale_jitter)
        jitter = spec.centre_jitter
        # (no draw when the fraction is 0, so caches without tracking-regime searches are
        # unchanged by this option)
        if spec.tracking_fraction > 0 and rng.uniform() < spec.tracking_fraction:
            jitter = spec.tracking_jitter
        off = (rng.uniform(size=2) - 0.5) * math.sqrt(size[0] * size[1]) * jitter
        sc = box1[:2] + box1[2:] / 2 + off
        sside = context_side(size, spec.search_factor)
        search = crop_square(img, sc, sside, spec.search_size, f0.image.reshape(-1, 3).mean(0))
        illum1 = illum0 * float(np.exp(rng.uniform(-0.2, 0.2)))
        search = photometric(search, illum1, rng)
        centre_img = sensor_to_image(f1.marker_px[m], b)
        lo = sc - sside / 2
        out.append(
            {
                "template": template,
                "search": search,
                "box": box_to_crop(box1, sc, sside).astype(np.float32),
                "centre": ((centre_img - lo) / sside).astype(np.float32),
                # sensor px per crop fraction, and the marker diameter in sensor px
                "scale": np.float32(sside * b),
                "diameter": np.float32(np.mean(f1.boxes_px[m][2:])),
                "marker": np.int8(m),
            }
        )
    return out


_WORKER: dict = {}


def _worker_init(spec_json: str) -> None:
    _WORKER["spec"] = PairSpec.model_validate_json(spec_json)
    _WORKER["renderers"] = _make_renderers(PlantParams(), _WORKER["spec"].randomise)


def _worker_scene(args: tuple[int, int]) -> tuple[int, list[dict[str, NDArray]]]:
    seed, index = args
    return index, render_scene(seed, index, _WORKER["renderers"], _WORKER["spec"])


def generate_cache(
    out_dir: str | Path,
    n_pairs: int,
    seed: int,
    spec: PairSpec | None = None,
    workers: int = 1,
    progress: bool = True,
) -> Path:
    """Render ``n_pairs`` crop pairs (rounded up to whole scenes) into ``out_dir``.

    Files: ``template.npy`` (N, St, St, 3) uint8, ``search.npy`` (N, Sx, Sx, 3) uint8,
    ``box.npy`` (N, 4) float32 (cx, cy, w, h crop fractions), ``centre.npy`` (N, 2) float32
    (true red centre, crop fractions), ``scale.npy`` (N,) sensor px per crop fraction,
    ``diameter.npy`` (N,) marker diameter in sensor px, and ``meta.json``. Deterministic in
    ``seed`` whatever ``workers`` is. An existing complete cache with the same meta is reused.
    """
    from tqdm import tqdm

    spec = spec or PairSpec()
    out = Path(out_dir)
    n_scenes = -(-int(n_pairs) // SEARCHES_PER_SCENE)
    n = n_scenes * SEARCHES_PER_SCENE
    meta = {
        "generator_version": GENERATOR_VERSION,
        "seed": int(seed),
        "pairs": n,
        "spec": spec.model_dump(),
        "renderers": N_RANDOM_RENDERERS if spec.randomise else N_RENDERERS,
    }
    if (out / "meta.json").is_file() and json.loads((out / "meta.json").read_text()).get(
        "complete"
    ) and {k: v for k, v in json.loads((out / "meta.json").read_text()).items()
           if k not in ("complete", "seconds")} == meta:
        return out
    out.mkdir(parents=True, exist_ok=True)
    (out / "meta.json").unlink(missing_ok=True)
    st, sx = spec.template_size, spec.search_size
    arrays = {
        "template": np.lib.format.open_memmap(out / "template.npy", "w+", np.uint8, (n, st, st, 3)),
        "search": np.lib.format.open_memmap(out / "search.npy", "w+", np.uint8, (n, sx, sx, 3)),
        "box": np.zeros((n, 4), np.float32),
        "centre": np.zeros((n, 2), np.float32),
        "scale": np.zeros(n, np.float32),
        "diameter": np.zeros(n, np.float32),
        "marker": np.zeros(n, np.int8),
    }
    t0 = time.perf_counter()
    jobs = [(int(seed), i) for i in range(n_scenes)]
    bar = tqdm(total=n, desc=f"rendering {out.name}", unit="pair", disable=not progress)

    def store(index: int, pairs: list[dict[str, NDArray]]) -> None:
        for j, p in enumerate(pairs):
            k = index * SEARCHES_PER_SCENE + j
            for key, arr in arrays.items():
                arr[k] = p[key]
        bar.update(len(pairs))

    if workers > 1:
        ctx = mp.get_context("fork")
        with ctx.Pool(workers, _worker_init, (spec.model_dump_json(),)) as pool:
            for index, pairs in pool.imap_unordered(_worker_scene, jobs, chunksize=16):
                store(index, pairs)
    else:
        _worker_init(spec.model_dump_json())
        for job in jobs:
            store(*_worker_scene(job))
    bar.close()
    for key in ("template", "search"):
        arrays[key].flush()
    for key in ("box", "centre", "scale", "diameter", "marker"):
        np.save(out / f"{key}.npy", arrays[key])
    meta["complete"] = True
    meta["seconds"] = round(time.perf_counter() - t0, 1)
    (out / "meta.json").write_text(json.dumps(meta, indent=2) + "\n")
    return out


class CropPairs:
    """A cache written by ``generate_cache``, read memory-mapped.

    ``batch(indices, rng=None)`` returns ImageNet-normalised float32 arrays (template
    (B, 3, St, St), search (B, 3, Sx, Sx)) and the labels; with ``rng`` each pair gets a random
    joint dihedral transform (training augmentation).
    """

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        meta_path = self.folder / "meta.json"
        if not meta_path.is_file() or not json.loads(meta_path.read_text()).get("complete"):
            raise FileNotFoundError(
                f"no complete crop-pair cache in {self.folder}; generate it with "
                f"python -m observer.transt.training.data --out {self.folder}"
            )
        self.meta = json.loads(meta_path.read_text())
        self.template = np.load(self.folder / "template.npy", mmap_mode="r")
        self.search = np.load(self.folder / "search.npy", mmap_mode="r")
        self.box = np.load(self.folder / "box.npy")
        self.centre = np.load(self.folder / "centre.npy")
        self.scale = np.load(self.folder / "scale.npy")
        self.diameter = np.load(self.folder / "diameter.npy")
        mk = self.folder / "marker.npy"
        self.marker = np.load(mk) if mk.is_file() else np.zeros(len(self.box), np.int8)

    def __len__(self) -> int:
        return len(self.box)

    def batch(
        self,
        indices: NDArray[np.int64],
        rng: np.random.Generator | None = None,
        absent_prob: float = 0.0,
        appearance_prob: float = 0.0,
    ) -> dict[str, NDArray]:
        """Pairs ``indices``; with ``rng``, the dihedral augmentation, in a fraction
        ``appearance_prob`` of the pairs a new look (``appearance_jitter``) and, in a fraction
        ``absent_prob``, the target removed from the search crop (``hide_target``;
        ``present`` False: every cell is background, no box label)."""
        idx = np.sort(np.asarray(indices))
        t = np.asarray(self.template[idx])
        s = np.array(self.search[idx])
        box, centre = self.box[idx].copy(), self.centre[idx].copy()
        present = np.ones(len(idx), dtype=bool)
        if rng is not None:
            ks = rng.integers(0, 8, size=len(idx))
            for i, k in enumerate(ks):
                t[i] = dihedral_image(t[i], int(k))
                s[i] = dihedral_image(s[i], int(k))
                box[i] = dihedral_box(box[i], int(k))
                centre[i] = dihedral_box(centre[i], int(k))
            if appearance_prob > 0:
                for i in np.flatnonzero(rng.uniform(size=len(idx)) < appearance_prob):
                    t[i], s[i] = appearance_jitter(t[i], s[i], box[i], rng)
            if absent_prob > 0:
                present = rng.uniform(size=len(idx)) >= absent_prob
                for i in np.flatnonzero(~present):
                    hide_target(s[i], box[i], rng)
        return {
            "template": normalise(t),
            "search": normalise(s),
            "box": box,
            "centre": centre,
            "scale": self.scale[idx],
            "diameter": self.diameter[idx],
            "present": present,
        }


def preview(folder: str | Path, path: str | Path, n: int = 8) -> None:
    """Write a PNG of the first ``n`` pairs with their label boxes (for a visual check)."""
    d = CropPairs(folder)
    rows = []
    for i in range(min(n, len(d))):
        s = cv2.cvtColor(np.asarray(d.search[i]), cv2.COLOR_RGB2BGR)
        sx = s.shape[0]
        cx, cy, w, h = d.box[i] * sx
        cv2.rectangle(s, (int(cx - w / 2), int(cy - h / 2)), (int(cx + w / 2), int(cy + h / 2)),
                      (0, 255, 0), 1)
        t = cv2.cvtColor(np.asarray(d.template[i]), cv2.COLOR_RGB2BGR)
        t = cv2.copyMakeBorder(t, 0, sx - t.shape[0], 0, 0, cv2.BORDER_CONSTANT)
        rows.append(np.hstack([t, s]))
    cv2.imwrite(str(path), np.vstack(rows))


def main(argv: list[str] | None = None) -> None:
    """The command ``python -m observer.transt.training.data``: render a crop-pair cache (and
    optionally a PNG preview) from the options in ``argv`` (default: the command line)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/transt_cache/train", help="cache folder")
    ap.add_argument("--pairs", type=int, default=8000, help="number of crop pairs")
    ap.add_argument("--seed", type=int, default=1, help="generator seed")
    ap.add_argument("--workers", type=int, default=2, help="render processes")
    ap.add_argument("--preview", default=None, help="also write a PNG preview here")
    a = ap.parse_args(argv)
    out = generate_cache(a.out, a.pairs, a.seed, workers=a.workers)
    if a.preview:
        preview(out, a.preview)
    print(f"cache ready: {out}")


if __name__ == "__main__":
    main()
