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
- The numba kernels of both engines are compiled into the disk cache (``_WARM_UP``: a short
  run of each engine through the command line, the event loop's first), started when the
  session starts. Without it, on a fresh clone every worker, and every sweep worker or notebook
  kernel a test starts meanwhile, would compile the same kernels at once (a minute of CPU for
  the batched engine's run loop alone); numba's cache index is also not safe against two
  processes saving different signatures of one function at the same time.
- The workers do not wait for the warm-up before they start; they wait only where they would
  otherwise compile what it is compiling. A worker about to compile (or load) a numba function
  first waits for the warm-up's run that compiles its module (``_wait_before_compiling``:
  the batched engine's for ``latency.compiled``, the event loop's for any other), then loads it
  from the cache. Tests marked ``engine`` (they run the compiled engines, in process or in
  processes they start) go after all the others and wait for the whole warm-up before they
  begin, so the workers run the other tests while the engines compile.
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
#: The warm-up's engines, in the order it runs them; ``<engine>.done`` appears in the warm-up's
#: folder when its run ends. The event loop's first: its kernels (physics, metrics, attitude
#: helpers) are the batched engine's too, which then loads them from the cache. Measured on a
#: fresh clone, one after the other: 28 s and 64 s of CPU, against 28 s and 96 s side by side.
_ENGINES = ("event", "batched")
#: Run in a process of its own with the warm-up folder and the engines as arguments: one short
#: run per engine through the command line, one after the other; each writes
#: ``<engine>.done`` when it ends.
_WARM_UP = """
import subprocess, sys
from pathlib import Path
folder = Path(sys.argv[1])
for engine in sys.argv[2:]:
    subprocess.run([sys.executable, "-m", "experiments.cli", "simulate",
                    str(folder / "scenario.yaml"), "--engine", engine,
                    "--out", str(folder / engine)],
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    (folder / f"{engine}.done").touch()
"""
#: How long a worker waits for the warm-up at most, s: a guard against a hung warm-up (the
#: tests then compile what they need themselves).
_WARM_UP_WAIT_S = 900.0
#: The controller's warm-up: its folder and process.
_warm_up_key = pytest.StashKey[tuple[Path, subprocess.Popen]]()
#: The session's cache folder of exported networks, when the session made it.
_cache_key = pytest.StashKey[Path]()
#: The warm-up's engines known to be done in this process.
_done: set[str] = set()


def _is_xdist_controller(config: pytest.Config) -> bool:
    return bool(getattr(config.option, "numprocesses", None)) and not hasattr(
        config, "workerinput")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "engine: runs the compiled engines (in process or in processes it starts); "
        "scheduled after the other tests, it waits for the engines' warm-up")


def pytest_sessionstart(session: pytest.Session) -> None:
    """In the controller (the only process without xdist), before the workers start: a cache
    folder of exported networks for the session (``observer.transt.export``, shared by the
    workers and the processes they start; a user's own cache is left alone); with xdist, start
    the warm-up."""
    config = session.config
    if hasattr(config, "workerinput"):
        return
    if not os.environ.get("PMSPM_CACHE_DIR"):
        cache = Path(tempfile.mkdtemp(prefix="pmspm-test-cache-"))
        config.stash[_cache_key] = cache
        os.environ["PMSPM_CACHE_DIR"] = str(cache)
    if not _is_xdist_controller(config) or config.option.collectonly:
        return
    folder = Path(tempfile.mkdtemp(prefix="pmspm-warm-up-"))
    (folder / "scenario.yaml").write_text(_WARM_UP_SCENARIO)
    config.stash[_warm_up_key] = (folder, subprocess.Popen(
        [sys.executable, "-c", _WARM_UP, str(folder), *_ENGINES], cwd=config.rootpath,
        stdin=subprocess.DEVNULL, start_new_session=True))  # its own group: see sessionfinish
    os.environ[_WARM_UP_ENV] = str(folder)  # the workers inherit it


def _wait_for_warm_up(*engines: str) -> None:
    """Return once the warm-up's runs of ``engines`` have ended (at once without a warm-up,
    e.g. without xdist; at most ``_WARM_UP_WAIT_S``)."""
    folder = os.environ.get(_WARM_UP_ENV)
    waiting = [e for e in engines if e not in _done]
    if not folder or not waiting:
        return
    deadline = time.monotonic() + _WARM_UP_WAIT_S
    while not all((Path(folder) / f"{e}.done").exists() for e in waiting):
        if time.monotonic() > deadline:
            return
        time.sleep(0.1)
    _done.update(waiting)


def _wait_before_compiling() -> None:
    """Make numba's dispatchers wait for the warm-up that compiles their module before they
    compile or load a signature (``Dispatcher.compile``: the first call of a signature in a
    process), so that a worker loads what the warm-up compiles instead of compiling it too."""
    from numba.core.dispatcher import Dispatcher

    compile_now = Dispatcher.compile

    def compile_after_warm_up(self: Dispatcher, sig: object) -> object:
        module = getattr(self.py_func, "__module__", "") or ""
        _wait_for_warm_up("batched" if module.startswith("latency.compiled") else "event")
        return compile_now(self, sig)

    Dispatcher.compile = compile_after_warm_up


def pytest_collection_finish(session: pytest.Session) -> None:
    """In an xdist worker, after collecting: torch and OpenCV on one thread (a test module may
    have set more when it was imported), numba's compilations after the warm-up's."""
    if not hasattr(session.config, "workerinput"):
        return
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)
    if "cv2" in sys.modules:
        sys.modules["cv2"].setNumThreads(1)
    if os.environ.get(_WARM_UP_ENV):
        _wait_before_compiling()


@pytest.fixture(autouse=True)
def _engines_compiled(request: pytest.FixtureRequest) -> None:
    """A test marked ``engine`` starts once both engines are in numba's cache."""
    if request.node.get_closest_marker("engine") is not None:
        _wait_for_warm_up(*_ENGINES)


def pytest_sessionfinish(session: pytest.Session) -> None:
    """In the controller: remove the session's cache folder; end the warm-up if it still runs
    (its process group: the runs it started too), remove its folder."""
    cache = session.config.stash.get(_cache_key, None)
    if cache is not None:
        shutil.rmtree(cache, ignore_errors=True)
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


def _shared_modules(root: Path) -> set[str]:
    """The test modules (paths relative to ``root``) with a shared fixture in their source."""
    return {path.relative_to(root).as_posix() for path in (root / "tests").rglob("test_*.py")
            if _SHARED_FIXTURE.search(path.read_text())}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The order in which the workers take the tests: those not marked ``engine`` first, and
    in each part the modules with a shared fixture first, those with the most tests first
    (xdist's ``loadscope`` order, kept in one piece), then the other tests as collected."""
    shared = _shared_modules(config.rootpath)
    module_of = {id(it): it.nodeid.split("::", 1)[0] for it in items}
    size: dict[str, int] = {}
    for it in items:
        size[module_of[id(it)]] = size.get(module_of[id(it)], 0) + 1
    first = {it.nodeid: k for k, it in enumerate(items)}

    def order(it: pytest.Item) -> tuple:
        module = module_of[id(it)]
        in_one_piece = module in shared
        return (it.get_closest_marker("engine") is not None, not in_one_piece,
                -size[module] if in_one_piece else 0, module if in_one_piece else "",
                first[it.nodeid])

    items.sort(key=order)


def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """The workers' schedule: a test module with a shared fixture (module, class or package
    scope, found in its source) is one unit of work, every other test is a unit of its own,
    taken in the order of ``pytest_collection_modifyitems``.
    (xdist's ``loadgroup`` would do this with markers, but it names the groups in the test ids,
    which pytest 9 no longer lets a plugin change.)"""
    from xdist.scheduler import LoadScopeScheduling

    shared = _shared_modules(config.rootpath)
    config.option.loadscopereorder = False  # the collection's order, not xdist's

    class ModulesWithSharedFixtures(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return module if module in shared else nodeid

    return ModulesWithSharedFixtures(config, log)
