"""Where an evaluation's trials come from: the code (lmjx's version and commit), the maps (their
content digests), the task set, the planner's configuration and its planning limit, the
simulator and its device, the host and the command.

`new_run` describes one invocation of `lmjx evaluate` (a "run": results.json keeps one entry
per run in its header, `lmjx.evaluation.results`); `trial_provenance` is the part each trial
record carries itself, so that a record taken out of its file still says what made it.
`conditions` are what must agree for trials to be pooled in one table (the code, the maps,
the task set, the planner, the simulator, the trials per cell and the seed base); the host,
the device and the command may differ between the runs of one evaluation (a run resumed on
another machine of the same kind), and the report lists them.

The code is named by git's commit where this package is part of a git checkout; a copy
without its .git folder names it with two environment variables together: LMJX_COMMIT (the
commit) and LMJX_SOURCE_DIGEST (`source_digest` of that commit's tree, which lmjx computes
here and compares: a copy whose files differ is refused in one line).  Without git and
without both, the commit is "unknown", and an unknown commit pools with no other run's
(`differences`).  `python -m lmjx.evaluation.provenance` prints both variables for a clean
checkout.

Nothing else here fails: what cannot be found out is recorded as "unknown" (a trial that
simulated nothing, Random's, records its device as "none").
"""

from __future__ import annotations

import datetime
import hashlib
import json
import os
import platform
import re
import secrets
import socket
import subprocess
import sys
from dataclasses import fields
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from lmjx import __version__
from lmjx.errors import ConfigError
from lmjx.mapfile.digest import DIGEST_ATTR, content_digest
from lmjx.runtime.cores import usable_cores
from lmjx.types import CONTROL_DT, PlannerConfig

if TYPE_CHECKING:
    from lmjx.mapfile.read import MapFile
    from lmjx.model.robot import Robot
    from lmjx.sim.scenarios import Task


class RunConfig(Protocol):
    """What a run's entry reads of its configuration (`lmjx.evaluation.evaluate.EvalConfig`)."""

    failures: tuple[str, ...]
    scenarios: tuple[int, ...]
    asms: tuple[str, ...]
    trials: int
    seed: int
    planner: PlannerConfig
    backend: str
    tasks: str
    part: tuple[int, int]
    scenes: tuple[Task, ...]  # tasks from scene files (`lmjx evaluate --scenes`); empty: the shipped scenarios


UNKNOWN = "unknown"
NONE = "none"  # the device of a trial that simulated nothing (Random)
COMMIT_ENV = "LMJX_COMMIT"  # names the commit of a checkout copied without its .git folder
SOURCE_ENV = "LMJX_SOURCE_DIGEST"  # with COMMIT_ENV: `source_digest` of that commit's tree, checked here
# the files `source_digest` covers: the code, the package's data (the robots' models, the task sets'
# scenes: they change what a trial does) and pyproject.toml
SOURCES = ("lmjx/**/*.py", "kernels/**/*.py", "lmjx/model/assets/*.xml", "lmjx/sim/scenes/*.toml", "pyproject.toml")
COMMIT_RE = re.compile(r"[0-9a-f]{40}")
PACKAGES = ("numpy", "jax", "jaxlib", "mujoco", "mujoco-mjx", "warp-lang", "h5py")
LIMIT_UNIT = (
    f"simulated control steps ({CONTROL_DT * 1000:g} ms of an action's motion, per candidate rollout and start), "
    "counted the same on every host"
)


def _git(args: list[str], cwd: Path) -> bytes | None:
    """git's output, or None where git is missing or fails (not a repository, not trusted)."""
    try:
        done = subprocess.run(["git", *args], cwd=cwd, capture_output=True, timeout=30, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout if done.returncode == 0 else None


def package_root() -> Path:
    """The folder that holds the lmjx package (a checkout's root, or site-packages)."""
    return Path(__file__).resolve().parents[2]


def source_digest(root: Path | None = None) -> str:
    """SHA-256 of the package's source files (`SOURCES` under `root`, default `package_root`):
    for each file, in the order of their relative paths (POSIX), the path, a NUL byte, its
    length in bytes (decimal), a NUL byte and its bytes.  Every file there that matches
    counts, tracked or not (a copy without .git cannot tell them apart): in a clean checkout
    without untracked source files they are the commit's."""
    root = root or package_root()
    files = sorted({p for pattern in SOURCES for p in root.glob(pattern) if p.is_file()})
    h = hashlib.sha256()
    for p in files:
        data = p.read_bytes()
        h.update(p.relative_to(root).as_posix().encode() + b"\0" + str(len(data)).encode() + b"\0" + data)
    return h.hexdigest()


def _tree_changes(root: Path) -> bytes | None:
    """How the tracked files differ from the commit (`git diff HEAD --binary`: empty where they
    do not), or None where git cannot tell."""
    return _git(["diff", "HEAD", "--binary"], root)


def code_version() -> dict[str, Any]:
    """lmjx's version and commit, and `source_digest` of the files it runs: `git rev-parse
    HEAD` where this package is a tracked part of a git checkout (with `dirty`: whether tracked
    files differ from the commit, and `changes`: a digest of that difference, so runs of one
    dirty tree can be told from another's); else the commit LMJX_COMMIT names, accepted only
    with LMJX_SOURCE_DIGEST equal to the files' digest (a one-line ConfigError otherwise: a
    copy that differs from the commit it names); else "unknown"."""
    root = package_root()
    digest = source_digest(root)
    out: dict[str, Any] = {"version": __version__, "commit": UNKNOWN, "commit_source": UNKNOWN, "dirty": None,
                           "changes": None, "source_digest": digest}  # fmt: skip
    head = _git(["rev-parse", "HEAD"], root)
    tracked = _git(["ls-files", "--error-unmatch", "lmjx/__init__.py"], root)
    if head is not None and tracked is not None:
        diff = _tree_changes(root)
        out |= {"commit": head.decode().strip(), "commit_source": "git"}
        if diff is not None:
            out["dirty"] = bool(diff)
            out["changes"] = hashlib.sha256(diff).hexdigest()[:16] if diff else None
        return out
    named, given = (os.environ.get(k, "").strip() for k in (COMMIT_ENV, SOURCE_ENV))
    if not named and not given:
        return out
    fix = "`python -m lmjx.evaluation.provenance` prints both in a clean checkout of the commit"
    if not given:
        raise ConfigError(f"{COMMIT_ENV} is set without {SOURCE_ENV}, the digest of that commit's source files; "
                          f"set both ({fix}) or neither")  # fmt: skip
    if not named:
        raise ConfigError(f"{SOURCE_ENV} is set without {COMMIT_ENV}; set both ({fix}) or neither")
    if not COMMIT_RE.fullmatch(named):
        raise ConfigError(f"{COMMIT_ENV}={named}: name the commit by its full 40-digit hash ({fix})")
    if given != digest:
        raise ConfigError(f"{SOURCE_ENV}={given[:16]}... but the source files here digest to {digest[:16]}...: "
                          f"they are not those of commit {named[:12]}; copy that commit's tree, or set both "
                          f"variables anew ({fix})")  # fmt: skip
    return out | {"commit": named, "commit_source": COMMIT_ENV}


def commit_environment() -> str:
    """`LMJX_COMMIT=... LMJX_SOURCE_DIGEST=...` for this checkout, to name its commit on a copy
    without .git; a one-line ConfigError where git cannot tell the commit or where tracked
    files differ from it or source files are not tracked (the digest would not be the
    commit's)."""
    root = package_root()
    here = code_version()
    if here["commit_source"] != "git" or here["dirty"] is None:
        raise ConfigError("no git checkout here to take the commit from; run this in a clean checkout of it")
    loose = _git(["status", "--porcelain", "--untracked-files=all", "--", *(f":(glob){x}" for x in SOURCES)], root)
    if here["dirty"] or loose:
        raise ConfigError("the source files differ from the commit (changed or untracked: git status); commit "
                          "or remove the changes, then run this again")  # fmt: skip
    return f"{COMMIT_ENV}={here['commit']} {SOURCE_ENV}={here['source_digest']}"


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or UNKNOWN


def _package_versions() -> dict[str, str]:
    out = {}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return out


def host_info() -> dict[str, Any]:
    """The machine: its name, platform, CPU and the cores this process may use, Python and the
    versions of the packages the results depend on."""
    return {
        "hostname": socket.gethostname() or UNKNOWN,
        "platform": platform.platform(),
        "cpu": _cpu_model(),
        "cores": usable_cores(),
        "python": platform.python_version(),
        "packages": _package_versions(),
    }


def _gpu_name() -> str:
    import warp as wp

    return wp.get_device("cuda:0").name


def simulator_description(name: str) -> str:
    """Where the planner's simulations ran, in words, for reports."""
    if name == "gpu":
        return f"gpu: MuJoCo Warp on {_gpu_name()}, whole scene"
    what = "whole scene" if name == "cpu" else "the target and its 3 nearest objects"
    return f"{name}: C MuJoCo mujoco.rollout on {usable_cores()} cores, {what}"


def simulator_info(name: str, simulates: bool = True) -> dict[str, Any]:
    """The planner's simulator (`name`: "cpu", "cpu-near", "gpu"; `simulates` False: a run of
    Random alone, which simulates nothing) and the device it runs on."""
    if not simulates:
        return {"name": NONE, "description": "none (Random simulates nothing)", "device": NONE}
    device = _gpu_name() if name == "gpu" else f"{_cpu_model()}, {usable_cores()} cores"
    return {"name": name, "description": simulator_description(name), "device": device}


def map_entry(m: MapFile) -> dict[str, Any]:
    """A map as a run records it: its path, content digest (the one the build stored, else
    computed here once) and edges."""
    stored = m.attrs.get(DIGEST_ATTR)
    if stored is not None:
        digest, source = (stored.decode() if isinstance(stored, bytes) else str(stored)), "stored"
    else:
        digest, source = content_digest(m.path)[0], "computed"
    return {"path": str(m.path), "digest": digest, "digest_source": source,
            "edges": None if m.edges is None else int(m.edges.n_edges)}  # fmt: skip


def task_digest(robot: Robot, tasks: str, scenarios: tuple[int, ...], scenes: tuple[Task, ...] = ()) -> str:
    """A digest of the tasks' definitions as the trials face them: every object, obstacle, goal
    region, jitter and budget, placed for the robot (`lmjx.sim.scenefile.definitions_digest`):
    the shipped `scenarios` of the task set `tasks`, or, where `scenes` are given (tasks read
    from scene files, whatever task sets they name), theirs."""
    from lmjx.sim.scenefile import definitions_digest

    if scenes:
        return definitions_digest(t.scenario for t in sorted(scenes, key=lambda t: t.number))
    from lmjx.sim.scenarios import resolve_task

    return definitions_digest(resolve_task(s, robot, tasks).scenario for s in sorted(scenarios))


def planner_fields(config: PlannerConfig, asm: str | None = None) -> dict[str, Any]:
    """Every field of the planner's configuration (`asm`: in place of its own; None: left out,
    for a run's entry, whose ASMs share the rest)."""
    out = {f.name: getattr(config, f.name) for f in fields(config)}
    if asm is None:
        out.pop("asm")
    else:
        out["asm"] = asm
    return out


def new_run(
    robot: Robot, maps: dict[str, MapFile], config: RunConfig, command: str | None, allow_mixed: bool = False
) -> dict[str, Any]:
    """The entry of one invocation of `lmjx evaluate` (results.json's header), with its id: a
    digest of the entry and a random nonce (every invocation has its own)."""
    simulates = bool(set(config.asms) - {"random"})
    run: dict[str, Any] = {
        "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "command": command or UNKNOWN,
        "robot": robot.key,
        "lmjx": code_version(),
        "maps": {f: map_entry(m) for f, m in sorted(maps.items()) if f in config.failures},
        "tasks": {"set": config.tasks, "digest": task_digest(robot, config.tasks, config.scenarios, config.scenes)},
        "trials_per_cell": config.trials,
        "seed_base": config.seed,
        "part": list(config.part),
        "cells": {"failures": list(config.failures), "scenarios": list(config.scenarios), "asms": list(config.asms)},
        "simulator": simulator_info(config.backend, simulates),
        "host": host_info(),
        "planner": planner_fields(config.planner),
        "planning_limit": {"max_sim_steps": config.planner.max_sim_steps, "unit": LIMIT_UNIT},
        "allow_mixed": allow_mixed,
    }
    # (with a nonce: two runs started in the same second on one host have their own ids)
    nonce = secrets.token_hex(8)
    run["id"] = hashlib.sha256((nonce + json.dumps(run, sort_keys=True, default=str)).encode()).hexdigest()[:12]
    run["trials_run"] = 0  # (the trials this run ran, counted as they end)
    return run


def trial_provenance(run: dict[str, Any], failure: str, asm: str) -> dict[str, Any]:
    """What a trial record carries of its run: the code, its map, the simulator and device,
    the host, the task set and the planner's whole configuration (with the trial's ASM)."""
    m = run["maps"].get(failure, {})
    sim = run["simulator"] if asm != "random" else simulator_info("", simulates=False)
    return {
        "lmjx": run["lmjx"]["version"],
        "commit": run["lmjx"]["commit"],
        "dirty": run["lmjx"]["dirty"],
        "source_digest": run["lmjx"].get("source_digest"),
        "map": {"path": m.get("path", UNKNOWN), "digest": m.get("digest", UNKNOWN)},
        "tasks": run["tasks"],
        "simulator": sim["name"],
        "device": sim["device"],
        "host": run["host"]["hostname"],
        "planner": run["planner"] | {"asm": asm},
    }


# ------------------------------------------------------------------------------ conditions


def unknown_run(run_id: str = UNKNOWN) -> dict[str, Any]:
    """The entry standing for trials whose run is not recorded (a results file written without
    provenance): every condition unknown, so they pool with nothing unless allowed."""
    return {"id": run_id, "started": UNKNOWN, "command": UNKNOWN, "robot": UNKNOWN,
            "lmjx": {"version": UNKNOWN, "commit": UNKNOWN, "commit_source": UNKNOWN, "dirty": None, "changes": None,
                     "source_digest": None},
            "maps": {}, "tasks": {"set": UNKNOWN, "digest": UNKNOWN}, "trials_per_cell": UNKNOWN,
            "seed_base": UNKNOWN, "simulator": {"name": UNKNOWN, "description": UNKNOWN, "device": UNKNOWN},
            "host": {"hostname": UNKNOWN}, "planner": {}, "planning_limit": {}, "unrecorded": True}  # fmt: skip


def short_commit(run: dict[str, Any]) -> str:
    c = run["lmjx"]
    text = c["commit"][:12] if c["commit"] != UNKNOWN else UNKNOWN
    return text + (f" with changes {c['changes']}" if c.get("changes") else "")


def differences(held: dict[str, Any], new: dict[str, Any]) -> list[tuple[str, str, str]]:
    """What differs between two runs' conditions: (what, held's, new's) each; empty where their
    trials may be pooled.  An unknown commit differs from every other run's, unknown or not
    (nothing says the code was the same); a run is compared with itself only by its id."""
    if held.get("unrecorded") or new.get("unrecorded"):
        return [("provenance", "not recorded" if held.get("unrecorded") else "recorded",
                 "not recorded" if new.get("unrecorded") else "recorded")]  # fmt: skip
    if held.get("id") is not None and held.get("id") == new.get("id"):
        return []
    out = []
    if held["robot"] != new["robot"]:
        out.append(("robot", held["robot"], new["robot"]))
    a, b = held["lmjx"], new["lmjx"]
    if UNKNOWN in (a["commit"], b["commit"]) or (a["commit"], a.get("changes")) != (b["commit"], b.get("changes")):
        out.append(("commit", short_commit(held), short_commit(new)))
    elif a.get("source_digest") and b.get("source_digest") and a["source_digest"] != b["source_digest"]:
        out.append(("source files", a["source_digest"][:12], b["source_digest"][:12]))
    for f in sorted(set(held["maps"]) & set(new["maps"])):
        if held["maps"][f]["digest"] != new["maps"][f]["digest"]:
            out.append((f"map of {f}", held["maps"][f]["digest"][:12], new["maps"][f]["digest"][:12]))
    if held["tasks"] != new["tasks"]:
        out.append(("task set", f"{held['tasks']['set']} {held['tasks']['digest']}",
                    f"{new['tasks']['set']} {new['tasks']['digest']}"))  # fmt: skip
    for key, what in (("trials_per_cell", "trials per cell"), ("seed_base", "seed base")):
        if held[key] != new[key]:
            out.append((what, str(held[key]), str(new[key])))
    if len({held["simulator"]["name"], new["simulator"]["name"]} - {"none"}) > 1:
        out.append(("simulator", held["simulator"]["name"], new["simulator"]["name"]))
    keys = [k for k in sorted(set(held["planner"]) | set(new["planner"])) if _compared(k, held, new)]
    for k in keys:
        x, y = held["planner"].get(k, UNKNOWN), new["planner"].get(k, UNKNOWN)
        if x != y:
            out.append((f"planner's {k}", str(x), str(y)))
    return out


def differences_text(diff: list[tuple[str, str, str]], first: str, second: str) -> str:
    """`differences` in words: 'commit (FIRST abc; SECOND def), ...'."""
    return ", ".join(f"{what} ({first} {a}; {second} {b})" for what, a, b in diff)


# levers only some ASMs read: compared only between runs that both ran such an ASM (a run of
# Random alone on a GPU host and one of Greedy pool, whatever Random's unused Greedy settings)
ASM_LEVERS = {
    "greedy_candidates": ("greedy",), "greedy_fraction": ("greedy",), "rescore_top": ("greedy",),
    "rescore_draws": ("greedy",), "when_stuck": ("greedy",), "lazy_tries": ("lazy",), "lazy_cap": ("lazy",),
    "lazy_fallback": ("lazy",), "servo": ("lazy", "greedy"),
}  # fmt: skip


def _compared(key: str, a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Whether the lever `key` is compared between runs `a` and `b` (`ASM_LEVERS`)."""
    users = ASM_LEVERS.get(key)
    if users is None:
        return True
    asms = [set(r.get("cells", {}).get("asms", users)) for r in (a, b)]
    return all(x & set(users) for x in asms)


if __name__ == "__main__":  # `python -m lmjx.evaluation.provenance`: the variables that name this checkout's commit
    try:
        print(commit_environment())
    except ConfigError as e:
        print(f"lmjx.evaluation.provenance: error: {e}", file=sys.stderr)
        sys.exit(2)
