"""A module's numba disk cache goes when a module whose code it compiles in changes."""

import types

from latency.numba_cache import drop_stale_cache


def test_the_cache_is_dropped_when_a_dependency_changes_and_kept_otherwise(tmp_path):
    source = tmp_path / "kernel.py"
    source.write_text("")
    dependency_file = tmp_path / "physics.py"
    dependency_file.write_text("STEP = 1\n")
    dependency = types.ModuleType("physics")
    dependency.__file__ = str(dependency_file)
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    cached = cache / "kernel._run-1.py311.nbi"
    other = cache / "loop._helper-1.py311.nbi"

    def fill() -> None:
        for f in (cached, other):
            f.write_text("")

    fill()
    drop_stale_cache(str(source), [dependency])  # no digest yet: dropped
    assert not cached.exists() and other.exists()
    fill()
    drop_stale_cache(str(source), [dependency])  # same sources: kept
    assert cached.exists()
    dependency_file.write_text("STEP = 2\n")
    drop_stale_cache(str(source), [dependency])  # the dependency changed: dropped
    assert not cached.exists() and other.exists()
