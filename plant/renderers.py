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
from plant.render_analytic import AnalyticRenderOptions
from plant.texture import TextureParams


def _analytic(plant: PlantParams, texture: TextureParams | None, seed: int,
              effects: AnalyticRenderOptions | None = None) -> Any:
    """``AnalyticRenderer`` with the printed pattern ``texture`` (None: the two markers) and
    the camera effects and distractors ``effects`` (None: the defaults)."""
    from plant.render_analytic import AnalyticRenderer

    options = (effects or AnalyticRenderOptions()).model_copy(update={"texture": texture})
    return AnalyticRenderer(plant, options=options, seed=seed)


def _mujoco(plant: PlantParams, texture: TextureParams | None, seed: int,
            effects: None = None) -> Any:
    """``MujocoRenderer`` with the printed pattern ``texture`` (its images carry no noise, so
    ``seed`` is unused; it has no camera-effect settings, ``effects`` must be None)."""
    from plant.render_mujoco import MujocoRenderer

    if effects is not None:
        raise ValueError("the mujoco renderer has no camera-effect settings; camera_effects "
                         "is for the analytic renderer")
    return MujocoRenderer(plant, texture=texture)


RENDERERS = Registry(
    "renderer",
    "the camera: plant state in, the exposed image out (image mode)",
    "(plant, texture, seed, effects) -> renderer with render(...)",
    "renderer: NAME (mode: image)",
)
RENDERERS.register("analytic", "closed-form markers with motion blur, noise and camera "
                   "effects (our construction)", _analytic, AnalyticRenderOptions,
                   prefix="camera_effects.")
RENDERERS.register("mujoco", "the MuJoCo scene rendered offscreen (MUJOCO_GL=egl)", _mujoco)
