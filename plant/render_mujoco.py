"""The bottom camera's view rendered by MuJoCo offscreen (the realistic renderer).

The scene is the MJCF of ``plant.mjcf.build_mjcf``: its camera "bottom" has the pose and field
of view of ``plant.camera.Camera``, so frames agree with ``plant.render_analytic`` and with the
ground truth of ``plant.scene``. MuJoCo renders an ideal centred pinhole; a non-zero lens
distortion (``CameraParams.dist_coeffs``) and calibrated intrinsics
(``CameraParams.intrinsics_px``) are applied afterwards by resampling the ideal image.

Textured variant (``texture=`` a ``plant.texture.TextureParams``, default None): the
plate carries the printed pattern of ``plant.texture`` instead of the two markers (see
``plant.mjcf``); OpenGL's mipmapped texture filtering does the anti-aliasing.

OpenGL backend: MuJoCo chooses it from the environment variable ``MUJOCO_GL`` when ``mujoco``
is first imported. This module sets ``MUJOCO_GL=egl`` (headless, works on CPU-only machines
through Mesa) unless the variable is already set, *before* importing mujoco. If something
imported mujoco earlier without the variable, export ``MUJOCO_GL=egl`` (or ``osmesa``) in the
shell instead.
"""

from __future__ import annotations

import os
import sys

_MUJOCO_ALREADY_IMPORTED = "mujoco" in sys.modules and "MUJOCO_GL" not in os.environ
os.environ.setdefault("MUJOCO_GL", "egl")

import cv2  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import ArrayLike, NDArray  # noqa: E402

from plant import attitude  # noqa: E402
from plant.camera import Camera  # noqa: E402
from plant.mjcf import build_mjcf, mjcf_assets  # noqa: E402
from plant.params import PlantParams  # noqa: E402
from plant.scene import (  # noqa: E402
    Frame,
    allowed_binnings,
    check_binning,
    check_exposure,
    choose_n_sub,
    ground_truth,
    sub_exposure_attitudes,
    vfc_pixel_travel,
)
from plant.texture import TextureParams, generate_texture  # noqa: E402

#: Name of the camera in the MJCF of ``plant.mjcf``.
CAMERA_NAME = "bottom"


class MujocoRenderer:
    """Render frames of the bottom camera with MuJoCo.

    Parameters
    ----------
    params : PlantParams, optional
        Geometry of rotor, VFC and camera (default ``PlantParams()``).
    binning : int, optional
        Sensor pixels per image pixel (default ``params.camera.binning``); must divide both
        sensor sides, and the frame must fit MuJoCo's offscreen buffer (the model's
        ``offwidth`` x ``offheight``, the full sensor in ``plant.mjcf``).
    blur_step_px : float
        Largest image-pixel step of a marker centre or plate corner between consecutive
        sub-exposure renders when ``n_sub`` is automatic (our choice: 1 px; each sub-frame
        costs a full render).
    max_sub_frames : int
        Cap on the automatic number of sub-frames (our choice: 16).
    texture : TextureParams, optional
        Draw the printed texture of ``plant.texture`` on the bottom plate instead of
        the two markers (default None: the markers).
    model : mujoco.MjModel, optional
        A compiled model to render instead of ``build_mjcf(params)``'s: the same scene with
        other materials or lights (``plant.render_unseen``); it must keep the camera
        ``CAMERA_NAME`` and the ball joint. Not together with ``texture``.

    The renderer holds an OpenGL context: call ``close()`` or use it as a context manager.
    """

    def __init__(
        self,
        params: PlantParams | None = None,
        binning: int | None = None,
        *,
        blur_step_px: float = 1.0,
        max_sub_frames: int = 16,
        texture: TextureParams | None = None,
        model: mujoco.MjModel | None = None,
    ) -> None:
        self.params = params or PlantParams()
        self.binning = check_binning(self.params, binning)
        if not blur_step_px > 0.0:
            raise ValueError(f"blur_step_px must be > 0 px, got {blur_step_px}")
        if int(max_sub_frames) < 1:
            raise ValueError(f"max_sub_frames must be >= 1, got {max_sub_frames}")
        self.blur_step_px = float(blur_step_px)
        self.max_sub_frames = int(max_sub_frames)
        self.camera = Camera.from_plant(self.params)
        if self.camera.roll_rad != 0.0:
            raise ValueError("camera.mount_roll_deg must be 0 for the MuJoCo renderer (its "
                             "camera has no roll); use the analytic renderer")
        self.width, self.height = self.camera.size(self.binning)
        if model is not None and texture is not None:
            raise ValueError("model: give a compiled model or a texture, not both")
        self.texture = None if texture is None else generate_texture(self.params, texture)
        if model is not None:
            self.model = model
        elif self.texture is None:
            self.model = mujoco.MjModel.from_xml_string(build_mjcf(self.params))
        else:
            self.model = mujoco.MjModel.from_xml_string(
                build_mjcf(self.params, texture=self.texture), mjcf_assets(self.texture)
            )
        self.data = mujoco.MjData(self.model)
        off_w, off_h = self.model.vis.global_.offwidth, self.model.vis.global_.offheight
        if self.width > off_w or self.height > off_h:
            fits = [
                b
                for b in allowed_binnings(self.params)
                if self.camera.size(b)[0] <= off_w and self.camera.size(b)[1] <= off_h
            ]
            raise ValueError(
                f"a {self.width} x {self.height} px frame (binning {self.binning}) exceeds "
                f"MuJoCo's offscreen buffer of {off_w} x {off_h} px (visual/global "
                f"offwidth/offheight); binnings that fit: {fits}"
            )
        try:
            self._renderer = mujoco.Renderer(self.model, self.height, self.width)
        except Exception as err:  # the GL backend is chosen at import time
            hint = (
                " mujoco was imported before plant.render_mujoco without MUJOCO_GL;"
                " export MUJOCO_GL=egl (or osmesa) before starting Python."
                if _MUJOCO_ALREADY_IMPORTED
                else ""
            )
            raise RuntimeError(
                f"cannot create a MuJoCo offscreen renderer with "
                f"MUJOCO_GL={os.environ.get('MUJOCO_GL')!r}: {err}.{hint}"
            ) from err
        self._maps = self._distortion_maps()

    def _distortion_maps(self) -> tuple[NDArray[np.float32], NDArray[np.float32]] | None:
        """Maps (for ``cv2.remap``) from each pixel of the camera (``Camera.matrix``, with the
        lens distortion) to MuJoCo's image, or None when the two are the same. MuJoCo renders
        a centred pinhole with square pixels of the camera's fy (``plant.mjcf``'s fovy), so a
        calibrated principal point off the centre or fx != fy is resampled too. Pixels whose
        ray falls outside the rendered field (corners under strong barrel distortion) repeat
        the border."""
        dist = np.asarray(self.camera.params.dist_coeffs, dtype=float)
        K = self.camera.matrix(self.binning)
        K_mujoco = np.array([[K[1, 1], 0.0, (self.width - 1) / 2.0],
                             [0.0, K[1, 1], (self.height - 1) / 2.0], [0.0, 0.0, 1.0]])
        if not np.any(dist) and np.allclose(K, K_mujoco, rtol=0.0, atol=1e-9):
            return None
        u, v = np.meshgrid(np.arange(self.width, dtype=float), np.arange(self.height, dtype=float))
        uv = np.stack([u, v], axis=-1).reshape(-1, 1, 2)
        ideal = cv2.undistortPoints(uv, K, dist, P=K_mujoco).reshape(self.height, self.width, 2)
        return ideal[..., 0].astype(np.float32), ideal[..., 1].astype(np.float32)

    def _render_one(self, q: NDArray[np.float64]) -> NDArray[np.uint8]:
        self.data.qpos[:] = q
        mujoco.mj_forward(self.model, self.data)
        self._renderer.update_scene(self.data, camera=CAMERA_NAME)
        return self._renderer.render()

    def render(
        self,
        q: ArrayLike,
        t_exposure: float = 0.0,
        exposure_s: float | None = None,
        omega: ArrayLike | None = None,
        *,
        n_sub: int | None = None,
    ) -> Frame:
        """Render one frame.

        Parameters
        ----------
        q : array_like (4,)
            Mid-exposure attitude (w, x, y, z; rotor to stator).
        t_exposure : float
            Mid-exposure time, s (recorded in the frame).
        exposure_s : float, optional
            Exposure time, s (default ``params.camera.exposure_s``).
        omega : array_like (3,), optional
            Body-frame angular velocity, rad/s, held over the exposure (default: at rest).
        n_sub : int, optional
            Sub-exposure renders to average; default automatic (``blur_step_px``), 1 when the
            image moves less than one step during the exposure.

        Returns
        -------
        Frame
            RGB image and full-sensor ground truth at mid-exposure.
        """
        if self._renderer is None:
            raise RuntimeError("render() called after close()")
        q = attitude.normalize(q)
        t, e, w = check_exposure(self.params, t_exposure, exposure_s, omega)
        if n_sub is None:
            travel = vfc_pixel_travel(self.params, q, w, e, self.binning)
            n = choose_n_sub(travel, self.blur_step_px, self.max_sub_frames)
        else:
            if isinstance(n_sub, bool) or int(n_sub) != n_sub or not 1 <= n_sub <= 255:
                raise ValueError(f"n_sub must be an integer in [1, 255], got {n_sub!r}")
            n = int(n_sub)
        qs = sub_exposure_attitudes(q, w, e, n)
        if n == 1:
            img = self._render_one(qs[0])
        else:
            acc = np.zeros((self.height, self.width, 3), np.uint16)
            for qk in qs:
                acc += self._render_one(qk)
            img = ((acc + n // 2) // n).astype(np.uint8)
        if self._maps is not None:
            img = cv2.remap(img, *self._maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        marker_px, boxes_px = ground_truth(self.params, q)
        return Frame(np.ascontiguousarray(img), marker_px, boxes_px, q, t, e, self.binning, n)

    def close(self) -> None:
        """Free the OpenGL context (idempotent)."""
        r, self._renderer = getattr(self, "_renderer", None), None
        if r is not None:
            r.close()

    def __enter__(self) -> MujocoRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()
