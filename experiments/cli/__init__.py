"""The ``pmspm`` command line (typer). ``pmspm --help`` lists the commands; every command's
``--help`` shows an example. Each command is a thin function that checks its arguments and calls
the module that does the work: ``loop`` (study, simulate, margins, sweep, parts), ``trackers``
(measure-latency, calibrate-loss, bench-trackers, track, calibrate-mount, calibrate) and
``design`` (tune-kalman, codesign); ``common`` holds the application and the shared checks.

Every mistake on the command line (a file that is not a YAML mapping, a field out of range, a
combination that cannot run, a non-finite or negative number, an output folder that cannot be
written, an unknown scheduler or storage) exits with status 2 and a message that names the
problem, without a traceback, before any expensive work starts (docs/reliability.md).
Settings that run but are far outside what the plant can do print a warning with the reason.
A Ctrl-C exits with status 130 and says that finished runs are kept.
"""

import importlib

from experiments.cli.common import app
from experiments.cli.loop import _expand

# Importing a command module registers its commands, in this order in ``pmspm --help``.
for _module in ("loop", "trackers", "design"):
    importlib.import_module(f"experiments.cli.{_module}")

__all__ = ["_expand", "app"]
