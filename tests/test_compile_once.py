"""Compiling once per machine (lmjx.edges.sampling.launch_sizes, lmjx.edges.compiling,
lmjx.runtime.cache.in_jax_cache): builds of any edge count, seed or chunking make the same
programs (checked on the accelerators' configuration, without a GPU: the programs are made,
not compiled), a build lists the other presets' programs for later builds, and the cache
lookup agrees with JAX's own (a persistent-cache hit when the program is compiled again),
and a build waiting for them stops on Ctrl-C without cutting a compilation short.  Only
programs of a few operations are compiled here."""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lmjx.mapfile.bundle
import lmjx.reach.ik_batch
import lmjx.runtime.batching
from lmjx.edges.compiling import (
    BackgroundCompile,
    InterruptedAfterMap,
    PresetCompiler,
    preset_failures,
    preset_programs,
    preset_record,
)
from lmjx.edges.sampling import EdgeKernels, launch_sizes
from lmjx.mapfile.bundle import BundleConfig
from lmjx.model.failure import parse_failure
from lmjx.reach.reachability import reach_config, reach_ik
from lmjx.runtime.batching import ChunkedKernel
from lmjx.runtime.cache import in_jax_cache, jax_cache_key

ROLLOUT_LAUNCH_GPU = 1 << 17  # edges per rollout launch on an accelerator (BundleConfig.kernel_chunk)
IK_LAUNCH_GPU = 1 << 19  # IK problems per launch on an accelerator (default_chunk)


@pytest.fixture
def accelerator(monkeypatch):
    """The platform seen as an accelerator by the functions that size and configure programs."""
    for module in (lmjx.mapfile.bundle, lmjx.reach.ik_batch, lmjx.runtime.batching):
        monkeypatch.setattr(module, "backend", lambda: "gpu")


def _programs(robot, spec: str, edges: int, seed: int, build_chunk: int | None, sharded: bool = False) -> list:
    """The programs a build makes (their keys and devices): the reach map's IK, the edges' IK
    and rollout."""
    failure = parse_failure(spec, robot)
    reach_cfg = reach_config(robot, seed=seed)
    config = BundleConfig(edges=edges, seed=seed, build_chunk=build_chunk, interaction_points=robot.default_ips)
    ks = EdgeKernels(robot, failure, config, sharded, reach_cfg.object_height / 2, ik_chunk=reach_cfg.chunk)
    return [reach_ik(robot, failure, reach_cfg).kernel.placed, ks.ik.kernel.placed, ks.rollout.placed]


def test_a_build_of_any_size_and_seed_makes_the_same_programs(robot, accelerator):
    assert launch_sizes(BundleConfig()) == (None, ROLLOUT_LAUNCH_GPU)
    assert launch_sizes(BundleConfig(), sharded=True) == (ROLLOUT_LAUNCH_GPU * 8, ROLLOUT_LAUNCH_GPU)
    assert launch_sizes(BundleConfig(chunk=4096)) == (None, 4096)  # an explicit launch size is kept
    small = _programs(robot, "case2", 10_000, 0, None)
    assert small == _programs(robot, "case2", 1_000_000, 7, None)
    assert small == _programs(robot, "case2", 2_000, 3, 1_000)  # --chunk: edges at a time, not the launch
    reach, edges_ik, rollout = small
    assert edges_ik == reach  # the edges' starts share the reach map's IK program
    assert IK_LAUNCH_GPU in reach and ROLLOUT_LAUNCH_GPU in rollout
    assert ("unroll_checks=True" in repr(reach)) and ("unroll_checks=True" in repr(rollout))  # accelerator settings
    # sharded (`lmjx build-map`'s default) over one device in all: the one-device programs, the
    # start IK the reach map's, which is what the presets compile for later builds
    assert _programs(robot, "case2", 10_000, 0, None, True) == small
    assert _programs(robot, "case2", 3_000_000, 5, 500, True) == small
    assert _programs(robot, "case1", 10_000, 0, None) != small  # lock angles are constants of the programs


def test_the_cpu_launch_sizes_are_the_cpu_defaults():
    assert launch_sizes(BundleConfig()) == (None, 512)  # the CPU's maps are built with these


def test_the_presets_compiled_for_later_builds(robot, ur5e, accelerator):
    names = [f.spec for f in preset_failures(robot, parse_failure("case2", robot))]
    assert names == ["none", "case1"]
    assert [f.spec for f in preset_failures(robot, parse_failure("none", robot))] == ["case1", "case2"]
    custom = parse_failure("J2=0.3,J4=-1.5", robot)
    assert [f.spec for f in preset_failures(robot, custom)] == ["none", "case1", "case2"]
    assert [f.spec for f in preset_failures(robot, parse_failure("J6=0.935,J7=-0.7193", robot))] == ["none", "case1"]
    assert [f.spec for f in preset_failures(ur5e, parse_failure("case1", ur5e))] == ["none", "case2"]
    # one IK program (the reach map's, shared by the edges) and one rollout per preset: the
    # programs a build of that preset makes
    reach_cfg = reach_config(robot)
    config = BundleConfig(interaction_points=robot.default_ips)
    warm = preset_programs(robot, parse_failure("case2", robot), reach_cfg, config, reach_cfg.object_height / 2)
    assert [(spec, stage) for spec, stage, _ in warm] == [("none", "ik"), ("none", "rollout"), ("case1", "ik"),
                                                          ("case1", "rollout")]  # fmt: skip
    keys = [k.placed for _, _, k in warm]
    assert keys[2:] == _programs(robot, "case1", 1_000_000, 0, None, sharded=True)[1:]  # the command's default
    assert keys[:2] == _programs(robot, "none", 100_000, 4, None)[1:]


def test_the_presets_are_the_programs_a_build_compiles(robot):
    """By JAX's own persistent-cache key: the case2 programs a build of none compiles for
    later builds are those a build of case2 compiles (another edge count, seed and chunking,
    sharded as `lmjx build-map` is by default, on this one device), also placed on a device
    given (as each device's of a build split over several: one program for all of them)."""
    reach_cfg = reach_config(robot)
    half = reach_cfg.object_height / 2
    config = BundleConfig(interaction_points=robot.default_ips)
    warm = preset_programs(robot, parse_failure("none", robot), reach_cfg, config, half)
    later = {stage: kernel for spec, stage, kernel in warm if spec == "case2"}
    case2 = parse_failure("case2", robot)
    other = BundleConfig(edges=7_000, seed=9, build_chunk=700, interaction_points=robot.default_ips)
    build = EdgeKernels(robot, case2, other, True, half, ik_chunk=reach_cfg.chunk)
    placed = EdgeKernels(robot, case2, other, False, half, device=jax.local_devices()[0], ik_chunk=reach_cfg.chunk)
    for stage, kernels in (("ik", (build.ik.kernel, placed.ik.kernel)), ("rollout", (build.rollout, placed.rollout))):
        keys = [jax_cache_key(k.lower()[0]) for k in (later[stage], *kernels)]
        assert keys[0] is not None and keys == [keys[0]] * 3, stage


class _Out(NamedTuple):
    y: jnp.ndarray


def _kernel(constant: float) -> ChunkedKernel:
    return ChunkedKernel(("test-cache", constant), lambda x: _Out(jnp.tanh(x) * constant), [], [(np.float32, (3,))], 8)


def test_the_cache_lookup_agrees_with_jax():
    """Before compiling, a new program is not in JAX's persistent cache; compiled, it is, and
    compiling it again is a persistent-cache hit by JAX's own count; the presets' compiler
    compiles what is missing and leaves what is there."""
    constant = float(int.from_bytes(os.urandom(3), "little"))  # a program no earlier run compiled (float32-exact)
    hits: list[str] = []

    def listen(event: str, **kw) -> None:
        if event == "/jax/compilation_cache/cache_hits":
            hits.append(event)

    before = jax.config.jax_persistent_cache_min_compile_time_secs
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)  # so small a program is kept too
    jax.monitoring.register_event_listener(listen)
    try:
        first = PresetCompiler([("f", "test", _kernel(constant))])
        assert in_jax_cache(first.programs[0][2].lower()[0]) is False
        first.run()
        assert first.compiled == ["f test"] and first.cached == [] and first.error is None
        again = _kernel(constant)  # another kernel of the same program (from the export the first saved)
        assert in_jax_cache(again.lower()[0]) is True
        hits.clear()
        again.lower()[0].compile()
        assert hits  # JAX found it in its cache too
        second = PresetCompiler([("f", "test", _kernel(constant))])
        second.run()
        assert second.cached == ["f test"] and second.compiled == []
        assert in_jax_cache(_kernel(constant + 1).lower()[0]) is False
    finally:
        jax.monitoring.unregister_event_listener(listen)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", before)


class _Unlowerable:
    """A stand-in program that fails when lowered: a build that lowers it says so."""

    key = "unlowerable"

    def lower(self, keep: bool = True):
        raise RuntimeError("lowered")


def test_a_record_spares_looking_the_presets_up(tmp_path):
    """Once the presets are all in the cache, the record of their cache keys lets the next
    build skip lowering and looking them up; a record whose programs the cache no longer
    holds (or that names other programs) is ignored."""
    constant = float(int.from_bytes(os.urandom(3), "little"))
    record = tmp_path / "programs" / "presets.json"
    before = jax.config.jax_persistent_cache_min_compile_time_secs
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)  # so small a program is kept too
    try:
        first = PresetCompiler([("f", "test", _kernel(constant))], record=record)
        first.run()
        assert first.compiled == ["f test"] and first.error is None
        keys = json.loads(record.read_text())["jax_keys"]
        assert keys == [jax_cache_key(_kernel(constant).lower()[0])]
        spared = PresetCompiler([("f", "test", _Unlowerable())], record=record)  # (it is not lowered)
        spared.run()
        assert spared.cached == ["f test"] and spared.error is None
        two = PresetCompiler([("f", "test", _Unlowerable()), ("g", "test", _Unlowerable())], record=record)
        two.run()  # the record holds one program's key: these are looked up
        assert two.error is not None and "lowered" in two.error
        record.write_text(json.dumps({"programs": ["f test"], "jax_keys": ["0" * 64]}))  # not in the cache
        stale = PresetCompiler([("f", "test", _Unlowerable())], record=record)
        stale.run()
        assert stale.cached == [] and stale.error is not None
    finally:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", before)
    named = preset_record([("f", "test", _kernel(1.0))])
    assert named == preset_record([("g", "x", _kernel(1.0))]) != preset_record([("f", "test", _kernel(2.0))])
    assert named is not None and named.parent.name == "programs" and preset_record([]) is None


def test_a_record_is_named_by_what_jax_keys_hold(monkeypatch):
    """A record is read without lowering its programs: one made under other XLA flags, JAX
    settings or another number of devices (whose programs JAX keys apart) is another record,
    not this one."""
    programs = [("f", "test", _kernel(1.0))]
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    named = preset_record(programs)
    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_hlo_as_text")
    flagged = preset_record(programs)
    monkeypatch.delenv("XLA_FLAGS")
    before = jax.config.jax_default_matmul_precision
    jax.config.update("jax_default_matmul_precision", "highest")
    try:
        precise = preset_record(programs)
    finally:
        jax.config.update("jax_default_matmul_precision", before)
    shown = jax.devices()
    real = jax.devices
    monkeypatch.setattr(jax, "devices", lambda *a: shown * 2)  # (a process shown twice the devices)
    doubled = preset_record(programs)
    monkeypatch.setattr(jax, "devices", real)
    assert named is not None and len({named, flagged, precise, doubled}) == 4
    assert preset_record(programs) == named


def test_a_kept_lowering_is_compiled_once_and_dropped(monkeypatch):
    """A program lowered to look it up (`lower`) is compiled from that lowering by whichever
    kernel of it compiles, and dropped then; a lowering kept while another kernel compiled
    the program is not kept for ever."""
    constant = float(int.from_bytes(os.urandom(3), "little"))
    first, second = _kernel(constant), _kernel(constant)
    first.lower()
    assert first.placed in lmjx.runtime.batching._LOWERED

    def unlowerable(*args, **kwargs):
        raise AssertionError("lowered again")

    monkeypatch.setattr(second, "_lower", unlowerable)
    second.compile()  # from the lowering `first` kept
    assert first.placed not in lmjx.runtime.batching._LOWERED and first.placed in lmjx.runtime.batching._COMPILED

    late, other = _kernel(constant + 1), _kernel(constant + 1)
    lower = late._lower

    def lower_while_compiled(*args, **kwargs):
        out = lower(*args, **kwargs)
        thread = threading.Thread(target=other.compile)  # another kernel of the program, meanwhile
        thread.start()
        thread.join()
        return out

    monkeypatch.setattr(late, "_lower", lower_while_compiled)
    late.lower()
    assert late.placed in lmjx.runtime.batching._COMPILED and late.placed not in lmjx.runtime.batching._LOWERED


def test_a_stopped_compiler_starts_no_program():
    compiler = PresetCompiler([("f", "test", _kernel(1.0)), ("g", "test", _kernel(2.0))])
    compiler.stop()
    compiler.run()
    assert compiler.compiled == [] and compiler.cached == [] and compiler.summary()["left"] == 2


class _Slow:
    """A stand-in program that takes a while to compile (JAX's cache cannot tell it)."""

    key = "slow"

    def lower(self, keep: bool = True):
        return self, []

    def compile(self) -> None:
        time.sleep(2.0)


def _interrupt(times: int, every: float = 0.2) -> threading.Thread:
    def send() -> None:
        for _ in range(times):
            time.sleep(every)
            os.kill(os.getpid(), signal.SIGINT)

    thread = threading.Thread(target=send, daemon=True)
    thread.start()
    return thread


def test_ctrl_c_lets_the_program_being_compiled_finish():
    """A first Ctrl-C while the build waits for the presets: no other program starts, the
    one under way finishes, and the build returns; a second leaves at once.  Python's own
    Ctrl-C handler is installed for the test, as in `lmjx` (a test runner's worker may
    ignore Ctrl-C), and put back after."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        _ctrl_c_twice()
    finally:
        signal.signal(signal.SIGINT, previous)


def _ctrl_c_twice() -> None:
    said: list[str] = []
    presets = PresetCompiler([(s, "x", _Slow()) for s in ("a", "b", "c")])
    background = BackgroundCompile([], presets)
    background.wait_own()
    sender = _interrupt(1)
    background.finish(said.append)
    sender.join()
    assert presets.compiled == ["a x"] and presets.summary()["left"] == 2
    assert "for later builds" in said[0] and "Ctrl-C again leaves now" in said[1]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored

    presets = PresetCompiler([(s, "x", _Slow()) for s in ("a", "b", "c")])
    background = BackgroundCompile([], presets)
    sender = _interrupt(2, every=0.15)
    with pytest.raises(InterruptedAfterMap):
        background.finish(said.append)
    sender.join()
    assert presets.stopped and len(presets.compiled) <= 1
    background.thread.join()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
