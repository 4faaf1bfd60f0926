"""The preflight of `lmjx build-map`: the output's size and the build's time, estimated
before any work from what the build will compute (`Work`: IK problems, edge-steps, states)
and measured per-stage rates (`RATES`), one table per platform.

The estimate is a sum of stages, as the build runs them on the CPU: starting the process,
the reach map, the edges' IK, their rollouts, the spatial index, the push counts, writing,
and compiling (less for programs JAX's persistent cache already holds: they are loaded).
On GPUs the edges' IK, rollouts and index gain what measured builds gained from each
device beyond the first (`device_gain`: a quarter, as each device's host work, in a process
of its own, shares the host's cores and memory with the others'); on a CPU the kernels'
stages scale with the cores from the measuring machine's.
Nothing here computes or compiles anything.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from lmjx.runtime.cores import usable_cores

DAY = 86_400.0
MAP_BYTES_PER_EDGE = 620.0  # the finished map, per sampled edge (case 2: 45 bytes a stored state)
PARTIAL_BYTES_PER_EDGE = 900.0  # the chunks in <out>.partial (raw arrays; case 2: about 885)
# Per sampled edge, the share whose start IK solves (then rolled out for the full `steps`:
# the rollout program runs every step of its launch) and the states kept; measured on the
# CPU builds of benchmarks/RESULTS.md ("lmjx bench --sections build"): case 2 0.756 and 12.7,
# case 1 0.646 and 10.9; about their mean.
ROLLED_PER_EDGE = 0.70
STATES_PER_EDGE = 11.8


@dataclass(frozen=True)
class StageRates:
    """Rates of a build's stages on one device (a GPU) or on `cores` CPU cores, after
    compilation; and compile seconds per program stage, compiled or loaded from the cache."""

    where: str  # the machine the rates were measured on
    cores: int  # CPU cores of that machine (the CPU's kernel rates scale with them)
    startup_s: float  # the process: Python, JAX, the robot model
    reach_problems_per_s: float  # the reach map's IK problems (cells x attempts x restarts)
    ik_problems_per_s: float  # the edges' start IK problems (edges x restarts)
    edge_steps_per_s: float  # rollout steps (edges rolled out x steps)
    index_states_per_s: float  # the spatial index (kept states rasterized)
    push_states_per_s: float  # the scenarios' push counts (kept states)
    write_states_per_s: float  # packing, writing and reading back the map, left after the edges
    # the edges' IK and rollouts' seconds times this where a build has several chunks: its
    # chunk threads then run side by side (a CPU's kernels leave cores idle that the other
    # thread's take)
    overlap: float
    # what each device beyond the first adds to the rate of the edges' stages (IK, rollouts,
    # index): 1.0 where they scale with the devices; on GPUs the host's work on the computed
    # edges sets the pace, each device's in a process of its own (`lmjx.edges.peers`) sharing
    # the host (2 x H200: the edges of a 5,000,000-edge build 1.25-1.31x as fast on two)
    device_gain: float
    # compiling, per stage (the reach map's, the edges', the index's, the push counts'): the
    # wall time it adds to a build when compiled here (the edges' and the index's compile
    # beside the reach map, and slow it), and when loaded from JAX's persistent cache
    compile_s: dict[str, float]
    cached_s: dict[str, float]


# The one table of measured rates (benchmarks/RESULTS.md, "lmjx bench --sections build").
# cpu: the 2-core machine, idle, `lmjx build-map --json` of 10,000 case-2 edges (`make run`'s
# map) with the programs cached, and with an empty cache (compile_s; the push counts' programs
# compile in the packer beside the rollouts); cores shared with other work slow every stage
# (at a load average of 8-15, 3-5x).
# gpu: one H200 with 16 host cores, `lmjx build-map --json` of 100,000, 1,000,000 and
# 5,000,000 case-2 edges with the programs cached (wall 5.0-5.3 s, 10.0 s, 28.7 s: 4.7 s per
# million edges beyond 5 s) and a cold 100,000-edge build (compile_s: the edges' include the
# other presets' programs compiled ahead for later builds, which the build waits for).  The
# IK and rollouts at 8 M problems/s and 18 M edge-steps/s, three quarters of that where two
# chunk threads run side by side; the index, the push counts and the packing and writing are
# done by the packers beside the rollouts, and count here by what they add to the wall
# (25 M, 40 M and 40 M states/s); 2.1 s of cache loads, 2.3 s of start-up and fixed costs.
RATES = {
    "cpu": StageRates(
        where="a 2-core CPU",
        cores=2,
        startup_s=2.5,
        reach_problems_per_s=19_000.0,
        ik_problems_per_s=14_800.0,
        edge_steps_per_s=65_000.0,
        index_states_per_s=125_000.0,
        push_states_per_s=1_200_000.0,
        write_states_per_s=40_000.0,
        overlap=0.68,
        device_gain=1.0,
        compile_s={"reach": 6.4, "edges": 12.5, "index": 10.2, "push": 9.0},
        cached_s={"reach": 0.7, "edges": 0.65, "index": 0.95, "push": 0.0},
    ),
    "gpu": StageRates(
        where="an H200",
        cores=16,
        startup_s=2.3,
        reach_problems_per_s=4_000_000.0,
        ik_problems_per_s=8_000_000.0,
        edge_steps_per_s=18_000_000.0,
        index_states_per_s=25_000_000.0,
        push_states_per_s=40_000_000.0,
        write_states_per_s=40_000_000.0,
        overlap=0.75,
        device_gain=0.25,
        compile_s={"reach": 10.0, "edges": 70.0, "index": 7.0, "push": 8.0},
        cached_s={"reach": 0.7, "edges": 0.8, "index": 0.6, "push": 0.0},
    ),
}


@dataclass(frozen=True)
class Work:
    """What a build computes, known from its settings before any of it is done."""

    edges: int  # sampled edges
    reach_problems: int  # the reach map's IK problems (0: the reach map is already computed)
    ik_problems: int  # the edges' start IK problems
    edge_steps: float  # rollout steps
    states: float  # kept states (index, push counts, writing)
    chunks: int = 1  # chunks of edges (each run by one chunk thread)

    @classmethod
    def of(
        cls, n: int, cells: int, attempts: int, restarts: int, ik_restarts: int, steps: int, chunk: int = 16384
    ) -> Work:
        """The work of `n` sampled edges of `steps` steps, computed in chunks of `chunk` edges,
        over a reach map of `cells` cells."""
        edges = (n * ik_restarts, n * ROLLED_PER_EDGE * steps, n * STATES_PER_EDGE)
        return cls(n, cells * attempts * restarts, *edges, chunks=-(-n // chunk))

    @classmethod
    def default(cls, n: int) -> Work:
        """The default settings' work (a 50 x 60 grid, k 10, M 8, 8 restarts, 100 steps)."""
        return cls.of(n, 3000, 10, 8, 8, 100)


@dataclass
class Preflight:
    edges: int
    map_bytes: float
    disk_bytes: float  # partial chunks + the map, at the end of the build
    seconds: float
    free_bytes: int
    devices: int
    basis: str
    stages: dict[str, float]  # the estimate's seconds per stage (they sum to `seconds`)

    def lines(self) -> list[str]:
        return [
            f"preflight: {self.edges:,} edges -> a map of about {size_text(self.map_bytes)} "
            f"({size_text(self.disk_bytes)} of disk while it is built; {size_text(self.free_bytes)} free), "
            f"about {duration_text(self.seconds)} ({self.basis})"
        ]

    def summary(self) -> dict:
        return {"seconds": round(self.seconds, 2), "stages": {k: round(v, 2) for k, v in self.stages.items()},
                "basis": self.basis}  # fmt: skip


def size_text(b: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if b < 1000 or unit == "TB":
            return f"{b:.0f} {unit}" if unit == "B" else f"{b:.1f} {unit}"
        b /= 1000
    return f"{b:.1f} TB"


def duration_text(s: float) -> str:
    if s < 120:
        return f"{s:.0f} s"
    if s < 2 * 3600:
        return f"{s / 60:.0f} min"
    if s < 2 * DAY:
        return f"{s / 3600:.1f} h"
    return f"{s / DAY:.1f} days"


def stage_seconds(work: Work, platform: str, devices: int, cores: int, cached: dict[str, bool | None]) -> dict:
    """Estimated seconds per stage of `work` on `platform` ("cpu" or an accelerator's) with
    `devices` accelerators or `cores` CPU cores; `cached`: per compile stage ("reach",
    "edges", "index", "push"), whether JAX's persistent cache holds its programs (None: unknown,
    counted as compiled)."""
    gpu = platform != "cpu"
    r = RATES["gpu" if gpu else "cpu"]
    kernels = cores / r.cores if not gpu else 1.0  # the CPU's kernels use all its cores
    per_device = (1 + (devices - 1) * r.device_gain) * kernels if gpu else kernels
    side_by_side = r.overlap if work.chunks > 1 else 1.0
    return {
        "startup": r.startup_s,
        "reach": work.reach_problems / (r.reach_problems_per_s * kernels),
        "ik": side_by_side * work.ik_problems / (r.ik_problems_per_s * per_device),
        "rollout": side_by_side * work.edge_steps / (r.edge_steps_per_s * per_device),
        "index": work.states / (r.index_states_per_s * per_device),
        "push": work.states / (r.push_states_per_s * kernels),
        "write": work.states / r.write_states_per_s,
        "compile": sum((r.cached_s if cached.get(s) else r.compile_s)[s] for s in r.compile_s),
    }


BUSY_FROM = 0.5  # load average (of other work) per core from which the preflight counts it


def busy_factor(cores: int) -> float:
    """How much slower a CPU build runs for the other work on the machine: its load average
    over the last minute shares the cores with the build's (a build's cores are its own at a
    load below BUSY_FROM per core).  Measured: at a load average of 3-6 on 2 cores a build the
    rates put at 73 s took 276 s; this gives 3.5x at a load average of 5."""
    try:
        load = os.getloadavg()[0]
    except OSError:  # (no load average on this platform)
        return 1.0
    if load < BUSY_FROM * cores:
        return 1.0
    return (load + cores) / cores


def preflight(
    n: int,
    out: Path,
    devices: int,
    platform: str,
    work: Work | None = None,
    cached: dict[str, bool | None] | None = None,
) -> Preflight:
    """Estimated size and time of a build of n edges (before any work): `work` (default: the
    default settings'), `cached` as for `stage_seconds` (default: nothing cached)."""
    cores = usable_cores()
    stages = stage_seconds(work or Work.default(n), platform, devices, cores, cached or {})
    where = f"{devices} x {RATES['gpu'].where}" if platform != "cpu" else f"{cores} CPU cores"
    compiled = "programs cached" if cached and all(cached.values()) else "compiling included"
    basis = f"per-stage rates for {where}, {compiled}"
    busy = busy_factor(cores) if platform == "cpu" else 1.0
    if busy > 1.0:  # other work shares the cores: every stage slower by as much
        stages = {k: v * busy for k, v in stages.items()}
        basis += f"; the machine is busy (load average {os.getloadavg()[0]:.1f} on {cores} cores): {busy:.1f}x"
    parent = out.parent if str(out.parent) else Path(".")
    return Preflight(
        n,
        n * MAP_BYTES_PER_EDGE,
        n * (MAP_BYTES_PER_EDGE + PARTIAL_BYTES_PER_EDGE),
        sum(stages.values()),
        shutil.disk_usage(parent).free,
        devices,
        basis,
        stages,
    )
