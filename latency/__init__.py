"""Time: latency models, the timed closed loop and its engines, exact-delay frequency-domain
margins; and the front door for closed-loop runs::

    from latency import Scenario, simulate, simulate_many

``Scenario`` (``latency.scenario``) describes a run; ``simulate`` runs one and
``simulate_many`` many (``latency.simulation``). The names are loaded on first use, so that
``import latency.margins`` stays light.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from latency.scenario import Scenario
    from latency.simulation import Engine, build_loop, simulate, simulate_many

__all__ = ["Engine", "Scenario", "build_loop", "simulate", "simulate_many"]

_HOMES = {"Scenario": "latency.scenario", "Engine": "latency.simulation",
          "build_loop": "latency.simulation", "simulate": "latency.simulation",
          "simulate_many": "latency.simulation"}


def __getattr__(name: str) -> Any:
    """The front door's names, imported from their modules on first use."""
    if name in _HOMES:
        return getattr(importlib.import_module(_HOMES[name]), name)
    raise AttributeError(f"module 'latency' has no attribute {name!r}")
