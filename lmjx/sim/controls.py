"""Servo controls of an action: its joint targets at the control rate turned into targets at a
simulator's physics rate (interpolated positions, held velocities), as the CPU simulator, the
"real" world and (on the device) the GPU simulator apply them."""

from __future__ import annotations

import numpy as np

from lmjx.types import CONTROL_DT, Action


def control_points(actions: list[Action]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The control points of several actions, padded to the longest: q* (n, T + 1, nj) with
    the point before the first (q - qd dt) in row 0, qd* (n, T, nj), and each action's
    number of control points (n,).  `controls` interpolates these; the GPU simulator does
    the same on the device."""
    n_pts = np.array([len(a.q) for a in actions], np.int32)
    nj = actions[0].q.shape[1]
    q = np.zeros((len(actions), int(n_pts.max()) + 1, nj))
    qd = np.zeros((len(actions), int(n_pts.max()), nj))
    for i, a in enumerate(actions):
        q[i, 0] = a.q[0] - a.qd[0] * CONTROL_DT
        q[i, 1 : len(a.q) + 1] = a.q
        q[i, len(a.q) + 1 :] = a.q[-1]
        qd[i, : len(a.q)] = a.qd
    return q, qd, n_pts


def controls(action: Action, physics_dt: float, settle: float) -> np.ndarray:
    """Servo controls (steps, 2 nj) at the physics rate: q* interpolated linearly between
    control points, qd* held; then `settle` seconds holding the final pose."""
    sub = round(CONTROL_DT / physics_dt)
    q = np.concatenate([action.q[:1] - action.qd[:1] * CONTROL_DT, action.q])  # the point before the first
    frac = (np.arange(1, sub + 1) / sub)[None, :, None]
    nj = q.shape[1]
    q_phys = (q[:-1, None, :] * (1 - frac) + q[1:, None, :] * frac).reshape(-1, nj)
    qd_phys = np.repeat(action.qd, sub, axis=0)
    hold = round(settle / physics_dt)
    q_hold = np.repeat(action.q[-1:], hold, axis=0)
    out = np.zeros((len(q_phys) + hold, 2 * nj))
    out[: len(q_phys), :nj] = q_phys
    out[: len(q_phys), nj:] = qd_phys
    out[len(q_phys) :, :nj] = q_hold
    return out
