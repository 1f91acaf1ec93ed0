"""Training of the TransT network, kept apart from the runtime package ``observer.transt``.

Only the training commands, the benchmarks and the tests import this package; the tracker, the
network service, the export and the weight loading never do (a test checks it), so a tracker
in the loop loads no training code.

* ``data``: the crop pairs rendered by the analytic renderer into a cache (``CropPairs``);
* ``augment``: the augmentations at load time (flips, target removal, appearance jitter);
* ``validation``: the rendered validation tracking sequences and true marker boxes;
* ``losses``: TransT's loss (``TransTLoss``);
* ``train``: the training command, ``python -m observer.transt.training.train``, which exports
  the shipped weights with their SHA-256 and model card (``model_card``).

See docs/transt.md.
"""
