"""Warp kernels of the GPU simulator's rollout step (MuJoCo Warp does the physics).

Pure kernels over device arrays, no I/O; `lmjx.simulate_gpu` captures them with
`mujoco_warp.step` into CUDA graphs.  Imports warp: load this module only where warp-lang
is installed.  (No `from __future__ import annotations`: Warp reads the annotations.)
"""

import warp as wp


@wp.kernel(enable_backward=False)
def set_controls(
    step: wp.array(dtype=wp.int32),
    q_pts: wp.array3d(dtype=wp.float32),
    qd_pts: wp.array3d(dtype=wp.float32),
    n_pts: wp.array(dtype=wp.int32),
    sub: int,
    nj: int,
    ctrl: wp.array2d(dtype=wp.float32),
):
    """Servo controls of every world at physics step `step[0]`: `actions.controls` on the
    device.  q* is linear between control points c and c + 1 (row 0 is the point before
    the first), qd* is held over the control period; after a world's last point its final
    pose is held with qd* = 0.  q_pts (W, P + 1, nj), qd_pts (W, P, nj), n_pts (W,),
    `sub` physics steps per control period, ctrl (W, 2 nj)."""
    w = wp.tid()
    k = step[0]
    c = k // sub
    f = float(k - c * sub + 1) / float(sub)
    n = n_pts[w]
    if c < n:
        for j in range(nj):
            ctrl[w, j] = q_pts[w, c, j] * (1.0 - f) + q_pts[w, c + 1, j] * f
            ctrl[w, nj + j] = qd_pts[w, c, j]
    else:
        for j in range(nj):
            ctrl[w, j] = q_pts[w, n, j]
            ctrl[w, nj + j] = 0.0


@wp.kernel(enable_backward=False)
def keep_final(
    step: wp.array(dtype=wp.int32),
    ends: wp.array(dtype=wp.int32),
    qpos: wp.array2d(dtype=wp.float32),
    final: wp.array2d(dtype=wp.float32),
):
    """After physics step `step[0]` (0-based): the positions of each world whose action ends
    with this step, kept (a world runs on, holding its last control, until the batch's
    longest action ends; its result is where its own ends).  ends (W,) in steps."""
    w = wp.tid()
    if step[0] + 1 == ends[w]:
        for i in range(qpos.shape[1]):
            final[w, i] = qpos[w, i]


@wp.kernel(enable_backward=False)
def advance(step: wp.array(dtype=wp.int32)):
    """The step counter, one up."""
    step[0] = step[0] + 1


@wp.kernel(enable_backward=False)
def start_state(
    qpos0: wp.array2d(dtype=wp.float32),
    ctrl0: wp.array2d(dtype=wp.float32),
    qpos: wp.array2d(dtype=wp.float32),
    qvel: wp.array2d(dtype=wp.float32),
    act: wp.array2d(dtype=wp.float32),
    qacc_warmstart: wp.array2d(dtype=wp.float32),
    ctrl: wp.array2d(dtype=wp.float32),
    time: wp.array(dtype=wp.float32),
    overflow: wp.array(dtype=wp.int32),
):
    """Each world at rest in its own start state: positions and servo targets from
    qpos0 (W, nq), ctrl0 (W, nu); velocities, activations, the solver's warm start, the
    clock and the overflow bits cleared.  That is all the state a MuJoCo Warp step carries
    from one step to the next in these scenes (no mocap, equality, plugin or sleep state)."""
    w = wp.tid()
    for i in range(qpos.shape[1]):
        qpos[w, i] = qpos0[w, i]
    for i in range(qvel.shape[1]):
        qvel[w, i] = 0.0
        qacc_warmstart[w, i] = 0.0
    for i in range(act.shape[1]):
        act[w, i] = 0.0
    for i in range(ctrl.shape[1]):
        ctrl[w, i] = ctrl0[w, i]
    time[w] = 0.0
    overflow[w] = 0
