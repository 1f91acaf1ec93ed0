"""The motor: geometry, torque map K(q), current allocation, rigid-body dynamics (MuJoCo model and
CasADi twin), the bottom camera, and the renderers of its view. Imports no other package here.

MuJoCo chooses its OpenGL backend when it is first imported, and every module here that imports
it is reached through this package, so the offscreen EGL default (CPU rendering on machines
without a GPU) is set here, before any of them. An explicit ``MUJOCO_GL`` wins.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
