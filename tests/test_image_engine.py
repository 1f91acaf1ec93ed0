"""The batched image engine against the event loop, and the shared network's batching."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import numpy as np
import pytest
import torch

from latency import Scenario, build_loop
from latency.image_engine import ImagePool, run_batch, run_images
from latency.loop import ClosedLoop
from observer.transt.network import build_transt
from observer.transt.service import NetworkService, shared_services

MEAS = ["meas_red_u_px", "meas_red_v_px", "meas_yellow_u_px", "meas_yellow_v_px"]
Q = ["qw", "qx", "qy", "qz"]


def _scenario(tracker: str, seed: int, **extra) -> Scenario:
    return Scenario.model_validate({
        "mode": "image", "tracker": tracker, "duration_s": 0.3, "seed": seed,
        "observer": {"kind": "solver"},
        "reference": {"kind": "random", "args": {"seed": seed, "max_rate_rad_s": 3.0}},
        "pipeline": {"observer": {"kind": "constant", "value_s": 0.016}}, **extra,
    })


def test_batched_image_runs_equal_the_event_loop_run_by_run() -> None:
    specs = [_scenario(t, s) for t in ("gk_transt", "dual_transt", "kcf_gk") for s in (1, 2)]
    event = [build_loop(s).run() for s in specs]
    before = {id(sv): sum(n for k, n in sv.batch_sizes.items() if k > 1)
              for sv in shared_services()}
    batched = run_batch([build_loop(s) for s in specs], max_network_batch=8)
    compared = 0
    for a, b in zip(event, batched, strict=True):
        assert len(a.frames) == len(b.frames) > 5
        np.testing.assert_allclose(b.frames[MEAS].to_numpy(), a.frames[MEAS].to_numpy(),
                                   atol=1e-3, equal_nan=True)
        np.testing.assert_array_equal(b.frames["lost"], a.frames["lost"])
        np.testing.assert_allclose(b.steps[Q].to_numpy(), a.steps[Q].to_numpy(), atol=1e-6)
        compared += 1
    assert compared == 6
    # the network calls of the four TransT runs were batched (calls of more than one crop)
    after = {id(sv): sum(n for k, n in sv.batch_sizes.items() if k > 1)
             for sv in shared_services()}
    assert sum(after.values()) > sum(before.get(k, 0) for k in after)


def test_engine_refuses_measured_latencies_and_measurement_runs() -> None:
    with pytest.raises(ValueError, match="model latencies"):
        run_images(build_loop, [_scenario("kcf_gk", 0, observer_latency="measured")], workers=1)
    meas = Scenario.model_validate({"duration_s": 0.3})
    with pytest.raises(ValueError, match="image-mode"):
        run_images(build_loop, [meas], workers=1)


def test_network_batching_gives_each_caller_its_own_rows() -> None:
    """Five callers, of two search-crop sizes (the configuration's and 32 px less, as a
    tracker with a smaller ``search_size`` sends), waiting together: each gets what it would
    alone."""
    torch.manual_seed(0)
    service = NetworkService(build_transt("small"), "eager")
    c = service.net.config
    rng = np.random.default_rng(0)
    n = 5
    sides = [c.search_size - 32 * (i % 2) for i in range(n)]
    searches = [rng.normal(size=(1, 3, s, s)).astype(np.float32) for s in sides]
    templates = [rng.normal(size=(1, 3, c.template_size, c.template_size)).astype(np.float32)
                 for _ in range(n)]
    zs = [service.template_tokens(t) for t in templates]
    alone = [service.evaluate(s, z) for s, z in zip(searches, zs, strict=True)]
    got: list = [None] * n
    registered = threading.Barrier(n)  # every caller registered before any calls: one batch

    def client(i: int) -> None:
        with service.client():
            registered.wait()
            got[i] = service.evaluate(searches[i], zs[i])

    with service.batching(max_batch=8):
        threads = [threading.Thread(target=client, args=(i,)) for i in range(n)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
    assert max(service.batch_sizes) > 1  # at least one call took several crops
    for (la, ba), (lb, bb), side in zip(alone, got, sides, strict=True):
        assert lb.shape == ((side // c.stride) ** 2, 2)
        np.testing.assert_allclose(lb, la, atol=1e-4)
        np.testing.assert_allclose(bb, ba, atol=1e-5)
    # different templates give different outputs: the rows were not mixed up
    assert not np.allclose(got[0][0], got[2][0], atol=1e-3)


def test_onnx_single_crop_and_batched_calls_agree_with_eager() -> None:
    """ONNX Runtime, one crop a call or three in one call, gives eager PyTorch's outputs (to
    float32 rounding through different kernels), each crop its own, for both search-crop sizes
    (one session each)."""
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    torch.manual_seed(1)
    net = build_transt("small")
    eager, onnx = NetworkService(net, "eager"), NetworkService(net, "onnx")
    c = net.config
    rng = np.random.default_rng(1)
    zs = np.concatenate([eager.template_tokens(
        rng.normal(size=(1, 3, c.template_size, c.template_size)).astype(np.float32))
        for _ in range(3)])
    compared = 0
    for side in (c.search_size, c.search_size - 32):
        x = rng.normal(size=(3, 3, side, side)).astype(np.float32)
        batched = onnx._run(x, zs)
        for i in range(3):
            want = eager.evaluate(x[i:i + 1], zs[i:i + 1])
            alone = onnx.evaluate(x[i:i + 1], zs[i:i + 1])
            for got in (alone, (batched[0][i], batched[1][i])):
                np.testing.assert_allclose(got[0], want[0], atol=1e-4)
                np.testing.assert_allclose(got[1], want[1], atol=1e-5)
                compared += 1
    assert compared == 12


def test_a_failing_network_call_reaches_every_waiting_caller() -> None:
    torch.manual_seed(0)
    service = NetworkService(build_transt("small"), "eager")
    bad = np.zeros((1, 2, 64, 64), np.float32)  # two colour channels: the conv refuses it
    z = np.zeros((1, service.net.config.template_feature_size ** 2, service.net.config.d_model),
                 np.float32)
    errors: list[BaseException] = []

    def client() -> None:
        with service.client():
            try:
                service.evaluate(bad, z)
            except Exception as exc:  # noqa: BLE001
                errors.append(exc)

    with service.batching(max_batch=4):
        threads = [threading.Thread(target=client) for _ in range(3)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
    assert len(errors) == 3


def test_runs_go_one_per_batch_by_default_and_in_batches_when_asked(monkeypatch):
    """``run_images`` hands a worker its runs one at a time by default (on this CPU batching
    the network did not pay for its threads: ``RUNS_PER_BATCH``) and in batches of
    ``runs_per_batch`` when asked, the results in the order of the specs."""
    from latency import image_engine

    chunks = []

    def fake(build, specs, max_network_batch):
        chunks.append(list(specs))
        return [build(s) for s in specs]

    monkeypatch.setattr(image_engine, "_run_specs", fake)
    assert image_engine.run_images(str, [1, 2, 3], workers=1) == ["1", "2", "3"]
    assert chunks == [[1], [2], [3]]
    chunks.clear()
    assert image_engine.run_images(str, [1, 2, 3], workers=1, runs_per_batch=2) == ["1", "2", "3"]
    assert chunks == [[1, 2], [3]]


def test_a_pool_refuses_bad_worker_counts_and_runs_after_it_closed() -> None:
    for bad in (0, -1, True, 1.5):
        with pytest.raises(ValueError, match="workers must be an integer"):
            ImagePool(bad)
    pool = ImagePool(2)
    pool.close()
    with pytest.raises(ValueError, match="closed"):
        run_images(build_loop, [_scenario("kcf_gk", 1)], pool=pool)
    with ImagePool(2) as other, pytest.raises(ValueError, match="differs from the pool"):
        run_images(build_loop, [_scenario("kcf_gk", 1)], workers=3, pool=other)


def _build_noting_the_process(spec: tuple[str, Scenario]) -> ClosedLoop:
    """``build_loop`` of the scenario, leaving a file named by this process's id in the
    folder (the engine's workers call it)."""
    folder, scenario = spec
    (Path(folder) / f"{os.getpid()}-{scenario.seed}").touch()
    return build_loop(scenario)


@pytest.mark.slow
def test_a_pool_runs_several_calls_on_the_same_workers(tmp_path) -> None:
    """Two ``run_images`` calls on one ``ImagePool`` of two workers run in two processes in
    all (without the pool, each call starts its own two), and give the event loop's results."""
    specs = [_scenario("kcf_gk", s) for s in (1, 2, 3, 4)]
    want = [build_loop(s).run() for s in specs]
    got = []
    with ImagePool(2) as pool:
        for part in (specs[:2], specs[2:]):
            got += run_images(_build_noting_the_process, [(str(tmp_path), s) for s in part],
                              pool=pool)
    processes = {p.name.split("-")[0] for p in tmp_path.iterdir()}
    assert len(list(tmp_path.iterdir())) == 4 and len(processes) == 2
    assert str(os.getpid()) not in processes
    for a, b in zip(want, got, strict=True):
        np.testing.assert_array_equal(b.frames[MEAS].to_numpy(), a.frames[MEAS].to_numpy())
        np.testing.assert_array_equal(b.steps[Q].to_numpy(), a.steps[Q].to_numpy())
