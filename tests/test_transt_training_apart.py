"""The TransT training code stays out of the runtime: importing the tracker or the trackers'
package loads no module of ``observer.transt.training``."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_runtime_imports_no_training_module():
    """A fresh interpreter that imports ``observer.transt.tracker`` and ``observer.trackers``
    (and so the network, service, export, backbone, fusion, crop and weights modules) has no
    ``observer.transt.training`` module in ``sys.modules``; the control run, which imports the
    training package itself, shows that the check would see one."""
    probe = ("import sys, {m}; "
             "print(sorted(k for k in sys.modules if k.startswith('observer.transt.training')))")
    env = {"PYTHONPATH": str(ROOT), "PATH": ""}

    def loaded(modules: str) -> str:
        return subprocess.run([sys.executable, "-c", probe.format(m=modules)], cwd=ROOT,
                              capture_output=True, text=True, check=True, env=env).stdout.strip()

    runtime = loaded("observer.transt.tracker, observer.transt.service, observer.transt.export, "
                     "observer.trackers")
    control = loaded("observer.transt.training.losses")
    assert runtime == "[]", f"runtime imports load training modules: {runtime}"
    assert "observer.transt.training.losses" in control, control
