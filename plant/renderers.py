"""The renderer family: the camera images of image mode, by name, with their builders
(``plant.registry``).

``analytic`` draws the two markers (or the printed pattern) in closed form with motion blur,
noise and camera effects (``plant.render_analytic``); ``mujoco`` renders the MuJoCo scene
offscreen (``plant.render_mujoco``, needs ``MUJOCO_GL=egl`` without a screen). Both are imported
only when built: MuJoCo's renderer loads an OpenGL context.
"""

from __future__ import annotations

from typing import Any

from plant.params import PlantParams
from plant.registry import Registry
from plant.texture import TextureParams


def _analytic(plant: PlantParams, texture: TextureParams | None, seed: int) -> Any:
    """``AnalyticRenderer`` with the printed pattern ``texture`` (None: the two markers)."""
    from plant.render_analytic import AnalyticRenderer, AnalyticRenderOptions

    return AnalyticRenderer(plant, options=AnalyticRenderOptions(texture=texture), seed=seed)


def _mujoco(plant: PlantParams, texture: TextureParams | None, seed: int) -> Any:
    """``MujocoRenderer`` with the printed pattern ``texture`` (its images carry no noise, so
    ``seed`` is unused)."""
    from plant.render_mujoco import MujocoRenderer

    return MujocoRenderer(plant, texture=texture)


RENDERERS = Registry(
    "renderer",
    "the camera: plant state in, the exposed image out (image mode)",
    "(plant, texture, seed) -> renderer with render(...)",
    "renderer: NAME (mode: image)",
)
RENDERERS.register("analytic", "closed-form markers with motion blur, noise and camera "
                   "effects (our construction)", _analytic)
RENDERERS.register("mujoco", "the MuJoCo scene rendered offscreen (MUJOCO_GL=egl)", _mujoco)
