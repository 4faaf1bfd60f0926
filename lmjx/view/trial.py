"""The trial view: a replayed trial (`lmjx.view.replay`) in its task's scene (`lmjx.view.world`:
the table, the fixed obstacles, the goal region, the target and the other objects, and the
arm), moved over time with a time slider and play/pause, seen by a camera that frames the arm
and the scene over the whole trial (`trial_camera`).  Each action is marked: its transit (the
interaction point's path, grey), its edge (cyan) and the target's displacement (a red
arrow), shown once the action has begun.  An HTML export plays the trial back with viser's
own timeline."""

from __future__ import annotations

import threading
import time
from typing import Any

import mujoco
import numpy as np

from lmjx.view import style
from lmjx.view.legend import Page, add_legend
from lmjx.view.replay import FRAME_RATE, Replay
from lmjx.view.shapes import shown_geoms
from lmjx.view.world import draw_world, moving_bodies

SPEEDS = ("0.5x", "1x", "2x", "4x")
ROOT = "/trial"
CAMERA_FRAMES = 60  # frames of a trial whose arm and objects the camera frames, at most (evenly spaced)
LEGEND = ("arm", "target", "obstacles", "fixed", "goal", "transit", "edge", "push")


def extent_points(m: mujoco.MjModel, frames: np.ndarray, sc, picks: int = CAMERA_FRAMES) -> np.ndarray:
    """(n, 3) points that bound what a trial shows: each drawn geom of a moving body (the
    arm, the boxes) at up to `picks` of its `frames` (qpos), as its bounding sphere's extreme
    points; the goal region's corners and the fixed obstacles' tops."""
    d = mujoco.MjData(m)
    moving = set(moving_bodies(m))
    geoms = np.array([g for g in shown_geoms(m, range(m.ngeom)) if int(m.geom_bodyid[g]) in moving], np.int64)
    offsets = np.concatenate([np.eye(3), -np.eye(3)])
    out = []
    for f in np.unique(np.linspace(0, len(frames) - 1, min(picks, len(frames))).round().astype(int)):
        d.qpos[:] = frames[f]
        mujoco.mj_kinematics(m, d)
        r = m.geom_rbound[geoms][:, None, None] * offsets[None]
        out.append((d.geom_xpos[geoms][:, None] + r).reshape(-1, 3))
    gx, gy = sc.goal_center
    hx, hy = sc.goal_half
    out.append(np.array([[gx + sx * hx, gy + sy * hy, 0.0] for sx in (-1, 1) for sy in (-1, 1)]))
    for b in sc.fixed:
        out.append(np.array([[b.x, b.y, b.zc + b.half[2]], [b.x, b.y, 0.0]]))
    return np.concatenate(out)


def trial_camera(rep: Replay) -> tuple:
    """The trial's first view: from the robot's front left (`style.TRIAL_CAMERA`'s direction),
    framing the arm and the objects over the whole trial, the goal and the fixed obstacles."""
    assert rep.task is not None
    return style.fit_camera(extent_points(rep.model, rep.frames, rep.task.scenario), style.TRIAL_CAMERA)


def _cm(v: float | None) -> str:
    return "?" if v is None else f"{v * 100:.2f} cm"


def _segments(path: np.ndarray) -> np.ndarray:
    return np.stack([path[:-1], path[1:]], axis=1).astype(np.float32) if len(path) > 1 else np.zeros((0, 2, 3))


class TrialView:
    """Draws a `Replay` into a viser server's scene, with its GUI; `show(frame)` moves the
    scene to a frame.  Every scene node lives under /trial."""

    def __init__(self, server: Any, rep: Replay, at: int = 0, gui: bool = True) -> None:
        self.server = server
        self.rep = rep
        self.lock = threading.RLock()
        self.d = mujoco.MjData(rep.model)
        self.playing = False
        self.speed = 1.0
        self.position = float(at)  # the frame shown, fractional while playing
        self.last_tick = time.monotonic()
        self.slider = None
        self.camera = trial_camera(rep)
        style.set_camera(server, self.camera)
        self._draw_static()
        self._draw_marks()
        self.page = self._page()
        if gui:
            self._gui()
        self.show(at)

    @property
    def n_frames(self) -> int:
        return len(self.rep.frames)

    def _draw_static(self) -> None:
        assert self.rep.task is not None
        self.d.qpos[:] = self.rep.frames[0]
        mujoco.mj_kinematics(self.rep.model, self.d)
        drawn = draw_world(self.server, ROOT, self.rep.model, self.d, self.rep.task.scenario)
        self.frames = drawn.frames
        self.parts = drawn.parts

    def _draw_marks(self) -> None:
        scene = self.server.scene
        self.marks = []
        for a in self.rep.actions:
            base = f"{ROOT}/actions/{a.index + 1}"
            nodes = []
            if len(a.transit_path) > 1:
                nodes.append(scene.add_line_segments(f"{base}/transit", _segments(a.transit_path), colors=style.TRANSIT,
                                                     thickness=2.0, thickness_units="screen"))  # fmt: skip
            if len(a.edge_path) > 1:
                nodes.append(scene.add_line_segments(f"{base}/edge", _segments(a.edge_path), colors=style.EDGE_PATH,
                                                     thickness=3.0, thickness_units="screen"))  # fmt: skip
            lift = np.array([0.0, 0.0, 0.04])
            if np.linalg.norm(a.target_after - a.target_before) > 1e-3:
                pts = np.stack([a.target_before + lift, a.target_after + lift])[None].astype(np.float32)
                nodes.append(scene.add_arrows(f"{base}/push", pts, colors=style.PUSH, shaft_radius=0.004,
                                              head_radius=0.01, head_length=0.02))  # fmt: skip
            nodes.append(scene.add_label(f"{base}/label", f"{a.index + 1}", position=a.target_before + 2 * lift))
            self.marks.append((a, nodes))

    def _check(self) -> str:
        """Whether the replay agrees with the record, in words."""
        rep = self.rep
        bad = rep.first_disagreement()
        check = (
            "The replay agrees with the record (the target's displacement after each action)."
            if bad is None
            else f"The replay parts from the record at action {bad.index + 1}: the target moved "
            f"{bad.moved_m * 100:.2f} cm ({bad.route}), the record says {_cm(bad.recorded_moved_m)} "
            f"({bad.recorded_route or '?'}): another map, or another version of lmjx?"
        )
        if not rep.complete:
            check += f" The replay stops at action {len(rep.actions) + 1}: no transit to its edge from where it stands."
        if not rep.scene_matches:
            check += " Its scene differs from the one the record describes (another lmjx, or an edited record)."
        return check

    def _page(self) -> Page:
        r, task = self.rep.record, self.rep.task
        assert task is not None
        scene = f"scene {task.name}" + (f" ({task.scenario.title})" if task.scenario.title != task.name else "")
        lines = (f"{r.title()}", f"{scene}, robot {r.robot}, failure {r.failure}, ASM {r.asm}, seed {r.seed}",
                 self._check())  # fmt: skip
        keys = tuple(k for k in LEGEND if k in self.parts or k in ("transit", "edge", "push"))
        return Page(f"Trial {r.key}", lines, keys)

    def _gui(self) -> None:
        gui, rep = self.server.gui, self.rep
        r = rep.record
        gui.add_markdown(f"**Trial {r.title()}**  \n{r.source}  \n{self._check()}")
        add_legend(self.server, self.page)
        self.slider = gui.add_slider(
            "Time (s)", min=0.0, max=max(float(rep.times[-1]), 0.1), step=1.0 / FRAME_RATE, initial_value=0.0
        )
        play = gui.add_button("Play / pause")
        speed = gui.add_dropdown("Speed", SPEEDS, initial_value="1x")
        options = ["start", *(f"action {a.index + 1}" for a in rep.actions), "end"]
        jump = gui.add_dropdown("Go to", tuple(options), initial_value="start")
        rows = ["| # | edge | transit | target moved (replay / record) |", "| ---: | ---: | --- | --- |"]
        for a in rep.actions:
            rec = "–" if a.recorded_moved_m is None else f"{a.recorded_moved_m * 100:.1f} cm"
            rows.append(f"| {a.index + 1} | {a.edge} | {a.route} | {a.moved_m * 100:.1f} cm / {rec} |")
        with gui.add_folder("Actions", expand_by_default=False):
            gui.add_markdown("\n".join(rows))

        def moved(event: Any) -> None:
            if event.client is not None and not self.playing:  # a user moved it (not `show`)
                self.show(round(float(self.slider.value) * FRAME_RATE))

        def toggle(_: Any) -> None:
            self.playing = not self.playing
            self.last_tick = time.monotonic()
            if self.playing and self.position >= self.n_frames - 1:
                self.position = 0.0

        def goto(_: Any) -> None:
            v = jump.value
            frame = 0 if v == "start" else self.n_frames - 1 if v == "end" else rep.actions[int(v.split()[1]) - 1].start
            self.playing = False
            self.show(frame)

        self.slider.on_update(moved)
        play.on_click(toggle)
        speed.on_update(lambda _: setattr(self, "speed", float(speed.value.rstrip("x"))))
        jump.on_update(goto)

    def show(self, frame: int) -> None:
        """Move the scene to frame `frame` (clamped)."""
        with self.lock:
            frame = int(np.clip(frame, 0, self.n_frames - 1))
            self.position = float(frame)
            m = self.rep.model
            self.d.qpos[:] = self.rep.frames[frame]
            mujoco.mj_kinematics(m, self.d)
            for b, handle in self.frames.items():
                handle.position = self.d.xpos[b].copy()
                handle.wxyz = self.d.xquat[b].copy()
            for a, nodes in self.marks:
                for n in nodes:
                    n.visible = a.start <= frame
            if self.slider is not None and not self.playing:
                self.slider.value = float(self.rep.times[frame])

    def tick(self) -> None:
        """Advance a playing trial by the time since the last tick."""
        now = time.monotonic()
        dt, self.last_tick = now - self.last_tick, now
        if not self.playing:
            return
        position = min(self.position + dt * self.speed * FRAME_RATE, self.n_frames - 1)
        self.show(int(position))
        self.position = position  # (`show` keeps the whole frame)
        if self.slider is not None:
            self.slider.value = float(self.rep.times[int(position)])
        if position >= self.n_frames - 1:
            self.playing = False

    def record_playback(self, serializer: Any, every: int = 1) -> None:
        """Feed a scene serializer the whole trial, frame by frame (viser's playback timeline)."""
        for f in range(0, self.n_frames, every):
            self.show(f)
            serializer.insert_sleep(every / FRAME_RATE)
        self.show(self.n_frames - 1)
