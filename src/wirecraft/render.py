"""Off-screen rendering on the CPU (Mesa through EGL or OSMesa) with the cheap settings.

Shadows, reflections and multisampling are off: with them MuJoCo's software rendering runs
at 10-15 frames/s at 224 x 224, without them at well over 100.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np


@dataclass(frozen=True)
class ViewPoint:
    """A free camera: the point looked at, distance, azimuth and elevation in degrees."""

    lookat: tuple[float, float, float] = (0.0, 0.0, 0.0)
    distance: float = 1.0
    azimuth: float = 135.0
    elevation: float = -30.0

    def camera(self) -> mujoco.MjvCamera:
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        cam.lookat[:] = self.lookat
        cam.distance, cam.azimuth, cam.elevation = self.distance, self.azimuth, self.elevation
        return cam


class FastRenderer:
    """``mujoco.Renderer`` with shadows and reflections switched off after each scene update."""

    def __init__(self, model: mujoco.MjModel, height: int = 224, width: int = 224) -> None:
        limit = model.vis.global_.offwidth, model.vis.global_.offheight
        if not (0 < width <= limit[0] and 0 < height <= limit[1]):
            raise ValueError(
                f"FastRenderer: a {width} x {height} image does not fit the model's off-screen "
                f"framebuffer of {limit[0]} x {limit[1]} (model.vis.global_.offwidth/offheight)"
            )
        model.vis.quality.offsamples = 0
        # What a camera sees: no site markers (TCP, plug tip...), which only help debugging.
        self._option = mujoco.MjvOption()
        self._option.sitegroup[:] = 0
        try:
            self._renderer = mujoco.Renderer(model, height=height, width=width)
        except Exception as err:
            raise RuntimeError(
                f"off-screen OpenGL (MUJOCO_GL={os.environ.get('MUJOCO_GL')}) is unavailable. "
                "On Debian/Ubuntu install libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1 (or "
                f"libosmesa6 and set MUJOCO_GL=osmesa): {err}"
            ) from err

    def render(self, data: mujoco.MjData, camera: mujoco.MjvCamera | str | int = -1) -> np.ndarray:
        self._renderer.update_scene(data, camera=camera, scene_option=self._option)
        scene = self._renderer.scene
        scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        return self._renderer.render()

    def render_depth(self, data: mujoco.MjData, camera: mujoco.MjvCamera | str | int = -1):
        """(H, W) float32 depth in metres from the camera."""
        self._renderer.enable_depth_rendering()
        try:
            self._renderer.update_scene(data, camera=camera, scene_option=self._option)
            return self._renderer.render().astype(np.float32)
        finally:
            self._renderer.disable_depth_rendering()

    def close(self) -> None:
        self._renderer.close()

    def __enter__(self) -> FastRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def save_png(image: np.ndarray, path: str | os.PathLike) -> Path:
    from PIL import Image

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.ascontiguousarray(image)).save(path)
    return path
