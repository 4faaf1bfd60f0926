"""Spreading a batch over every accelerator: all local devices of one host through JAX's
sharding APIs (`jax.sharding.Mesh` + `NamedSharding`), and several hosts through
`jax.distributed` (multi-controller JAX: every process runs the same program on its own
devices; arrays are global).

The batch axis is the only one split; every item is computed by the same per-device program
whatever the number of devices (the chunk per device is fixed), so a sharded run gives the
same numbers as a single-device one.  Nothing here knows about IK.
"""

from __future__ import annotations

import contextlib
import os

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from lmjx.errors import ConfigError

AXIS = "batch"


def init_distributed(coordinator: str, num_processes: int, process_id: int) -> None:
    """Join a multi-process run (call before any other JAX work).  On CPUs the processes
    exchange results through gloo collectives."""
    if num_processes < 1 or not (0 <= process_id < num_processes):
        raise ConfigError(f"process id {process_id} is not in 0..{num_processes - 1}")
    if ":" not in coordinator:
        raise ConfigError(f"--coordinator must be host:port, got '{coordinator}'")
    if os.environ.get("JAX_PLATFORMS", "") == "cpu" or jax.config.jax_platforms == "cpu":
        with contextlib.suppress(AttributeError):  # newer JAX: gloo is the default
            jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator_address=coordinator, num_processes=num_processes, process_id=process_id)


def mesh() -> Mesh:
    """A one-axis mesh over every device of every process."""
    return Mesh(np.array(jax.devices()), (AXIS,))


def device_count() -> int:
    return jax.device_count()


def batch_sharding(m: Mesh) -> NamedSharding:
    return NamedSharding(m, PartitionSpec(AXIS))


def replicated(m: Mesh) -> NamedSharding:
    return NamedSharding(m, PartitionSpec())


def per_device(fn, m: Mesh, n_replicated: int, n_batched: int):
    """`fn(*replicated, *batched)` run by every device on its own rows of the batched
    arguments (`shard_map`); its outputs are split along axis 0 like its batched inputs."""
    specs = (PartitionSpec(),) * n_replicated + (PartitionSpec(AXIS),) * n_batched
    if hasattr(jax, "shard_map"):
        try:
            return jax.shard_map(fn, mesh=m, in_specs=specs, out_specs=PartitionSpec(AXIS), check_vma=False)
        except TypeError:  # a JAX whose shard_map still takes check_rep
            return jax.shard_map(fn, mesh=m, in_specs=specs, out_specs=PartitionSpec(AXIS), check_rep=False)
    from jax.experimental.shard_map import shard_map

    return shard_map(fn, mesh=m, in_specs=specs, out_specs=PartitionSpec(AXIS), check_rep=False)


def put_batch(x: np.ndarray, m: Mesh) -> jax.Array:
    """A global array split along axis 0 over the mesh; each process supplies its own
    devices' rows from its (identical) host copy."""
    x = np.asarray(x)
    return jax.make_array_from_callback(x.shape, batch_sharding(m), lambda idx: x[idx])


def put_replicated(x: np.ndarray, m: Mesh) -> jax.Array:
    x = np.asarray(x)
    return jax.make_array_from_callback(x.shape, replicated(m), lambda idx: x[idx])


def to_host(y: jax.Array) -> np.ndarray:
    """The whole array on this host (gathered from the other processes if there are any)."""
    if jax.process_count() > 1 and not y.is_fully_addressable:
        from jax.experimental import multihost_utils

        return np.asarray(multihost_utils.process_allgather(y, tiled=True))
    return np.asarray(y)
