"""The planner's simulator on a CUDA GPU: MuJoCo Warp, as shipped inside mujoco-mjx.

`GpuSimulator` implements the `simulate.Simulator` interface on the scene the CPU simulator
runs (every object, the table as a box, the planner's physics), with three changes that
alter no physics:
  * box-box contacts use MuJoCo's primitive box-box collider (`mjDSBL_NATIVECCD` on the
    device model), which is what C MuJoCo uses for box pairs whatever that flag says;
    MuJoCo Warp's default for box pairs is its convex (GJK/EPA) path, measured 0.5 cm
    (median) off C MuJoCo where the primitive path is 1e-6 m off;
  * the caller may fuse the robot's jointless bodies into their parents
    (`scene.build_scene(fuse_static=True)`): the same rigid bodies in a shallower tree;
  * objects start 0.1 micrometre lower (`SETTLE_NUDGE`): resting exactly on the table, they
    would float above it after rounding to float32 and miss their first contacts.
tests/test_simulate_gpu.py checks both facts and the agreement with C MuJoCo.

How a batch of candidate actions is rolled out:
  * candidates are padded to one of a few fixed batch sizes (`GpuSimConfig.buckets`); for
    each size one device `Data` of that many worlds is made and two CUDA graphs are
    captured (`segment` physics steps, and one step), once per scene and size, and reused
    by every later call, decision and trial;
  * a captured step computes every world's servo controls on the device from its action's
    control points (`kernels.warp_rollout.set_controls`: the interpolation of
    `actions.controls`), runs `mujoco_warp.step`, and advances a step counter held on the
    device, so relaunching a graph needs nothing from the host;
  * a rollout is `steps // segment` launches of the long graph and the rest as single
    steps, for the batch's longest action; every other world's result is kept at the step
    its own action (and settle time) ends, as C MuJoCo's is, so no result depends on what
    else shares the batch;
  * each world may start from its own state (`simulate_many`: several decisions, possibly
    of several trials, in one batch);
  * overflowing contact or constraint buffers are detected per world (MuJoCo Warp's
    overflow bits) and the batch is rolled out again with larger buffers, never silently
    wrong.
Capture and compilation time is kept apart (`capture_seconds`) from run time.
Nothing here plans: `lmjx.planner.edge_planner` decides what to simulate.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, replace

import mujoco
import numpy as np

from lmjx.errors import ConfigError
from lmjx.sim.controls import control_points
from lmjx.sim.scene import Scene, set_state
from lmjx.types import CONTROL_DT, Action

MAX_REGROWTH = 4
# The planner places what it observes exactly at rest on the table (zero distance: C MuJoCo
# makes the contacts there).  In float32 such a box's height rounds up to a fraction of a
# nanometre above the table and MuJoCo Warp finds no contact in the first step: the box
# drops, and a pushed one ends millimetres from where C MuJoCo's does.  Lowering every
# object by this much at the start puts both on the same side of the tie.
SETTLE_NUDGE = 1e-7  # [m]
# MuJoCo Warp's overflow bits (mujoco_warp.OverflowType) that mean a buffer was too small
ROWS_OVERFLOW = (1 << 0) | (1 << 1)  # NEFC, NJMAX_NNZ: constraint rows (njmax)
CONTACTS_OVERFLOW = (1 << 2) | (1 << 3) | (1 << 4)  # BROADPHASE, NARROWPHASE, CCD: contacts (naconmax)


@dataclass(frozen=True)
class GpuSimConfig:
    """How the GPU simulator lays out its work (not physics: that is the scene's)."""

    buckets: tuple[int, ...] = (256, 1024, 4096)  # batch sizes candidates are padded to
    segment: int = 32  # physics steps per captured graph
    contacts_per_world: int = 96  # contact buffer (all worlds share naconmax = this x worlds)
    rows_per_world: int = 400  # constraint rows per world (njmax)
    native_ccd: bool = False  # box-box through the convex (GJK/EPA) path instead of the primitive one
    device: str | None = None  # a Warp device ("cuda:0"); None: the first CUDA device

    def validate(self) -> None:
        if not self.buckets or any(b < 1 for b in self.buckets) or list(self.buckets) != sorted(self.buckets):
            raise ConfigError(f"GPU batch sizes must be positive and increasing, got {self.buckets}")
        if self.segment < 1 or self.contacts_per_world < 1 or self.rows_per_world < 1:
            raise ConfigError("segment, contacts_per_world and rows_per_world must be positive")


def warp_problem() -> str | None:
    """Why the GPU simulator cannot run here (None when it can).  The CUDA driver is looked
    for first: importing MuJoCo Warp takes seconds, which a machine without CUDA need not pay."""
    import importlib.util

    if importlib.util.find_spec("warp") is None:
        return "warp-lang is not installed (pip install -e '.[gpu]')"
    if not _cuda_driver():
        return "no NVIDIA CUDA driver on this machine"
    import warp as wp

    try:
        from mujoco.mjx.third_party import mujoco_warp  # noqa: F401
    except ImportError as e:
        return f"MuJoCo Warp is missing from mujoco-mjx ({e})"
    from lmjx.runtime.cache import configure_warp

    configure_warp()
    wp.config.log_level = wp.LOG_WARNING
    try:
        wp.init()
        n = wp.get_cuda_device_count()
    except Exception as e:  # the driver or toolkit refused: say so in one line
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        return f"Warp cannot start ({type(e).__name__}: {first})"
    if n == 0:
        return "no CUDA GPU is visible to Warp"
    return None


def _cuda_driver() -> bool:
    """Whether the CUDA driver library loads (asked before Warp, which complains without one)."""
    import ctypes

    for name in ("libcuda.so.1", "libcuda.so"):
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


class _Batch:
    """One batch size: its device Data, control and start buffers, and captured graphs."""

    def __init__(self, sim: GpuSimulator, worlds: int, points: int) -> None:
        import warp as wp
        from mujoco.mjx.third_party import mujoco_warp as mjw

        from kernels.warp_rollout import advance, keep_final, set_controls

        self.worlds = worlds
        self.points = points
        dev = sim.device
        nj = sim.nj
        host = mujoco.MjData(sim.mjm)  # no contacts yet: every state is set on the device later
        # the device model's own MjModel: its options decide which buffers Data needs
        self.d = mjw.put_data(
            sim.mjm,
            host,
            nworld=worlds,
            naconmax=sim.config.contacts_per_world * worlds,
            njmax=sim.config.rows_per_world,
        )
        self.step = wp.zeros(1, dtype=wp.int32, device=dev)
        self.q_pts = wp.zeros((worlds, points + 1, nj), dtype=wp.float32, device=dev)
        self.qd_pts = wp.zeros((worlds, points, nj), dtype=wp.float32, device=dev)
        self.n_pts = wp.zeros(worlds, dtype=wp.int32, device=dev)
        self.ends = wp.zeros(worlds, dtype=wp.int32, device=dev)
        self.final = wp.zeros((worlds, sim.mjm.nq), dtype=wp.float32, device=dev)
        self.qpos0 = wp.zeros((worlds, sim.mjm.nq), dtype=wp.float32, device=dev)
        self.ctrl0 = wp.zeros((worlds, sim.mjm.nu), dtype=wp.float32, device=dev)

        def steps(n: int) -> None:
            for _ in range(n):
                wp.launch(
                    set_controls,
                    dim=worlds,
                    inputs=[self.step, self.q_pts, self.qd_pts, self.n_pts, sim.sub, nj],
                    outputs=[self.d.ctrl],
                    device=dev,
                )
                mjw.step(sim.m, self.d)
                wp.launch(keep_final, dim=worlds, inputs=[self.step, self.ends, self.d.qpos], outputs=[self.final],
                          device=dev)  # fmt: skip
                wp.launch(advance, dim=1, inputs=[self.step], device=dev)

        self.graphs = {}
        for n in sorted({sim.config.segment, 1}):
            with wp.ScopedCapture(device=dev) as cap:
                steps(n)
            self.graphs[n] = cap.graph

    def run(self, n: int, segment: int) -> None:
        import warp as wp

        for _ in range(n // segment):
            wp.capture_launch(self.graphs[segment])
        for _ in range(n % segment):
            wp.capture_launch(self.graphs[1])


class GpuSimulator:
    """Batched rollouts of candidate actions with MuJoCo Warp on a CUDA GPU.

    Args:
      scene: the planner's scene (`scene.build_scene`); simulated whole.
      settle: seconds of holding the final pose after each action.
      config: batch sizes, graph length, buffer sizes, device.
    """

    name = "gpu"
    prefers_batches = True  # a batch of many costs about as much as one candidate

    def __init__(self, scene: Scene, settle: float = 0.5, config: GpuSimConfig | None = None) -> None:
        import warp as wp
        from mujoco.mjx.third_party import mujoco_warp as mjw

        from lmjx.runtime.cache import configure_warp

        self.config = config or GpuSimConfig()
        self.config.validate()
        configure_warp()
        wp.config.log_level = wp.LOG_WARNING
        wp.init()
        self.device = wp.get_device(self.config.device or ("cuda:0" if wp.get_cuda_device_count() else "cpu"))
        self.scene = scene
        self.settle = settle
        self.nj = len(scene.robot_qpos)
        self.physics_dt = float(scene.model.opt.timestep)
        self.sub = round(CONTROL_DT / self.physics_dt)  # physics steps per control point
        self.mjm = copy.copy(scene.model)
        if not self.config.native_ccd:
            # C MuJoCo collides box pairs with its primitive box-box routine; MuJoCo Warp does
            # the same only with native CCD off (which it reads for box pairs alone: a scene's
            # cylinders keep its convex GJK/EPA path).
            self.mjm.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_NATIVECCD
        t0 = time.perf_counter()
        with wp.ScopedDevice(self.device):
            self.m = mjw.put_model(self.mjm)
            self.m.opt.warn_overflow = 0  # overflow is read per world and acted on, not printed
        self.capture_seconds = time.perf_counter() - t0
        self._batches: dict[int, _Batch] = {}
        self._host = mujoco.MjData(scene.model)
        self.steps_run = 0  # candidate physics steps simulated (padding worlds not counted)
        self.reruns = 0  # batches rolled out again with larger buffers after an overflow

    @property
    def description(self) -> str:
        return f"MuJoCo Warp on {self.device.name}, whole scene ({self.scene.n_objects} objects)"

    @property
    def full_batch(self) -> int:
        """Candidates that fill the largest batch (`lmjx.evaluation.lockstep` simulates the
        waiting requests at once when they reach it)."""
        return self.config.buckets[-1]

    def bucket(self, n: int) -> int:
        """The batch size n candidates are padded to (the largest size for more)."""
        return next((b for b in self.config.buckets if n <= b), self.config.buckets[-1])

    def _batch(self, worlds: int, points: int) -> _Batch:
        import warp as wp

        b = self._batches.get(worlds)
        if b is None or b.points < points:
            t0 = time.perf_counter()
            capacity = 1 << math.ceil(math.log2(max(points, 2 * b.points if b else 256)))
            with wp.ScopedDevice(self.device):
                b = _Batch(self, worlds, capacity)
            self._batches[worlds] = b
            self.capture_seconds += time.perf_counter() - t0
        return b

    def prepare(self, worlds: int, points: int = 256) -> float:
        """Capture the graphs for the batch size of `worlds` candidates now (seconds taken)."""
        before = self.capture_seconds
        self._batch(self.bucket(worlds), points)
        return self.capture_seconds - before

    def simulate(self, robot_q: np.ndarray, obj_qpos: np.ndarray, actions: list[Action]) -> np.ndarray:
        """Final object qpos (len(actions), n_objects, 7) after each action and the settle time."""
        return self.simulate_many([(robot_q, obj_qpos, actions)])[0]

    def simulate_many(self, requests: list[tuple[np.ndarray, np.ndarray, list[Action]]]) -> list[np.ndarray]:
        """`simulate` for several start states at once: all their candidates in one batch
        (more than the largest batch size: several, of candidates of similar length, so that
        few worlds idle while the longest action of their batch finishes)."""
        starts, acts = [], []
        heights = self.scene.obj_qpos + 2
        for robot_q, obj_qpos, actions in requests:
            set_state(self.scene, self._host, robot_q, obj_qpos)
            qpos = self._host.qpos.copy()
            qpos[heights] -= SETTLE_NUDGE
            starts += [(qpos, self._host.ctrl.copy())] * len(actions)
            acts += actions
        n = len(acts)
        out = np.empty((n, self.scene.model.nq))
        if n:
            q_pts, qd_pts, n_pts = control_points(acts)
            qpos0 = np.stack([s[0] for s in starts])
            ctrl0 = np.stack([s[1] for s in starts])
            size = self.bucket(n)
            order = np.argsort(n_pts, kind="stable") if n > size else np.arange(n)
            for a in range(0, n, size):
                idx = order[a : a + size]
                out[idx] = self._rollout(qpos0[idx], ctrl0[idx], q_pts[idx], qd_pts[idx], n_pts[idx], size)
        objects = np.stack([out[:, a : a + 7] for a in self.scene.obj_qpos], axis=1) if n else out
        results, at = [], 0
        for _, obj_qpos, actions in requests:
            k = len(actions)
            results.append(objects[at : at + k] if k else np.zeros((0, len(obj_qpos), 7)))
            at += k
        return results

    def _rollout(
        self,
        qpos0: np.ndarray,
        ctrl0: np.ndarray,
        q_pts: np.ndarray,
        qd_pts: np.ndarray,
        n_pts: np.ndarray,
        size: int,
    ) -> np.ndarray:
        """Final qpos (k, nq) of k <= size candidates rolled out in a batch of `size` worlds;
        padding worlds repeat the first candidate and are dropped."""
        import warp as wp

        from kernels.warp_rollout import start_state

        k = len(n_pts)
        last = int(n_pts.max())
        ends = n_pts * self.sub + round(self.settle / self.physics_dt)  # each candidate's own steps
        steps = int(ends.max())
        pad = np.r_[np.arange(k), np.zeros(size - k, int)]
        for _ in range(MAX_REGROWTH + 1):
            b = self._batch(size, last)
            q_all = np.zeros((size, b.points + 1, self.nj), np.float32)
            qd_all = np.zeros((size, b.points, self.nj), np.float32)
            q_all[:, : last + 1] = q_pts[pad, : last + 1]
            qd_all[:, :last] = qd_pts[pad, :last]
            with wp.ScopedDevice(self.device):
                b.q_pts.assign(q_all)
                b.qd_pts.assign(qd_all)
                b.n_pts.assign(n_pts[pad].astype(np.int32))
                b.ends.assign(ends[pad].astype(np.int32))
                b.qpos0.assign(qpos0[pad].astype(np.float32))
                b.ctrl0.assign(ctrl0[pad].astype(np.float32))
                b.step.zero_()
                d = b.d
                wp.launch(
                    start_state,
                    dim=size,
                    inputs=[b.qpos0, b.ctrl0],
                    outputs=[d.qpos, d.qvel, d.act, d.qacc_warmstart, d.ctrl, d.time, d.overflow],
                )
                b.run(steps, self.config.segment)
                qpos = b.final.numpy()[:k].astype(np.float64)
                overflow = int(np.bitwise_or.reduce(d.overflow.numpy()))
                rows_seen = int(d.nefc.numpy().max())  # at the last step: a floor for what is needed
                contacts_seen = int(d.nacon.numpy()[0]) // size
            self.steps_run += k * steps
            grow_rows = bool(overflow & ROWS_OVERFLOW)
            grow_contacts = bool(overflow & CONTACTS_OVERFLOW)
            if not (grow_rows or grow_contacts):
                return qpos
            # a buffer was too small for some world: grow it and roll the batch out again
            self.reruns += 1
            cfg = self.config
            self.config = replace(
                cfg,
                rows_per_world=max(2 * cfg.rows_per_world, rows_seen * 5 // 4) if grow_rows else cfg.rows_per_world,
                contacts_per_world=max(2 * cfg.contacts_per_world, contacts_seen * 5 // 4)
                if grow_contacts
                else cfg.contacts_per_world,
            )
            self._batches.clear()
        raise RuntimeError(f"MuJoCo Warp overflowed its buffers after growing them {MAX_REGROWTH} times")
