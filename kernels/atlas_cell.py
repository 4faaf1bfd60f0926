"""One Reach-Ability attempt at one cell of one map of the failure atlas, whole on the device.

Given (map, cell, attempt) it draws the attempt's target perturbation and the M restart
configurations from a counter-based key (seed, map, attempt, cell), places the locked
joints at their angles, runs the masked IK (`ik.ik_solve(free_mask=...)`) and its acceptance
checks for every restart, and says whether any restart was accepted.  Nothing but three
integers goes in and one bool comes out per item, so the host neither draws nor ships the
restarts, and the draws do not depend on how items are batched or sharded.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .ik import IKSettings, ik_check, ik_solve
from .model import ArmModel


class CellAttempt(NamedTuple):
    hit: jnp.ndarray  # () bool: some restart was accepted


def atlas_cell(
    arm: ArmModel,
    settings: IKSettings,
    sites: tuple[int, ...],
    seed: int,
    restarts: int,
    eps: float,
    attempt_site: np.ndarray,
    attempt_pm: np.ndarray,
    z_lo: np.ndarray,
    z_hi: np.ndarray,
    masks: jnp.ndarray,
    locks: jnp.ndarray,
    centres: jnp.ndarray,
    map_id: jnp.ndarray,
    cell: jnp.ndarray,
    attempt: jnp.ndarray,
) -> CellAttempt:
    """Args (static first): the arm, solver settings, candidate sites, seed, M, the
    perturbation radius, per-attempt site / PM flag / height band (numpy, (k,));
    then traced tables: masks (N, nj) 1 free / 0 locked, locks (N, nj) lock angles, centres
    (n, 2) cell centres; and the item: map_id, cell, attempt (() int32)."""
    nj = arm.lower.shape[0]
    free = tuple(range(nj))
    key = jax.random.fold_in(jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(seed), map_id), attempt), cell)
    k_off, k_q = jax.random.split(key)
    u = jax.random.uniform(k_off, (2,), jnp.float32)
    r = eps * jnp.sqrt(u[0]) * (attempt > 0)
    th = 2 * jnp.pi * u[1]
    xy = centres[cell] + jnp.stack([r * jnp.cos(th), r * jnp.sin(th)])
    zl = jnp.asarray(z_lo, jnp.float32)[attempt]
    zh = jnp.asarray(z_hi, jnp.float32)[attempt]
    target = jnp.concatenate([xy, jnp.stack([zl, zh])])
    site = jnp.asarray(attempt_site, jnp.int32)[attempt]
    pm = jnp.asarray(attempt_pm)[attempt]
    lo = jnp.asarray(arm.lower, jnp.float32)
    hi = jnp.asarray(arm.upper, jnp.float32)
    mask = masks[map_id]
    q0 = lo + jax.random.uniform(k_q, (restarts, nj), jnp.float32) * (hi - lo)
    q0 = jnp.where(mask > 0, q0, locks[map_id])
    q_any = np.zeros(nj)

    def one(q_start: jnp.ndarray) -> jnp.ndarray:
        q = ik_solve(arm, settings, free, q_any, sites, target, site, pm, q_start, free_mask=mask)
        return ik_check(arm, settings, free, q_any, sites, target, site, pm, q).ok

    return CellAttempt(jnp.any(jax.vmap(one)(q0)))
