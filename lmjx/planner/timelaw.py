"""The time law of a transit: where its path turns, the arm slows to rest and speeds up again.

A transit is a chain of straight lines in joint space (to the park pose and down, a roadmap's
waypoints, a retreat), each checked at constant speed by `lmjx.planner.transit.TransitPlanner`, and
executed by joint servos (`lmjx.planner.transit.controls`).  Followed at constant speed, the chain
turns at full speed at every corner; the real arm's servos then overshoot the turn (0.05-0.07
rad at 1.3 rad/s on a hard-tunnel trial: a link against the tunnel's roof where the
plan kept 3 cm, more than the transits' 2 cm margin absorbs).

`retime` keeps the path and changes only when each point of it is reached: the path is cut
at its corners (where the planned joint velocity changes by more than CORNER_JUMP between two
control steps: a turn, or a change of speed), and between corners the arm follows the path as
planned, except that it slows to rest into every corner and speeds up out of it along a half
cosine over RAMP (the acceleration continuous, zero at rest).  Gentle bends (a path sampled
along a curve, the way back along the arm's trail) are followed at the planned speed: stopping
at each would make the arm lurch at the servos' own frequency.  The transit's start and end
are left as they were (it leaves from rest; it hands over to the edge at speed), so the
arm does not stop just short of the objects an edge starts near.  Pure functions of arrays.
"""

from __future__ import annotations

from itertools import pairwise

import numpy as np

RAMP = 0.4  # into and out of a corner the arm slows down and speeds up over this [s]
CORNER_JUMP = 0.1  # a change of the planned joint velocity above this between control steps is a corner [rad/s]


def _law(t: float, rise: bool, fall: bool) -> tuple[float, float, float]:
    """(total time, ramp time r, peak rate V of s) of a run whose time at its planned speed is
    t, with a rise from rest and / or a fall to rest of at most RAMP each, at the peak
    acceleration of a RAMP-long ramp at the planned speed (where t is too short to reach
    it, the ramps meet below it)."""
    m = int(rise) + int(fall)
    if m == 0:
        return t, 0.0, 1.0 / t
    if t >= m * RAMP / 2:
        return t + m * RAMP / 2, RAMP, 1.0 / t
    r = float(np.sqrt(2 * t * RAMP / m))  # the ramps alone: m V r / 2 = 1 at V / r = 1 / (t RAMP)
    return m * r, r, 2.0 / (m * r)


def ramp_time(t: float, rise: bool = True, fall: bool = True) -> float:
    """The time [s] a run takes whose time at its planned speed is t [s] (`_law`)."""
    return _law(max(float(t), 1e-9), rise, fall)[0]


def ramped(t: float, n: int, rise: bool = True, fall: bool = True) -> np.ndarray:
    """The fractions s_k (n,) of a run done at n evenly spaced times k = 1..n (s_n = 1) that
    span its `ramp_time`: the planned speed, preceded by a half-cosine rise from rest over r
    (`rise`) and followed by the mirror-image fall to rest (`fall`)."""
    t = max(float(t), 1e-9)
    total, r, v = _law(t, rise, fall)
    tau = np.arange(1, n + 1) * (total / n)

    def up(x: np.ndarray) -> np.ndarray:  # s done x seconds into a rise (r > 0 with a rise or a fall)
        return 0.5 * v * (x - r / np.pi * np.sin(np.pi * x / r))

    s = v * (tau - (r / 2 if rise else 0.0))  # the planned speed
    if rise:
        s = np.where(tau < r, up(np.minimum(tau, r)), s)
    if fall:
        s = np.where(tau > total - r, 1.0 - up(np.clip(total - tau, 0.0, r)), s)
    s[-1] = 1.0
    return np.clip(s, 0.0, 1.0)


def corners(q0: np.ndarray, targets: np.ndarray, dt: float) -> np.ndarray:
    """Indices k (into targets) after which the planned velocity changes by more than
    CORNER_JUMP [rad/s] on some joint: the velocity from targets[k-1] (q0 for k = 0) to
    targets[k] against the next one's."""
    return _corners(_path(q0, targets), dt)


def _path(q0: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """q0 then targets, (T + 1, nj) float64."""
    return np.concatenate([np.asarray(q0, np.float64)[None], np.asarray(targets, np.float64)])


def _corners(path: np.ndarray, dt: float) -> np.ndarray:
    v = np.diff(path, axis=0) / dt
    jump = np.abs(np.diff(v, axis=0)).max(axis=1) if len(v) > 1 else np.zeros(0)
    return np.nonzero(jump > CORNER_JUMP)[0]


def retime(q0: np.ndarray, targets: np.ndarray, dt: float) -> np.ndarray:
    """The joint targets (m, nj) at the control period dt of the path q0 -> targets (T, nj),
    planned at dt, slowed to rest into each of its `corners` and sped up out of them (see
    the module docstring); the path itself and its start and end unchanged."""
    targets = np.asarray(targets, np.float64)
    if len(targets) < 2:
        return targets
    path = _path(q0, targets)
    turns = _corners(path, dt)
    if not len(turns):
        return targets  # no sharp corner: as planned
    cuts = np.concatenate([[0], turns + 1, [len(targets)]])
    out = []
    for i, (a, b) in enumerate(pairwise(cuts)):
        rise, fall = i > 0, i < len(cuts) - 2
        t = (b - a) * dt
        n = int(np.ceil(ramp_time(t, rise, fall) / dt - 1e-9))
        x = a + ramped(t, n, rise, fall) * (b - a)  # where along the path (in planned steps)
        k = np.minimum(np.floor(x).astype(int), len(path) - 2)
        f = (x - k)[:, None]
        out.append(path[k] * (1 - f) + path[k + 1] * f)
    return np.concatenate(out)
