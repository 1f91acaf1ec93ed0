"""Train the ``small`` TransT on cached analytic-render crop pairs (CPU, resumable).

Recipe (a 1.9 M-parameter TransT-shaped model with TransT's loss weights, AdamW 5e-4 and batch
32 reached 0.1 marker diameters median error in 300 steps in a first trial here, docs/transt.md):
TransT's loss (``observer.transt.training.losses``: 8.334 CE + 5 L1 + 2 GIoU, background
weight 0.0625), AdamW with learning rate 5e-4 and weight decay 1e-4 (TransT's decay), batch 32,
a 30-step linear warm-up and a cosine decay to 10 % (our choice), gradient-norm clipping at 1
(our choice), dropout 0.1 (TransT), trained from scratch (no ImageNet weights can be fetched
here).

Data: ``observer.transt.training.data``, a training cache (seed 1) and a validation cache
(seed 2) that is never trained on; both are rendered first if missing. Every ``--eval-every``
steps the script measures the validation centre error; at the end it also tracks three rendered
validation sequences (seeds 1001-1003) with ``TransTTracker``.

Checkpoints (``--out``, default ``runs/transt_train/``): ``last.pt`` every ``--ckpt-every`` steps
(model, optimiser, step, wall time, RNG state); rerunning the same command resumes from it
(``--fresh`` starts over). ``history.jsonl`` logs the losses and validation metrics, and
``metrics.json`` the final numbers. With ``--export`` the final weights go to that file with
their SHA-256 (``observer.transt.weights``) and ``MODEL_CARD.md`` is written beside them.

The shipped weights come from two runs (``observer.transt.weights.REBUILD_COMMAND``): 1000 steps
on red targets from scratch, then 300 steps (``--init-from`` the first, lr 2e-4) on a cache in
which half the scenes have the yellow marker as the target (``--yellow-fraction 0.5``), so that
the network follows its template (the dual-TransT baseline tracks the yellow marker with it).
Set ``OMP_WAIT_POLICY=PASSIVE`` on a shared machine: with spinning OpenMP threads a step took
ten times longer whenever another process held a core.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from observer.transt.network import (
    CONFIGS,
    TransTConfig,
    TransTNet,
    build_transt,
    count_parameters,
)
from observer.transt.tracker import TransTTracker, hanning_window
from observer.transt.training.data import (
    CropPairs,
    PairSpec,
    generate_cache,
)
from observer.transt.training.losses import TransTLoss, cxcywh_to_xyxy, giou
from observer.transt.training.model_card import write_model_card
from observer.transt.training.validation import (
    VALIDATION_SEQUENCE_FRAMES,
    VALIDATION_SEQUENCE_SEEDS,
    marker_box_image,
    validation_sequence,
)
from observer.transt.weights import CARD_NAME, load_weights, save_weights
from plant.appearance import (
    heldout_options,
)

#: Seed of the target removal in the validation pairs' absent copies.
VALIDATION_ABSENT_SEED = 1004


def lr_factor(step: int, total: int, warmup: int = 30, floor: float = 0.1) -> float:
    """Learning-rate multiplier: linear warm-up, then cosine decay to ``floor``."""
    if step < warmup:
        return (step + 1) / warmup
    t = min(1.0, (step - warmup) / max(1, total - warmup))
    return floor + (1.0 - floor) * 0.5 * (1.0 + math.cos(math.pi * t))


@torch.no_grad()
def evaluate_pairs(
    net: TransTNet, pairs: CropPairs, window_influence: float, batch: int = 64
) -> dict[str, float]:
    """Centre error and IoU on crop pairs, decoded as the tracker does (Hanning window).

    Errors are distances between the predicted box centre and the true red centre
    (``Frame.marker_px[0]``) in full-sensor px, also in marker diameters. ``*_nowin`` decodes
    without the window (plain argmax of the target probability). ``val_*_score_*`` are the
    highest target probability of each search (the tracker's confidence), on the pairs as they
    are and with the target removed from every search (``augment.hide_target``, fixed seeds).
    """
    net.eval()
    fs = net.config.search_feature_size
    win = torch.from_numpy(hanning_window(fs))
    errs, errs_nw, dias, ious, seen, absent = [], [], [], [], [], []
    for start in range(0, len(pairs), batch):
        idx = np.arange(start, min(start + batch, len(pairs)))
        b = pairs.batch(idx)
        logits, boxes = net(torch.from_numpy(b["template"]), torch.from_numpy(b["search"]))
        prob = logits.softmax(-1)[..., 0]
        seen.append(prob.max(dim=1).values.numpy())
        h = pairs.batch(idx, np.random.default_rng([VALIDATION_ABSENT_SEED, start]), 1.0)
        h_logits, _ = net(torch.from_numpy(h["template"]), torch.from_numpy(h["search"]))
        absent.append(h_logits.softmax(-1)[..., 0].max(dim=1).values.numpy())
        for use_win, out in ((True, errs), (False, errs_nw)):
            score = prob * (1 - window_influence) + win * window_influence if use_win else prob
            best = score.argmax(dim=1)
            pred = boxes[torch.arange(len(best)), best]
            d = (pred[:, :2].numpy() - b["centre"]) * b["scale"][:, None]
            out.append(np.hypot(d[:, 0], d[:, 1]))
            if use_win:
                iou, _ = giou(cxcywh_to_xyxy(pred), cxcywh_to_xyxy(torch.from_numpy(b["box"])))
                ious.append(iou.numpy())
        dias.append(b["diameter"])
    e, e_nw, dia = np.concatenate(errs), np.concatenate(errs_nw), np.concatenate(dias)
    return {
        "val_pairs": float(len(e)),
        "val_centre_err_median_px": float(np.median(e)),
        "val_centre_err_p90_px": float(np.percentile(e, 90)),
        "val_centre_err_median_diam": float(np.median(e / dia)),
        "val_within_20px": float(np.mean(e < 20.0)),
        "val_centre_err_median_px_nowin": float(np.median(e_nw)),
        "val_iou_mean": float(np.mean(np.concatenate(ious))),
        "val_present_score_median": float(np.median(np.concatenate(seen))),
        "val_absent_score_median": float(np.median(np.concatenate(absent))),
        "val_absent_score_p90": float(np.percentile(np.concatenate(absent), 90)),
    }


def evaluate_sequences(
    net: TransTNet,
    seeds: tuple[int, ...] = VALIDATION_SEQUENCE_SEEDS,
    n_frames: int = VALIDATION_SEQUENCE_FRAMES,
    marker: int = 0,
    heldout: str | None = None,
) -> dict[str, float]:
    """Track rendered validation sequences from the true first box of marker 0 (red; keys
    ``seq_*``) or 1 (yellow; keys ``seq_yellow_*``); centre error (sensor px) of the box centre
    against ``Frame.marker_px[marker]`` and the per-frame track time. ``heldout`` ("pattern" or
    "lighting") renders them in that held-out appearance family
    (``plant.appearance.heldout_options``; keys ``heldout_<family>_*``)."""
    errs, times = [], []
    for seed in seeds:
        frames = validation_sequence(seed, n_frames, *(heldout_options(seed, heldout)
                                                        if heldout else (None, None)))
        trk = TransTTracker(net.eval())
        trk.initialize(frames[0].image, marker_box_image(frames[0], marker))
        for f in frames[1:]:
            r = trk.track(f.image)
            box = r.box_image_px
            times.append(r.compute_time_s)
            c = (box[:2] + box[2:] / 2 + 0.5) * f.binning - 0.5  # image -> sensor px
            errs.append(float(np.hypot(*(c - f.marker_px[marker]))))
    e = np.asarray(errs)
    e = np.where(np.isfinite(e), e, np.inf)
    p = "seq" if marker == 0 else "seq_yellow"
    if heldout:
        p = f"heldout_{heldout}" + ("" if marker == 0 else "_yellow")
    out = {
        f"{p}_frames": float(len(e)),
        f"{p}_centre_err_median_px": float(np.median(e)),
        f"{p}_centre_err_p95_px": float(np.percentile(e, 95)),
        f"{p}_centre_err_max_px": float(np.max(e)),
        f"{p}_precision_20px": float(np.mean(e < 20.0)),
    }
    if marker == 0 and not heldout:
        out["seq_track_time_median_s"] = float(np.median(times))
    return out


def _save_ckpt(path: Path, net, opt, step: int, wall: float, rng: np.random.Generator) -> None:
    tmp = path.with_suffix(".tmp")
    torch.save(
        {
            "net": net.state_dict(),
            "opt": opt.state_dict(),
            "step": step,
            "wall_s": wall,
            "rng": rng.bit_generator.state,
            "torch_rng": torch.get_rng_state(),
            "config": net.config.model_dump(),
        },
        tmp,
    )
    tmp.replace(path)


def _parser() -> argparse.ArgumentParser:
    """The command line of ``python -m observer.transt.training.train``."""
    ap = argparse.ArgumentParser(description="Train the small TransT on analytic renders.")
    ap.add_argument("--config", default="small", choices=sorted(CONFIGS))
    ap.add_argument("--cache", default="runs/transt_cache", help="folder of the pair caches")
    ap.add_argument("--train-pairs", type=int, default=12000)
    ap.add_argument("--val-pairs", type=int, default=512)
    ap.add_argument("--train-seed", type=int, default=1)
    ap.add_argument("--val-seed", type=int, default=2)
    ap.add_argument("--render-workers", type=int, default=2)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--lr", type=float, default=5e-4)
    ap.add_argument("--weight-decay", type=float, default=1e-4)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0, help="init and batch-order seed")
    ap.add_argument("--eval-every", type=int, default=100)
    ap.add_argument("--ckpt-every", type=int, default=25)
    ap.add_argument("--out", default="runs/transt_train")
    ap.add_argument("--export", default=None, help="write the final weights here")
    ap.add_argument("--fresh", action="store_true", help="ignore an existing checkpoint")
    ap.add_argument(
        "--yellow-fraction", type=float, default=0.0,
        help="fraction of training scenes whose target is the yellow marker",
    )
    ap.add_argument(
        "--init-from", default=None,
        help="start from these weights (a file written by --export, SHA-256 checked)",
    )
    ap.add_argument("--warmup", type=int, default=30, help="learning-rate warm-up steps")
    ap.add_argument(
        "--randomise", action="store_true",
        help="domain-randomised training and validation caches (PairSpec.randomise)",
    )
    ap.add_argument(
        "--absent-prob", type=float, default=0.0,
        help="fraction of training searches with the target removed (augment.hide_target), "
        "labelled all background",
    )
    ap.add_argument(
        "--appearance-prob", type=float, default=0.0,
        help="fraction of training pairs given a new look at load time "
        "(augment.appearance_jitter: textures, lighting, colour, a Bayer sensor, gamma, "
        "distractors, blur and JPEG)",
    )
    ap.add_argument(
        "--tracking-fraction", type=float, default=0.0,
        help="fraction of the training searches centred near the target (search-centre jitter "
        "factor 1 instead of TransT's 3), the regime of tracking; validation keeps 3",
    )
    ap.add_argument(
        "--export-from", default=None,
        help="skip training: evaluate this checkpoint (last.pt or best.pt of --out) and "
        "export it to --export",
    )
    return ap


def _caches(a: argparse.Namespace, config: TransTConfig) -> tuple[CropPairs, CropPairs, float]:
    """The training and validation pair caches (rendered if missing) and the render time, s."""
    spec = PairSpec.for_config(config, a.yellow_fraction, a.randomise, a.tracking_fraction)
    t_cache = time.perf_counter()
    tag = f"_y{a.yellow_fraction:g}" if a.yellow_fraction > 0 else ""
    dr = "_dr" if a.randomise else ""
    tag += dr
    if a.tracking_fraction > 0:
        tag += f"_tr{a.tracking_fraction:g}"
    train_dir = generate_cache(
        Path(a.cache) / f"train_s{a.train_seed}{tag}", a.train_pairs, a.train_seed, spec,
        workers=a.render_workers,
    )
    val_dir = generate_cache(
        Path(a.cache) / f"val_s{a.val_seed}{dr}", a.val_pairs, a.val_seed,
        PairSpec.for_config(config, randomise=a.randomise), workers=a.render_workers,
    )
    train, val = CropPairs(train_dir), CropPairs(val_dir)
    cache_s = float(train.meta.get("seconds", 0.0)) + float(val.meta.get("seconds", 0.0))
    print(f"caches ready in {time.perf_counter() - t_cache:.0f} s: {len(train)} train, "
          f"{len(val)} validation pairs", flush=True)
    return train, val, cache_s


def _network(a: argparse.Namespace, config: TransTConfig) -> tuple[TransTNet, dict]:
    """A new network of ``config`` (seeded by ``--seed``), or the ``--init-from`` weights with
    their metadata."""
    torch.manual_seed(a.seed)
    net = build_transt(config)
    init_meta: dict = {}
    if a.init_from:
        start, init_meta = load_weights(a.init_from)
        if start.config != config:
            raise SystemExit(f"--init-from {a.init_from} holds a {start.config.name} network")
        net.load_state_dict(start.state_dict())
        print(f"initialised from {a.init_from} ({init_meta.get('steps')} steps)", flush=True)
    return net, init_meta


@dataclass
class _Run:
    """What training changes: the network, the optimiser, the batch-order generator, the step,
    the training wall time (s) and the best validation median centre error (sensor px)."""

    net: TransTNet
    opt: torch.optim.Optimizer
    rng: np.random.Generator
    best: float
    step: int = 0
    wall: float = 0.0


def _restore(a: argparse.Namespace, out: Path, run: _Run) -> None:
    """Load ``--export-from``, or resume from ``out/last.pt`` (dropping later history records)
    unless ``--fresh``."""
    net, opt, rng = run.net, run.opt, run.rng
    step, wall = 0, 0.0
    ckpt = out / "last.pt"
    if a.export_from:
        st = torch.load(a.export_from, map_location="cpu", weights_only=False)
        net.load_state_dict(st["net"])
        step, wall = int(st["step"]), float(st["wall_s"])
        print(f"exporting {a.export_from} (step {step}, {wall / 60:.1f} min)", flush=True)
    elif ckpt.is_file() and not a.fresh:
        st = torch.load(ckpt, map_location="cpu", weights_only=False)
        net.load_state_dict(st["net"])
        opt.load_state_dict(st["opt"])
        step, wall = int(st["step"]), float(st["wall_s"])
        rng.bit_generator.state = st["rng"]
        torch.set_rng_state(st["torch_rng"])
        print(f"resumed from {ckpt} at step {step} ({wall / 60:.1f} min)", flush=True)
        hist_path = out / "history.jsonl"
        if hist_path.is_file():  # drop records of steps after the checkpoint
            keep = [ln for ln in hist_path.read_text().splitlines()
                    if ln.strip() and json.loads(ln)["step"] <= step]
            hist_path.write_text("".join(ln + "\n" for ln in keep))
    elif a.fresh:
        (out / "history.jsonl").unlink(missing_ok=True)
    run.step, run.wall = step, wall


def _train_step(
    a: argparse.Namespace, net: TransTNet, opt: torch.optim.Optimizer, loss_fn: TransTLoss,
    train: CropPairs, rng: np.random.Generator, step: int,
) -> dict[str, float]:
    """One optimiser step on a random batch (learning rate by ``lr_factor``); the loss parts."""
    net.train()
    for g in opt.param_groups:
        g["lr"] = a.lr * lr_factor(step, a.steps, a.warmup)
    b = train.batch(rng.choice(len(train), a.batch, replace=False), rng, a.absent_prob,
                    a.appearance_prob)
    logits, boxes = net(torch.from_numpy(b["template"]), torch.from_numpy(b["search"]))
    loss, parts = loss_fn(logits, boxes, torch.from_numpy(b["box"]),
                          torch.from_numpy(b["present"]))
    opt.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
    opt.step()
    return parts


def _train(
    a: argparse.Namespace, out: Path, run: _Run, train: CropPairs, val: CropPairs,
    config: TransTConfig,
) -> list[float]:
    """Train from ``run.step`` to ``--steps``: validation every ``--eval-every`` steps, a record
    per step in ``history.jsonl``, ``best.pt`` at the best validation median error, ``last.pt``
    every ``--ckpt-every`` steps. Returns the last 50 losses."""
    from tqdm import tqdm

    net, opt, rng, step, wall, best = run.net, run.opt, run.rng, run.step, run.wall, run.best
    loss_fn = TransTLoss()
    ckpt = out / "last.pt"
    hist = (out / "history.jsonl").open("a")
    recent = _recent_losses(out / "history.jsonl", step)
    bar = tqdm(total=a.steps, initial=step, desc="training", unit="step")
    while step < a.steps and not a.export_from:
        t0 = time.perf_counter()
        parts = _train_step(a, net, opt, loss_fn, train, rng, step)
        step += 1
        wall += time.perf_counter() - t0
        recent = (recent + [parts["loss"]])[-50:]
        rec = {"step": step, "wall_s": round(wall, 2), "lr": opt.param_groups[0]["lr"], **parts}
        if step % a.eval_every == 0 or step == a.steps:
            rec.update(evaluate_pairs(net, val, config.window_influence))
            bar.write(
                f"step {step}: val median centre error "
                f"{rec['val_centre_err_median_px']:.1f} sensor px "
                f"({rec['val_centre_err_median_diam']:.3f} diameters), "
                f"within 20 px {rec['val_within_20px']:.3f}, IoU {rec['val_iou_mean']:.3f}, "
                f"score present {rec['val_present_score_median']:.2f} / target removed "
                f"{rec['val_absent_score_median']:.2f}"
            )
        hist.write(json.dumps(rec) + "\n")
        hist.flush()
        if rec.get("val_centre_err_median_px", np.inf) < best:
            best = rec["val_centre_err_median_px"]
            _save_ckpt(out / "best.pt", net, opt, step, wall, rng)
        bar.set_postfix(loss=f"{np.mean(recent):.3f}", iou=f"{parts['iou']:.2f}")
        bar.update(1)
        if step % a.ckpt_every == 0 or step == a.steps:
            _save_ckpt(ckpt, net, opt, step, wall, rng)
    bar.close()
    hist.close()
    run.step, run.wall, run.best = step, wall, best
    return recent


def _final_metrics(net: TransTNet, val: CropPairs, config: TransTConfig) -> dict[str, float]:
    """Validation pairs, then sequences of both markers, clean and on the held-out families."""
    net.eval()
    metrics = evaluate_pairs(net, val, config.window_influence)
    metrics.update(evaluate_sequences(net))
    metrics.update(evaluate_sequences(net, marker=1))
    for family in ("pattern", "lighting"):
        for marker in (0, 1):
            metrics.update(evaluate_sequences(net, marker=marker, heldout=family))
    return metrics


def main(argv: list[str] | None = None) -> None:
    """The command ``python -m observer.transt.training.train``: render the caches if missing,
    train (resuming from ``--out/last.pt``), evaluate, and with ``--export`` write the weights,
    their SHA-256 and the model card (options in ``argv``, default: the command line)."""
    a = _parser().parse_args(argv)
    torch.set_num_threads(a.threads)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    config = CONFIGS[a.config]
    train, val, cache_s = _caches(a, config)
    net, init_meta = _network(a, config)
    opt = torch.optim.AdamW(net.parameters(), lr=a.lr, weight_decay=a.weight_decay)
    run = _Run(net, opt, np.random.default_rng(a.seed), _read_history_best(out / "history.jsonl"))
    _restore(a, out, run)
    recent = _train(a, out, run, train, val, config)
    step, wall = run.step, run.wall

    metrics = _final_metrics(net, val, config)
    final_loss = float(np.mean(recent)) if recent else float("nan")
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    print(json.dumps(metrics, indent=2))
    if a.export:
        meta = {
            "config": config.model_dump(),
            "parameters": count_parameters(net),
            "steps": step,
            "batch": a.batch,
            "lr": a.lr,
            "weight_decay": a.weight_decay,
            "threads": a.threads,
            "seed": a.seed,
            "wall_s": round(wall, 1),
            "cache_s": round(cache_s, 1),
            "final_loss": final_loss,
            "train_pairs": len(train),
            "train_seed": a.train_seed,
            "val_pairs": len(val),
            "val_seed": a.val_seed,
            "yellow_fraction": a.yellow_fraction,
            "init_from": a.init_from,
            "init_meta": init_meta,
            "generator_version": int(train.meta["generator_version"]),
            "machine": _machine(),
            "metrics": metrics,
            "randomise": a.randomise,
            "absent_prob": a.absent_prob,
            "appearance_prob": a.appearance_prob,
            "tracking_fraction": a.tracking_fraction,
            "command": ("python -m observer.transt.training.train "
                        + " ".join(_training_args(sys.argv[1:]))),
        }
        export = Path(a.export)
        digest = save_weights(net, export, meta)
        write_model_card(export.parent / CARD_NAME, meta, export, digest)
        print(f"exported {export} (SHA-256 {digest})")


def _training_args(args: list[str]) -> list[str]:
    """Command-line arguments without ``--export-from X`` (the command that trained the run)."""
    out, skip = [], False
    for x in args:
        if skip:
            skip = False
        elif x == "--export-from":
            skip = True
        elif not x.startswith("--export-from="):
            out.append(x)
    return out


def _read_history_best(path: Path) -> float:
    """Smallest validation median centre error (sensor px) logged in ``history.jsonl`` (the
    score of ``best.pt``), or infinity."""
    if not path.is_file():
        return float("inf")
    vals = [json.loads(ln).get("val_centre_err_median_px") for ln in path.read_text().splitlines()
            if ln.strip()]
    return min((v for v in vals if v is not None), default=float("inf"))


def _recent_losses(path: Path, step: int, n: int = 50) -> list[float]:
    """Training losses of the last ``n`` logged steps up to ``step`` (a resumed or exported
    run reports the same final loss as an uninterrupted one)."""
    if not path.is_file():
        return []
    recs = [json.loads(ln) for ln in path.read_text().splitlines() if ln.strip()]
    return [r["loss"] for r in recs if r["step"] <= step][-n:]


def _machine() -> str:
    """CPU model and core count of this machine."""
    import os

    from plant.machine import cpu_model

    return f"{cpu_model()}, {os.cpu_count()} cores"


if __name__ == "__main__":
    main()
