"""CasADi functions compiled to machine code once and loaded from an on-disk cache.

CasADi evaluates an SX function in its virtual machine, one instruction at a time. The same
function written out as C (``casadi.CodeGenerator``) and compiled by the system C compiler runs
the instructions as machine code. ``compiled`` does that for a group of functions: it generates
their C code, names the shared library after the SHA-256 of that code and of the compiler
command, compiles it only if no library of that name exists yet, and returns the functions
loaded from it (``casadi.external``). The same problem in a later process (a sweep worker, a
test) therefore loads the library without compiling; a changed problem has different code and
gets a new library.

Cache folder: ``$PMSPM_CACHE_DIR`` if set, else ``__pycache__/casadi`` beside this module (as
numba's cache, git-ignored), else a folder in the system's temporary directory when the package
folder is read-only. Concurrent processes compiling the same library wait on a lock file, so
two workers that start together compile it once. Compiler: ``$CC`` or ``gcc``; ``compiled``
returns None when there is none or when compiling fails (with a warning), and callers keep the
virtual machine.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import shutil
import subprocess
import tempfile
import warnings
from pathlib import Path

import casadi as ca

#: Optimisation level of the generated code. Our choice by measurement (docs/controllers.md):
#: on the MPC's Jacobian -O1 ran as fast as -O2 and compiled faster; -O0 ran slower than
#: CasADi's virtual machine.
OPT_FLAGS = ("-O1",)


def cache_dir() -> Path:
    """The folder of the compiled libraries (module docstring), created if missing."""
    env = os.environ.get("PMSPM_CACHE_DIR")
    candidates = [Path(env)] if env else []
    candidates += [Path(__file__).with_name("__pycache__") / "casadi",
                   Path(tempfile.gettempdir()) / f"pmspm-casadi-{os.getuid()}"]
    for folder in candidates:
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError:
            continue
        if os.access(folder, os.W_OK):
            return folder
    raise OSError(f"no writable cache folder among {[str(c) for c in candidates]}")


def compiler() -> str | None:
    """Path of the C compiler (``$CC`` or ``gcc``), None if there is none."""
    return shutil.which(os.environ.get("CC", "gcc"))


def compiled(functions: list[ca.Function], prefix: str) -> list[ca.Function] | None:
    """``functions`` compiled into one shared library (cached, module docstring) and loaded
    from it, in order, under their own names (which must be distinct C identifiers). None
    without a C compiler or when compiling fails (a warning says why). ``prefix`` names the
    library file (``<prefix>_<hash>.so``)."""
    gen = ca.CodeGenerator(f"{prefix}.c", {"with_header": False})
    for f in functions:
        gen.add(f)
    lib = compiled_library([gen.dump()], prefix)
    return None if lib is None else [ca.external(f.name(), str(lib)) for f in functions]


def compiled_library(sources: list[str], prefix: str, flags: tuple[str, ...] = ()) -> Path | None:
    """The shared library of the C ``sources`` (one translation unit each), compiled with the
    extra compiler and linker ``flags`` (include folders, libraries) and cached as
    ``compiled`` caches (module docstring): its path, or None without a C compiler or when
    compiling fails (a warning says why)."""
    cc = compiler()
    if cc is None:
        return None
    command = [cc, *OPT_FLAGS, "-shared", "-fPIC"]
    digest = hashlib.sha256("\0".join([*command[1:], *flags, ca.__version__, *sources]).encode())
    folder = cache_dir()
    lib = folder / f"{prefix}_{digest.hexdigest()[:20]}.so"
    if not lib.exists():
        with open(folder / f"{lib.name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # another process may be compiling it
            if not lib.exists():
                failure = _compile(command, sources, flags, lib)
                if failure:
                    warnings.warn(f"compiling {prefix} with {cc} failed ({failure}); CasADi's "
                                  "virtual machine evaluates the functions instead",
                                  stacklevel=3)
                    return None
    return lib


def _compile(command: list[str], sources: list[str], flags: tuple[str, ...], lib: Path) -> str:
    """Compile ``sources`` into ``lib`` atomically (temporary files, then a rename). Returns
    "" on success, else why it failed (the end of the compiler's messages)."""
    with tempfile.TemporaryDirectory(dir=lib.parent) as tmp:
        c_files = [Path(tmp) / f"code{i}.c" for i in range(len(sources))]
        for c_file, source in zip(c_files, sources, strict=True):
            c_file.write_text(source)
        out = Path(tmp) / lib.name
        try:
            subprocess.run([*command, *map(str, c_files), "-o", str(out), *flags], check=True,
                           capture_output=True)
        except subprocess.CalledProcessError as exc:
            return f"exit status {exc.returncode}: {exc.stderr.decode(errors='replace')[-300:]}"
        except OSError as exc:
            return str(exc)
        os.replace(out, lib)
    return ""
