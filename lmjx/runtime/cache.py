"""Where lmjx keeps compiled programs between runs, so that each is compiled once per machine.

Three caches live in one per-user folder:
  * `<dir>/jax`: JAX's persistent compilation cache (the IK, rollout and clearance kernels);
  * `<dir>/export`: those kernels traced (JAX exports; tracing them takes seconds too), keyed
    by the kernel, lmjx's kernel sources, JAX's version and the platform (`lmjx.runtime.batching`);
  * `<dir>/warp`: Warp's kernel cache (MuJoCo Warp's kernels, for the GPU simulator).
Beside them, not a compiled program: `<dir>/pushes`, the push counts of a map and scenario
(`lmjx.mapfile.pushmap.cached_counts`).
The folder is, in this order: `--cache-dir DIR` on the command line, the environment
variable `LMJX_CACHE_DIR`, `$XDG_CACHE_HOME/lmjx`, `~/.cache/lmjx`.  `off` turns lmjx's
caching off (JAX then compiles every run; Warp keeps its own default cache).  A
`JAX_COMPILATION_CACHE_DIR` the user set is left alone.  Nothing here compiles anything;
`in_jax_cache` tells whether a lowered program is in JAX's persistent cache without
compiling it (`jax_cache_key`: the key it is kept under), what a build needs to compile
the programs of later builds only where they are missing (`lmjx.edges.compiling`).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

ENV = "LMJX_CACHE_DIR"
OFF = "off"
MIN_COMPILE_SECONDS = "0.2"  # programs that compile faster than this are not worth a file


def cache_dir(choice: str | None = None) -> Path | None:
    """The cache folder for a `--cache-dir` value (None: from the environment); None when off."""
    text = choice if choice is not None else os.environ.get(ENV)
    if text is not None and text.strip():
        return None if text.strip().lower() == OFF else Path(text).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "lmjx"


def configure(choice: str | None = None, warn: Callable[[str], None] | None = None) -> Path | None:
    """Point JAX (through its environment variables, before JAX starts) and Warp (through
    `LMJX_CACHE_DIR`, read when the GPU simulator starts Warp) at the cache folder.

    A folder that cannot be written is not an error: `warn` is told in one line and caching
    is turned off for this run (everything still runs, compiling again)."""
    folder = cache_dir(choice)
    if folder is None:
        os.environ[ENV] = OFF
        return None
    try:
        (folder / "jax").mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".probe.", dir=folder / "jax")
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        if warn is not None:
            warn(
                f"cannot write the compile cache in {folder} ({e.strerror or type(e).__name__}); running without "
                "it (compiling again): give --cache-dir a writable folder, or --cache-dir off"
            )
        os.environ[ENV] = OFF
        return None
    os.environ[ENV] = str(folder)
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(folder / "jax"))
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", MIN_COMPILE_SECONDS)
    return folder


def configure_warp() -> None:
    """Before `warp.init()`: Warp's kernel cache inside the lmjx cache folder (if one is set)."""
    import warp as wp

    text = os.environ.get(ENV)
    if text and text != OFF and wp.config.kernel_cache_dir is None:
        wp.config.kernel_cache_dir = str(Path(text) / "warp")


def jax_cache_key(lowered: Any) -> str | None:
    """The key under which JAX's persistent compilation cache keeps the program `lowered` (a
    `jax.stages.Lowered` of one jitted function) compiled, computed as JAX's compiler does,
    without compiling it.  None when it cannot tell (no persistent cache, or a JAX whose
    internals differ from those this reads: JAX has no public call for it).  On a GPU the
    key leaves out which device the program runs on (JAX strips the device assignment), so
    one entry serves every device of a kind; on the CPU it does not."""
    try:
        import numpy as np
        from jax._src import compiler
        from jax._src.interpreters import pxla

        low = lowered._lowering
        args = low.compile_args
        devices = low._device_list
        ins = tuple(pxla.maybe_concretize_mesh(s, devices) for s in args["in_shardings"])
        outs = tuple(pxla.maybe_concretize_mesh(s, devices) for s in args["out_shardings"])
        to_inputs, to_outputs = pxla.get_prop_to_input_output(ins, outs, len(args["ordered_effects"]))
        dev = np.array(list(devices), dtype=object)  # as jax's _cached_compilation lays them out
        options = pxla.create_compile_options(
            low._hlo, args["tuple_args"], to_inputs, to_outputs, args["backend"], dev, dict(low._compiler_options_kvs)
        )
        return compiler._get_cache_key(options, args["backend"], low._hlo, dev)
    except Exception:  # another JAX's internals
        return None


def in_jax_cache(lowered: Any) -> bool | None:
    """Whether JAX's persistent compilation cache holds the program `lowered` compiled,
    without compiling it: its key (`jax_cache_key`) looked up.  None when it cannot tell;
    callers then compile, which loads a cached program anyway."""
    return jax_cache_entry(lowered)[1]


def jax_cache_entry(lowered: Any) -> tuple[str | None, bool | None]:
    """(`jax_cache_key` of `lowered`, `in_jax_cache`'s answer): the key computed once."""
    key = jax_cache_key(lowered)
    if key is None:
        return None, None
    try:
        return key, key_in_jax_cache(key, lowered._lowering.compile_args["backend"])
    except Exception:  # another JAX's internals
        return key, None


def key_in_jax_cache(key: str, backend: Any = None) -> bool | None:
    """Whether JAX's persistent compilation cache holds an entry under `key` (a
    `jax_cache_key`) for `backend` (None: JAX's default).  None when it cannot tell."""
    try:
        from jax._src import compiler, xla_bridge

        return bool(compiler._is_executable_in_cache(backend or xla_bridge.get_backend(), key))
    except Exception:  # another JAX's internals
        return None
