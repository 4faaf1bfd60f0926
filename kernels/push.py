"""Where the arm's table-checked capsules pass low over the table, for a run of edge states.

A push toward the goal (`lmjx.planner.pushfield`) is a capsule whose lower axis end is low
over the table at one state and moves on at the next.  `low_ends` gives that end per
capsule; `low_samples` keeps, of a run of consecutive states, the (state, capsule) pairs
whose lower end is at most `z_max` high, compacted to a fixed budget so that only those leave
the device (a few percent of all pairs).  Pure functions of arrays: the caller jits them.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .collision import capsule_ends
from .model import ArmModel


class LowSamples(NamedTuple):
    """The low (state, capsule) pairs of a run of states, at most `budget` of them."""

    count: jnp.ndarray  # () int32, how many pairs passed (more than budget: only the first budget are here)
    index: jnp.ndarray  # (budget,) int32, state * nt + position in arm.table_caps, in that order
    low: jnp.ndarray  # (budget, 3) the lower axis end at the state [m]
    next_xy: jnp.ndarray  # (budget, 2) x, y of the same capsule's lower end at the next state [m]


def low_ends(arm: ArmModel, q: jnp.ndarray) -> jnp.ndarray:
    """(nt, 3) the lower (by z) axis end of each table-checked capsule `arm.table_caps`
    (the first end where both are as low) at joint angles q (nj,)."""
    ends = capsule_ends(arm, q)
    caps = np.asarray(arm.table_caps)
    a, b = ends.a[caps], ends.b[caps]
    return jnp.where((a[:, 2] <= b[:, 2])[:, None], a, b)


def low_samples(
    arm: ArmModel, q: jnp.ndarray, has_next: jnp.ndarray, z_max: jnp.ndarray, rows: jnp.ndarray, budget: int
) -> LowSamples:
    """The (state, capsule) pairs of states q[:-1] (n + 1, nj) whose lower end (`low_ends`)
    is at most z_max (nt,) high, for the states with `has_next` (n,) whose index lies in
    [rows[0], rows[1]); with the end's position there and its x, y at the next state (q's
    next row).  `budget` (static): pairs returned at most; `count` says how many passed."""
    low = jax.vmap(lambda x: low_ends(arm, x))(q)  # (n + 1, nt, 3)
    n, nt = has_next.shape[0], low.shape[1]
    state = jnp.arange(n)
    ok = has_next & (state >= rows[0]) & (state < rows[1])
    passed = (low[:-1, :, 2] <= z_max[None]) & ok[:, None]
    flat = passed.reshape(-1)
    (index,) = jnp.nonzero(flat, size=budget, fill_value=0)
    s, c = index // nt, index % nt
    return LowSamples(flat.sum().astype(jnp.int32), index.astype(jnp.int32), low[s, c], low[s + 1, c, :2])
