"""The push pairs as the planner first computed them, kept as the reference the two-stage
computation (`lmjx.mapfile.pushmap.push_pairs`) must equal exactly: every state of every
edge whose start is clear of the fixed obstacles through the capsule-ends kernel, the cut
at a fixed obstacle on every state, then the tests of `push_pairs` and `np.unique`."""

from __future__ import annotations

import math

import numpy as np

from lmjx.edges.index import capsule_ends_kernel
from lmjx.mapfile.bundle import Bundle
from lmjx.mapfile.pushmap import HEIGHT, MAX_ANGLE, far_objects
from lmjx.model.failure import Failure
from lmjx.model.robot import Robot
from lmjx.planner.transit import TransitPlanner
from lmjx.reach.reachability import ReachResult
from lmjx.sim.goalfield import GoalField
from lmjx.sim.scenarios import Scenario
from lmjx.sim.sceneboxes import EDGE_BOXES, MIN_EDGE_STATES, box_kernel, cut_at_fixed

STATES_PER_CALL = 200_000  # edge states read and checked per pass


def reference_push_pairs(
    robot: Robot,
    failure: Failure,
    bundle: Bundle,
    reach: ReachResult,
    sc: Scenario,
    field: GoalField,
    max_angle: float = MAX_ANGLE,
    height: float = HEIGHT,
) -> tuple[np.ndarray, np.ndarray]:
    """(cell, edge) pairs, unique, sorted by cell then edge (`pushmap.push_pairs`)."""
    tp = TransitPlanner(robot, failure, batched=True)
    tp.set_scene(sc, far_objects(sc), acting=False)
    fixed = np.nonzero(~tp.scene.movable)[0]
    ny, nx = reach.labels.shape
    found: list[np.ndarray] = []
    if not len(fixed):
        starts_clear = np.ones(bundle.n_edges, bool)
    else:
        starts_clear = tp.scene_slacks(np.asarray(bundle.q_start, np.float64))[:, fixed].min(axis=1) >= 0
    edges = np.nonzero(starts_clear)[0]
    arm = robot.arm
    caps = np.asarray(arm.table_caps)
    r_cap = np.asarray(arm.cap_r, np.float64)[caps]
    ends_kernel = capsule_ends_kernel(robot)
    boxes = box_kernel(robot, tp.scene.padded(EDGE_BOXES, fixed)) if len(fixed) else None
    gy, gx = np.gradient(field.values, field.cell)  # the descent is minus this
    cos_min = math.cos(math.radians(max_angle))
    cell = reach.config.cell
    x0, y0 = reach.xs[0] - cell / 2, reach.ys[0] - cell / 2
    width = bundle.n_edges
    lengths = np.asarray(bundle.length, np.int64)
    offsets = np.asarray(bundle.offset, np.int64)
    i = 0
    while i < len(edges):
        # a run of edges whose states (contiguous in the file) make one pass
        j, n = i, 0
        while j < len(edges) and (n == 0 or n + lengths[edges[j]] <= STATES_PER_CALL):
            n += int(lengths[edges[j]])
            j += 1
        es = edges[i:j]
        i = j
        lo, hi = int(offsets[es[0]]), int(offsets[es[-1]] + lengths[es[-1]])
        block = np.asarray(bundle.q[lo:hi], np.float32)
        rows = np.concatenate([np.arange(offsets[e], offsets[e] + lengths[e]) for e in es]) - lo
        q = block[rows]
        lens = lengths[es]
        owner = np.repeat(np.arange(len(es)), lens)
        k = np.arange(len(owner)) - np.concatenate([[0], np.cumsum(lens)[:-1]])[owner]
        clearance = None if boxes is None else boxes.run(q)["box_clearance"][:, : len(fixed)].min(axis=1)
        prefix = cut_at_fixed(clearance, owner, k, lens)
        prefix[prefix < MIN_EDGE_STATES] = 0  # such an edge is never offered (`edge_prefixes`)
        ends = ends_kernel.run(q)
        a = ends["a"][:, caps].astype(np.float64)
        b = ends["b"][:, caps].astype(np.float64)
        low = np.where((a[..., 2] <= b[..., 2])[..., None], a, b)  # (m, nc, 3)
        z = low[..., 2] - arm.table_z - r_cap[None]
        moving = k + 1 < prefix[owner]  # this state and the next are executed
        row, cap = np.nonzero((z <= height) & moving[:, None])
        if not len(row):
            continue
        p = low[row, cap, :2]
        v = low[row + 1, cap, :2] - p
        fx = np.clip(np.floor((p[:, 0] - field.lo[0]) / field.cell).astype(np.int64), 0, field.shape[1] - 1)
        fy = np.clip(np.floor((p[:, 1] - field.lo[1]) / field.cell).astype(np.int64), 0, field.shape[0] - 1)
        g = -np.stack([gx[fy, fx], gy[fy, fx]], axis=1)
        speed, gn = np.hypot(v[:, 0], v[:, 1]), np.hypot(g[:, 0], g[:, 1])
        toward = ((v * g).sum(axis=1) >= cos_min * speed * gn) & (speed > 1e-4) & (gn > 0)
        cx = np.floor((p[toward, 0] - x0) / cell).astype(np.int64)
        cy = np.floor((p[toward, 1] - y0) / cell).astype(np.int64)
        inside = (cx >= 0) & (cx < nx) & (cy >= 0) & (cy < ny)
        e = es[owner[row[toward]]][inside]
        found.append(np.unique((cy[inside] * nx + cx[inside]) * width + e))  # each edge once per cell
    pairs = np.unique(np.concatenate(found)) if found else np.zeros(0, np.int64)
    return pairs // width, pairs % width
