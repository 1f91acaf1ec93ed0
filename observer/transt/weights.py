"""Shipped TransT weights: file layout, SHA-256 check at load, and the command that rebuilds them.

The ``small`` network trained here (``observer.transt.train``) ships as
``observer/transt/weights/transt_small.pt``: a ``torch.save`` of a dict with the configuration
(``'config'``, a ``TransTConfig`` as a dict), the state dict (``'net'``, the same key layout as
the published TransT checkpoint's ``'net'`` entry) and metadata (``'meta'``). Its SHA-256 digest
sits beside it in ``transt_small.pt.sha256`` (``sha256sum`` format) and is checked before the
file is deserialised: a missing or corrupt file raises ``WeightsError`` naming the file and
the command that rebuilds it. Nothing is ever downloaded.
"""

from __future__ import annotations

import hashlib
import string
from pathlib import Path

import torch

from observer.transt.network import TransTConfig, TransTNet

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
SMALL_WEIGHTS = WEIGHTS_DIR / "transt_small.pt"

#: The commands that regenerate the training data, train (stage 1: red targets; stage 2:
#: continued with half the scenes on the yellow marker; stages 3 and 4: domain-randomised
#: scenes, then target-absent searches too) and export ``transt_small.pt`` with its
#: ``.sha256``; see ``weights/MODEL_CARD.md`` for what they produced here.
REBUILD_COMMAND = (
    "OMP_WAIT_POLICY=PASSIVE python -m observer.transt.train --steps 1000 "
    "--export runs/transt_train/transt_small_red.pt && "
    "OMP_WAIT_POLICY=PASSIVE python -m observer.transt.train "
    "--init-from runs/transt_train/transt_small_red.pt --yellow-fraction 0.5 --train-seed 3 "
    "--train-pairs 6000 --steps 300 --lr 2e-4 --warmup 20 --out runs/transt_train_mixed "
    "--export observer/transt/weights/transt_small.pt && "
    "sh benchmarks/transt_dr.sh train dr && sh benchmarks/transt_dr.sh export dr && "
    "sh benchmarks/transt_dr.sh train absent && sh benchmarks/transt_dr.sh export absent"
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
    is missing, fails the SHA-256 check or does not hold a matching TransT state dict.
    """
    p = Path(path)
    verify(p, expected_sha256)
    try:
        blob = torch.load(p, map_location="cpu", weights_only=True)
        config = TransTConfig.model_validate(blob["config"])
        net = TransTNet(config)
        net.load_state_dict(blob["net"], strict=True)
    except Exception as exc:  # a file with the right digest but the wrong content
        raise WeightsError(
            f"TransT weights file {p} could not be loaded: {exc}\n" + _rebuild_hint(p)
        ) from exc
    net.eval()
    return net, dict(blob.get("meta", {}))
