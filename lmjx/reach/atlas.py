"""The failure atlas: the Reach-Ability map's PM and NPM+PM areas for every set of 2 and 3
locked joints of a robot (the Panda by default), at K lock angles per locked joint.

Every map is computed as `lmjx.reach.reachability` computes one (same grid, attempts, restarts, interaction
points, acceptance checks and smoothing; strategy "rounds": attempt by attempt, only the cells
still unlabelled go on), but by one program for every failure: all seven joints are solved
for (as many as the robot has) and a 0/1 mask says which are locked (`kernels.ik.ik_solve(free_mask=...)`), so cells of
many maps share every launch; an item (map, cell, attempt) draws its own perturbation and
restarts on the device (`kernels.atlas_cell`); and the batch axis is split over every device
of every process (`lmjx.runtime.sharding`).

Lock angles: the range of joint j is cut into K equal bins and one angle is drawn uniformly in
each (seeded), the same K angles for joint j in every subset.  A subset of s joints gets the
K^s combinations: for the Panda's 7 joints 21 x 9 + 35 x 27 = 1,134 maps at K = 3, for the
UR5e's 6 joints 15 x 9 + 20 x 27 = 675.

Randomness: every (map, attempt, cell) draws its target perturbation and restart angles from
a counter-based key (seed, map number, attempt, cell), so a map's labels do not depend on
which maps share its launches, on the group size, on the chunk size, on the number of
devices or processes, or on a resumed run.

Resumable: after every group of maps the whole atlas so far is written (atomically) to
`<out>.partial`; a rerun with the same parameters picks it up and computes only the groups
not in it; the finished atlas is renamed to `<out>`.  In a multi-process run, process 0
reads and writes the files and tells the others what is done.
"""

from __future__ import annotations

import itertools
import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from lmjx.errors import ConfigError
from lmjx.mapfile.h5 import h5open
from lmjx.model.robot import Robot
from lmjx.reach.ik_batch import device_description
from lmjx.reach.reachability import NPM, PM, UNREACHABLE, ReachConfig, attempt_plan, smooth_labels
from lmjx.runtime.fileio import atomic_path, check_writable
from lmjx.runtime.progress import Progress

SCHEMA = "lmjx-atlas"
VERSION = 1
MAX_LOCKED = 3


@dataclass(frozen=True)
class AtlasConfig:
    sizes: tuple[int, ...] = (2, 3)  # numbers of locked joints
    angles: int = 3  # K lock angles per locked joint
    seed: int = 0
    group: int = 256  # maps per series of launches and per checkpoint (not part of the content)
    reach: ReachConfig = field(default_factory=ReachConfig)

    def validate(self, robot: Robot) -> None:
        if not self.sizes or any(s not in (1, 2, 3) for s in self.sizes) or len(set(self.sizes)) != len(self.sizes):
            raise ConfigError(f"--joints must list distinct numbers of locked joints among 1, 2, 3, got {self.sizes}")
        if not 1 <= self.angles <= 12:
            raise ConfigError(f"--angles must be 1..12, got {self.angles}")
        if self.group < 1:
            raise ConfigError(f"--group must be positive, got {self.group}")
        self.reach.validate(robot)

    def params(self) -> dict:
        """What defines the atlas's content (stored in the file; a resume must match)."""
        r = asdict(self.reach)
        for k in ("strategy", "chunk", "traced_locks"):  # how, not what
            r.pop(k)
        return {"sizes": list(self.sizes), "angles": self.angles, "seed": self.seed, "reach": r}


def lock_angles(robot: Robot, k: int, seed: int) -> np.ndarray:
    """(nq, K) lock angles: one uniform draw in each of K equal bins of each joint's range."""
    rng = np.random.default_rng([seed, 7919])
    u = rng.random((robot.nq, k))
    lo, hi = robot.lower[:, None], robot.upper[:, None]
    return lo + (np.arange(k)[None, :] + u) / k * (hi - lo)


def entries(robot: Robot, config: AtlasConfig) -> tuple[np.ndarray, np.ndarray]:
    """Every map of the atlas, in order: locked joints (N, 3) 1-based with -1 padding, and
    their angles (N, 3) with NaN padding."""
    table = lock_angles(robot, config.angles, config.seed)
    joints, angles = [], []
    for s in sorted(config.sizes):
        for subset in itertools.combinations(range(1, robot.nq + 1), s):
            for idx in itertools.product(range(config.angles), repeat=s):
                joints.append(list(subset) + [-1] * (MAX_LOCKED - s))
                angles.append([table[j - 1, i] for j, i in zip(subset, idx, strict=True)] + [np.nan] * (MAX_LOCKED - s))
    return np.array(joints, np.int8), np.array(angles, np.float64)


@dataclass
class AtlasState:
    """The atlas so far (what the file holds)."""

    config: AtlasConfig
    joints: np.ndarray  # (N, 3) int8
    angles: np.ndarray  # (N, 3)
    xs: np.ndarray
    ys: np.ndarray
    labels: np.ndarray  # (N, ny, nx) int8 raw
    labels_smooth: np.ndarray  # (N, ny, nx) int8
    done: np.ndarray  # (N,) bool
    robot_hash: str
    robot: str = "panda"  # the robot's name (a shipped robot's, or a user MJCF's model name)
    run: dict = field(default_factory=dict)  # how it was computed (device, times): not content

    @property
    def n(self) -> int:
        return len(self.joints)

    def areas(self, smooth: bool = True) -> dict[str, np.ndarray]:
        lab = self.labels_smooth if smooth else self.labels
        a = self.config.reach.cell**2
        return {
            "pm": (lab == PM).sum(axis=(1, 2)) * a,
            "npm_pm": (lab >= NPM).sum(axis=(1, 2)) * a,
        }

    def spec(self, i: int) -> str:
        return ",".join(f"J{j}={a:.4f}" for j, a in zip(self.joints[i], self.angles[i], strict=True) if j > 0)


def empty_state(robot: Robot, config: AtlasConfig) -> AtlasState:
    joints, angles = entries(robot, config)
    xs, ys = config.reach.grid()
    n = len(joints)
    shape = (n, len(ys), len(xs))
    return AtlasState(
        config, joints, angles, xs, ys, np.full(shape, -1, np.int8), np.full(shape, -1, np.int8),
        np.zeros(n, bool), robot.model_hash, _robot_name(robot),
    )  # fmt: skip


def _robot_name(robot: Robot) -> str:
    from lmjx.model.robot import ROBOTS

    return robot.key if robot.key in ROBOTS else robot.name


def write_atlas(path: str | Path, st: AtlasState) -> None:
    """The atlas to HDF5, atomically."""
    with atomic_path(path) as tmp, h5open(tmp, "w") as f:
        f.attrs["schema"] = SCHEMA
        f.attrs["version"] = VERSION
        f.attrs["params"] = json.dumps(st.config.params(), sort_keys=True)
        f.attrs["robot_hash"] = st.robot_hash
        f.attrs["robot"] = st.robot
        f.attrs["complete"] = bool(st.done.all())
        f.attrs["cell_m"] = st.config.reach.cell
        f["xs"], f["ys"] = st.xs, st.ys
        f["locked_joints"] = st.joints
        f["lock_angles"] = st.angles
        f["done"] = st.done
        opts = {"compression": "gzip", "compression_opts": 4, "chunks": (1, *st.labels.shape[1:])}
        f.create_dataset("labels", data=st.labels, **opts)
        f.create_dataset("labels_smooth", data=st.labels_smooth, **opts)
        for smooth, name in ((True, "area"), (False, "area_raw")):
            for k, v in st.areas(smooth).items():
                f[f"{name}_{k}_m2"] = np.where(st.done, v, np.nan)
        g = f.create_group("run")  # how, not what: differs between runs of the same atlas
        g.attrs["json"] = json.dumps(st.run, sort_keys=True)


def read_atlas(path: str | Path, robot: Robot | None = None) -> AtlasState:
    p = Path(path)
    if not p.exists():
        raise ConfigError(f"no atlas at {p}")
    try:
        f = h5open(p, "r")
    except OSError as e:
        raise ConfigError(f"{p} is not an HDF5 file ({e})") from None
    with f:
        if f.attrs.get("schema") != SCHEMA:
            raise ConfigError(f"{p} is not an lmjx atlas (schema {f.attrs.get('schema')!r})")
        params = json.loads(f.attrs["params"])
        reach = ReachConfig(**{**params["reach"], **_tuples(params["reach"])})
        config = AtlasConfig(tuple(params["sizes"]), params["angles"], params["seed"], reach=reach)
        name = str(f.attrs.get("robot", "panda"))
        if robot is not None and name != _robot_name(robot):
            raise ConfigError(f"{p} is an atlas of the robot '{name}', not '{_robot_name(robot)}'")
        return AtlasState(
            config, f["locked_joints"][...], f["lock_angles"][...], f["xs"][...], f["ys"][...], f["labels"][...],
            f["labels_smooth"][...], f["done"][...], str(f.attrs["robot_hash"]), name,
            json.loads(f["run"].attrs["json"]),
        )  # fmt: skip


def _tuples(d: dict) -> dict:
    return {k: tuple(v) for k, v in d.items() if isinstance(v, list)}


class AtlasRunner:
    """Computes the maps of an atlas, group by group: per attempt, one batch of (map, cell)
    items over every cell still unlabelled, each item solved whole on the device
    (`kernels.atlas_cell`)."""

    def __init__(self, robot: Robot, config: AtlasConfig, sharded: bool = True) -> None:
        from functools import partial

        from kernels.atlas_cell import atlas_cell
        from lmjx.runtime.batching import ChunkedKernel

        self.robot = robot
        self.config = config
        rc = config.reach
        sites, attempt_site, attempt_pm, z_lo, z_hi = attempt_plan(robot, rc)
        xs, ys = rc.grid()
        gx, gy = np.meshgrid(xs, ys)
        centres = np.stack([gx.ravel(), gy.ravel()], axis=-1).astype(np.float32)
        self.n_cells = len(centres)
        eps = rc.cell / 2 if rc.epsilon is None else rc.epsilon
        joints, angles = entries(robot, config)
        masks = np.ones((len(joints), robot.nq), np.float32)
        locks = np.zeros((len(joints), robot.nq), np.float32)
        for i, (js, ang) in enumerate(zip(joints, angles, strict=True)):
            for j, v in zip(js, ang, strict=True):
                if j > 0:
                    masks[i, j - 1] = 0.0
                    locks[i, j - 1] = v
        settings = rc.ik_settings()
        one = partial(
            atlas_cell, robot.arm, settings, sites, rc.seed * 1_000_003 + config.seed, rc.restarts, float(eps),
            attempt_site, attempt_pm, z_lo, z_hi,
        )  # fmt: skip
        key = (
            "atlas-cell", robot.model_hash, sites, settings, rc.seed, config.seed, rc.restarts, float(eps),
            tuple(attempt_site), tuple(attempt_pm), tuple(z_lo), tuple(z_hi), masks.shape, centres.shape,
        )  # fmt: skip
        # Items are cells (M restarts each): modest chunks per device, since the rounds shrink
        # from attempt to attempt and a chunk padded far beyond its items is wasted work.
        from lmjx.runtime.batching import backend

        chunk = rc.chunk or (1 << 13 if backend() != "cpu" else 512)
        inputs = [(np.int32, ()), (np.int32, ()), (np.int32, ())]
        self.kernel = ChunkedKernel(key, one, [masks, locks, centres], inputs, chunk, sharded=sharded)

    @property
    def compile_seconds(self) -> float:
        return self.kernel.compile_seconds

    def run_group(self, st: AtlasState, ids: np.ndarray, progress: Progress | None = None) -> None:
        """Compute maps `ids` into `st`."""
        rc = self.config.reach
        best = np.full((len(ids), self.n_cells), -1, np.int32)
        for a in range(rc.attempts):
            rows, cells = np.nonzero(best < 0)
            if len(rows) == 0:
                break
            res = self.kernel.run(ids[rows].astype(np.int32), cells.astype(np.int32), np.full(len(rows), a, np.int32))
            hit = res["hit"]
            best[rows[hit], cells[hit]] = a
        lab = np.where(best < 0, UNREACHABLE, np.where(best < rc.n_pm, PM, NPM)).astype(np.int8)
        ny, nx = len(st.ys), len(st.xs)
        for r, i in enumerate(ids):
            st.labels[i] = lab[r].reshape(ny, nx)
            st.labels_smooth[i] = smooth_labels(st.labels[i], rc.fill_neighbors)
            st.done[i] = True
        if progress is not None:
            progress.update(len(ids))


def build_atlas(
    robot: Robot,
    config: AtlasConfig,
    out: str | Path,
    progress: bool = True,
    sharded: bool = True,
    say: Callable[[str], None] | None = None,
) -> AtlasState:
    """Compute (or finish) the atlas into `out`; `say` is told in one line when an earlier
    run's maps are kept (a resumed run)."""
    import jax

    config.validate(robot)
    out = Path(out)
    partial = out.with_name(out.name + ".partial")
    lead = jax.process_index() == 0
    if lead:
        check_writable(out, "atlas")
    st = empty_state(robot, config)
    for src in (out, partial):
        if lead and src.exists():
            old = read_atlas(src, robot)
            old.config = replace(old.config, group=config.group)
            if old.config.params() != config.params() or old.robot_hash != robot.model_hash:
                raise ConfigError(
                    f"{src} holds an atlas with other parameters (or another robot model); "
                    "choose another --out or remove it"
                )
            st = old
            if say is not None and st.done.any():
                say(f"resuming the atlas kept in {src}: {int(st.done.sum())} of {st.n} maps already computed")
            break
    if jax.process_count() > 1:  # everyone follows process 0's record of what is done
        from jax.experimental import multihost_utils

        done = multihost_utils.broadcast_one_to_all(st.done.astype(np.int32))
        if not lead:
            st = empty_state(robot, config)
        st.done[:] = np.asarray(done) > 0
    device = device_description()
    runner = AtlasRunner(robot, config, sharded)
    gsize = config.group
    left = np.nonzero(~st.done)[0]
    todo = [left[s : s + gsize] for s in range(0, len(left), gsize)]
    bar = Progress(total=st.n, desc="atlas", enabled=progress and lead, unit="map")
    bar.update(int(st.done.sum()))
    t0 = time.perf_counter()
    run = dict(st.run)
    run.setdefault("sessions", [])
    session = {
        "device": device,
        "devices": jax.device_count() if sharded else 1,
        "processes": jax.process_count(),
        "maps": 0,
        "seconds": 0.0,
    }
    run["sessions"].append(session)
    for ids in todo:
        runner.run_group(st, ids, bar)
        session["maps"] += len(ids)
        session["seconds"] = round(time.perf_counter() - t0, 3)
        session["compile_s"] = round(runner.compile_seconds, 3)
        st.run = run
        if lead:
            write_atlas(partial, st)
    bar.close()
    if lead and st.done.all():
        if partial.exists():
            partial.replace(out)
        elif not out.exists():
            write_atlas(out, st)
    return st


def same_content(a: str | Path, b: str | Path) -> list[str]:
    """What differs between two atlas files, run records (device, times) aside: [] if nothing."""
    diffs = []
    with h5open(a, "r") as fa, h5open(b, "r") as fb:
        for k in ("schema", "version", "params", "robot_hash", "robot", "complete", "cell_m"):
            if fa.attrs.get(k) != fb.attrs.get(k):
                diffs.append(f"attribute {k}")
        for name in sorted((set(fa) | set(fb)) - {"run"}):
            if name not in fa or name not in fb:
                diffs.append(f"{name} missing")
            elif not np.array_equal(fa[name][...], fb[name][...], equal_nan=fa[name].dtype.kind == "f"):
                diffs.append(name)
    return diffs


def summarize(st: AtlasState) -> list[dict]:
    """Per joint subset: the distribution of areas over its lock angles and the failures
    that NPM turns from unusable (PM = 0) into usable (NPM+PM > 0)."""
    areas = st.areas()
    rows = []
    keys = [tuple(int(j) for j in row if j > 0) for row in st.joints]
    for subset in sorted(set(keys), key=lambda t: (len(t), t)):
        idx = [i for i, k in enumerate(keys) if k == subset and st.done[i]]
        if not idx:
            continue
        pm, npm = areas["pm"][idx], areas["npm_pm"][idx]
        rescued = [st.spec(i) for i in idx if areas["pm"][i] == 0 and areas["npm_pm"][i] > 0]
        rows.append({
            "locked": "+".join(f"J{j}" for j in subset),
            "maps": len(idx),
            "pm_m2": {"min": float(pm.min()), "median": float(np.median(pm)), "max": float(pm.max())},
            "npm_pm_m2": {"min": float(npm.min()), "median": float(np.median(npm)), "max": float(npm.max())},
            "pm_zero": int((pm == 0).sum()),
            "rescued_by_npm": rescued,
            "unusable": int((npm == 0).sum()),
        })  # fmt: skip
    return rows


def plane_area(st: AtlasState) -> float:
    return len(st.xs) * len(st.ys) * st.config.reach.cell**2


def expected_maps(sizes: tuple[int, ...], k: int, nq: int) -> int:
    """How many maps an atlas of `sizes` locked joints at K = k angles has for an nq-joint arm."""
    return sum(math.comb(nq, s) * k**s for s in sizes)
