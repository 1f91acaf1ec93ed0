"""Dropping a module's numba disk cache when a module its compiled functions call has changed.

numba invalidates a cached function when its own source file changes, not when a function it
calls in another file does: a kernel that compiles in another module's functions would
otherwise keep running their old code after an edit there. A digest of those modules, kept
beside the cache, says when to drop it.
"""

from __future__ import annotations

import contextlib
import hashlib
import inspect
from collections.abc import Iterable
from pathlib import Path
from types import ModuleType


def drop_stale_cache(module_file: str, dependencies: Iterable[ModuleType]) -> None:
    """Delete the numba cache of the module at ``module_file`` (its ``__pycache__`` entries)
    when one of ``dependencies`` has changed since the cache was written."""
    source = Path(module_file)
    folder = source.with_name("__pycache__")
    digest = hashlib.sha256()
    for module in dependencies:
        digest.update(Path(inspect.getfile(module)).read_bytes())
    stamp = folder / f"{source.stem}.deps.sha256"
    if stamp.is_file() and stamp.read_text() == digest.hexdigest():
        return
    with contextlib.suppress(OSError):  # a read-only install: numba caches elsewhere
        for cached in folder.glob(f"{source.stem}.*.nb[ic]"):
            cached.unlink(missing_ok=True)
        folder.mkdir(exist_ok=True)
        stamp.write_text(digest.hexdigest())
