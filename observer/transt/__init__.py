"""TransT (Chen et al., "Transformer Tracking", CVPR 2021) in plain torch: the network, its
shipped weights and the tracker (seed 000 §3.1 builds GK-TransT on it).

* ``network``: ``TransTNet`` in two configurations, ``TRANST50`` (the published layout, loads the
  official checkpoint with ``load_official_state_dict``) and ``SMALL`` (trained here, shipped).
* ``tracker``: ``TransTTracker``, an ``observer.tracking.SingleObjectTracker``
  (``initialize(frame, box)`` / ``track(frame, search_centre_image_px=None) -> TrackResult``);
  ``TransTTracker.small()`` loads the shipped weights.
* ``training``: TransT's loss, the cached crop pairs and the training command, a subpackage
  that no runtime module imports (the tracker loads no training code).
* ``weights``: SHA-256-checked weight files.

See docs/transt.md.
"""

from observer.transt.network import (
    CONFIGS,
    SMALL,
    TRANST50,
    LoadReport,
    TransTConfig,
    TransTNet,
    build_transt,
    count_parameters,
    load_official_state_dict,
)
from observer.transt.tracker import TransTStep, TransTTracker
from observer.transt.weights import SMALL_WEIGHTS, WeightsError, load_weights

__all__ = [
    "CONFIGS",
    "SMALL",
    "SMALL_WEIGHTS",
    "TRANST50",
    "LoadReport",
    "TransTConfig",
    "TransTNet",
    "TransTStep",
    "TransTTracker",
    "WeightsError",
    "build_transt",
    "count_parameters",
    "load_official_state_dict",
    "load_weights",
]
