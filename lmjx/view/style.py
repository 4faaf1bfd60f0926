"""The viewer's colours and cameras, in one place: each kind of thing has a hue of its own
(cells, edges, the arm, the selected cell), so that a picture can be read, and checked
pixel by pixel, without a legend."""

from __future__ import annotations

import numpy as np

RGB = tuple[int, int, int]

TABLE: RGB = (96, 96, 104)  # dark grey: everything else stands out on it
ARM: RGB = (236, 236, 240)  # the Panda's white
NPM: RGB = (235, 135, 15)  # cells reachable by pushing and poking only (orange)
PM: RGB = (40, 180, 80)  # cells reachable by a grasp (green)
SELECTED: RGB = (220, 30, 40)  # the selected cell (red)
TRANSIT: RGB = (150, 150, 160)  # a trial's transits (grey)
EDGE_PATH: RGB = (40, 200, 230)  # a trial's executed edges (cyan)
PUSH: RGB = (220, 30, 40)  # the target's displacement by an action (red)

CELL_HEIGHT = 0.002  # the cells' tiles [m]: thin, just over the table top
CELL_FILL = 0.86  # a tile's side as a fraction of the cell (the grid stays visible)
PATH_THICKNESS = 3.0  # edges' interaction-point paths [screen pixels]

# (position, look-at, vertical field of view [rad]) of the first view of each kind
MAP_CAMERA = ((1.35, -0.95, 1.2), (0.36, 0.06, 0.12), np.deg2rad(50.0))
# the trial's: MuJoCo's view of a trial (lmjx.sim.render.TRIAL_VIEW: look-at (0.36, 0.24, 0.22), 1.5 m
# away, azimuth 212 deg, elevation -34 deg, 45 deg field of view), from the robot's front left
TRIAL_CAMERA = ((1.415, 0.899, 1.059), (0.36, 0.24, 0.22), np.deg2rad(45.0))
AMBIENT = 1.1  # the ambient light's intensity


def colormap(values: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """(n, 3) uint8 colours of `values` from cyan (lo) to magenta (hi), linearly (matplotlib's
    "cool"); lo and hi default to the values' range."""
    v = np.asarray(values, np.float64)
    lo = float(np.nanmin(v)) if lo is None and len(v) else (lo or 0.0)
    hi = float(np.nanmax(v)) if hi is None and len(v) else (hi or 1.0)
    t = np.clip((v - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.full(len(v), 0.5)
    t = np.nan_to_num(t, nan=0.5)
    return (np.stack([t, 1.0 - t, np.ones_like(t)], axis=1) * 255).round().astype(np.uint8)


def set_camera(server, camera: tuple) -> None:
    """The first view of every browser that opens the server (and of an HTML export), and
    the lighting."""
    # no environment map (a preset's HDR picture takes software WebGL many seconds to apply, and
    # viser's default one washes the colours out): an ambient light and viser's directional ones
    server.scene.configure_environment_map(hdri=None)
    server.scene.add_light_ambient("/lights/ambient", intensity=AMBIENT)
    position, look_at, fov = camera
    server.initial_camera.position = position
    server.initial_camera.look_at = look_at
    server.initial_camera.fov = float(fov)
    server.initial_camera.up = (0.0, 0.0, 1.0)
