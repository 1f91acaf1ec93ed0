"""The TransT training code stays apart: importing the tracker or the trackers' package loads no
module of ``observer.transt.training``, and the training entry points never load the
evaluation-only image source ``plant.render_unseen``."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Run in a fresh interpreter: the runtime imports, then the training entry points; prints what
#: each step has loaded.
PROBE = """
import json, sys
import observer.transt.tracker, observer.transt.service, observer.transt.export
import observer.trackers
runtime = sorted(k for k in sys.modules if k.startswith("observer.transt.training"))
import observer.transt.training.data, observer.transt.training.train
print(json.dumps({"runtime": runtime,
                  "training": sorted(k for k in sys.modules
                                     if k.startswith("observer.transt.training")),
                  "unseen": "plant.render_unseen" in sys.modules}))
"""


def test_runtime_imports_no_training_module_and_training_no_unseen_source():
    """A fresh interpreter that imports ``observer.transt.tracker`` and ``observer.trackers``
    (and so the network, service, export, backbone, fusion, crop and weights modules) has no
    ``observer.transt.training`` module in ``sys.modules``; once it imports the training entry
    points it has them (the control: the check would see one), and still not
    ``plant.render_unseen`` (directly or through another module)."""
    out = subprocess.run([sys.executable, "-c", PROBE], cwd=ROOT, capture_output=True,
                         text=True, check=True, env={"PYTHONPATH": str(ROOT), "PATH": ""})
    loaded = json.loads(out.stdout)
    assert loaded["runtime"] == [], f"runtime imports load training modules: {loaded['runtime']}"
    assert {"observer.transt.training.data", "observer.transt.training.train"} <= set(
        loaded["training"]), loaded["training"]
    assert loaded["unseen"] is False
