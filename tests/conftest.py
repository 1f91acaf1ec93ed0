"""Shared test setup, before any test module imports numpy or mujoco.

- MuJoCo picks its GL backend at first import.
- OpenBLAS (numpy's and scipy's) runs one thread. The suite's linear algebra is on small
  matrices (the sampled loop's and the MPC law's matrix exponentials, 3x3 to 8x8), where
  OpenBLAS's thread hand-off costs far more than the arithmetic: measured on the two shared
  cores, ``scipy.linalg.expm`` of a 3x3 matrix took 24 ms a call with the default threads and
  0.08 ms with one. The results are the same; ``setdefault`` leaves a caller's choice alone.
- Hypothesis runs without its per-example deadline: a deadline is wall-clock time, and the
  first example of a test may load compiled code from numba's cache.

In parallel (pytest-xdist, ``make test``: ``-n 2``):

- The tests of a module with a module- or class-scoped fixture run in one worker
  (``pytest_xdist_make_scheduler``), so such a fixture (the quick study, the engines' grid) is
  computed once, not once per worker; the other tests are shared out one by one.
- Before the workers run a test, the numba kernels of both engines are compiled into the disk
  cache by one process each (``_WARM_UP``: a short run of each engine through the command
  line), started when the session starts, so that they compile while the workers start and
  collect. Without it, on a fresh clone every worker, and every sweep worker or notebook
  kernel a test starts meanwhile, would compile the same kernels at once (a minute of CPU each
  for the compiled run loop); numba's cache index is also not safe against two processes
  saving different signatures of one function at the same time. With a warm cache the two
  processes only load it.
- torch, OpenCV and Mesa's software renderer run one thread in each worker (set before they
  load, or after collection): with two workers on two cores, more threads only wait for each
  other.
"""

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # read when OpenBLAS loads (and by workers)
if os.environ.get("PYTEST_XDIST_WORKER"):  # two workers already keep both cores busy
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # torch's threads, here and in subprocesses
    os.environ.setdefault("LP_NUM_THREADS", "1")  # Mesa llvmpipe's (MuJoCo's EGL rendering)

from hypothesis import settings  # noqa: E402

settings.register_profile("no_deadline", deadline=None)
settings.load_profile("no_deadline")

#: The environment variable through which the workers learn the warm-up's folder.
_WARM_UP_ENV = "PMSPM_TEST_WARM_UP"
#: A short run of the measurement model (long enough to pass the scenario's checks).
_WARM_UP_SCENARIO = "duration_s: 0.3\nobserver: {kind: solver}\n"
#: Run in a process of its own with the warm-up folder as argument: one short run per engine
#: through the command line, side by side, then the file ``done``.
_WARM_UP = """
import subprocess, sys
from pathlib import Path
folder = Path(sys.argv[1])
runs = [subprocess.Popen([sys.executable, "-m", "experiments.cli", "simulate",
                          str(folder / "scenario.yaml"), "--engine", engine,
                          "--out", str(folder / engine)],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for engine in ("batched", "event")]
for run in runs:
    run.wait()
(folder / "done").touch()
"""
#: How long a worker waits for the warm-up at most, s: a guard against a hung warm-up (the
#: tests then compile what they need themselves).
_WARM_UP_WAIT_S = 900.0
#: The controller's warm-up: its folder and process.
_warm_up_key = pytest.StashKey[tuple[Path, subprocess.Popen]]()


def _is_xdist_controller(config: pytest.Config) -> bool:
    return bool(getattr(config.option, "numprocesses", None)) and not hasattr(
        config, "workerinput")


def pytest_sessionstart(session: pytest.Session) -> None:
    """In the xdist controller, before the workers start: start the warm-up."""
    config = session.config
    if not _is_xdist_controller(config) or config.option.collectonly:
        return
    folder = Path(tempfile.mkdtemp(prefix="pmspm-warm-up-"))
    (folder / "scenario.yaml").write_text(_WARM_UP_SCENARIO)
    config.stash[_warm_up_key] = (folder, subprocess.Popen(
        [sys.executable, "-c", _WARM_UP, str(folder)], cwd=config.rootpath,
        stdin=subprocess.DEVNULL, start_new_session=True))  # its own group: see sessionfinish
    os.environ[_WARM_UP_ENV] = str(folder)  # the workers inherit it


def pytest_collection_finish(session: pytest.Session) -> None:
    """In an xdist worker, after collecting: torch on one thread (a test module may have set
    more when it was imported), then wait for the warm-up to finish."""
    if not hasattr(session.config, "workerinput"):
        return
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)
    if "cv2" in sys.modules:
        sys.modules["cv2"].setNumThreads(1)
    folder = os.environ.get(_WARM_UP_ENV)
    if not folder:
        return
    deadline = time.monotonic() + _WARM_UP_WAIT_S
    while not (Path(folder) / "done").exists() and time.monotonic() < deadline:
        time.sleep(0.1)


def pytest_sessionfinish(session: pytest.Session) -> None:
    """In the xdist controller: end the warm-up if it still runs (its process group: the
    runs it started too), remove its folder."""
    started = session.config.stash.get(_warm_up_key, None)
    if started is None:
        return
    folder, process = started
    if process.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    shutil.rmtree(folder, ignore_errors=True)


#: A module-, class- or package-scoped fixture in a test module's source.
_SHARED_FIXTURE = re.compile(r"""scope\s*=\s*["'](module|class|package)["']""")


def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """The workers' schedule: a test module with a shared fixture (module, class or package
    scope, found in its source) is one unit of work, every other test is a unit of its own;
    the modules go first, those with the most tests first (xdist's ``loadscope`` order).
    (xdist's ``loadgroup`` would do this with markers, but it names the groups in the test ids,
    which pytest 9 no longer lets a plugin change.)"""
    from xdist.scheduler import LoadScopeScheduling

    root = config.rootpath
    shared = {path.relative_to(root).as_posix()
              for path in (root / "tests").rglob("test_*.py")
              if _SHARED_FIXTURE.search(path.read_text())}

    class ModulesWithSharedFixtures(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return module if module in shared else nodeid

    return ModulesWithSharedFixtures(config, log)
