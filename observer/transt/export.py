"""ONNX export of TransT's per-frame step and an ONNX Runtime session for it (optional backend).

The exported graph is ``TransTNet.track_features`` with the template's position encoding baked
in: inputs ``search`` (B, 3, Sx, Sx) float32 (ImageNet-normalised crops) and ``z`` (B, Lz, d)
float32 (the template tokens from ``TransTNet.template_features``, computed once at ``init``);
outputs ``logits`` (B, L, 2) and ``boxes`` (B, L, 4). The batch axis B is free, so one call can
take the crops of many runs (``observer.transt.service``). Needs ``onnx`` for the export and
``onnxruntime`` to run it (both project dependencies); they are imported lazily, so a checkout
without them still runs the eager backend, and the error says what is missing.

Exported models are kept in a disk cache (``onnx_cache_dir``): an export takes about 1.4 s of
CPU, and every process that runs the network (a command, each worker of the image engine, each
test worker) would otherwise export the same graph again. A cached model is found by a digest
of everything the graph is made from: the network's configuration and every parameter and
buffer, the search size, the torch version and opset, and the source of the modules that
define the graph, so a changed weight or a changed line of the network makes a new entry.
The cache keeps the ``CACHE_KEEP`` entries used last (a read marks an entry used) and deletes
the others when it writes a new one: each entry is about 6.7 MB, and new weights or a changed
network line would otherwise leave every old export behind.
"""

from __future__ import annotations

import hashlib
import inspect
import io
import os
import tempfile
import warnings
from pathlib import Path

import torch
from torch import Tensor, nn

from observer.transt import backbone, fusion, network
from observer.transt.network import TransTNet

#: The ONNX opset of the export.
OPSET = 17
#: The environment variable naming the cache folder of exported models ("off": no cache).
CACHE_ENV = "PMSPM_CACHE_DIR"
#: Exported models the cache keeps (the most recently used; our choice: two search sizes of
#: the shipped network and of a few retrained or edited ones).
CACHE_KEEP = 8


def template_position(net: TransTNet) -> Tensor:
    """The template tokens' position encoding (1, Lz, d): the same for every template."""
    fz = net.config.template_feature_size
    return net.backbone[1].encode(fz, fz).flatten(2).transpose(1, 2).contiguous()


class _TrackStep(nn.Module):
    """``track_features`` with the template position encoding as a constant buffer."""

    def __init__(self, net: TransTNet) -> None:
        super().__init__()
        self.net = net
        self.register_buffer("pos_z", template_position(net))

    def forward(self, search: Tensor, z: Tensor) -> tuple[Tensor, Tensor]:
        return self.net.track_features(search, z, self.pos_z)


def export_onnx(net: TransTNet, path: str | Path | None = None,
                search_size: int | None = None) -> bytes:
    """Export the per-frame step of ``net`` (eval mode) to ONNX for search crops of
    ``search_size`` px (default: the configuration's; the graph's spatial size is fixed);
    returns the model bytes and writes them to ``path`` when given."""
    c = net.config
    step = _TrackStep(net.eval()).eval()
    side = c.search_size if search_size is None else int(search_size)
    search = torch.zeros(1, 3, side, side)
    z = torch.zeros(1, c.template_feature_size**2, c.d_model)
    buf = io.BytesIO()
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            step,
            (search, z),
            buf,
            input_names=["search", "z"],
            output_names=["logits", "boxes"],
            dynamo=False,
            opset_version=OPSET,
            dynamic_axes={name: {0: "batch"} for name in ("search", "z", "logits", "boxes")},
        )
    data = buf.getvalue()
    if path is not None:
        Path(path).write_bytes(data)
    return data


def onnx_cache_dir() -> Path | None:
    """The folder of cached exports: ``$PMSPM_CACHE_DIR/onnx`` if that variable is set (None if
    it is "off"), else ``$XDG_CACHE_HOME/pmspm/onnx`` (``~/.cache/pmspm/onnx``)."""
    root = os.environ.get(CACHE_ENV)
    if root == "off":
        return None
    if not root:
        root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "pmspm"
    return Path(root) / "onnx"


def export_digest(net: TransTNet, search_size: int | None = None) -> str:
    """SHA-256 (hex) of what the exported graph of ``net`` at ``search_size`` is made from (the
    module docstring): two nets with the same digest export the same model."""
    h = hashlib.sha256()
    side = net.config.search_size if search_size is None else int(search_size)
    h.update(f"{torch.__version__}|opset {OPSET}|search {side}|{net.config!r}".encode())
    for module in (network, backbone, fusion):
        h.update(inspect.getsource(module).encode())
    h.update(inspect.getsource(_TrackStep).encode())
    for name, tensor in (*net.state_dict().items(), ("pos_z", template_position(net))):
        t = tensor.detach().cpu().contiguous()
        h.update(f"{name}|{t.dtype}|{tuple(t.shape)}".encode())
        h.update(t.numpy().tobytes() if t.dtype != torch.bfloat16 else t.float().numpy().tobytes())
    return h.hexdigest()


def cached_export(net: TransTNet, search_size: int | None = None) -> bytes:
    """``export_onnx(net, search_size=...)``, read from the disk cache when it holds that graph
    (``export_digest``), else exported and written there (through a temporary file and a
    rename, so a reader never sees half a file; a folder that cannot be written only means no
    cache)."""
    folder = onnx_cache_dir()
    if folder is None:
        return export_onnx(net, search_size=search_size)
    with torch.inference_mode():
        path = folder / f"{export_digest(net, search_size)}.onnx"
    if path.is_file():
        data = path.read_bytes()
        try:
            os.utime(path)  # used now: the pruning keeps the entries used last
        except OSError:
            pass
        return data
    data = export_onnx(net, search_size=search_size)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, suffix=".part")
    except OSError:
        return data
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except OSError:
        Path(tmp).unlink(missing_ok=True)
    prune_cache(folder)
    return data


def prune_cache(folder: Path, keep: int = CACHE_KEEP) -> list[Path]:
    """Delete all but the ``keep`` most recently used exports (``*.onnx`` by modification
    time, which a read renews) in ``folder``; returns the deleted files. Files another process
    deletes first, or that cannot be deleted, are skipped."""
    entries = []
    for f in folder.glob("*.onnx"):
        try:
            entries.append((f.stat().st_mtime_ns, f))
        except OSError:
            continue
    deleted = []
    for _, f in sorted(entries, reverse=True)[keep:]:
        try:
            f.unlink()
            deleted.append(f)
        except OSError:
            continue
    return deleted


def onnx_session(
    net: TransTNet, num_threads: int | None = None, spinning: bool | None = None,
    search_size: int | None = None,
):  # -> onnxruntime session
    """An ONNX Runtime ``InferenceSession`` of ``net``'s per-frame step on the CPU, for search
    crops of ``search_size`` px (default: the configuration's).

    ``num_threads`` intra-op threads (default: the environment variable
    ``PMSPM_ORT_THREADS``, else 1) and ``spinning`` (default: off) of the worker threads. Our
    default, by measurement on this 2-core machine (docs/transt.md): 2 spinning threads make the
    bare network call faster (3.8 ms against 6.1 ms) but keep a core busy after every call, and
    the tracker's own OpenCV work, the other marker's tracker or the renderer that run next then
    slowed by several times (OpenCV KCF 35 ms instead of 5 ms in the interleaved benchmark).
    """
    try:
        import onnxruntime as ort
    except ImportError as exc:  # optional dependency
        raise ImportError(
            "the 'onnx' backend needs onnxruntime (pip install onnxruntime onnx); "
            "use backend='eager' otherwise"
        ) from exc
    opts = ort.SessionOptions()
    n = num_threads if num_threads is not None else int(os.environ.get("PMSPM_ORT_THREADS", "1"))
    if n < 1:
        raise ValueError(f"num_threads must be >= 1, got {n}")
    opts.intra_op_num_threads = int(n)
    opts.inter_op_num_threads = 1
    opts.add_session_config_entry("session.intra_op.allow_spinning", "1" if spinning else "0")
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(cached_export(net, search_size), opts,
                                providers=["CPUExecutionProvider"])
