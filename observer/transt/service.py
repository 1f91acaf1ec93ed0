"""The process's TransT network: built once, shared by every tracker, batched across runs.

A ``NetworkService`` holds one network's per-frame step (``TransTNet.track_features``) in one
backend: eager PyTorch, ``torch.compile`` or ONNX Runtime (exported with a batch axis,
``observer.transt.export``; one session per search-crop size, the configuration's built with the
service and any other by ``prepare``). ``evaluate(search, z)`` runs the step for one search crop
against one template's tokens. ``shared_service(weights, backend)`` returns the process's
service of a weights file, so the weights are read, checked and exported once per process, not
once per tracker or per run.

Batching across runs: inside ``service.batching(max_batch)``, threads that registered with
``service.client()`` (one per closed-loop run, ``latency.image_engine``) no longer run the network
one crop at a time. A call waits until every registered thread is either waiting on the network
or done (or ``max_batch`` crops wait), then one call of the network takes all waiting crops
stacked on the batch axis and each thread gets its own rows back. Each crop's result depends
only on its own input (the network has no batch-coupled layer: no batch norm in training mode),
so a run computes what it would alone, to the rounding of the batched matrix products.

Written here rather than taken from a serving library: the batch is formed from the threads of
one process that are known to be about to call (the runs of a lockstep engine), with no time-out
and no request queue to tune; a serving framework (Triton, TorchServe) batches by waiting a time
window and runs out of process.
"""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from numpy.typing import NDArray

from observer.transt.export import template_position
from observer.transt.network import TransTNet
from observer.transt.weights import load_weights, sha256_of

Backend = Literal["eager", "compile", "onnx"]


@dataclass
class _Request:
    """One crop waiting for the network: inputs, then outputs once the batch has run."""

    search: NDArray[np.float32]
    z: NDArray[np.float32]
    logits: NDArray[np.float32] | None = None
    boxes: NDArray[np.float32] | None = None
    error: BaseException | None = None
    done: bool = field(default=False)


class NetworkService:
    """One network's per-frame step, callable from many trackers and threads.

    Parameters
    ----------
    net : the network (put in eval mode here).
    backend : "eager", "compile" (``torch.compile``) or "onnx" (ONNX Runtime, batch axis).
    num_threads : ONNX Runtime intra-op threads (default: ``export.onnx_session``'s).

    Attributes
    ----------
    batch_sizes : Counter of the number of crops per network call (for benchmarks).
    """

    def __init__(self, net: TransTNet, backend: Backend = "eager",
                 num_threads: int | None = None) -> None:
        if backend not in ("eager", "compile", "onnx"):
            raise ValueError(f"backend must be 'eager', 'compile' or 'onnx', got {backend!r}")
        self.net = net.eval()
        self.backend = backend
        with torch.inference_mode():
            self._pos_z = template_position(net)
        self._compiled = torch.compile(net.track_features, dynamic=False) \
            if backend == "compile" else None
        self._num_threads = num_threads
        #: ONNX Runtime sessions by search-crop side, px (the graph's spatial size is fixed).
        self._ort: dict[int, object] = {}
        self._ort_lock = threading.Lock()
        if backend == "onnx":
            self.prepare(net.config.search_size)
        self.batch_sizes: Counter[int] = Counter()
        self._cv = threading.Condition()
        self._max_batch = 0  # 0: not batching
        self._clients = 0
        self._pending: list[_Request] = []

    def prepare(self, search_size: int) -> None:
        """Build what the backend needs for search crops of ``search_size`` px (the ONNX
        Runtime session of that size; nothing for the torch backends). Raises what the export
        or the session raises."""
        if self.backend != "onnx":
            return
        with self._ort_lock:
            if search_size not in self._ort:
                from observer.transt.export import onnx_session

                self._ort[search_size] = onnx_session(self.net, self._num_threads,
                                                      search_size=search_size)

    def template_tokens(self, template: NDArray[np.float32]) -> NDArray[np.float32]:
        """Template tokens (1, Lz, d) of a normalised template crop (1, 3, St, St)."""
        with torch.inference_mode():
            z, _ = self.net.template_features(torch.from_numpy(template))
        return z.contiguous().numpy()

    def evaluate(self, search: NDArray[np.float32], z: NDArray[np.float32]
                 ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """Logits (L, 2) and boxes (L, 4) of one normalised search crop (1, 3, Sx, Sx) against
        template tokens ``z`` (1, Lz, d); batched with other runs' crops while batching."""
        with self._cv:
            batching = self._max_batch > 0 and self._clients > 0
        if not batching:
            self.batch_sizes[1] += 1
            logits, boxes = self._run(search, z)
            return logits[0], boxes[0]
        req = _Request(search, z)
        with self._cv:
            self._pending.append(req)
            self._flush_if_ready()
            while not req.done:
                self._cv.wait()
        if req.error is not None:
            raise req.error
        assert req.logits is not None and req.boxes is not None
        return req.logits, req.boxes

    def _run(self, search: NDArray[np.float32], z: NDArray[np.float32]
             ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """The network on a stack of crops (B, 3, Sx, Sx) and tokens (B, Lz, d)."""
        if self.backend == "onnx":
            side = int(search.shape[-1])
            if side not in self._ort:
                self.prepare(side)
            logits, boxes = self._ort[side].run(None, {"search": search, "z": z})
            return logits, boxes
        fn = self._compiled if self._compiled is not None else self.net.track_features
        with torch.inference_mode():
            logits, boxes = fn(torch.from_numpy(search), torch.from_numpy(z), self._pos_z)
        return logits.numpy(), boxes.numpy()

    def _flush_if_ready(self) -> None:
        """With the lock held: run the waiting crops when every client waits or the batch is
        full. The network runs with the lock held: the other clients wait on it anyway."""
        n = len(self._pending)
        if n == 0 or (n < self._clients and n < self._max_batch):
            return
        batch, self._pending = self._pending[: self._max_batch], self._pending[self._max_batch:]
        # one network call per search-crop size among the waiting crops
        sizes = dict.fromkeys(r.search.shape for r in batch)
        for shape in sizes:
            group = [r for r in batch if r.search.shape == shape]
            try:
                logits, boxes = self._run(np.concatenate([r.search for r in group]),
                                          np.concatenate([r.z for r in group]))
            except Exception as exc:  # noqa: BLE001 - handed to every waiting caller
                for r in group:
                    r.error, r.done = exc, True
            else:
                for i, r in enumerate(group):
                    r.logits, r.boxes, r.done = logits[i], boxes[i], True
            self.batch_sizes[len(group)] += 1
        self._cv.notify_all()

    @contextmanager
    def batching(self, max_batch: int) -> Iterator[NetworkService]:
        """Batch the calls of registered client threads (at most ``max_batch`` crops a call)."""
        if max_batch < 1:
            raise ValueError(f"max_batch must be >= 1, got {max_batch}")
        with self._cv:
            if self._max_batch:
                raise RuntimeError("this network service is already batching")
            self._max_batch = int(max_batch)
        try:
            yield self
        finally:
            with self._cv:
                self._max_batch = 0

    @contextmanager
    def client(self) -> Iterator[None]:
        """Register the calling thread as one run whose network calls are batched."""
        with self._cv:
            self._clients += 1
        try:
            yield
        finally:
            with self._cv:
                self._clients -= 1
                self._flush_if_ready()


#: The process's services: (weights path, content digest, backend) -> service.
_SERVICES: dict[tuple[str, str, Backend], NetworkService] = {}
_SERVICES_LOCK = threading.Lock()


def shared_service(weights: str | Path, backend: Backend = "onnx") -> NetworkService:
    """The process's ``NetworkService`` of a weights file (checked against its recorded SHA-256
    by ``observer.transt.weights.load_weights``): built and exported once per process and
    backend, then shared. A changed file (another digest) gets a service of its own."""
    p = Path(weights).resolve()
    try:
        digest = sha256_of(p)
    except OSError:
        digest = ""  # load_weights names the missing file and the command that rebuilds it
    key = (str(p), digest, backend)
    with _SERVICES_LOCK:
        if key not in _SERVICES:
            net, _ = load_weights(p)
            _SERVICES[key] = NetworkService(net, backend)
        return _SERVICES[key]


def shared_services() -> list[NetworkService]:
    """The services ``shared_service`` has built in this process."""
    with _SERVICES_LOCK:
        return list(_SERVICES.values())
