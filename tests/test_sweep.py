"""The sweep runner: content ids, local vs Dask, interruption and resume, failed runs."""

import os
import signal
import subprocess
import sys
import time

import pandas as pd

from experiments.sweep import run_id, run_sweep, table

TARGET = "experiments.scenario:run_summary"


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


def test_local_and_dask_give_identical_tables(tmp_path):
    local = run_sweep(TARGET, configs(), tmp_path / "local", workers=2, progress=False)
    dask = run_sweep(
        TARGET, configs(), tmp_path / "dask", scheduler="local", workers=2, progress=False
    )
    assert len(local) == 4 and (local.error == "").all()
    pd.testing.assert_frame_equal(results(local), results(dask))


def test_interrupted_sweep_resumes_without_recomputing(tmp_path):
    full = run_sweep(TARGET, configs(), tmp_path / "full", workers=1, progress=False)
    out = tmp_path / "killed"
    code = (
        "from experiments.sweep import run_sweep; import tests.test_sweep as t; "
        f"run_sweep(t.TARGET, t.configs(), {str(out)!r}, workers=1, progress=False)"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code], cwd=os.getcwd(), start_new_session=True
    )
    deadline = time.time() + 120
    while time.time() < deadline and len(list((out / "runs").glob("*.parquet"))) < 1:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)  # the whole process group, workers included
    proc.wait()
    done_before = {p.name: p.stat().st_mtime_ns for p in (out / "runs").glob("*.parquet")}
    assert 1 <= len(done_before) < 4
    resumed = run_sweep(TARGET, configs(), out, workers=1, progress=False)
    for name, mtime in done_before.items():  # finished runs were not recomputed
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
