"""Run a one-item kernel over a flat batch: jit(vmap(...)), fixed-size padded chunks, one
compilation per kernel key, compile time kept apart from run time.

The IK batches (`lmjx.ik_batch`) and the edge rollouts (`lmjx.bundle`) both run through
`ChunkedKernel`.  It owns no algorithm.
"""

from __future__ import annotations

import hashlib
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

_COMPILED: dict[tuple, tuple[Callable, dict[str, tuple[tuple[int, ...], np.dtype]]]] = {}
_SOURCES = ("batching.py", "kernels/__init__.py")  # with every kernels/*.py: what a traced program depends on


def _code_version() -> str:
    """A hash of lmjx's version and the source of everything a kernel's trace depends on."""
    from . import __version__

    here = Path(__file__).parent
    h = hashlib.sha256(__version__.encode())
    for f in sorted({*(here / s for s in _SOURCES), *(here / "kernels").glob("*.py")}):
        h.update(f.name.encode() + f.read_bytes())
    return h.hexdigest()


def exported(key: tuple, fn: Callable, args: list, names: list[str]) -> Callable:
    """`fn` traced once per machine: from a JAX export in the lmjx cache folder when an
    earlier run saved one for this kernel (its key, lmjx's kernel sources, JAX's version and
    the platform), else traced now and saved.  Returns a jitted callable; `names` receives
    the output field names.  Without a cache folder (or on any error) it traces as usual."""
    from .cache import cache_dir

    folder = cache_dir()
    if folder is None:
        return fn
    dev = jax.devices()[0]
    ident = repr((key, _code_version(), jax.__version__, dev.platform, getattr(dev, "device_kind", "")))
    path = folder / "export" / (hashlib.sha256(ident.encode()).hexdigest() + ".jaxexport")
    try:
        from jax import export

        if path.exists():
            blob = path.read_bytes()
            head = blob.index(b"\n")
            names[:] = blob[:head].decode().split(",")
            return jax.jit(export.deserialize(bytearray(blob[head + 1 :])).call)
        specs = [jax.ShapeDtypeStruct(np.shape(a), a.dtype) for a in args]
        exp = export.export(fn)(*specs)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_bytes(",".join(names).encode() + b"\n" + exp.serialize())
        os.replace(tmp, path)
        return jax.jit(exp.call)
    except Exception:  # an old or damaged export, no flatbuffers, a read-only folder: trace as usual
        return fn


def backend() -> str:
    """'gpu', 'cpu', ... : the platform JAX computes on."""
    return jax.default_backend()


def device_description() -> str:
    dev = jax.devices()[0]
    kind = getattr(dev, "device_kind", "") or ""
    return f"{dev.platform}" + (f" ({kind})" if kind and dev.platform != "cpu" else "")


class ChunkedKernel:
    """jit(vmap(one)) over chunks of `chunk` items.

    Args:
      key: identifies the program (static arguments folded into `one`); equal keys share
        one compilation within the process.
      one: the kernel for one item, `one(*shared, *per_item)`; returns a NamedTuple.
      shared: arrays passed unbatched to every item (e.g. traced lock angles).
      inputs: (dtype, trailing shape) of each per-item input.
      chunk: items per call (per device when sharded); batches are padded to a multiple of it.
      sharded: split every call's batch over all devices of all processes (`lmjx.sharding`);
        each device runs the one-device program on `chunk` items, so results do not depend
        on the number of devices.
    """

    def __init__(
        self,
        key: tuple,
        one: Callable,
        shared: Sequence[np.ndarray],
        inputs: Sequence[tuple[type, tuple[int, ...]]],
        chunk: int,
        sharded: bool = False,
    ) -> None:
        self.sharded = sharded
        self.mesh = None
        if sharded:
            from . import sharding

            self.mesh = sharding.mesh()
            chunk = chunk * sharding.device_count()
        self.key = (*key, chunk, tuple((np.dtype(d).str, s) for d, s in inputs), len(shared), sharded)
        self.one = one
        if self.mesh is not None:
            from .sharding import put_replicated

            self.shared = [put_replicated(np.asarray(a), self.mesh) for a in shared]
        else:
            self.shared = [jnp.asarray(np.asarray(a)) for a in shared]
        self.inputs = list(inputs)
        self.chunk = chunk
        self.compile_seconds = 0.0
        self.kernel_seconds = 0.0  # time in kernel calls and transfers, compilation excluded
        # where run()'s time goes when results come back: waiting for the device, copying to
        # the host, selecting rows (the rest: preparing and dispatching launches)
        self.timing = {"device_wait": 0.0, "to_host": 0.0, "mask": 0.0}
        self._fn: Callable | None = None
        self._out: dict[str, tuple[tuple[int, ...], np.dtype]] = {}

    def _build(self) -> None:
        if self.key in _COMPILED:
            self._fn, self._out = _COMPILED[self.key]
            return
        t0 = time.perf_counter()
        # numpy dummies: a jnp.zeros of a new shape would itself compile a small program.
        dummy = [self._put(np.zeros((self.chunk, *s), d)) for d, s in self.inputs]
        axes = (None,) * len(self.shared) + (0,) * len(self.inputs)
        vmapped = jax.vmap(self.one, in_axes=axes)
        names: list[str] = []

        def flat(*args):  # the kernel's NamedTuple as a plain tuple (what an export can hold)
            res = vmapped(*args)
            names[:] = res._fields
            return tuple(res)

        if self.mesh is not None:
            # Each device runs the one-device program on its own rows (shard_map), rather
            # than leaving the split to XLA's partitioner, which may keep a batched while
            # loop's carry whole and compute every row on every device.
            from .sharding import per_device

            plain = jax.jit(per_device(flat, self.mesh, len(self.shared), len(self.inputs)))
        else:
            plain = jax.jit(flat)
        # Tracing these kernels takes seconds; a traced program saved by an earlier run (a JAX
        # export) is loaded instead, and XLA's persistent cache then spares the compilation.
        fn = plain if self.sharded else exported(self.key, plain, [*self.shared, *dummy], names)
        try:
            compiled = fn.lower(*self.shared, *dummy).compile()
        except Exception:
            if fn is plain:
                raise
            compiled = plain.lower(*self.shared, *dummy).compile()  # an export this JAX cannot run
        # One warm-up call is counted with the compilation: it loads the program onto the
        # device, so that timed calls measure steady-state work.
        res = jax.block_until_ready(compiled(*self.shared, *dummy))
        self.compile_seconds = time.perf_counter() - t0
        self._out = {k: (np.shape(v)[1:], np.dtype(v.dtype)) for k, v in zip(names, res, strict=True)}
        self._fn = compiled
        _COMPILED[self.key] = (compiled, self._out)

    def _put(self, x: np.ndarray) -> jax.Array:
        if self.mesh is None:
            return jnp.asarray(x)
        from .sharding import put_batch

        return put_batch(x, self.mesh)

    def _host(self, y: jax.Array) -> np.ndarray:
        if self.mesh is None:
            return np.asarray(y)
        from .sharding import to_host

        return to_host(y)

    def run(
        self,
        *arrays: np.ndarray,
        progress: Callable[[int], None] | None = None,
        mask_by: str | None = None,
        masked: tuple[str, ...] = (),
    ) -> dict[str, np.ndarray]:
        """Apply the kernel to every item of `arrays` (all of length n); numpy results.
        With `mask_by`, the outputs named in `masked` keep only the rows where output
        `mask_by` is true, selected as each output of each launch comes back (one full
        output on the host at a time), so host memory holds only what is kept."""
        if self._fn is None:
            self._build()
        assert self._fn is not None
        t0 = time.perf_counter()
        n = len(arrays[0])
        c = self.chunk
        outs: list[dict[str, np.ndarray]] = []
        pending: tuple | None = None  # the call in flight: the device works while the host prepares the next

        names = list(self._out)
        order = sorted(range(len(names)), key=lambda i: names[i] in masked)  # the mask first

        def collect(p: tuple) -> None:
            res, count = p  # res: a list, emptied as its outputs come back
            got: dict[str, np.ndarray] = {}
            for i in order:
                v, res[i] = res[i], None
                t0 = time.perf_counter()
                v.block_until_ready()
                t1 = time.perf_counter()
                host = self._host(v)[:count]
                del v  # the device array and its host copy go as soon as the rows are taken
                t2 = time.perf_counter()
                if names[i] in masked:
                    host = host[got[mask_by].astype(bool)]
                got[names[i]] = host
                self.timing["device_wait"] += t1 - t0
                self.timing["to_host"] += t2 - t1
                self.timing["mask"] += time.perf_counter() - t2
            outs.append({k: got[k] for k in names})
            if progress is not None:
                progress(count)

        for start in range(0, n, c):
            stop = min(start + c, n)
            parts = []
            for a, (dtype, _) in zip(arrays, self.inputs, strict=True):
                part = np.asarray(a[start:stop], dtype=dtype)
                if stop - start < c:
                    part = np.concatenate([part, np.repeat(part[-1:], c - (stop - start), axis=0)], axis=0)
                parts.append(self._put(part))
            res = list(self._fn(*self.shared, *parts))  # asynchronous dispatch
            if pending is not None:
                collect(pending)
            pending = (res, stop - start)
            del res, parts
        if pending is not None:
            collect(pending)
        self.kernel_seconds += time.perf_counter() - t0
        if not outs:
            return {k: np.zeros((0, *shape), dtype) for k, (shape, dtype) in self._out.items()}
        return {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}
