"""The numba disk cache of the compiled run loop's modules.

numba drops a cached function when its own source file changes, not when a function it
compiles in from another file does (``latency.numba_cache``). The run loop's kernels call one
another across this package's modules and into the plant's, the observer's and the MPC's
compiled functions, and read the array layout's constants (``layout``) as compile-time
constants: each module of the package names the modules its kernels compile in
(``COMPILED_IN``, from ``compiled_in``) and drops its cache when one of them changes."""

from __future__ import annotations

from collections.abc import Iterable
from types import ModuleType


def compiled_in(external: Iterable[ModuleType],
                siblings: Iterable[ModuleType] = ()) -> tuple[ModuleType, ...]:
    """The modules whose code a module's kernels compile in: ``external`` (modules outside
    this package) and this package's ``siblings`` together with theirs (each sibling's
    ``COMPILED_IN``), each once, in order."""
    out: dict[ModuleType, None] = dict.fromkeys(external)
    for module in siblings:
        out[module] = None
        out.update(dict.fromkeys(module.COMPILED_IN))
    return tuple(out)
