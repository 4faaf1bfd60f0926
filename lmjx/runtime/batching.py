"""Run a one-item kernel over a flat batch: jit(vmap(...)), fixed-size padded chunks, one
compilation per kernel key, compile time kept apart from run time.

The IK batches (`lmjx.reach.ik_batch`) and the edge rollouts (`lmjx.mapfile.bundle`) both run through
`ChunkedKernel`.  It owns no algorithm.
"""

from __future__ import annotations

import hashlib
import os
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from lmjx.runtime.compiletime import compile_span, told_compiled

_COMPILED: dict[tuple, tuple[Callable, dict[str, tuple[tuple[int, ...], np.dtype]]]] = {}
_COMPILING: dict[tuple, threading.Lock] = {}  # one lock per program: threads wanting it compile it once
_COMPILING_LOCK = threading.Lock()
# programs lowered (`ChunkedKernel.lower`) and not compiled yet, by `placed`: their compile
# takes them instead of lowering again, whichever kernel of the program compiles it
_LOWERED: dict[tuple, tuple[jax.stages.Lowered, list[str], bool]] = {}
KEEP_BLOCKS = 16  # blocks a device returns its kept rows in (see ChunkedKernel)
# what a compiled program is called where a long compile is told (`telling_compiled`)
PROGRAM_NAMES = {"ik": "the inverse kinematics", "rollout": "the edges' rollout", "capsule_ends": "the arm's capsules",
                 "boxes_clearance": "the clearance to a scene's boxes", "boxes_lower_bound": "its lower bound",
                 "arm_clearance": "the arm's clearance to itself and the table"}  # fmt: skip


def _code_version() -> str:
    """A hash of lmjx's version and the source of everything a kernel's trace depends on."""
    import kernels
    from lmjx import __version__

    here = Path(__file__).parent
    h = hashlib.sha256(__version__.encode())
    for f in sorted({here / "batching.py", *Path(kernels.__file__).parent.glob("*.py")}):
        h.update(f.name.encode() + f.read_bytes())
    return h.hexdigest()


def program_ident(key: tuple) -> str:
    """A hex name for the program of kernel key `key` as this machine makes it: the key,
    lmjx's kernel sources, JAX's version and the platform (what its trace depends on)."""
    dev = jax.devices()[0]
    ident = repr((key, _code_version(), jax.__version__, dev.platform, getattr(dev, "device_kind", "")))
    return hashlib.sha256(ident.encode()).hexdigest()


def exported(key: tuple, fn: Callable, args: list, names: list[str]) -> Callable:
    """`fn` traced once per machine: from a JAX export in the lmjx cache folder when an
    earlier run saved one for this kernel (its key, lmjx's kernel sources, JAX's version and
    the platform), else traced now and saved.  Returns a jitted callable; `names` receives
    the output field names.  Without a cache folder (or on any error) it traces as usual."""
    from lmjx.runtime.cache import cache_dir

    folder = cache_dir()
    if folder is None:
        return fn
    path = folder / "export" / (program_ident(key) + ".jaxexport")
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


_PINNED = {"ok": True}  # off after the first failure: a JAX or platform without pinned host memory


def fetch(arrays: Sequence[jax.Array]) -> list[np.ndarray]:
    """Single-device arrays on the host.  On a GPU they go through pinned (page-locked) host
    memory: one DMA each, all started at once, then viewed by numpy without a copy (JAX's
    plain copy lands in freshly mapped pageable memory, measured at 1.5-2 GB/s on an H200
    against 18 GB/s this way; benchmarks/shard_scaling.py)."""
    arrays = list(arrays)
    if arrays and _PINNED["ok"] and arrays[0].devices().pop().platform == "gpu":
        try:
            moved = [jax.device_put(a, a.sharding.with_memory_kind("pinned_host")) for a in arrays]
            return [np.asarray(m) for m in moved]
        except Exception:  # no pinned host memory here: the plain copy from now on
            _PINNED["ok"] = False
    for a in arrays:
        a.copy_to_host_async()
    return [np.asarray(a) for a in arrays]


def default_device() -> jax.Device:
    """The device JAX places an array on when given none (its default device)."""
    return jax.device_put(np.zeros((), np.int8)).devices().pop()


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
      sharded: split every call's batch over all devices of all processes (`lmjx.runtime.sharding`);
        each device runs the one-device program on `chunk` items, so results do not depend
        on the number of devices.
      keep_by, kept: the outputs named in `kept` come back only for the items whose boolean
        output `keep_by` is true (in item order, or as `run`'s `kept_dest` places them).
      compact: the other items' `kept` rows are never copied off the device: each device
        sorts its kept rows first (stable) and returns them in `KEEP_BLOCKS` blocks, of
        which only those holding kept rows are copied.  By default on accelerators, in one
        process; else every row comes back and the kept ones are selected on the host (a
        CPU's device memory is the host's: nothing to spare; several processes gather whole
        outputs), and the program is the one of a kernel with nothing kept.
      device: run on this device (not sharded); by default JAX's default device (the same
        program, placed there: `placed` tells them apart within the process).
    """

    def __init__(
        self,
        key: tuple,
        one: Callable,
        shared: Sequence[np.ndarray],
        inputs: Sequence[tuple[type, tuple[int, ...]]],
        chunk: int,
        sharded: bool = False,
        keep_by: str | None = None,
        kept: tuple[str, ...] = (),
        device: jax.Device | None = None,
        compact: bool | None = None,
    ) -> None:
        from lmjx.runtime import sharding

        # one device in all: the one-device program itself (the same numbers), which an
        # export in the cache spares tracing
        sharded = sharded and sharding.device_count() > 1 and device is None
        if not sharded and device is None:
            # placed on the default device, as on any other: a program lowered for arrays
            # placed on a device differs from one lowered for arrays placed nowhere, and a
            # GPU's persistent-cache key leaves out which device, so that one cache entry
            # serves this program on every device (a build's devices, later builds' too)
            device = default_device()
        self.device = device
        self._lock = threading.Lock()  # several threads may share a kernel: one builds it
        self.sharded = sharded
        self.keep_by, self.kept = keep_by, tuple(kept) if keep_by else ()
        # One process on accelerators: blocks of kept rows are copied from each device.  A
        # CPU, or several processes (`lmjx.runtime.sharding.to_host` gathers whole outputs): every
        # row comes back and the kept ones are selected on the host.
        if compact is None:
            compact = jax.process_count() == 1 and backend() != "cpu"
        self.compact = bool(self.kept) and compact and jax.process_count() == 1
        self.mesh = None
        if sharded:
            self.mesh = sharding.mesh()
            chunk = chunk * sharding.device_count()
        # the program: a kernel that copies every row is the same program whatever it keeps
        outputs = (self.keep_by, self.kept) if self.compact else ()
        self.key = (*key, chunk, tuple((np.dtype(d).str, s) for d, s in inputs), len(shared), sharded, outputs)
        self.placed = (*self.key, device.id if device is not None else None)  # what _COMPILED holds
        self.one = one
        self.shared = self._placed(shared)
        self.inputs = list(inputs)
        self.chunk = chunk
        self.compile_seconds = 0.0
        self.kernel_seconds = 0.0  # time in kernel calls and transfers, compilation excluded
        # where run()'s time goes when results come back: waiting for the device, copying to
        # the host, selecting rows, placing kept rows (the rest: preparing and dispatching)
        self.timing = {"device_wait": 0.0, "to_host": 0.0, "mask": 0.0, "place": 0.0}
        self.copied_bytes = 0  # copied off the devices by run()
        self._fn: Callable | None = None
        self._out: dict[str, tuple[tuple[int, ...], np.dtype]] = {}  # the program's outputs

    def _results(self) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
        """run()'s results, (shape, dtype) per item: the outputs copied whole, then each
        output compacted into blocks (named by its first block, "name#0")."""
        plain = {k: v for k, v in self._out.items() if "#" not in k}
        return plain | {k.removesuffix("#0"): v for k, v in self._out.items() if k.endswith("#0")}

    def compile(self) -> None:
        """Compile the program now (it is otherwise compiled by the first `run`).  Kernels
        with the same key share one compilation, also when threads ask for it at once.
        `compile_seconds` grows by the time spent here: lowering and compiling (or loading
        the program from the persistent cache), or waiting for another thread doing so;
        nothing is run."""
        with self._lock:
            if self._fn is None:
                t0 = time.perf_counter()
                with _COMPILING_LOCK:
                    program = _COMPILING.setdefault(self.placed, threading.Lock())
                with program, compile_span():
                    compiled_here = self._fn is None and self.placed not in _COMPILED
                    self._build_locked()
                self.compile_seconds += time.perf_counter() - t0
                if compiled_here:
                    told_compiled(PROGRAM_NAMES.get(str(self.key[0]), str(self.key[0])), time.perf_counter() - t0)

    def lower(self, keep: bool = True) -> tuple[jax.stages.Lowered, list[str]]:
        """The program lowered for launches of `chunk` items (what `compile` compiles), and
        its output names; nothing is compiled or run.  With `keep`, kept until the program
        is compiled, which then needs no lowering of its own (a build looks its programs up
        in the cache before compiling them)."""
        with self._lock:
            if keep and self._fn is None and self.placed not in _COMPILED:
                with _COMPILING_LOCK:
                    kept = _LOWERED.get(self.placed)
                if kept is None:
                    kept = self._lower()
                    with _COMPILING_LOCK:
                        if self.placed not in _COMPILED:  # (another kernel of it may have compiled it meanwhile)
                            _LOWERED[self.placed] = kept
            else:
                kept = self._lower()
        lowered, names, _ = kept
        return lowered, list(names)

    def _lower(self, export: bool = True) -> tuple[jax.stages.Lowered, list[str], bool]:
        """`lower`, and whether the program came from an export: with `export` (and not
        sharded) from the trace an earlier run saved in the cache folder (`exported`: no
        tracing), else traced now."""
        # numpy dummies: a jnp.zeros of a new shape would itself compile a small program.
        dummy = [self._put(np.zeros((self.chunk, *s), d)) for d, s in self.inputs]
        axes = (None,) * len(self.shared) + (0,) * len(self.inputs)
        vmapped = jax.vmap(self.one, in_axes=axes)
        names: list[str] = []

        per_device_chunk = self.chunk // (self.mesh.size if self.mesh is not None else 1)
        block = -(-per_device_chunk // KEEP_BLOCKS)

        def flat(*args):  # the kernel's NamedTuple as a plain tuple (what an export can hold)
            res = vmapped(*args)
            fields = list(res._fields)
            outs = list(res)
            if self.compact:
                # this device's kept rows first, in item order; each kept output split in blocks
                order = jnp.argsort(~res._asdict()[self.keep_by].astype(bool), stable=True)
                pad = block * KEEP_BLOCKS - per_device_chunk
                for name in self.kept:
                    i = fields.index(name)
                    x = outs[i][order]
                    x = jnp.concatenate([x, jnp.zeros((pad, *x.shape[1:]), x.dtype)]) if pad else x
                    outs[i] = None
                    for b in range(KEEP_BLOCKS):
                        fields.append(f"{name}#{b}")
                        outs.append(x[b * block : (b + 1) * block])
                keep = [i for i, o in enumerate(outs) if o is not None]
                fields, outs = [fields[i] for i in keep], [outs[i] for i in keep]
            names[:] = fields
            return tuple(outs)

        if self.mesh is not None:
            # Each device runs the one-device program on its own rows (shard_map), rather
            # than leaving the split to XLA's partitioner, which may keep a batched while
            # loop's carry whole and compute every row on every device.
            from lmjx.runtime.sharding import per_device

            plain = jax.jit(per_device(flat, self.mesh, len(self.shared), len(self.inputs)))
        else:
            plain = jax.jit(flat)
        args = [*self.shared, *dummy]
        if export and not self.sharded:
            # Tracing these kernels takes seconds; a traced program saved by an earlier run
            # (a JAX export) is loaded instead, and XLA's persistent cache then spares the
            # compilation.
            fn = exported(self.key, plain, args, names)
            if fn is not plain:
                try:
                    return fn.lower(*args), names, True
                except Exception:  # an export this JAX cannot lower: traced as usual
                    pass
        return plain.lower(*args), names, False

    def _build_locked(self) -> None:
        if self.placed in _COMPILED:
            self._fn, self._out = _COMPILED[self.placed]
            return
        from lmjx.runtime.compilelock import compiling

        with _COMPILING_LOCK:
            kept = _LOWERED.pop(self.placed, None)
        # another process compiling this program meanwhile: wait for it, then load its
        # compilation from the persistent cache
        with compiling(program_ident(self.key)):
            lowered, names, from_export = kept if kept is not None else self._lower()
            try:
                compiled = lowered.compile()
            except Exception:
                if not from_export:
                    raise
                lowered, names, _ = self._lower(export=False)  # an export this JAX cannot compile
                compiled = lowered.compile()
        # No warm-up call: the first launch loads what remains to load; its outputs'
        # shapes come from the program.
        self._out = {k: (tuple(v.shape[1:]), np.dtype(v.dtype)) for k, v in zip(names, compiled.out_info, strict=True)}
        self._fn = compiled
        with _COMPILING_LOCK:
            _COMPILED[self.placed] = (compiled, self._out)
            _LOWERED.pop(self.placed, None)  # a lowering kept meanwhile (`lower`): never compiled now

    def _put(self, x: np.ndarray) -> jax.Array:
        if self.device is not None:
            return jax.device_put(x, self.device)
        if self.mesh is None:
            return jax.device_put(x)  # jnp.asarray would compile a small program per shape
        from lmjx.runtime.sharding import put_batch

        return put_batch(x, self.mesh)

    def _host(self, y: jax.Array) -> np.ndarray:
        if self.mesh is None:
            return fetch([y])[0]
        from lmjx.runtime.sharding import to_host

        return to_host(y)

    def _kept_blocks(self, res: list, blocks: dict[str, list[int]], keep: np.ndarray) -> dict[str, list[np.ndarray]]:
        """The kept rows of each compacted output, as host arrays in item order: from every
        device, the blocks that hold its kept rows (all copied at once), each cut to the
        kept rows it holds."""
        shards_of = {k: [sorted(res[i].addressable_shards, key=lambda s: s.index[0].start or 0) for i in ids]
                     for k, ids in blocks.items()}  # fmt: skip
        for ids in blocks.values():
            for i in ids:
                res[i] = None
        first = next(iter(shards_of.values()))[0]
        per_device = self.chunk // len(first)
        block = first[0].data.shape[0]
        counts = [int(keep[d * per_device : (d + 1) * per_device].sum()) for d in range(len(first))]
        wanted = [(k, d, b, s[d].data) for k, shards in shards_of.items() for d in range(len(first))
                  for b, s in enumerate(shards[: -(-counts[d] // block)])]  # fmt: skip
        host = fetch([w[3] for w in wanted])
        out: dict[str, list[np.ndarray]] = {k: [] for k in blocks}
        for (k, d, b, a), h in zip(wanted, host, strict=True):
            out[k].append(h[: min(block, counts[d] - b * block)])
            self.copied_bytes += a.nbytes
        return out

    def _placed(self, shared: Sequence[np.ndarray]) -> list:
        if self.mesh is not None:
            from lmjx.runtime.sharding import put_replicated

            return [put_replicated(np.asarray(a), self.mesh) for a in shared]
        if self.device is not None:
            return [jax.device_put(np.asarray(a), self.device) for a in shared]
        return [jax.device_put(np.asarray(a)) for a in shared]

    def set_shared(self, *shared: np.ndarray) -> None:
        """New values for the shared arrays (the same shapes and dtypes: the same program)."""
        old = [(a.shape, a.dtype) for a in self.shared]
        new = [(np.shape(a), np.asarray(a).dtype) for a in shared]
        if old != new:
            raise ValueError(f"shared arrays {new} do not match the program's {old}")
        self.shared = self._placed(shared)

    def launch(self, *parts: np.ndarray) -> dict[str, jax.Array]:
        """One call of the program on exactly `chunk` items, its outputs left on the device,
        by name (for device-side work that follows; a kernel with nothing kept)."""
        if self._fn is None:
            self.compile()
        assert self._fn is not None and not self.compact and self.mesh is None
        placed = [self._put(np.asarray(p, dtype=d)) for p, (d, _) in zip(parts, self.inputs, strict=True)]
        return dict(zip(self._out, self._fn(*self.shared, *placed), strict=True))

    def run(
        self,
        *arrays: np.ndarray,
        progress: Callable[[int], None] | None = None,
        kept_dest: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> dict[str, np.ndarray]:
        """Apply the kernel to every item of `arrays` (all of length n); numpy results, the
        `kept` outputs for the items whose `keep_by` output is true only: in item order, or
        row j (the j-th kept item) at row `kept_dest(keep)[j]`, where `keep` is the (n,)
        `keep_by` mask (each kept row is copied once, straight to its place)."""
        if self._fn is None:
            self.compile()
        assert self._fn is not None
        t0 = time.perf_counter()
        n = len(arrays[0])
        c = self.chunk
        outs: list[dict[str, np.ndarray]] = []
        kept_parts: dict[str, list[np.ndarray]] = {k: [] for k in self.kept}  # kept rows in item order, in pieces
        pending: tuple | None = None  # the call in flight: the device works while the host prepares the next

        names = list(self._out)
        plain = [i for i, k in enumerate(names) if "#" not in k]  # outputs copied whole
        order = sorted(plain, key=lambda i: names[i] in self.kept)  # the mask first
        blocks = {k: [names.index(f"{k}#{b}") for b in range(KEEP_BLOCKS)] for k in self.kept} if self.compact else {}
        results = self._results()

        def collect(p: tuple) -> None:
            res, count = p  # res: a list, emptied as its outputs come back
            got: dict[str, np.ndarray] = {}
            for i in order:
                v, res[i] = res[i], None
                t0 = time.perf_counter()
                v.block_until_ready()
                t1 = time.perf_counter()
                host = self._host(v)[:count]
                self.copied_bytes += v.nbytes
                del v  # the device array and its host copy go as soon as the rows are taken
                t2 = time.perf_counter()
                if names[i] in self.kept:
                    kept_parts[names[i]].append(host[got[self.keep_by].astype(bool)])
                else:
                    got[names[i]] = host
                self.timing["device_wait"] += t1 - t0
                self.timing["to_host"] += t2 - t1
                self.timing["mask"] += time.perf_counter() - t2
            if blocks:
                t1 = time.perf_counter()
                for k, parts in self._kept_blocks(res, blocks, got[self.keep_by][:count].astype(bool)).items():
                    kept_parts[k] += parts
                self.timing["to_host"] += time.perf_counter() - t1
            outs.append(got)
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
        whole = {k: np.concatenate([o[k] for o in outs]) if outs else np.zeros((0, *results[k][0]), results[k][1])
                 for k in results if k not in self.kept}  # fmt: skip
        if self.kept:
            t1 = time.perf_counter()
            whole |= self._place(kept_parts, whole[self.keep_by].astype(bool), kept_dest, results)
            self.timing["place"] += time.perf_counter() - t1
        self.kernel_seconds += time.perf_counter() - t0
        return whole

    @staticmethod
    def _place(parts: dict[str, list[np.ndarray]], keep: np.ndarray, kept_dest, results: dict) -> dict[str, np.ndarray]:
        """Each kept output's pieces (its kept rows in item order) in one array, every row
        copied once: in item order, or to the rows `kept_dest(keep)` gives."""
        n = int(keep.sum())
        dest = None if kept_dest is None else np.asarray(kept_dest(keep))
        out = {}
        for k, pieces in parts.items():
            shape, dtype = results[k]
            rows = np.empty((n, *shape), dtype)
            at = 0
            for x in pieces:
                if dest is None:
                    rows[at : at + len(x)] = x
                else:
                    rows[dest[at : at + len(x)]] = x
                at += len(x)
            assert at == n, (k, at, n)
            out[k] = rows
        return out
