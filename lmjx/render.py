"""Renderings of a trial: the "real" world recorded while actions execute, drawn with
MuJoCo's renderer into a frame strip (.png), an animation (.gif) or a video (.mp4, needs
imageio with ffmpeg).  Rendering needs OpenGL: on a headless Linux machine install OSMesa
(Debian: libosmesa6) and set MUJOCO_GL=osmesa, or use EGL on a GPU machine."""

from __future__ import annotations

import os
from pathlib import Path

import mujoco
import numpy as np

from .errors import ConfigError
from .executor import SimulatedRealWorld
from .fileio import atomic_path

FORMATS = (".png", ".gif", ".mp4")


def check_render_path(path: str) -> None:
    ext = Path(path).suffix.lower()
    if ext not in FORMATS:
        raise ConfigError(f"--render: '{path}' must end in .png (frame strip), .gif or .mp4")
    if ext == ".mp4":
        try:
            import imageio.v2  # noqa: F401
        except ImportError:
            raise ConfigError("--render .mp4 needs imageio and imageio-ffmpeg; use .gif or .png instead") from None
    try:
        m = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='1'/></worldbody></mujoco>")
        with mujoco.Renderer(m, 16, 16) as r:
            r.render()
    except Exception as e:
        gl = os.environ.get("MUJOCO_GL", "default")
        raise ConfigError(
            f"--render: no OpenGL for MuJoCo (MUJOCO_GL={gl}: {type(e).__name__}); on a headless machine install "
            "OSMesa (Debian: libosmesa6) and set MUJOCO_GL=osmesa"
        ) from None


class Recorder:
    """Keeps the world's state every `period` seconds of execution."""

    def __init__(self, world: SimulatedRealWorld, period: float = 0.1) -> None:
        self.world = world
        self.period = period
        self.frames: list[np.ndarray] = []
        self._next = 0.0
        world.on_step = self._step

    def _step(self, m: mujoco.MjModel, d: mujoco.MjData) -> None:
        if d.time >= self._next:
            self.frames.append(d.qpos.copy())
            self._next = d.time + self.period

    def images(self, width: int = 480, height: int = 360, every: int = 1) -> list[np.ndarray]:
        scene = self.world.scene
        assert scene is not None
        m = scene.model
        d = mujoco.MjData(m)
        cam = mujoco.MjvCamera()
        cam.lookat[:] = (0.4, 0.0, 0.1)
        cam.distance = 1.5
        cam.azimuth = 200.0
        cam.elevation = -40.0
        out = []
        with mujoco.Renderer(m, height, width) as r:
            for q in self.frames[::every]:
                d.qpos[:] = q
                mujoco.mj_forward(m, d)
                r.update_scene(d, camera=cam)
                out.append(r.render().copy())
        return out

    def write(self, path: str) -> None:
        ext = Path(path).suffix.lower()
        if ext == ".png":
            n = 8
            step = max(1, len(self.frames) // n)
            imgs = self.images(320, 240, every=step)[:n]
            strip = np.concatenate(imgs, axis=1) if imgs else np.zeros((240, 320, 3), np.uint8)
            from PIL import Image

            with atomic_path(path) as tmp:
                Image.fromarray(strip).save(tmp, format="PNG")
        elif ext == ".gif":
            from PIL import Image

            imgs = [Image.fromarray(i) for i in self.images(360, 270, every=2)]
            with atomic_path(path) as tmp:
                imgs[0].save(tmp, format="GIF", save_all=True, append_images=imgs[1:], duration=200, loop=0)
        else:
            import imageio.v2 as imageio

            with atomic_path(path) as tmp:
                imageio.mimwrite(tmp, self.images(640, 480), fps=10, format="FFMPEG")
