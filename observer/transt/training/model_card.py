"""The model card written beside exported TransT weights (``MODEL_CARD.md``).

``write_model_card`` turns the training run's metadata, and that of the runs it continued,
into the card: the architecture and parameter count, the file and its SHA-256 (the lines
``observer.transt.weights.card_facts`` reads back at every load), the training data, each
stage's data, steps and wall time, the validation metrics and the commands that reproduce it.
"""

from __future__ import annotations

from pathlib import Path

from observer.transt.training.data import N_RANDOM_RENDERERS, PairSpec
from observer.transt.training.validation import (
    VALIDATION_SEQUENCE_FRAMES,
    VALIDATION_SEQUENCE_SEEDS,
)
from observer.transt.weights import card_file_line
from plant.appearance import (
    HELD_OUT_LIGHTING,
    HELD_OUT_OCCLUDER,
    HELD_OUT_PATTERN,
    TRAIN_LIGHTINGS,
    TRAIN_OCCLUDERS,
    TRAIN_PATTERNS,
)


def _randomisation_lines() -> list[str]:
    """Model-card lines on the domain randomisation and the held-out appearance families."""
    return [
        "Domain randomisation (`PairSpec.randomise`, the last stage): each scene comes from one "
        f"of {N_RANDOM_RENDERERS} renderers of random appearance (`plant.appearance`): rotor "
        "colour and pattern, plate colour, marker shades (hue ±8°, saturation and value "
        "±15 %) and diameters (6.5-9.5 mm), uneven lighting, white balance, highlights, red "
        "or yellow distractor stickers of other shades and sizes; occluders of the colour "
        "families " + ", ".join(TRAIN_OCCLUDERS) + " over 20-60 % of the target in 35 % of "
        "the searches; highlights on the target and red, yellow or red-brown discs beside it; "
        "per crop white balance ±10 %, read noise 0-8 DN, Gaussian blur (25 %) and JPEG "
        "compression at quality 25-90 (25 %).",
        "",
        "**Held-out appearance families** (chosen before training, never in the training "
        f"data; for evaluation only): the rotor pattern `{HELD_OUT_PATTERN}`, the lighting "
        f"`{HELD_OUT_LIGHTING}` (an off-axis light up to 2.5x brighter), and `{HELD_OUT_OCCLUDER}` "
        "occluders. Training used the patterns " + ", ".join(TRAIN_PATTERNS) + " and the "
        "lightings " + ", ".join(TRAIN_LIGHTINGS) + ". The `heldout_pattern_*` and "
        "`heldout_lighting_*` metrics below track sequences rendered in those families "
        "(`plant.appearance.heldout_options`); the tracking benchmark has the held-out cases too.",
        "",
    ]


def _same_caches(a: dict, b: dict) -> bool:
    """Two runs read the same pair caches (a later stage reusing its predecessor's)."""
    keys = ("train_seed", "train_pairs", "val_seed", "yellow_fraction", "randomise",
            "tracking_fraction")
    return all(a.get(k) == b.get(k) for k in keys)


def _stage_lines(meta: dict, reused_caches: bool = False) -> list[str]:
    """Model-card lines describing one training run (``reused_caches``: its caches were
    rendered for the stage before, so their time is not counted again)."""
    y = float(meta.get("yellow_fraction", 0.0) or 0.0)
    target = "the red marker" if y == 0 else f"the red marker, the yellow one in {y:.0%} of scenes"
    tf = float(meta.get("tracking_fraction", 0.0) or 0.0)
    near, wide = (PairSpec.model_fields[k].default for k in ("tracking_jitter", "centre_jitter"))
    jitter = ("" if tf == 0 else
              f"; {tf:.0%} of the searches in the regime of tracking, the target within "
              f"±{near / 2:g} box sizes of the crop centre (search-centre jitter factor {near:g} "
              f"instead of {wide:g})")
    return [
        f"- Data: {meta['train_pairs']} crop pairs (seed {meta['train_seed']}, target {target}"
        f"{jitter})"
        + (f"; the target removed from {meta['absent_prob']:.0%} of the searches "
           "(`augment.hide_target`: inpainted, covered or replaced by another part of the crop), "
           "labelled all background." if meta.get("absent_prob") else "."),
        f"- {meta['steps']} steps of batch {meta['batch']} (AdamW, lr {meta['lr']}, weight decay "
        f"{meta['weight_decay']}, warm-up + cosine to 10 %), TransT's loss weights "
        "(8.334, 5, 2); final training loss (mean of the last 50 steps) "
        f"{meta['final_loss']:.3f}.",
        f"- Wall time: {meta['wall_s'] / 60:.1f} min of training on {meta['threads']} CPU "
        f"threads ({meta['machine']}, shared with other jobs)"
        + ("; the previous stage's caches." if reused_caches else
           f", plus {meta['cache_s'] / 60:.1f} min rendering its caches."),
        f"- Command: `{meta['command']}`",
    ]


def write_model_card(path: Path, meta: dict, weights: Path, digest: str) -> None:
    """Write MODEL_CARD.md to ``path`` from the run's metadata ``meta`` (and, for a run
    started with ``--init-from``, the metadata of the runs it continued, ``meta['init_meta']``
    in turn); it records the weights file ``weights`` and its SHA-256 ``digest``
    (``weights.card_file_line``), the architecture, the data, every training stage, the
    validation metrics (beside those before this stage) and the commands that reproduce it."""
    stages = [meta]
    while stages[0].get("init_meta"):
        stages.insert(0, stages[0]["init_meta"])
    init = meta.get("init_meta") or {}
    lines = (_model_lines(meta, bool(init), weights, digest) + _data_lines(meta)
             + _training_lines(stages) + _metrics_lines(meta["metrics"], init)
             + _reproduce_lines(stages))
    path.write_text("\n".join(lines))


def _model_lines(meta: dict, continued: bool, weights: Path, digest: str) -> list[str]:
    """The card's title and its "Model" section: architecture, parameters, input, file."""
    cfg = meta["config"]
    return [
        "# Model card: TransT `small` (observer/transt/weights/transt_small.pt)",
        "",
        "Written by `observer.transt.training.train` at export; numbers are from the runs below.",
        "",
        "## Model",
        "",
        f"- Architecture: TransT (Chen et al., CVPR 2021) as in `observer/transt/network.py`, "
        f"configuration `{cfg['name']}`: bottleneck ResNet (stem width "
        f"{cfg['backbone_inplanes']}, blocks {tuple(cfg['backbone_blocks'])}, layer3 dilation "
        f"{cfg['layer3_dilation']}, output stride 8), d = {cfg['d_model']}, {cfg['nhead']} heads, "
        f"FFN {cfg['dim_feedforward']}, {cfg['num_fusion_layers']} fusion layers, template "
        f"{cfg['template_size']} px, search {cfg['search_size']} px, context factors "
        f"{cfg['template_factor']:g} / {cfg['search_factor']:g}, window influence "
        f"{cfg['window_influence']}. Trained from scratch (no ImageNet weights).",
        f"- Parameters: {meta['parameters']:,}.",
        "- Input: RGB uint8 frames (ImageNet-normalised crops inside the tracker). Target: the "
        "marker in the template box, trained on the red main marker (seed 000 §3.2)"
        + (" and the yellow auxiliary marker." if continued or meta.get("yellow_fraction")
           else "."),
        card_file_line(weights, digest),
        "",
    ]


def _data_lines(meta: dict) -> list[str]:
    """The card's "Training data" section: the rendered pairs, the domain randomisation (for
    a randomised run) and the validation data."""
    return [
        "## Training data",
        "",
        "Crop pairs rendered by `plant.render_analytic` (generator version "
        f"{meta['generator_version']}, `observer/transt/training/data.py`): random workspace "
        "attitudes (tilt 0-15°, free spin and yaw), a short motion between template and search "
        "frame, motion blur up to about 1.2 marker diameters, partial occlusion (25 %), "
        "highlights and colour stickers as distractors, illumination 0.5-1.6x, read noise "
        "0-5 DN, TransT's centre jitter (factor 3) and scale jitter (0.25), joint dihedral "
        "flips at load time.",
        "",
        *(_randomisation_lines() if meta.get("randomise") else []),
        f"Validation (never trained on): {meta['val_pairs']} red-target pairs from seed "
        f"{meta['val_seed']}, and {len(VALIDATION_SEQUENCE_SEEDS)} tracking sequences of "
        f"{VALIDATION_SEQUENCE_FRAMES} frames (seeds {VALIDATION_SEQUENCE_SEEDS}, "
        "`validation.validation_sequence`), tracked from the true first box.",
        "",
    ]


def _training_lines(stages: list[dict]) -> list[str]:
    """The card's "Training" section: one block per stage, then the total steps and minutes
    (a stage reusing its predecessor's caches does not count their rendering time again)."""
    lines = ["## Training", ""]
    reused = [i > 0 and _same_caches(st, stages[i - 1]) for i, st in enumerate(stages)]
    for i, st in enumerate(stages, start=1):
        if len(stages) > 1:
            lines += [f"Stage {i}{f' (continued from stage {i - 1})' if i > 1 else ''}:", ""]
        lines += _stage_lines(st, reused[i - 1]) + [""]
    total_min = sum(st["wall_s"] + (0.0 if r else st["cache_s"])
                    for st, r in zip(stages, reused, strict=True)) / 60
    lines += [f"Total: {sum(st['steps'] for st in stages)} steps, {total_min:.1f} min "
              "including cache rendering.", ""]
    return lines


def _metrics_lines(metrics: dict[str, float], init: dict) -> list[str]:
    """The card's "Validation metrics" table, with a column of the metrics before this stage
    when the run continued another (``init``, that run's metadata)."""
    lines = [
        "## Validation metrics",
        "",
        "Centre errors are in full-sensor pixels (2448 x 2048 sensor; frames are 4x binned) "
        "against the true marker centre `Frame.marker_px`; a marker diameter is about 190 "
        "sensor px. `val_*`: crop pairs decoded as the tracker does (`_nowin`: without the "
        "Hanning window); `seq_*`: the red marker tracked through the sequences, "
        "`seq_yellow_*`: the yellow one.",
        "",
        "| metric | value |" + (" before this stage |" if init else ""),
        "|---|---|" + ("---|" if init else ""),
    ]
    for k, v in metrics.items():
        extra = ""
        if init:
            v1 = init.get("metrics", {}).get(k)
            extra = f" {v1:.4g} |" if v1 is not None else " - |"
        lines.append(f"| {k} | {v:.4g} |{extra}")
    return lines


def _reproduce_lines(stages: list[dict]) -> list[str]:
    """The card's "Reproduce" section: every stage's command and how the stages chain."""
    return [
        "",
        "## Reproduce",
        "",
        "```",
        *[f"OMP_WAIT_POLICY=PASSIVE {st['command']}" for st in stages],
        "```",
        "",
        "(renders the caches into `runs/transt_cache/` if missing, trains into `--out` "
        "(default `runs/transt_train/`), resumable, and exports the weights with their SHA-256 "
        "and this card. Each stage's `--init-from` is the file the stage before exported: "
        "stage 1's export was kept as `runs/transt_train/transt_small_red.pt` for stage 2; "
        "stage 3 read stage 2's export from the weights folder and exported to "
        "`runs/transt_train_dr/transt_small_dr.pt` for stage 4; stage 4's export, shipped "
        "until stage 5, was kept as `runs/transt_train_absent/transt_small_absent.pt` for "
        "stage 5 (`benchmarks/transt_dr.sh` runs stages 3, 4 and 5 in this order, exporting "
        "each to the file the next reads). The number of render workers changes only the "
        "rendering time, not the pairs. CPU timings vary with the machine's load; the numbers "
        "depend on the thread count only through floating-point summation order.)",
        "",
    ]
