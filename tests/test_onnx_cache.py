"""The disk cache of exported TransT networks (``observer.transt.export.cached_export``)."""

import copy

import pytest
import torch

from observer.transt import export
from observer.transt.weights import load_weights

pytest.importorskip("onnx")


@pytest.fixture(scope="module")
def net():
    return load_weights()[0]


def test_a_cached_graph_is_the_exported_one_and_a_changed_network_is_exported_anew(
        net, tmp_path, monkeypatch):
    """The first call exports and writes one file; the second reads it (torch's exporter made to
    fail proves it is not called) and gets the same bytes; one changed weight, or another search
    size, is a new digest and a new export; "off" writes nothing."""
    monkeypatch.setenv(export.CACHE_ENV, str(tmp_path))
    first = export.cached_export(net)
    files = list((tmp_path / "onnx").glob("*.onnx"))
    assert len(files) == 1 and files[0].read_bytes() == first

    def no_export(*args, **kwargs):
        raise AssertionError("exported again")

    monkeypatch.setattr(torch.onnx, "export", no_export)
    assert export.cached_export(net) == first
    changed = copy.deepcopy(net)
    with torch.no_grad():
        next(changed.parameters()).view(-1)[0] += 1e-3
    assert export.export_digest(changed) != export.export_digest(net)
    assert export.export_digest(net, 96) != export.export_digest(net)
    with pytest.raises(AssertionError, match="exported again"):
        export.cached_export(changed)
    monkeypatch.setenv(export.CACHE_ENV, "off")
    assert export.onnx_cache_dir() is None
    with pytest.raises(AssertionError, match="exported again"):
        export.cached_export(net)
    assert len(list((tmp_path / "onnx").glob("*"))) == 1


def test_the_cache_keeps_the_exports_used_last(net, tmp_path, monkeypatch):
    """Ten old entries of distinct ages, then one read of the oldest and one new export: the
    cache keeps CACHE_KEEP files, the new one and the one just read among them, and deletes
    the least recently used."""
    import os

    monkeypatch.setenv(export.CACHE_ENV, str(tmp_path))
    folder = tmp_path / "onnx"
    folder.mkdir()
    old = []
    for k in range(10):
        f = folder / f"{k:064x}.onnx"
        f.write_bytes(b"x")
        os.utime(f, ns=(10**18 + k * 10**9,) * 2)
        old.append(f)
    read = folder / f"{export.export_digest(net, 96)}.onnx"
    read.write_bytes(b"graph")
    os.utime(read, ns=(10**18 - 10**9,) * 2)  # older than every other entry
    assert export.cached_export(net, 96) == b"graph"  # a read: now the newest
    export.cached_export(net)  # a new export: written, then the cache pruned
    kept = set(folder.glob("*.onnx"))
    new = folder / f"{export.export_digest(net)}.onnx"
    assert len(kept) == export.CACHE_KEEP
    assert {new, read} <= kept
    assert kept - {new, read} == set(old[-(export.CACHE_KEEP - 2):])
