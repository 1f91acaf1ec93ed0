"""Shipped TransT weights: file layout, SHA-256 check at load, and the command that rebuilds them.

The ``small`` network trained here (``observer.transt.training.train``) ships as
``observer/transt/weights/transt_small.pt``: a ``torch.save`` of a dict with the configuration
(``'config'``, a ``TransTConfig`` as a dict), the state dict (``'net'``, the same key layout as
the published TransT checkpoint's ``'net'`` entry) and metadata (``'meta'``). Its SHA-256 digest
sits beside it in ``transt_small.pt.sha256`` (``sha256sum`` format) and is checked before the
file is deserialised: a missing or corrupt file raises ``WeightsError`` naming the file and
the command that rebuilds it. Nothing is ever downloaded.

**The model card** (``MODEL_CARD.md`` beside the weights, written at export by
``observer.transt.training.train``) records the file's name and SHA-256, the configuration's
name and the parameter count (``card_facts``). When a card beside a weights file names that
file, the file must match it: the SHA-256, the configuration stored in the file (equal to the code's
configuration of that name, ``network.CONFIGS``) and the parameter count; otherwise
``WeightsError`` names the mismatch and the rebuild command. The shipped weights must have
their card.
"""

from __future__ import annotations

import hashlib
import re
import string
from dataclasses import dataclass
from pathlib import Path

import torch

from observer.transt.network import CONFIGS, TransTConfig, TransTNet, count_parameters

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
SMALL_WEIGHTS = WEIGHTS_DIR / "transt_small.pt"
#: The model card's file name, beside the weights it describes.
CARD_NAME = "MODEL_CARD.md"
#: The shipped weights' measured accuracy (network alone) on the evaluation-only image source
#: ``plant.render_unseen``, with the SHA-256 of the weights measured; written by
#: ``benchmarks/bench_transt_unseen.py``, read (never recomputed) by the study's report.
UNSEEN_ACCURACY = WEIGHTS_DIR / "unseen_accuracy.json"
_CARD_FILE = re.compile(r"^- File: `([^`]+)`, SHA-256 `([0-9a-fA-F]{64})`", re.MULTILINE)
_CARD_CONFIG = re.compile(r"configuration `([\w.-]+)`")
_CARD_PARAMETERS = re.compile(r"^- Parameters: ([\d,]+)", re.MULTILINE)

#: The commands that regenerate the training data, train (stage 1: red targets; stage 2:
#: continued with half the scenes on the yellow marker; stages 3 to 5: domain-randomised
#: scenes, then target-absent searches too, then searches in the regime of tracking) and
#: export ``transt_small.pt`` with its ``.sha256`` and model card; see
#: ``weights/MODEL_CARD.md`` for what they produced here.
REBUILD_COMMAND = (
    "OMP_WAIT_POLICY=PASSIVE python -m observer.transt.training.train --steps 1000 "
    "--export runs/transt_train/transt_small_red.pt && "
    "OMP_WAIT_POLICY=PASSIVE python -m observer.transt.training.train "
    "--init-from runs/transt_train/transt_small_red.pt --yellow-fraction 0.5 --train-seed 3 "
    "--train-pairs 6000 --steps 300 --lr 2e-4 --warmup 20 --out runs/transt_train_mixed "
    "--export observer/transt/weights/transt_small.pt && "
    "sh benchmarks/transt_dr.sh train dr && sh benchmarks/transt_dr.sh export dr && "
    "sh benchmarks/transt_dr.sh train absent && sh benchmarks/transt_dr.sh export absent && "
    "sh benchmarks/transt_dr.sh train track && sh benchmarks/transt_dr.sh export track"
)


class WeightsError(RuntimeError):
    """A weight file is missing, fails its SHA-256 check, or does not hold TransT weights."""


def sha256_of(path: str | Path) -> str:
    """Hex SHA-256 digest of a file."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def checksum_path(path: str | Path) -> Path:
    """Where the digest of ``path`` is kept: ``<path>.sha256``."""
    p = Path(path)
    return p.with_name(p.name + ".sha256")


def _rebuild_hint(path: Path) -> str:
    return f"Rebuild it (and its .sha256) with:\n    {REBUILD_COMMAND}\n(weights file: {path})"


def _recorded_digest(cp: Path, p: Path) -> str:
    """The SHA-256 recorded in the checksum file ``cp`` of weights ``p`` (``sha256sum`` format:
    64 hex digits, then the file name), lower case; ``WeightsError`` if the file is
    unreadable, empty or does not start with such a digest."""
    try:
        fields = cp.read_text(encoding="ascii").split()
    except (OSError, UnicodeDecodeError) as exc:
        problem = f"cannot be read as text ({exc})"
    else:
        digest = fields[0] if fields else ""
        if len(digest) == 64 and all(c in string.hexdigits for c in digest):
            return digest.lower()
        problem = ("is empty" if not fields
                   else f"does not start with a 64-digit hex SHA-256 (it starts {digest[:20]!r})")
    raise WeightsError(f"checksum file {cp} of TransT weights {p} {problem}\n" + _rebuild_hint(p))


def verify(path: str | Path, expected_sha256: str | None = None) -> str:
    """Check ``path`` against ``expected_sha256`` (default: the digest in ``<path>.sha256``).

    Returns the digest; raises ``WeightsError`` (naming the file and the rebuild command) when
    the file or its digest is missing, the checksum file is empty or malformed, or the digests
    differ.
    """
    p = Path(path)
    if not p.is_file():
        raise WeightsError(f"TransT weights file not found: {p}\n" + _rebuild_hint(p))
    if expected_sha256 is None:
        cp = checksum_path(p)
        if not cp.is_file():
            raise WeightsError(
                f"checksum file not found for TransT weights {p}: expected {cp}\n"
                + _rebuild_hint(p)
            )
        expected_sha256 = _recorded_digest(cp, p)
    actual = sha256_of(p)
    if actual != expected_sha256.lower():
        raise WeightsError(
            f"TransT weights file {p} is corrupt or was changed: SHA-256 {actual} does not "
            f"match the recorded {expected_sha256}.\n" + _rebuild_hint(p)
        )
    return actual


@dataclass(frozen=True)
class CardFacts:
    """What a model card records about its weights file: the file name, its SHA-256 (lower
    case), the configuration name and the parameter count."""

    file: str
    sha256: str
    config: str
    parameters: int


def card_file_line(path: str | Path, digest: str) -> str:
    """The model card's line that names the weights file and its SHA-256 (``card_facts``)."""
    name = Path(path).name
    return (f"- File: `{name}`, SHA-256 `{digest}` (checked at every load, against this card "
            f"and `{name}.sha256`).")


def card_facts(card: str | Path) -> CardFacts:
    """The facts a model card records (``CardFacts``); ``WeightsError`` naming the card when
    it cannot be read or lacks one of them."""
    cp = Path(card)
    try:
        text = cp.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise WeightsError(f"model card {cp} cannot be read ({exc})") from exc
    f, c, n = _CARD_FILE.search(text), _CARD_CONFIG.search(text), _CARD_PARAMETERS.search(text)
    missing = [what for what, m in (("the file line '- File: `<name>`, SHA-256 `<64 hex>`'", f),
                                    ("the configuration ('configuration `<name>`')", c),
                                    ("the parameter count ('- Parameters: <n>')", n)) if m is None]
    if missing:
        raise WeightsError(f"model card {cp} does not record {' or '.join(missing)}")
    return CardFacts(f.group(1), f.group(2).lower(), c.group(1), int(n.group(1).replace(",", "")))


def _card_for(p: Path) -> CardFacts | None:
    """The facts of the model card beside ``p`` if it describes ``p`` (None when there is no
    card or it names another file); the shipped weights must have their card."""
    cp = p.parent / CARD_NAME
    shipped = p.resolve() == SMALL_WEIGHTS.resolve()
    if not cp.is_file():
        if shipped:
            raise WeightsError(f"model card not found for the shipped TransT weights {p}: "
                               f"expected {cp}\n" + _rebuild_hint(p))
        return None
    try:
        facts = card_facts(cp)
    except WeightsError as exc:
        raise WeightsError(f"{exc}\n" + _rebuild_hint(p)) from exc
    if facts.file != p.name:
        if shipped:
            raise WeightsError(f"model card {cp} describes `{facts.file}`, not the shipped "
                               f"weights {p.name}\n" + _rebuild_hint(p))
        return None
    return facts


def _check_architecture(net: TransTNet, card: CardFacts, p: Path) -> None:
    """``WeightsError`` unless the loaded network has the card's configuration, equal to the
    code's configuration of that name, and the card's parameter count."""
    cfg, cp = net.config, p.parent / CARD_NAME
    problem = ""
    if cfg.name != card.config:
        problem = f"holds a `{cfg.name}` network, the model card {cp} a `{card.config}` one"
    elif card.config not in CONFIGS:
        problem = f"is a `{card.config}` network, a configuration the code does not define"
    elif cfg != CONFIGS[card.config]:
        diff = {k: (v, getattr(CONFIGS[card.config], k)) for k, v in cfg.model_dump().items()
                if getattr(CONFIGS[card.config], k) != v}
        problem = (f"has a `{cfg.name}` architecture other than the code's "
                   "(field: file vs code) " + ", ".join(f"{k}: {a} vs {b}"
                                                        for k, (a, b) in diff.items()))
    elif count_parameters(net) != card.parameters:
        problem = (f"has {count_parameters(net):,} parameters, the model card {cp} "
                   f"{card.parameters:,}")
    if problem:
        raise WeightsError(f"TransT weights file {p} {problem}.\n" + _rebuild_hint(p))


def save_weights(net: TransTNet, path: str | Path, meta: dict | None = None) -> str:
    """Write ``net``'s configuration, state dict and ``meta`` to ``path`` and its digest to
    ``<path>.sha256``; returns the digest."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    sd = {k: v.detach().cpu().clone() for k, v in net.state_dict().items()}
    torch.save({"config": net.config.model_dump(), "net": sd, "meta": dict(meta or {})}, p)
    digest = sha256_of(p)
    checksum_path(p).write_text(f"{digest}  {p.name}\n")
    return digest


def load_weights(
    path: str | Path = SMALL_WEIGHTS, expected_sha256: str | None = None
) -> tuple[TransTNet, dict]:
    """Verify and load a weights file written by ``save_weights``.

    Returns the network (in eval mode) and its metadata. Raises ``WeightsError`` when the file
    is missing, fails the SHA-256 check, does not hold a matching TransT state dict, or does
    not match the model card beside it (SHA-256 or architecture, see the module docstring).
    """
    p = Path(path)
    digest = verify(p, expected_sha256)
    card = _card_for(p)
    if card is not None and card.sha256 != digest:
        raise WeightsError(
            f"TransT weights file {p} does not match its model card {p.parent / CARD_NAME}: "
            f"SHA-256 {digest}, the card records {card.sha256}.\n" + _rebuild_hint(p))
    try:
        blob = torch.load(p, map_location="cpu", weights_only=True)
        config = TransTConfig.model_validate(blob["config"])
        net = TransTNet(config)
        net.load_state_dict(blob["net"], strict=True)
    except Exception as exc:  # a file with the right digest but the wrong content
        raise WeightsError(
            f"TransT weights file {p} could not be loaded: {exc}\n" + _rebuild_hint(p)
        ) from exc
    if card is not None:
        _check_architecture(net, card, p)
    net.eval()
    return net, dict(blob.get("meta", {}))
