"""The time law of the transits' straight pieces: each starts and ends at rest.

A transit is a chain of straight lines in joint space (to the park pose and down, a
roadmap's waypoints, a retreat), executed by joint servos (`lmjx.actions.controls`).  A
chain followed at constant speed turns at full speed at every corner; the real arm's
servos then overshoot the turn (0.05-0.07 rad at 1.3 rad/s in the ninth session's trial
2011: a link against the tunnel's roof where the plan kept 3 cm, more than the transits'
2 cm margin absorbs).  Here every piece speeds up from rest along a half cosine over RAMP,
holds its constant speed, and slows back to rest, the acceleration continuous (zero at
rest): the arm stops at every corner and at the edge's start, and follows each piece
closely.  Pure functions of the pieces' times.
"""

from __future__ import annotations

import numpy as np

RAMP = 0.4  # a piece speeds up from rest, and slows down to rest, over this [s]


def ramp_time(t: np.ndarray | float) -> np.ndarray:
    """The time [s] of straight pieces whose time at constant speed is t [s], each starting
    and ending at rest (`ramped`): t + RAMP, or where t < RAMP (too short to reach full
    speed at the same acceleration) 2 sqrt(t RAMP)."""
    t = np.asarray(t, np.float64)
    return np.where(t >= RAMP, t + RAMP, 2.0 * np.sqrt(t * RAMP))


def ramped(t: float, n: int) -> np.ndarray:
    """The fractions s_k (n,) of a straight piece done at the control steps k = 1..n (s_n = 1):
    the piece's speed rises from rest along a half cosine over RAMP, holds the constant speed
    of time t (the largest joint at its transit speed), and falls back to rest symmetrically
    (where t < RAMP the rise and the fall meet, at the same peak acceleration); the n steps
    span `ramp_time(t)` or a little more."""
    t = max(float(t), 1e-9)
    r = RAMP if t >= RAMP else float(np.sqrt(t * RAMP))
    v = 1.0 / max(t, r)  # peak rate of s [1/s]
    total = float(ramp_time(t))
    tau = np.arange(1, n + 1) * (total / n)

    def rise(x: np.ndarray) -> np.ndarray:  # s done after x seconds of the rise (x <= r)
        return 0.5 * v * (x - r / np.pi * np.sin(np.pi * x / r))

    s = np.where(
        tau <= r,
        rise(np.minimum(tau, r)),
        np.where(tau >= total - r, 1.0 - rise(np.clip(total - tau, 0.0, r)), 0.5 * v * r + v * (tau - r)),
    )
    s[-1] = 1.0
    return np.clip(s, 0.0, 1.0)
