"""A build's compiling, once per machine: its own programs in a thread of their own while the
Reach-Ability map is computed, then the programs that builds of the robot's other preset
failures will need, so that a later build of another preset loads them from the cache
(seconds) instead of compiling them (tens of seconds each).

A failure's programs are the Reach-Ability map's IK (which the edges' starts share) and the
edge rollout (`lmjx.edges.sampling.EdgeKernels`); their lock angles are compiled-in
constants (a program taking them as inputs rounds differently, which would change the
maps), so every failure has programs of its own, and their launch sizes depend on neither
the edge count nor the seed.  The presets (the robot's and `none`) are compiled where JAX's
persistent cache does not already hold them (`lmjx.runtime.cache.in_jax_cache`); a custom
failure ('J2=0.3,J4=-1.5') compiles its own the first time it is built on a machine.  They
are compiled, never run, and not kept in memory (the cache keeps them): host work beside
the build's device work.

They are the programs the build of that failure makes (`EdgeKernels`: sharded over one
device in all is not sharded), placed on the default device; every program is lowered for
arrays placed on a device (`lmjx.runtime.batching.ChunkedKernel`), and a GPU's cache key
leaves the device out, so the same cache entries serve a build split over several GPUs of
one process (each device's programs load from them).
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import json
import os
import signal
import sys
import threading
import time
import weakref
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from lmjx.edges.sampling import EdgeKernels
from lmjx.mapfile.bundle import BundleConfig
from lmjx.model.failure import Failure, parse_failure
from lmjx.model.robot import Robot
from lmjx.reach.reachability import ReachConfig, reach_ik
from lmjx.runtime.batching import ChunkedKernel, program_ident
from lmjx.runtime.cache import cache_dir, jax_cache_entry, key_in_jax_cache
from lmjx.runtime.fileio import write_text_atomic


class InterruptedAfterMap(KeyboardInterrupt):
    """Ctrl-C twice while other failures' programs were compiling: the map is written."""


def preset_failures(robot: Robot, failure: Failure) -> list[Failure]:
    """`none` and the robot's presets, less `failure` (the same locked joints and angles)."""
    specs = ["none", *robot.profile.presets]
    return [f for f in (parse_failure(s, robot) for s in specs) if f.locked != failure.locked]


def preset_programs(
    robot: Robot, failure: Failure, reach_cfg: ReachConfig, config: BundleConfig, cube_half: float
) -> list[tuple[str, str, ChunkedKernel]]:
    """(failure spec, stage, program) for the programs a one-process build of each other
    preset (`preset_failures`) compiles with these settings: the same keys and launch sizes
    (`reach_ik`, `EdgeKernels`), made, not compiled; each program once."""
    out, seen = [], set()
    for f in preset_failures(robot, failure):
        edges = EdgeKernels(robot, f, config, False, cube_half, ik_chunk=reach_cfg.chunk)
        for stage, kernel in (("ik", reach_ik(robot, f, reach_cfg).kernel), ("ik", edges.ik.kernel),
                              ("rollout", edges.rollout)):  # fmt: skip
            if kernel.key not in seen:
                seen.add(kernel.key)
                out.append((f.spec, stage, kernel))
    return out


def preset_record(programs: list[tuple[str, str, ChunkedKernel]]) -> Path | None:
    """Where the record that `programs` are all in JAX's persistent cache is kept: a file in
    the cache folder named by the programs (`program_ident`: their keys, lmjx's kernel
    sources, JAX's version, the platform) and by what else JAX's cache keys hold
    (`compile_setting`); None without a cache folder."""
    folder = cache_dir()
    if folder is None or not programs:
        return None
    names = "\n".join([compile_setting(), *(program_ident(kernel.key) for _, _, kernel in programs)])
    return folder / "programs" / (hashlib.sha256(names.encode()).hexdigest() + ".json")


def compile_setting() -> str:
    """What makes JAX's cache key of a program that `program_ident` leaves out: jaxlib's
    version, the backend's (its driver and plugin) and how many devices it shows, XLA's flags
    and the JAX settings that change a trace.  A record is read without lowering its
    programs: where one of these changed, the keys it holds are the old programs', still in
    the cache, not those a build would compile now.  (The devices: measured on 2 H200s, a
    build shown one of them (CUDA_VISIBLE_DEVICES) after builds shown both compiled every
    program again, the ones placed on one device included, and a record made under the two
    said its presets were compiled.)"""
    import jax
    import jaxlib

    devices = jax.devices()
    backend = devices[0].client
    return repr((jaxlib.__version__, getattr(backend, "platform_version", ""), len(devices),
                 os.environ.get("XLA_FLAGS", ""), os.environ.get("LIBTPU_INIT_ARGS", ""),
                 bool(jax.config.jax_enable_x64), str(jax.config.jax_default_matmul_precision)))  # fmt: skip


@dataclass
class PresetCompiler:
    """Compiles the programs of `preset_programs` that JAX's persistent cache lacks, one
    after the other (`run`); `stop` lets the program being compiled finish and starts no
    other (a compilation cannot be interrupted, and one cut short while its result is
    written would leave a half-written cache entry).

    `record` (`preset_record`): once every program is in the cache, their cache keys are
    written there; a later build that finds that record, and every key in the cache, has
    nothing to do and lowers none of them (lowering and looking up the presets' programs
    takes about 0.7 s of a 10 s build on an H200, beside the build's own work)."""

    programs: list[tuple[str, str, ChunkedKernel]]
    record: Path | None = None
    compiled: list[str] = field(default_factory=list)  # "case1 ik", ...: compiled here
    cached: list[str] = field(default_factory=list)  # found in the cache: nothing to do
    seconds: float = 0.0  # spent looking them up and compiling
    error: str | None = None  # why the rest was not compiled (the build is not failed for it)
    _stop: threading.Event = field(default_factory=threading.Event, repr=False)

    @property
    def failures(self) -> list[str]:
        return list(dict.fromkeys(spec for spec, _, _ in self.programs))

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    def stop(self) -> None:
        self._stop.set()

    def run(self) -> None:
        t0 = time.perf_counter()
        if self._recorded():
            self.cached = [f"{spec} {stage}" for spec, stage, _ in self.programs]
            self.seconds = time.perf_counter() - t0
            return
        keys: list[str | None] = []  # each program's cache key
        compiled: list[str | None] = []  # those of the programs compiled here
        try:
            for spec, stage, kernel in self.programs:
                if self._stop.is_set():
                    return
                t0 = time.perf_counter()
                lowered, _ = kernel.lower(keep=False)  # (compiled here, not by the kernel)
                key, cached = jax_cache_entry(lowered)
                keys.append(key)
                if cached:
                    self.cached.append(f"{spec} {stage}")
                else:
                    lowered.compile()  # into the persistent cache; the executable is dropped
                    self.compiled.append(f"{spec} {stage}")
                    compiled.append(key)
                self.seconds += time.perf_counter() - t0
        except Exception as e:  # a later build compiles what is missing
            self.error = f"{type(e).__name__}: {e}"
            return
        self._write_record(keys, compiled)

    def _recorded(self) -> bool:
        """Whether `record` says every program is in the cache, and the cache still holds them."""
        if self.record is None or not self.record.is_file():
            return False
        try:
            keys = json.loads(self.record.read_text())["jax_keys"]
        except (OSError, ValueError, KeyError, TypeError):
            return False
        return len(keys) == len(self.programs) and all(key_in_jax_cache(k) for k in keys)

    def _write_record(self, keys: list[str | None], compiled: list[str | None]) -> None:
        """The record of the programs' cache keys, where every one is in the cache now: those
        found there, and those `compiled` here once JAX kept them (it keeps only programs
        that took a while to compile: a quicker one is not recorded)."""
        if self.record is None or None in keys or not all(key_in_jax_cache(k) for k in compiled if k is not None):
            return
        text = json.dumps({"programs": [f"{s} {t}" for s, t, _ in self.programs], "jax_keys": keys})
        with contextlib.suppress(OSError):  # a read-only cache: the next build looks the programs up again
            write_text_atomic(self.record, text)

    def summary(self) -> dict:
        left = len(self.programs) - len(self.compiled) - len(self.cached)
        return {"failures": self.failures, "compiled": self.compiled, "cached": self.cached, "left": left,
                "seconds": round(self.seconds, 4), **({"error": self.error} if self.error else {})}  # fmt: skip


def _yield_cores() -> None:
    """Lower this thread's scheduling priority (Linux: a thread's nice value, which the
    compiler's worker threads started from it inherit), so that compiling for later builds
    takes the cores the build leaves idle."""
    if not sys.platform.startswith("linux"):
        return
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, min(19, os.getpriority(os.PRIO_PROCESS, tid) + 10))
    except OSError:
        pass


def first_then_together(steps: list[Callable[[], object]]) -> Callable[[], None]:
    """One step: the first of `steps` (the first device's programs), then the others in
    threads of their own (the other devices', the same programs placed elsewhere: in JAX's
    persistent cache once the first is compiled, so that they are loaded side by side rather
    than compiled again each); the first error is raised."""

    def run() -> None:
        if not steps:
            return
        steps[0]()
        if len(steps) > 1:
            with ThreadPoolExecutor(len(steps) - 1, thread_name_prefix="lmjx-compile") as pool:
                for done in [pool.submit(step) for step in steps[1:]]:
                    done.result()

    return run


_RUNNING: weakref.WeakSet[BackgroundCompile] = weakref.WeakSet()


@atexit.register
def _finish_at_exit() -> None:
    """Before the interpreter exits (after a failed build, say): no other program is
    started, and the one being compiled finishes, so that no cache entry is left
    half-written (a command that leaves at once, on Ctrl-C, does not come here)."""
    for background in list(_RUNNING):
        background.abandon()
        if background.thread.is_alive():
            print("lmjx: finishing the program being compiled before leaving", file=sys.stderr)
            background.thread.join()


class BackgroundCompile:
    """A build's compiling in a daemon thread of its own: `own` (the build's programs) side
    by side, then `presets` (other failures' programs, for later builds).
    `wait_own` waits for the build's programs (raising their error, if any); `finish`, at the
    end of the build, for the presets'; `abandon`, on a failed build, starts no other, of
    either kind."""

    def __init__(self, own: list[Callable[[], object]], presets: PresetCompiler | None = None) -> None:
        self.presets = presets
        self._own_done = threading.Event()
        self._abandoned = threading.Event()
        self._failed: list[BaseException] = []
        self.thread = threading.Thread(target=self._run, args=(own,), name="lmjx-compile", daemon=True)
        _RUNNING.add(self)
        self.thread.start()

    def _run(self, own: list[Callable[[], object]]) -> None:
        try:
            if own and not self._abandoned.is_set():
                # side by side: loading a program from the cache (or compiling it) leaves the
                # interpreter free most of the time, and the first of them is the longest
                with ThreadPoolExecutor(len(own), thread_name_prefix="lmjx-compile") as pool:
                    for done in [pool.submit(step) for step in own]:
                        done.result()
        except BaseException as e:  # handed to whoever waits
            self._failed.append(e)
            return
        finally:
            self._own_done.set()
        if self.presets is not None:
            _yield_cores()
            self.presets.run()

    def wait_own(self) -> None:
        self._own_done.wait()
        if self._failed:
            raise self._failed[0]

    def abandon(self) -> None:
        self._abandoned.set()
        if self.presets is not None:
            self.presets.stop()

    def finish(self, say: Callable[[str], None]) -> None:
        """Wait for the presets' programs, saying so when there is a wait.  In the main
        thread, a first Ctrl-C lets the program being compiled finish and starts no other;
        a second leaves at once (`InterruptedAfterMap`)."""
        if self.presets is None or not self.thread.is_alive():
            return
        names = ", ".join(self.presets.failures)
        say(f"compiling the programs of {names} for later builds on this machine (once; Ctrl-C stops it; "
            "the map is written)")  # fmt: skip
        main = threading.current_thread() is threading.main_thread()
        before = (signal.getsignal(signal.SIGINT) or signal.default_int_handler) if main else None

        def first(signum: int, frame: object) -> None:
            self.presets.stop()  # type: ignore[union-attr]
            signal.signal(signal.SIGINT, before)
            say("stopping once the program being compiled is done (Ctrl-C again leaves now; the map is written)")

        if main:
            signal.signal(signal.SIGINT, first)
        try:
            while self.thread.is_alive():
                self.thread.join(0.2)
        except KeyboardInterrupt as e:
            raise InterruptedAfterMap() from e
        finally:
            if main and signal.getsignal(signal.SIGINT) is first:
                signal.signal(signal.SIGINT, before)
