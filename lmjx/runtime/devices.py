"""Which local device a map build's device work goes to: every accelerator in turn (a turn
per kind of work), or, in a process that owns one device (`own_device`: a build whose other
GPUs run in peer processes, or such a peer), that one."""

from __future__ import annotations

import contextlib
import threading

import jax

_LOCK = threading.Lock()
_TURN: dict[str, int] = {}  # round robin over the local devices, a turn per kind of work
_OWN: list[jax.Device | None] = []  # the devices `own_device` set, innermost last


@contextlib.contextmanager
def own_device(device: jax.Device | None = None):
    """Within: `index_devices` is `device` alone (None: JAX's default device): a build's
    process whose other devices run in peer processes (`lmjx.edges.peers`), or such a
    peer, each placing its index and push work on its own device."""
    with _LOCK:
        _OWN.append(device)
    try:
        yield
    finally:
        with _LOCK:
            _OWN.pop()


def index_devices() -> list[jax.Device | None]:
    """The devices the map's index runs on, in turn: every local accelerator (None: JAX's
    default, the first); on a CPU the default device alone (host devices share the cores);
    under `own_device`, its device."""
    if _OWN:
        return [_OWN[-1]]
    devices = jax.local_devices()
    if devices[0].platform == "cpu":
        return [None]
    return [None, *devices[1:]]


def next_device(kind: str = "index") -> jax.Device | None:
    """The next of `index_devices()` for work of `kind`, in turn (thread-safe): where the
    build's packers place their device work (the index, the push samples), so that it does
    not all queue behind the first device's rollouts.  Each kind has a turn of its own (a
    packer asks for the index's, then the push samples': one shared turn gave the index the
    first device every time)."""
    devices = index_devices()
    with _LOCK:
        i = _TURN.get(kind, 0)
        _TURN[kind] = i + 1
    return devices[i % len(devices)]
