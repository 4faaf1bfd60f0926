"""Renderings of a trial: the "real" world recorded while actions execute, drawn with
MuJoCo's renderer into a frame strip (.png), an animation (.gif) or a video (.mp4, needs
imageio with ffmpeg); and still images of a scene (`scene_image`).  Rendering needs OpenGL:
on a headless Linux machine install OSMesa (Debian: libosmesa6) and set MUJOCO_GL=osmesa,
or use EGL where the machine has it (a GPU's driver, or Mesa's).  Nothing here plans or simulates."""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from lmjx.errors import ConfigError
from lmjx.runtime.fileio import atomic_path

if TYPE_CHECKING:
    from lmjx.sim.realworld import SimulatedRealWorld
    from lmjx.sim.scene import Scene

FORMATS = (".png", ".gif", ".mp4")


@dataclass(frozen=True)
class View:
    """A free camera: the point it looks at [m], its distance [m], azimuth and elevation [deg]."""

    lookat: tuple[float, float, float] = (0.4, 0.0, 0.1)
    distance: float = 1.5
    azimuth: float = 200.0
    elevation: float = -40.0

    def camera(self) -> mujoco.MjvCamera:
        cam = mujoco.MjvCamera()
        cam.lookat[:] = self.lookat
        cam.distance = self.distance
        cam.azimuth = self.azimuth
        cam.elevation = self.elevation
        return cam


TRIAL_VIEW = View(lookat=(0.36, 0.24, 0.22), distance=1.5, azimuth=212.0, elevation=-34.0)


def gl_problem() -> str | None:
    """None if MuJoCo can render offscreen here, else a one-line reason with the fix."""
    try:
        m = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='1'/></worldbody></mujoco>")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # GLFW warns before it fails
            with mujoco.Renderer(m, 16, 16) as r:
                r.render()
    except Exception as e:
        gl = os.environ.get("MUJOCO_GL", "unset")
        return (
            f"no OpenGL for MuJoCo (MUJOCO_GL={gl}: {type(e).__name__}); on a headless machine install OSMesa "
            "(Debian: libosmesa6) and set MUJOCO_GL=osmesa, or MUJOCO_GL=egl where EGL is installed"
        )
    return None


def scene_image(scene: Scene, qpos: np.ndarray, view: View, width: int = 720, height: int = 540) -> np.ndarray:
    """(height, width, 3) uint8 picture of `scene` at the state `qpos` (nq,), seen from `view`."""
    m = scene.model
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_forward(m, d)
    with mujoco.Renderer(m, height, width) as r:
        r.update_scene(d, camera=view.camera())
        return r.render().copy()


def check_render_path(path: str) -> None:
    ext = Path(path).suffix.lower()
    if ext not in FORMATS:
        raise ConfigError(f"--render: '{path}' must end in .png (frame strip), .gif or .mp4")
    if ext == ".mp4":
        try:
            import imageio.v2  # noqa: F401
        except ImportError:
            raise ConfigError("--render .mp4 needs imageio and imageio-ffmpeg; use .gif or .png instead") from None
    problem = gl_problem()
    if problem is not None:
        raise ConfigError(f"--render: {problem}")


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

    def images(
        self, width: int = 480, height: int = 360, every: int = 1, pick: list[int] | None = None
    ) -> list[np.ndarray]:
        scene = self.world.scene
        assert scene is not None
        m = scene.model
        d = mujoco.MjData(m)
        cam = TRIAL_VIEW.camera()
        out = []
        with mujoco.Renderer(m, height, width) as r:
            for q in [self.frames[i] for i in pick] if pick is not None else self.frames[::every]:
                d.qpos[:] = q
                mujoco.mj_forward(m, d)
                r.update_scene(d, camera=cam)
                out.append(r.render().copy())
        return out

    def write(self, path: str) -> None:
        ext = Path(path).suffix.lower()
        if ext == ".png":
            n = 8  # two rows of four frames
            pick = sorted({round(x) for x in np.linspace(0, len(self.frames) - 1, n)}) if self.frames else []
            imgs = self.images(400, 300, pick=pick)  # the first and the last frame included
            imgs += [np.zeros((300, 400, 3), np.uint8)] * (n - len(imgs))
            strip = np.concatenate([np.concatenate(imgs[:4], axis=1), np.concatenate(imgs[4:], axis=1)], axis=0)
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
