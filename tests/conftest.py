"""Shared test setup, before any test module imports numpy or mujoco.

- MuJoCo picks its GL backend at first import.
- OpenBLAS (numpy's and scipy's) runs one thread. The suite's linear algebra is on small
  matrices (the sampled loop's and the MPC law's matrix exponentials, 3x3 to 8x8), where
  OpenBLAS's thread hand-off costs far more than the arithmetic: measured on the two shared
  cores, ``scipy.linalg.expm`` of a 3x3 matrix took 24 ms a call with the default threads and
  0.08 ms with one. The results are the same; ``setdefault`` leaves a caller's choice alone.
- Hypothesis runs without its per-example deadline: a deadline is wall-clock time, and the
  first example of a test may load compiled code from numba's cache.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # read when OpenBLAS loads (and by workers)

from hypothesis import settings  # noqa: E402

settings.register_profile("no_deadline", deadline=None)
settings.load_profile("no_deadline")
