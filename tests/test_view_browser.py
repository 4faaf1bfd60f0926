"""`lmjx view` in a real browser: headless Chromium (Debian's `chromium`) opens the view a
server serves, or the HTML export offline, and takes a screenshot; pixel checks find the
arm, the cells, the edges and the selected cell where the camera puts them (the known 3D
points projected with the view's camera), and a trial's target at its last frame; the HTML
pages of a map, a scene file and a trial are not blank, show their legend in its colours and
the whole arm.  Skipped where Chromium is not installed (test_view.py checks the scene the
server sends there)."""

from __future__ import annotations

import colorsys

import numpy as np
import pytest
from conftest import cli

viser = pytest.importorskip("viser")

import test_view  # noqa: E402

from lmjx.view import style  # noqa: E402
from lmjx.view.browser import find_chromium, screenshot  # noqa: E402

pytestmark = pytest.mark.skipif(find_chromium() is None, reason="no chromium (Debian: apt install chromium)")

trial_json = test_view.trial_json  # the fixtures: plan records of a shipped scenario and of a scene file
scene_trial_json = test_view.scene_trial_json
SIZE = (1200, 800)
PANEL_X = 850  # the GUI panel covers the window right of this


def project(points: np.ndarray, camera: tuple, size: tuple[int, int] = SIZE) -> np.ndarray:
    """(n, 2) pixel coordinates of world points seen by `camera` (position, look-at, vertical
    field of view; z up), as three.js's perspective camera projects them."""
    pos, look, fov = (np.asarray(camera[0], float), np.asarray(camera[1], float), camera[2])
    f = (look - pos) / np.linalg.norm(look - pos)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    d = np.asarray(points, float) - pos
    x, y, z = d @ r, d @ u, d @ f
    t = np.tan(fov / 2)
    w, h = size
    return np.stack([(x / (z * t * w / h) + 1) / 2 * w, (1 - y / (z * t)) / 2 * h], axis=1)


def hsv(image: np.ndarray) -> np.ndarray:
    """(h, w, 3) hue [deg], saturation, value of an RGB image."""
    flat = image.reshape(-1, 3) / 255.0
    out = np.array([colorsys.rgb_to_hsv(*p) for p in flat])
    out[:, 0] *= 360
    return out.reshape(image.shape)


def fraction_near(image: np.ndarray, pixels: np.ndarray, kind, radius: int = 3) -> float:
    """Of the points `pixels` inside the scene's part of the window, the fraction with a pixel
    of `kind` (a test on h, s, v arrays) within `radius`."""
    inside = [(int(x), int(y)) for x, y in pixels if radius <= x < PANEL_X - radius and radius <= y < SIZE[1] - radius]
    assert inside, "no point falls in the picture"
    hits = 0
    for x, y in inside:
        patch = hsv(image[y - radius : y + radius + 1, x - radius : x + radius + 1])
        hits += bool(kind(patch[..., 0], patch[..., 1], patch[..., 2]).any())
    return hits / len(inside)


def npm(h, s, v):  # the blue NPM tiles
    return (h > 185) & (h < 215) & (s > 0.3)


def edge(h, s, v):  # the edges' cyan-to-magenta paths
    return (h > 170) & (h < 320) & (s > 0.12)


def arm(h, s, v):  # the orange arm, shaded (not the yellow target)
    return (h > 12) & (h < 38) & (s > 0.55) & (v > 0.25)


def selected(h, s, v):
    return ((h < 15) | (h > 345)) & (s > 0.5)


@pytest.fixture
def served():
    """Serve a view in this process: start(view_maker) -> url; stopped after the test."""
    from lmjx.view.server import start_server, stop_server, url_of

    servers = []

    def start(make):
        s = start_server("127.0.0.1", 0, "lmjx")
        servers.append(s)
        make(s)
        return url_of(s).replace("localhost", "127.0.0.1")

    yield start
    for s in servers:
        stop_server(s)


def test_map_with_a_selected_cell_in_chromium(small_map, served, tmp_path, robot):
    from PIL import Image

    from lmjx.planner.clearance import park_pose
    from lmjx.view.map import MapView, MapViewSettings, robot_qpos
    from lmjx.view.mapdata import MapData
    from lmjx.view.shapes import ArmPoser, arm_geoms

    data = MapData(small_map)
    views = []
    url = served(lambda s: views.append(MapView(s, data, MapViewSettings(cap=60))))
    shot = screenshot(url, tmp_path / "map.png", size=SIZE)
    image = np.asarray(Image.open(shot).convert("RGB"))
    sel = views[0].selected

    iy, ix = np.nonzero(data.labels_smooth == 1)
    far = np.hypot(data.xs[ix] - data.xs[sel.ix], data.ys[iy] - data.ys[sel.iy]) > 0.15  # away from the edges
    tiles = np.stack([data.xs[ix], data.ys[iy], np.full(len(ix), style.CELL_HEIGHT)], axis=1)[far]
    camera = views[0].camera
    assert fraction_near(image, project(tiles, camera), npm, radius=2) > 0.9

    middles = np.array([p[len(p) // 2] for p in sel.p])
    assert fraction_near(image, project(middles, camera), edge) > 0.7

    m = robot.mj
    poser = ArmPoser(m, robot_qpos(robot), arm_geoms(m, {m.body(b).name for b in range(1, m.nbody)}))
    centres, _ = poser.poses(park_pose(robot, data.failure))
    assert fraction_near(image, project(centres, camera), arm) > 0.8

    cell = np.array([[data.xs[sel.ix], data.ys[sel.iy], style.CELL_HEIGHT]])
    assert fraction_near(image, project(cell, camera), selected, radius=4) == 1.0
    # and no tile where the map has none: the unreachable cells two cells or more from a reachable one
    reach = data.labels_smooth >= 1
    near = reach.copy()
    for dy in (-2, -1, 0, 1, 2):
        for dx in (-2, -1, 0, 1, 2):
            near |= np.roll(np.roll(reach, dy, axis=0), dx, axis=1)
    uy, ux = np.nonzero(~near)
    empty = np.stack([data.xs[ux], data.ys[uy], np.full(len(ux), style.CELL_HEIGHT)], axis=1)
    assert len(empty) > 20
    assert fraction_near(image, project(empty, camera), npm, radius=1) < 0.05
    data.close()


def test_trial_at_its_last_frame_in_chromium(trial_json, plan_map, robot, served, tmp_path):
    from PIL import Image

    from lmjx.mapfile.read import load_map
    from lmjx.view.replay import replay
    from lmjx.view.trial import TrialView
    from lmjx.view.trialrecord import read_trial

    with load_map(plan_map, lazy=True) as m:
        rep = replay(robot, m, read_trial(trial_json, None))
    views = []
    url = served(lambda s: views.append(TrialView(s, rep, at=len(rep.frames) - 1)))
    image = np.asarray(Image.open(screenshot(url, tmp_path / "trial.png", size=SIZE)).convert("RGB"))

    def target(h, s, v):  # the yellow cube
        return (h > 35) & (h < 65) & (s > 0.5) & (v > 0.4)

    def goal(h, s, v):  # the green goal region
        return (h > 100) & (h < 150) & (s > 0.4)

    sc = rep.task.scenario
    camera = views[0].camera
    end = rep.actions[-1].target_after
    # the cube at its last place: the arm that pushed it there hides part of it from this camera
    assert fraction_near(image, project(end[None], camera), target, radius=20) == 1.0
    start = rep.actions[0].target_before
    if np.hypot(*(end - start)[:2]) > 0.08:  # where it stood at first, no cube now
        assert fraction_near(image, project(start[None], camera), target, radius=3) == 0.0
    corners = np.array([[sc.goal_center[0] + sx * sc.goal_half[0] * 0.7, sc.goal_center[1] + sy * sc.goal_half[1] * 0.7,
                         0.001] for sx in (-1, 1) for sy in (-1, 1)])  # fmt: skip
    assert fraction_near(image, project(corners, camera), goal, radius=6) >= 0.5  # (objects on it)
    # the arm where the last frame has it
    from lmjx.view.map import robot_qpos
    from lmjx.view.shapes import ArmPoser, arm_geoms

    m = robot.mj
    poser = ArmPoser(m, robot_qpos(robot), arm_geoms(m, {m.body(b).name for b in range(1, m.nbody)}))
    centres, _ = poser.poses(rep.frames[-1][rep.robot_qpos])
    assert fraction_near(image, project(centres, camera), arm) > 0.7


LEGEND_BOX = (480, 360)  # the export's legend lies within this corner (width, height) at the top left
BAR = 42  # the height of the playback bar at the bottom of a trial's export


def check_page(image: np.ndarray, legend: tuple[str, ...]) -> None:
    """A page's screenshot: a scene drawn beside the legend (not blank), the legend's colour
    squares in their exact colours, and no pixel of the arm on the window's border (nothing of
    it cut off)."""
    w, h = LEGEND_BOX
    scene = np.concatenate([image[h:, :].reshape(-1, 3), image[:h, w:].reshape(-1, 3)])
    assert scene.std(axis=0).mean() > 20 and len(np.unique(scene // 16, axis=0)) > 30, "a blank page"
    corner = image[:h, :w].reshape(-1, 3).astype(int)
    for key in legend:
        rgb = np.array([int(v) for v in style.SWATCHES[key].css[4:-1].split(",")])
        assert (np.abs(corner - rgb).max(axis=1) <= 2).sum() >= 60, f"the legend's {key} square is missing"
    from matplotlib.colors import rgb_to_hsv

    a = rgb_to_hsv(image[..., :3] / 255.0) * np.array([360.0, 1.0, 1.0])  # (the whole window at once)
    is_arm = arm(a[..., 0], a[..., 1], a[..., 2])
    H = is_arm.shape[0]
    assert is_arm.sum() > 2000, "no arm"
    border = np.zeros_like(is_arm)
    border[:4], border[:, :4], border[:, -4:], border[H - BAR - 6 : H - BAR] = True, True, True, True
    assert not (is_arm & border).any(), "the arm is cut off"


@pytest.fixture(scope="module")
def pages(small_map, plan_map, scene_trial_json, tmp_path_factory):
    """The HTML exports of a map, a scene file over a map, and a trial of that scene file,
    each with its screenshot (window size SIZE)."""
    folder = tmp_path_factory.mktemp("pages")
    made = {
        "map": (small_map, "--edges", "30"),
        "scene": (test_view.BENCH, "--map", plan_map),
        "trial": (scene_trial_json, "--map", plan_map),
    }
    shots = {}
    for name, args in made.items():
        out = folder / f"{name}.html"
        cli("view", *args, "--html", out).ok()
        shots[name] = screenshot(out.resolve().as_uri(), folder / f"{name}.png", size=SIZE)
    return shots


@pytest.mark.parametrize(
    "page,legend",
    [
        ("map", ("pm", "npm", "unreachable", "arm", "selected")),
        ("scene", ("pm", "npm", "unreachable", "arm", "target", "obstacles", "fixed", "goal")),
        ("trial", ("arm", "target", "obstacles", "fixed", "goal", "transit", "edge", "push")),
    ],
)
def test_html_pages_are_readable_alone_in_chromium(pages, page, legend):
    from PIL import Image

    check_page(np.asarray(Image.open(pages[page]).convert("RGB")), legend)
