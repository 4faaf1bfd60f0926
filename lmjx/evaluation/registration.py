"""A registered evaluation: the conditions a replicate is bound to before its first trial, read
from the page that registers it and enforced on the run.

A registration page (markdown, e.g. docs/evaluation/REPLICATE.md) holds, under a `#` heading
named "Registration" (any level; no other heading between them), one fenced code block tagged
`toml` (other toml blocks of the page are not read).  Its keys, every one required:

* `commit`: the 40-digit hash of the commit every trial runs;
* `base_seed`: the trials' base seed (trial seeds: `trial_seed(base_seed, scenario, trial)`);
* `rule`: the acceptance rule, in words;
* `[maps.FAILURE]`, one table per failure: `command` (how the map is built) and `digest` (its
  content digest: `benchmarks/map_digest.py`, `provenance.map_entry`);
* `[[arms]]`, one table per evaluation registered, each of its own task set: `name`, `tasks`
  ("paper" or "hard"), `trials` (per cell), `failures`, `scenarios`, `asms`, `sim` (the
  planner's simulator: "gpu", "cpu" or "cpu-near"), `candidates` (Greedy's, equal to the
  levers' greedy_candidates) and `[arms.levers]`: every lever of the planner's configuration,
  as results.json records it in `runs[].planner` (`provenance.planner_fields`; a lever whose
  value is none takes the string "none").

`read_registration` reads a page (a one-line ConfigError naming the key that is missing or
wrong); `check_against` lists how a run's entry (`provenance.new_run`) differs from an arm;
`enforce` refuses a run that differs from the arm of its task set (`RegistrationError`: one
line naming the first difference and its fix).  `lmjx evaluate --registered FILE` enforces it
before any trial runs; `benchmarks/eval_acceptance.py --registered FILE` checks every record
against it afterwards.
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from lmjx.errors import ConfigError, LmjxError
from lmjx.evaluation.provenance import COMMIT_ENV, COMMIT_RE, NONE, SOURCE_ENV, UNKNOWN
from lmjx.planner.levers import check_value
from lmjx.types import ASMS, PlannerConfig

HEADING = "registration"  # the heading the block lies under (case aside)
TASK_SETS = ("paper", "hard")
SIMULATORS = ("gpu", "cpu", "cpu-near")
LEVERS = tuple(f.name for f in fields(PlannerConfig) if f.name != "asm")  # what runs[].planner records
DIGEST_RE = re.compile(r"[0-9a-f]{64}")
_FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})\s*([^\s`]*)")
_HEADING = re.compile(r"^ {0,3}#{1,6}(?:\s+(.*?))?\s*$")
ARM_KEYS = ("name", "tasks", "trials", "failures", "scenarios", "asms", "sim", "candidates", "levers")
TOP_KEYS = ("commit", "base_seed", "rule", "maps", "arms")


class RegistrationError(LmjxError):
    """A run differs from the evaluation registered (its commit, tree, maps, levers, task set,
    seeds, trials, cells or simulator)."""


@dataclass(frozen=True)
class MapSpec:
    """A registered map: how it is built and its content digest."""

    command: str
    digest: str


@dataclass(frozen=True)
class Arm:
    """One registered evaluation: a task set's cells, trials and planner configuration."""

    name: str
    tasks: str
    trials: int
    failures: tuple[str, ...]
    scenarios: tuple[int, ...]
    asms: tuple[str, ...]
    sim: str
    candidates: int
    levers: Mapping[str, Any]

    def simulator(self, asms: tuple[str, ...] | None = None) -> str:
        """The simulator a run (or trial) of `asms` (default the arm's) records: "none" where
        Random alone runs (it simulates nothing), else the arm's."""
        return self.sim if set(self.asms if asms is None else asms) - {"random"} else NONE


@dataclass(frozen=True)
class Registration:
    """What a registration page binds an evaluation to (the module's docstring)."""

    path: str
    commit: str
    base_seed: int
    rule: str
    maps: Mapping[str, MapSpec]
    arms: tuple[Arm, ...]

    def arm(self, name: str) -> Arm:
        """The arm called `name`; a one-line ConfigError where there is none."""
        for a in self.arms:
            if a.name == name:
                return a
        raise ConfigError(f"{self.path} registers no arm '{name}'; its arms: {self._arms()}")

    def arm_for(self, tasks: str) -> Arm:
        """The arm of the task set `tasks` (each arm has its own); a one-line RegistrationError
        where none is registered."""
        for a in self.arms:
            if a.tasks == tasks:
                return a
        raise RegistrationError(f"--registered {self.path}: the task set is {tasks}, which it registers no arm "
                                f"of (its arms: {self._arms()}); run with the --tasks of one")  # fmt: skip

    def _arms(self) -> str:
        return ", ".join(f"{a.name} (tasks {a.tasks})" for a in self.arms)


@dataclass(frozen=True)
class Difference:
    """How a run differs from the registration (what it has against what is registered) and
    how to run the registered one instead."""

    what: str
    fix: str

    def __str__(self) -> str:
        return f"{self.what}; {self.fix}"


# ------------------------------------------------------------------------------ reading


def registration_blocks(text: str) -> list[str]:
    """The bodies of the fenced code blocks tagged `toml` under a heading named Registration
    (no other heading between them), in the order they come."""
    blocks: list[str] = []
    under, fence, tag, body = False, "", "", []
    for line in text.splitlines():
        if fence:
            close = line.strip()
            if line.startswith(" " * 4) or not close.startswith(fence) or close.strip(fence[0]):
                body.append(line)
                continue
            if under and tag == "toml":
                blocks.append("\n".join(body))
            fence = ""
            continue
        opened = _FENCE.match(line)
        if opened:
            fence, tag, body = opened.group(1), opened.group(2).lower(), []
            continue
        heading = _HEADING.match(line)
        if heading:
            words = (heading.group(1) or "").rstrip("#").strip()
            under = words.lower() == HEADING
    if fence and under and tag == "toml":  # a block left open runs to the page's end
        blocks.append("\n".join(body))
    return blocks


def read_registration(path: str | Path) -> Registration:
    """The registration of the page at `path`; a one-line ConfigError where the page cannot be
    read, holds no such block or several, or its block lacks a key or holds one of another
    type or value."""
    p = Path(path)
    where = f"--registered {p}"
    try:
        text = p.read_text()
    except FileNotFoundError:
        raise ConfigError(f"{where}: no such file; give the page that registers the evaluation") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{where}: cannot be read ({type(e).__name__}); give a readable markdown page") from None
    blocks = registration_blocks(text)
    if len(blocks) != 1:
        raise ConfigError(f"{where}: holds {len(blocks)} ```toml blocks under a heading 'Registration'; a "
                          "registration page holds exactly one (its keys: lmjx.evaluation.registration)")  # fmt: skip
    try:
        data = tomllib.loads(blocks[0])
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{where}: its registration block is not TOML ({e}); write it as TOML") from None
    return _registration(data, str(p), where)


def _fail(where: str, key: str, want: str, got: Any = None, missing: bool = False) -> ConfigError:
    if missing:
        return ConfigError(f"{where}: the registration lacks `{key}` ({want}); add it to its toml block")
    shown = repr(got)
    shown = shown if len(shown) <= 60 else shown[:57] + "..."
    return ConfigError(f"{where}: the registration's `{key}` must be {want}, got {shown}; correct its toml block")


def _take(table: Mapping[str, Any], key: str, name: str, want: str, ok: Any, where: str) -> Any:
    """table[key], checked by `ok` (a predicate), or a one-line ConfigError naming `name`."""
    if key not in table:
        raise _fail(where, name, want, missing=True)
    value = table[key]
    if not ok(value):
        raise _fail(where, name, want, value)
    return value


def _no_others(table: Mapping[str, Any], keys: tuple[str, ...], prefix: str, where: str) -> None:
    for k in table:
        if k not in keys:
            raise ConfigError(f"{where}: the registration has an unknown key `{prefix}{k}` (its keys: "
                              f"{', '.join(keys)}); correct its toml block")  # fmt: skip


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _list_of(kind: type, choices: tuple | None = None) -> Any:
    def ok(v: Any) -> bool:
        items_ok = all(isinstance(x, kind) and not isinstance(x, bool) for x in v) if isinstance(v, list) else False
        return bool(v) and items_ok and len(set(v)) == len(v) and (choices is None or set(v) <= set(choices))

    return ok


def _registration(data: dict[str, Any], path: str, where: str) -> Registration:
    _no_others(data, TOP_KEYS, "", where)
    commit = _take(data, "commit", "commit", "the commit's 40-digit hash (lower case)",
                   lambda v: isinstance(v, str) and COMMIT_RE.fullmatch(v), where)  # fmt: skip
    base = _take(data, "base_seed", "base_seed", "a whole number at least 0", lambda v: _is_int(v) and v >= 0, where)
    rule = _take(data, "rule", "rule", "the acceptance rule, a text", lambda v: isinstance(v, str) and v.strip(), where)
    tables = _take(data, "maps", "maps", "a table per failure: [maps.FAILURE]",
                   lambda v: isinstance(v, dict) and v and all(isinstance(x, dict) for x in v.values()),
                   where)  # fmt: skip
    maps = {}
    for failure, spec in tables.items():
        _no_others(spec, ("command", "digest"), f"maps.{failure}.", where)
        command = _take(spec, "command", f"maps.{failure}.command", "the command that builds the map, a text",
                        lambda v: isinstance(v, str) and v.strip(), where)  # fmt: skip
        digest = _take(spec, "digest", f"maps.{failure}.digest", "the map's 64-digit content digest (lower case)",
                       lambda v: isinstance(v, str) and DIGEST_RE.fullmatch(v), where)  # fmt: skip
        maps[failure] = MapSpec(command, digest)
    entries = _take(data, "arms", "arms", "one [[arms]] table per registered evaluation",
                    lambda v: isinstance(v, list) and v and all(isinstance(x, dict) for x in v), where)  # fmt: skip
    arms = tuple(_arm(entry, i, maps, where) for i, entry in enumerate(entries))
    for key in ("name", "tasks"):
        seen = [getattr(a, key) for a in arms]
        twice = next((x for x in seen if seen.count(x) > 1), None)
        if twice is not None:
            raise ConfigError(f"{where}: two arms have the {key} '{twice}'; give each arm its own {key} (a run's "
                              "arm is the one of its task set)")  # fmt: skip
    return Registration(path, commit, base, rule, maps, arms)


def _arm(entry: dict[str, Any], i: int, maps: dict[str, MapSpec], where: str) -> Arm:
    name = _take(entry, "name", f"arms[{i}].name", "the arm's name, a text",
                 lambda v: isinstance(v, str) and v.strip(), where)  # fmt: skip
    at = f"arms[{name}]."
    _no_others(entry, ARM_KEYS, at, where)
    tasks = _take(entry, "tasks", at + "tasks", "paper or hard", lambda v: v in TASK_SETS, where)
    trials = _take(entry, "trials", at + "trials", "a whole number at least 1", lambda v: _is_int(v) and v >= 1, where)
    failures = _take(entry, "failures", at + "failures", "a list of failures, each with a [maps.FAILURE] table",
                     lambda v: _list_of(str)(v) and set(v) <= set(maps), where)  # fmt: skip
    scenarios = _take(entry, "scenarios", at + "scenarios", "a list of the scenarios 1, 2, 3",
                      _list_of(int, (1, 2, 3)), where)  # fmt: skip
    asms = _take(entry, "asms", at + "asms", f"a list of the ASMs {', '.join(ASMS)}", _list_of(str, ASMS), where)
    sim = _take(entry, "sim", at + "sim", " or ".join(SIMULATORS), lambda v: v in SIMULATORS, where)
    candidates = _take(entry, "candidates", at + "candidates", "a whole number at least 1",
                       lambda v: _is_int(v) and v >= 1, where)  # fmt: skip
    given = _take(entry, "levers", at + "levers", "a table of every lever, KEY = VALUE",
                  lambda v: isinstance(v, dict), where)  # fmt: skip
    for key in given:
        if key not in LEVERS:
            raise ConfigError(f"{where}: the registration's `{at}levers` has an unknown key `{key}` (its keys: the "
                              f"levers results.json records in runs[].planner); correct its toml block")  # fmt: skip
    levers = {}
    for key in LEVERS:
        if key not in given:
            raise _fail(where, f"{at}levers.{key}", "every lever of the planner's configuration", missing=True)
        levers[key] = check_value(key, given[key], f"{where}: the registration's `{at}levers`")
    if levers["greedy_candidates"] != candidates:
        raise ConfigError(f"{where}: the registration's `{at}candidates` is {candidates} but its "
                          f"levers.greedy_candidates {levers['greedy_candidates']}; make them agree")  # fmt: skip
    return Arm(name, tasks, trials, tuple(failures), tuple(scenarios), tuple(asms), sim, candidates, levers)


# ------------------------------------------------------------------------------ checking


def _text(v: Any) -> str:
    return "none" if v is None else str(v).lower() if isinstance(v, bool) else str(v)


def _commit(registration: Registration, code: Mapping[str, Any]) -> list[Difference]:
    """How the run's code (`provenance.code_version`) differs from the registered commit and a
    clean tree."""
    want = registration.commit
    commit, source = code.get("commit", UNKNOWN), code.get("commit_source", UNKNOWN)
    if commit == UNKNOWN:
        return [Difference(f"the code's commit is unknown (no git checkout, and no {COMMIT_ENV} with "
                           f"{SOURCE_ENV}), the registration's {want[:12]}",
                           f"run in a checkout of {want}, or on a copy of its tree set both variables "
                           "(python -m lmjx.evaluation.provenance prints them in the checkout)")]  # fmt: skip
    if commit != want and source == COMMIT_ENV:
        return [Difference(f"the code is at commit {commit[:12]} (named by {COMMIT_ENV}), the registration's "
                           f"{want[:12]}", f"copy the registered commit's tree and name it: {COMMIT_ENV}={want} with "
                           f"its {SOURCE_ENV}")]  # fmt: skip
    if commit != want:
        return [Difference(f"the code is at commit {commit[:12]} (git's), the registration's {want[:12]}",
                           f"check out the registered commit (git checkout {want}) and run there")]  # fmt: skip
    if source == "git" and code.get("dirty") is None:
        return [Difference("git cannot tell whether tracked files differ from the commit (git diff failed)",
                           "run where git works, in a checkout of the registered commit")]  # fmt: skip
    if code.get("dirty"):
        changes = code.get("changes")
        return [Difference(f"tracked files differ from commit {want[:12]} (their changes' digest {changes})",
                           "undo the changes (git stash) to run the registered code")]  # fmt: skip
    return []


def _cells(arm: Arm, run: Mapping[str, Any]) -> list[Difference]:
    cells = run.get("cells", {})
    out = []
    for key, option in (("failures", "--failures"), ("scenarios", "--scenarios"), ("asms", "--asms")):
        have, want = list(cells.get(key, [])), list(getattr(arm, key))
        if sorted(map(str, have)) != sorted(map(str, want)):
            listed = ",".join(map(str, want))
            out.append(Difference(f"the {key} are {','.join(map(str, have)) or 'none'}, the registration's {listed}",
                                  f"run with {option} {listed}"))  # fmt: skip
    return out


def check_against(
    registration: Registration, arm_name: str, run: Mapping[str, Any], maps: Mapping[str, Mapping[str, Any]]
) -> list[Difference]:
    """How the run `run` (its entry: `provenance.new_run`) differs from the arm `arm_name`: the
    code (commit, a clean tree), the task set, the cells, the maps (`maps`: failure -> its
    entry, `provenance.map_entry`: path and digest), the base seed, the trials per cell, the
    simulator and every lever of the planner; empty where the run is the registered one."""
    arm = registration.arm(arm_name)
    out = _commit(registration, run.get("lmjx", {}))
    tasks = run.get("tasks", {}).get("set", UNKNOWN)
    if tasks != arm.tasks:
        out.append(Difference(f"the task set is {tasks}, the registration's {arm.tasks}",
                              f"run with --tasks {arm.tasks}"))  # fmt: skip
    out += _cells(arm, run)
    for failure in arm.failures:
        spec, entry = registration.maps[failure], maps.get(failure)
        if entry is None:
            out.append(Difference(f"no map of {failure} is given", f"build it with: {spec.command}"))
            continue
        digest = str(entry.get("digest"))
        if digest != spec.digest:
            out.append(Difference(f"the map {entry.get('path', failure)} has digest {digest[:12]}..., the "
                                  f"registration {spec.digest[:12]}...", "give --maps the folder of the registered "
                                  f"maps (built with: {spec.command})"))  # fmt: skip
    for key, option, want in (("seed_base", "--seed", registration.base_seed),
                              ("trials_per_cell", "--trials", arm.trials)):  # fmt: skip
        if run.get(key) != want:
            out.append(Difference(f"the {key.replace('_', ' ')} is {run.get(key)}, the registration's {want}",
                                  f"run with {option} {want}"))  # fmt: skip
    sim = run.get("simulator", {}).get("name", UNKNOWN)
    want_sim = arm.simulator(tuple(run.get("cells", {}).get("asms", ())))
    if sim != want_sim:
        out.append(Difference(f"the simulator is {sim}, the registration's {want_sim}", f"run with --sim {arm.sim}"))
    planner = run.get("planner", {})
    for key in LEVERS:
        have = planner.get(key, UNKNOWN)
        if have != arm.levers[key]:
            want = _text(arm.levers[key])
            out.append(Difference(f"the planner's {key} is {_text(have)}, the registration's {want}",
                                  f"run with --set {key}={want} (and no other option that sets it)"))  # fmt: skip
    extra = sorted(set(planner) - set(LEVERS))
    if extra:
        out.append(Difference(f"the planner has levers the registration lacks ({', '.join(extra)})",
                              "register the evaluation anew with every lever this lmjx records"))  # fmt: skip
    return out


def enforce(
    registration: Registration,
    run: Mapping[str, Any],
    maps: Mapping[str, Mapping[str, Any]] | None = None,
    arm_name: str | None = None,
) -> Arm:
    """The arm `run` (its entry) is a run of: `arm_name`'s, else the arm of the run's task set;
    refused (`RegistrationError`, one line naming the first difference and its fix) unless
    the run is that arm's as registered (`check_against`; `maps` default: the run's own)."""
    arm = registration.arm(arm_name) if arm_name else registration.arm_for(run.get("tasks", {}).get("set", UNKNOWN))
    found = check_against(registration, arm.name, run, run.get("maps", {}) if maps is None else maps)
    if found:
        raise RegistrationError(f"--registered {registration.path}: {found[0]}")
    return arm
