"""Shared test setup: MuJoCo picks its GL backend at first import, so set it before any test
module imports mujoco."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
