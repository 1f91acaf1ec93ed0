"""ONNX export of TransT's per-frame step and an ONNX Runtime session for it (optional backend).

The exported graph is ``TransTNet.track_features`` with the template's position encoding baked
in: inputs ``search`` (B, 3, Sx, Sx) float32 (ImageNet-normalised crops) and ``z`` (B, Lz, d)
float32 (the template tokens from ``TransTNet.template_features``, computed once at ``init``);
outputs ``logits`` (B, L, 2) and ``boxes`` (B, L, 4). The batch axis B is free, so one call can
take the crops of many runs (``observer.transt.service``). Needs ``onnx`` for the export and
``onnxruntime`` to run it (both project dependencies); they are imported lazily, so a checkout
without them still runs the eager backend, and the error says what is missing.
"""

from __future__ import annotations

import io
import os
import warnings
from pathlib import Path

import torch
from torch import Tensor, nn

from observer.transt.network import TransTNet


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
            opset_version=17,
            dynamic_axes={name: {0: "batch"} for name in ("search", "z", "logits", "boxes")},
        )
    data = buf.getvalue()
    if path is not None:
        Path(path).write_bytes(data)
    return data


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
    return ort.InferenceSession(export_onnx(net, search_size=search_size), opts,
                                providers=["CPUExecutionProvider"])
