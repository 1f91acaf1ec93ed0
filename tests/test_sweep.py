"""The sweep runner: content ids, local vs Dask, interruption and resume, failed runs, sweeps
sharing a folder, workers that end with their parent, Ctrl-C under Dask."""

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import psutil
import pytest

from experiments.sweep import run_id, run_sweep, sweep_id, table
from latency.simulation import run_summary

pytestmark = pytest.mark.engine  # runs the compiled engines

TARGET = "latency.simulation:run_summary"


def configs():
    out = []
    for delay in (0.01633, 0.03123):
        for seed in (0, 1):
            out.append(
                {
                    "name": f"d{delay}-s{seed}",
                    "duration_s": 0.4,
                    "seed": seed,
                    "observer": {"kind": "solver"},
                    "pipeline": {"observer": {"kind": "constant", "value_s": delay}},
                }
            )
    return out


def results(df: pd.DataFrame) -> pd.DataFrame:
    cols = ["run_id"] + sorted(c for c in df.columns if c.startswith("result."))
    return df[cols].reset_index(drop=True)


def test_run_id_is_content_derived():
    a = {"x": 1, "y": {"z": 2}}
    assert run_id(a) == run_id({"y": {"z": 2}, "x": 1})
    assert run_id(a) != run_id({"x": 1, "y": {"z": 3}})


@pytest.mark.slow  # starts a Dask LocalCluster, like the Dask variants below
def test_local_and_dask_give_identical_tables(tmp_path):
    local = run_sweep(TARGET, configs(), tmp_path / "local", workers=2, progress=False)
    dask = run_sweep(
        TARGET, configs(), tmp_path / "dask", scheduler="local", workers=2, progress=False
    )
    assert len(local) == 4 and (local.error == "").all()
    pd.testing.assert_frame_equal(results(local), results(dask))


def gated_run_summary(config: dict) -> dict:
    """``TARGET``'s run, except in a process started with ``SWEEP_TEST_GATE`` (a folder): there
    each run first claims a numbered file ``started-<n>`` (first come, first numbered), and
    every run after the first waits for the file ``interrupted`` (``GATE_SITECUSTOMIZE``
    writes it when the sweep's process takes a Ctrl-C) and then ends its process without a
    result (as a killed worker would), or waits until it is killed. So the sweep has finished
    exactly one run when ``started-1`` appears (with one worker, runs follow one another, and
    a run's row is written before the worker takes the next)."""
    gate = os.environ.get("SWEEP_TEST_GATE")
    if gate:
        n = 0
        while True:
            try:
                os.close(os.open(Path(gate) / f"started-{n}", os.O_CREAT | os.O_EXCL))
                break
            except FileExistsError:
                n += 1
        if n >= 1:
            while not (Path(gate) / "interrupted").exists():  # the sweep's Ctrl-C, or a kill
                time.sleep(0.05)
            os._exit(0)
    return run_summary(config)


def test_interrupted_sweep_resumes_without_recomputing(tmp_path):
    target = "tests.test_sweep:gated_run_summary"
    full = run_sweep(target, configs(), tmp_path / "full", workers=1, progress=False)
    out, gate = tmp_path / "killed", tmp_path / "gate"
    gate.mkdir()
    code = (
        "from experiments.sweep import run_sweep; import tests.test_sweep as t; "
        f"run_sweep({target!r}, t.configs(), {str(out)!r}, workers=1, progress=False)"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=os.getcwd(), start_new_session=True,
                            env=os.environ | {"SWEEP_TEST_GATE": str(gate)})
    try:
        # the event: the second run has started (and blocks), so the first has been written
        deadline = time.monotonic() + 300  # a guard against a hang, not a synchronisation
        while not (gate / "started-1").exists():
            assert proc.poll() is None and time.monotonic() < deadline, "the sweep did not start"
            time.sleep(0.05)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the whole process group, workers included
        proc.wait()
    done_before = {p.name: p.stat().st_mtime_ns for p in (out / "runs").glob("*.parquet")}
    assert len(done_before) == 1
    resumed = run_sweep(target, configs(), out, workers=1, progress=False)
    for name, mtime in done_before.items():  # the finished run was not recomputed
        assert (out / "runs" / name).stat().st_mtime_ns == mtime
    pd.testing.assert_frame_equal(results(resumed), results(full))


def test_a_failing_run_is_recorded_and_the_sweep_goes_on(tmp_path):
    bad = {"duration_s": -1.0}
    df = run_sweep(TARGET, [bad, configs()[0]], tmp_path, workers=1, progress=False)
    assert len(df) == 2
    row = df[df.run_id == run_id(bad)].iloc[0]
    assert "duration_s" in row.error and "Traceback" in row.traceback
    assert (df[df.run_id != run_id(bad)].error == "").all()
    assert len(table(tmp_path)) == 2


def double(config: dict) -> dict:
    """A cheap run function for the bookkeeping tests."""
    return {"twice": 2 * config["x"]}


def sleeper(config: dict) -> dict:
    """A run that says it started (a file named by its worker's pid) and then takes long."""
    (Path(config["folder"]) / f"{os.getpid()}.pid").write_text("")
    time.sleep(120)
    return {}


def test_two_sweeps_in_one_folder_each_report_only_their_runs(tmp_path):
    a = [{"x": 0}, {"x": 1}]
    b = [{"x": 1}, {"x": 2}, {"x": 2}]  # one run shared with a, one repeated
    df_a = run_sweep("tests.test_sweep:double", a, tmp_path, workers=1, progress=False)
    shared = tmp_path / "runs" / f"{run_id({'x': 1})}.parquet"
    mtime = shared.stat().st_mtime_ns
    df_b = run_sweep("tests.test_sweep:double", b, tmp_path, workers=1, progress=False)
    assert sorted(df_a["config.x"]) == [0, 1] and sorted(df_b["config.x"]) == [1, 2]
    assert list(df_b["result.twice"]) == [2 * x for x in df_b["config.x"]]
    assert shared.stat().st_mtime_ns == mtime  # reused by content id, not recomputed
    assert len(table(tmp_path)) == 3  # the folder holds both sweeps' runs
    manifest = json.loads((tmp_path / "sweeps" / f"{sweep_id(b)}.json").read_text())
    assert manifest["run_ids"] == [run_id({"x": 1}), run_id({"x": 2})]
    assert sweep_id(a) != sweep_id(b) and sweep_id(b) == sweep_id(list(reversed(b)))


def test_cli_sweeps_sharing_a_folder_report_their_own_grid(tmp_path):
    from typer.testing import CliRunner

    from experiments.cli import app

    out = tmp_path / "sw"
    tables = []
    for seeds in ("[0, 1]", "[1, 2]"):
        spec = tmp_path / "spec.yaml"
        spec.write_text("base: {duration_s: 0.3, observer: {kind: solver}}\n"
                        f"grid: {{seed: {seeds}}}\n")
        result = CliRunner().invoke(app, ["sweep", str(spec), "--out", str(out),
                                          "--workers", "1"])
        assert result.exit_code == 0, result.output
        assert "2 runs (0 failed)" in result.output
        tables.append(pd.read_parquet(result.output.split(": ")[-1].strip()))
    assert [sorted(t["config.seed"]) for t in tables] == [[0, 1], [1, 2]]


def _alive(pid: int) -> bool:
    """Whether process ``pid`` still runs (a zombie waiting to be reaped has ended)."""
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


# The Dask variants start a LocalCluster (about 15 s each on two cores): they run in the slow
# lane, with the Dask tables check above; the process pool's variants stay in the fast suite.
@pytest.mark.parametrize("scheduler", [None, pytest.param("local", marks=pytest.mark.slow)],
                         ids=["pool", "dask"])
def test_sigkill_of_the_sweep_process_leaves_no_workers(tmp_path, scheduler):
    code = (
        "from experiments.sweep import run_sweep; "
        f"run_sweep('tests.test_sweep:sleeper', [{{'folder': {str(tmp_path)!r}, 'i': i}} "
        f"for i in range(2)], {str(tmp_path / 'out')!r}, scheduler={scheduler!r}, workers=2, "
        "progress=False)"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=os.getcwd(),
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(list(tmp_path.glob("*.pid"))) < 2:
            time.sleep(0.05)
        workers = [int(p.stem) for p in tmp_path.glob("*.pid")]
        assert len(workers) == 2 and all(_alive(w) for w in workers)
        proc.kill()  # SIGKILL of the sweep's process alone, not of its group
        proc.wait()
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and any(_alive(w) for w in workers):
            time.sleep(0.05)
        assert not any(_alive(w) for w in workers)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)


#: Installed in every Python process of a test's sweep (Dask's workers are spawned, not
#: forked, so a patch in the parent would not reach them): with ``SWEEP_TEST_GATE`` set, the
#: command line's run function is ``gated_run_summary``. In the sweep's own process (the one
#: started with ``SWEEP_TEST_MAIN``, which it then removes so that its workers do not see it),
#: a Ctrl-C first writes ``interrupted`` into the gate folder, then interrupts as Python does.
GATE_SITECUSTOMIZE = """
import os
import signal
from pathlib import Path

if os.environ.get("SWEEP_TEST_GATE"):
    import latency.simulation
    import tests.test_sweep
    latency.simulation.run_summary = tests.test_sweep.gated_run_summary
    if os.environ.pop("SWEEP_TEST_MAIN", None):
        gate = Path(os.environ["SWEEP_TEST_GATE"])

        def _interrupt(signum, frame):
            (gate / "interrupted").touch()
            raise KeyboardInterrupt

        signal.signal(signal.SIGINT, _interrupt)
"""


@pytest.mark.parametrize("backend", [pytest.param(["--scheduler", "local"],
                                                  marks=pytest.mark.slow), []],
                         ids=["dask", "pool"])
def test_ctrl_c_ends_the_sweep_without_worker_tracebacks(tmp_path, backend):
    spec = tmp_path / "spec.yaml"
    spec.write_text("base: {duration_s: 0.3, observer: {kind: solver}}\n"
                    "grid: {seed: [0, 1, 2, 3, 4, 5, 6, 7]}\n")
    out, gate, site = tmp_path / "out", tmp_path / "gate", tmp_path / "site"
    gate.mkdir()
    site.mkdir()
    (site / "sitecustomize.py").write_text(GATE_SITECUSTOMIZE)
    path = os.pathsep.join([str(site), os.getcwd(), os.environ.get("PYTHONPATH", "")])
    proc = subprocess.Popen(
        [sys.executable, "-m", "experiments.cli", "sweep", str(spec), "--out", str(out),
         "--workers", "2", "--engine", "event", *backend],  # one run per job
        cwd=os.getcwd(), start_new_session=True, stderr=subprocess.PIPE, text=True,
        env=os.environ | {"SWEEP_TEST_GATE": str(gate), "SWEEP_TEST_MAIN": "1",
                          "PYTHONPATH": path},
    )
    try:
        # the event: both workers have taken a run after the first (and block), so the first
        # run has finished and been written, and no other run can finish
        deadline = time.monotonic() + 300  # a guard against a hang, not a synchronisation
        while not (gate / "started-2").exists():
            assert proc.poll() is None and time.monotonic() < deadline, "the sweep did not start"
            time.sleep(0.05)
        os.killpg(proc.pid, signal.SIGINT)  # what a terminal's Ctrl-C does
        _, stderr = proc.communicate(timeout=120)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    assert "Traceback" not in stderr, stderr
    assert proc.returncode == 130, stderr
    assert "interrupted: the runs that finished are kept" in stderr
    assert len(list((out / "runs").glob("*.parquet"))) == 1  # the one that finished is kept


def batch_sizes(configs: list[dict]) -> list[dict]:
    """A batch run function for the tests: each run reports the size of its batch."""
    return [{"batch": len(configs)} for _ in configs]


@pytest.mark.parametrize(("n_runs", "workers", "want"), [(23, 2, [6, 6, 6, 5]),
                                                          (20, 2, [10, 10]),
                                                          (7, 3, [3, 2, 2])])
def test_batched_sweep_gives_every_worker_as_many_batches(tmp_path, n_runs, workers, want):
    """Batches of at most ``batch_size`` (10) runs, as many per worker, sizes within one: 23
    runs on 2 workers are 4 batches (not 3, where one worker would run the last alone)."""
    configs = [{"i": i} for i in range(n_runs)]
    df = run_sweep("tests.test_sweep:batch_sizes", configs, tmp_path, workers=workers,
                   progress=False, batch_size=10)
    sizes = df.groupby("result.batch").size()
    got = sorted((b for b, n in sizes.items() for _ in range(n // b)), reverse=True)
    assert got == want
