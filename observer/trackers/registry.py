"""The tracker family: every marker-pair tracker by name, with what it is and its builder
(``plant.registry``).

Names say what they are: ``kcf`` and ``csrt`` are OpenCV's trackers alone, one per marker;
``kcf_gk`` and ``csrt_gk`` are the same trackers on the red marker inside the GK assistance;
``gk_transt`` is the TransT network inside the GK assistance (seed 000 §3.2) and ``dual_transt``
two networks, one per marker. ``transt`` is the former scenario name of ``gk_transt``.
The builders are ``observer.trackers.make_pair_tracker``'s.
"""

from __future__ import annotations

import functools
from typing import Any

from plant.registry import Registry


def _build(name: str, *args: Any, **kwargs: Any) -> Any:
    """``observer.trackers.make_pair_tracker(name, ...)`` (imported here: the implementations
    import this package's base classes)."""
    from observer.trackers import make_pair_tracker

    return make_pair_tracker(name, *args, **kwargs)


TRACKERS = Registry(
    "tracker",
    "the marker-pair tracker of image mode: frame in, both marker centres (sensor px) out",
    "(params, refine=None, transt_factory=None, clock=None, **kwargs) -> MarkerPairTracker",
    "tracker: NAME (mode: image)",
)
for _name, _summary in {
    "gk_transt": "GK-TransT: one TransT network on the red marker inside the GK assistance "
                 "(seed 000 §3.2)",
    "dual_transt": "two independent TransT networks, one per marker (the seed's original "
                   "TransT)",
    "kcf": "OpenCV KCF alone, one per marker",
    "csrt": "OpenCV CSRT alone, one per marker",
    "kcf_numpy": "the numpy KCF alone, one per marker",
    "k2cf": "K²CF, one per marker (seed 004 §3.2)",
    "kcf_gk": "OpenCV KCF on the red marker inside the GK assistance (no network)",
    "csrt_gk": "OpenCV CSRT on the red marker inside the GK assistance (no network)",
}.items():
    TRACKERS.register(_name, _summary, functools.partial(_build, _name))
TRACKERS.rename("transt", "gk_transt")
