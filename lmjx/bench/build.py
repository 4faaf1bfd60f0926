"""`lmjx bench --sections build`: the user's `lmjx build-map` timed end to end.

Each size runs the real command (`python -m lmjx.cli build-map ... --json`) in a fresh
process, into a temporary folder removed afterwards, with this process's cache folder
(`LMJX_CACHE_DIR`): compiling or loading programs is what a user's build pays too.  From its
JSON summary: seconds per stage (reach map, IK, rollouts, spatial index, push counts,
writing, compiling by stage, and what is left: starting the process, drawing, packing,
waiting), the device's own kernel time (IK + rollouts + index + push counts, device-seconds),
the ratio of wall time to it (a build bound by the host shows as a large ratio), and the
preflight's estimate beside the wall time.  Speed is measured here, never asserted in tests.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from lmjx.errors import LmjxError

SIZES = {"gpu": [100_000, 1_000_000], "cpu": [10_000]}  # sampled edges per platform
STAGES = ("reach", "ik", "rollout", "index", "push", "write", "compile", "other")


class BuildBenchError(LmjxError):
    """The timed build failed."""


def build_sizes(on_gpu: bool, edges: list[int] | None) -> list[int]:
    """The sizes to time: `edges` when given, else the platform's (`SIZES`)."""
    return list(edges) if edges else SIZES["gpu" if on_gpu else "cpu"]


def build_args(failure: str, edges: int, robot_flag: list[str], seed: int = 0) -> list[str]:
    """`lmjx build-map`'s options for one timed build (its --out and --json aside)."""
    return [*robot_flag, "--failure", failure, "--edges", str(edges), "--seed", str(seed)]


def run_build(args: list[str]) -> dict:
    """Run `lmjx build-map ARGS --json` in a fresh process into a temporary folder; its row
    (`build_row`)."""
    with tempfile.TemporaryDirectory(prefix="lmjx-bench-build-") as tmp:
        cmd = [sys.executable, "-m", "lmjx.cli", "build-map", *args, "--out", str(Path(tmp) / "map.h5"), "--json"]
        t0 = time.perf_counter()
        r = subprocess.run(cmd, capture_output=True, text=True, env=os.environ.copy())
        wall = time.perf_counter() - t0
    if r.returncode != 0:
        last = (r.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise BuildBenchError(f"the timed build-map {' '.join(args)} failed: {last}; run it alone to see why")
    return build_row(json.loads(r.stdout), wall)


def build_row(summary: dict, wall: float) -> dict:
    """One build's figures from its `--json` summary and its process's wall time: seconds
    per stage (they sum to `wall`; `other` is what no stage accounts for, and is below zero
    where stages overlap, as the index packed beside the rollouts), kernel seconds, the
    wall / kernel ratio and the preflight's error."""
    e = summary["edges"]
    by_stage = summary["compile_seconds_by_stage"]
    timing = e["writer_timing"]
    stages = {
        "reach": e["reach_seconds"] - by_stage.get("reach", 0.0),
        "ik": e["ik_seconds"],
        "rollout": e["rollout_seconds"],
        "index": e["index"].get("seconds", 0.0),
        "push": e["push_seconds"],
        # the writing process's own work, its content digest (the wait for it, computed beside
        # the push counts, where the summary has it) and the move: what the build waits for
        # once the edges are done
        "write": e["write_seconds"] + e["finish_seconds"] + timing.get("digest_wait", timing.get("digest", 0.0))
        + timing.get("replace", 0.0) + timing.get("remove_partial", 0.0),
        "compile": summary["compile_seconds"],
    }  # fmt: skip
    stages["other"] = wall - sum(stages.values())
    kernel = stages["ik"] + stages["rollout"] + stages["index"] + stages["push"]
    pre = e.get("preflight", {})
    row = {
        "failure": summary["failure"],
        "edges": e["edges_sampled"],
        "edges_valid": e["edges_valid"],
        "states": e["states"],
        "device": e["device"],
        "devices": e["devices"],
        "wall_s": round(wall, 3),
        "build_s": e.get("build_seconds"),
        "stages_s": {k: round(v, 3) for k, v in stages.items()},
        "compile_by_stage_s": by_stage,
        "kernel_s": round(kernel, 3),
        "wall_over_kernel": round(wall / kernel, 2) if kernel > 0 else None,
        "preflight_s": pre.get("seconds"),
        "preflight_stages_s": pre.get("stages"),
        "preflight_basis": pre.get("basis"),
    }
    if pre.get("seconds") is not None:
        row["preflight_error_pct"] = round(100.0 * (pre["seconds"] - wall) / wall, 1)
    return row


def bench_build(failure: str, sizes: list[int], robot_flag: list[str]) -> dict:
    """Time `lmjx build-map --failure F --edges N` for each size."""
    return {"failure": failure, "rows": [run_build(build_args(failure, n, robot_flag)) for n in sizes]}


def print_build(report: dict) -> None:
    print(f"  build-map --failure {report['failure']}, end to end (seconds per stage):")
    print("    " + f"{'edges':>10} {'wall':>8} " + " ".join(f"{s:>8}" for s in STAGES)
          + f" {'kernels':>8} {'wall/k':>7} {'preflight':>10}")  # fmt: skip
    for r in report["rows"]:
        pre = f"{r['preflight_s']:.1f} ({r['preflight_error_pct']:+.0f}%)" if r.get("preflight_s") is not None else "-"
        ratio = f"{r['wall_over_kernel']:.2f}" if r["wall_over_kernel"] is not None else "-"
        print(
            "    "
            + f"{r['edges']:>10,} {r['wall_s']:>8.1f} "
            + " ".join(f"{r['stages_s'][s]:>8.1f}" for s in STAGES)
            + f" {r['kernel_s']:>8.1f} {ratio:>7} {pre:>10}"
        )
        comp = ", ".join(f"{k} {v:.1f}" for k, v in r["compile_by_stage_s"].items())
        print(f"    {'':>10} compile by stage: {comp}; {r['edges_valid']:,} valid edges, {r['states']:,} states")
