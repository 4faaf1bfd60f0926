"""results.json: an evaluation's trials and the runs that made them.

The file is one JSON object: `format` ("lmjx-results"), `format_version` (2), `runs` (one
entry per invocation of `lmjx evaluate` that ran trials into it: `lmjx.evaluation.provenance`,
`new_run`) and `trials` (one record per trial, each naming its run by `run` and carrying its
own `provenance`).  A file written without provenance (a JSON list of trial records) is read
as trials of an unknown run.

`check_conditions` is the rule for pooling: trials of runs whose conditions differ (another
commit, other maps, another task set, planner configuration, simulator, trials per cell or
seed base) are refused with one line naming what differs, unless pooling is allowed
(`--allow-mixed`), which the report then says; a run whose commit is unknown (no git, and
the commit not named by LMJX_COMMIT with LMJX_SOURCE_DIGEST) pools with no other run.
Resuming an evaluation (`lmjx evaluate` into an existing --out) and merging parts
(`benchmarks/eval_acceptance.py --merge`) both apply it.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lmjx.errors import ConfigError, MixedRunsError
from lmjx.evaluation.provenance import (
    COMMIT_ENV,
    SOURCE_ENV,
    UNKNOWN,
    differences,
    differences_text,
    unknown_run,
)
from lmjx.runtime.fileio import write_text_atomic

FORMAT = "lmjx-results"
FORMAT_VERSION = 2


@dataclass
class Results:
    """What a results.json holds: the runs (header entries) and the trial records."""

    runs: list[dict[str, Any]] = field(default_factory=list)
    trials: list[dict[str, Any]] = field(default_factory=list)
    # trials a merge found twice and kept once, the later (`merge`, --allow-mixed): which
    # trial, the run of the record kept and of the one dropped, and whether that one succeeded
    replaced: list[dict[str, Any]] = field(default_factory=list)

    def run_of(self, record: dict[str, Any]) -> dict[str, Any]:
        """The entry of the run that made `record` (an unknown run where none is recorded)."""
        rid = record.get("run")
        for run in self.runs:
            if run["id"] == rid:
                return run
        return unknown_run(UNKNOWN if rid is None else str(rid))

    def runs_used(self) -> list[dict[str, Any]]:
        """The runs that made the trials held, in the order they first appear, with the number
        of trials each holds here (`trials_held`)."""
        held = Counter(str(r.get("run", UNKNOWN)) for r in self.trials)
        out, seen = [], set()
        for r in self.trials:
            run = self.run_of(r)
            if run["id"] not in seen:
                seen.add(run["id"])
                out.append(run | {"trials_held": held[run["id"]]})
        return out

    def to_json(self) -> str:
        body = {"format": FORMAT, "format_version": FORMAT_VERSION, "runs": self.runs, "trials": self.trials}
        if self.replaced:
            body["replaced"] = self.replaced
        return json.dumps(body, indent=1) + "\n"


def read_results(path: str | Path) -> Results:
    """The results at `path` (none where the file does not exist); a one-line ConfigError
    where it is not an lmjx results file."""
    p = Path(path)
    if not p.exists():
        return Results()
    try:
        data = json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ConfigError(f"{p} exists but cannot be read ({e}); move it away to start afresh") from None
    if isinstance(data, list) and all(isinstance(r, dict) for r in data):
        return Results([], data)  # written without provenance
    if not (isinstance(data, dict) and data.get("format") == FORMAT):
        raise ConfigError(f"{p} is not an lmjx results file; move it away to start afresh")
    if data.get("format_version") != FORMAT_VERSION:
        raise ConfigError(f"{p} is a results file of format {data.get('format_version')}, which this lmjx "
                          f"({FORMAT_VERSION}) does not read; use the lmjx that wrote it")  # fmt: skip
    return Results(list(data.get("runs", [])), list(data.get("trials", [])), list(data.get("replaced", [])))


def trials_of(path: str | Path) -> list[dict[str, Any]]:
    """The trial records of a results.json (either format)."""
    return read_results(path).trials


def write_results(path: str | Path, results: Results) -> None:
    write_text_atomic(path, results.to_json())


def check_conditions(held: Results, new: dict[str, Any], allow_mixed: bool, where: str) -> None:
    """Refuse (`MixedRunsError`, one line) to pool trials of `new` (a run's entry) with those
    `held` where their runs' conditions differ, unless `allow_mixed`."""
    if allow_mixed:
        return
    found = _first_difference(held.runs_used(), [new])
    if found is not None:
        run, _, diff = found
        name = f"name the commit with {COMMIT_ENV} and {SOURCE_ENV}, " if _unknown_commit(diff) else ""
        raise MixedRunsError(
            f"{where} holds {_trials(run['trials_held'])} run under other conditions: "
            f"{differences_text(diff, 'there', 'here')}; {name}use another --out, or --allow-mixed to pool them "
            "(the report then says so)"
        )


def _unknown_commit(diff: list[tuple[str, str, str]]) -> bool:
    """Whether `diff` (`differences`) holds a commit that is unknown (no git, none named)."""
    return any(what == "commit" and UNKNOWN in (a, b) for what, a, b in diff)


def _first_difference(held: list[dict[str, Any]], new: list[dict[str, Any]]) -> tuple[dict, dict, dict] | None:
    """The first (held run, new run, their `differences`) where a run of `new` ran under
    other conditions than one of `held`; None where all agree."""
    for run in new:
        for old in held:
            diff = differences(old, run)
            if diff:
                return old, run, diff
    return None


def trial_key(record: dict[str, Any]) -> tuple:
    """What names a trial: (failure, scenario, ASM, seed)."""
    return (record["failure"], record["scenario"], record["asm"], record["seed"])


def merge(parts: list[tuple[str, Results]], allow_mixed: bool = False) -> Results:
    """The trials of several results (named, e.g. by their folders), each once, with their
    runs.  Refused (`MixedRunsError`, one line) where a part's trials ran under other
    conditions than those before it, or where a trial comes twice with different records
    (run twice: a cell run again), unless `allow_mixed`: then the later record is kept and
    the file says which it replaced (`Results.replaced`).  A record given twice alike (a
    folder given twice) counts once."""
    merged = Results()
    where: dict[tuple, tuple[int, str]] = {}  # trial -> (its place in merged.trials, the part it came from)
    for name, part in parts:
        found = None if allow_mixed else _first_difference(merged.runs_used(), part.runs_used())
        if found is not None:
            _, run, diff = found
            unknown = f"run them where git or {COMMIT_ENV} with {SOURCE_ENV} names the commit, or "
            unknown = unknown if _unknown_commit(diff) else ""
            raise MixedRunsError(
                f"{name} holds {_trials(run['trials_held'])} run under other conditions than those before it: "
                f"{differences_text(diff, 'before', 'its')}; {unknown}give --allow-mixed to pool them (the report "
                "then says so)"
            )
        for r in part.trials:
            k = trial_key(r)
            if k not in where:
                where[k] = (len(merged.trials), name)
                merged.trials.append(r)
                continue
            i, first = where[k]
            if merged.trials[i] == r:
                continue
            if not allow_mixed:
                raise MixedRunsError(
                    f"{name} holds trial {'/'.join(map(str, k))} again, with another record than {first}'s (a trial "
                    "run twice); leave one out, or give --allow-mixed to keep the later (the report then says so)"
                )
            old = merged.trials[i]
            merged.replaced.append(
                {"trial": list(k), "kept_run": r.get("run", UNKNOWN), "dropped_run": old.get("run", UNKNOWN),
                 "dropped_success": old["success"]}
            )  # fmt: skip
            merged.trials[i] = r
            where[k] = (i, name)
        ids = {x["id"] for x in merged.runs}
        merged.runs += [x for x in part.runs if x["id"] not in ids]
        merged.replaced += part.replaced
    return merged


def mixed_lines(results: Results) -> list[str]:
    """The report's note on trials pooled from runs whose conditions differ (--allow-mixed):
    each run with what differs from the first and how many trials it holds; none where every
    run's conditions agree."""
    runs = results.runs_used()
    diffs = [differences(runs[0], r) for r in runs[1:]]
    lines = []
    if results.replaced:
        lines += [
            f"**Trials run twice**: {len(results.replaced)} trials were merged from two runs each; the later record "
            "is kept (--allow-mixed): "
            + ", ".join(f"{'/'.join(map(str, x['trial']))} (run {x['kept_run']} kept, {x['dropped_run']}'s "
                        f"{'success' if x['dropped_success'] else 'failure'} dropped)" for x in results.replaced)
            + ".",
            "",
        ]  # fmt: skip
    if not any(diffs):
        return lines
    lines += [
        "**Mixed runs** (pooled with --allow-mixed): these trials come from runs whose conditions differ, and a "
        "cell's rate pools them:",
        "",
        f"* run {runs[0]['id']}: {_trials(runs[0]['trials_held'])} (the first)",
    ]
    for r, d in zip(runs[1:], diffs, strict=True):
        what = differences_text(d, "the first", "this") if d else "the first's conditions"
        lines.append(f"* run {r['id']}: {_trials(r['trials_held'])}; {what}")
    return [*lines, ""]


def _code(run: dict[str, Any]) -> str:
    c = run["lmjx"]
    state = {True: f"; uncommitted changes, their digest {c.get('changes')}", False: "; clean"}.get(c["dirty"], "")
    source = {"git": "git", COMMIT_ENV: f"named by {COMMIT_ENV}, the files checked against {SOURCE_ENV}"}.get(
        c["commit_source"], "unknown"
    )
    files = f"; source files' digest {c['source_digest'][:16]}" if c.get("source_digest") else ""
    return f"lmjx {c['version']}, commit {c['commit']} ({source}{state}{files})"


def provenance_lines(results: Results) -> list[str]:
    """The report's opening: where its trials come from (the first run's code, maps, task set,
    simulator, host, planner and command; every run, where several made them)."""
    runs = results.runs_used()
    lines = ["## Provenance", ""]
    recorded = [r for r in runs if not r.get("unrecorded")]
    if not recorded:
        return [*lines, "Not recorded: these trials were written without their provenance (commit, maps, "
                "simulator and host unknown).", ""]  # fmt: skip
    r = recorded[0]
    maps = "; ".join(
        f"{f} `{m['path']}`, digest `{m['digest']}` ({m['digest_source']})"
        + (f", {m['edges']:,} edges" if m.get("edges") is not None else "")
        for f, m in r["maps"].items()
    )
    host = r["host"]
    packages = ", ".join(f"{k} {v}" for k, v in host.get("packages", {}).items())
    limit = r.get("planning_limit", {})
    lines += [
        f"* **Code**: {_code(r)}.",
        f"* **Maps**: {maps}.",
        f"* **Tasks**: the {r['tasks']['set']} set (its definition's digest `{r['tasks']['digest']}`), "
        f"{r['trials_per_cell']} trials per cell, seed base {r['seed_base']} (trial seed: base x 100,000 + "
        "scenario x 1,000 + trial).",
        f"* **Simulator**: {r['simulator']['description']}; device: {r['simulator']['device']}.",
        f"* **Host**: {host['hostname']}, {host['platform']}, {host['cpu']}, {host['cores']} cores; Python "
        f"{host['python']}; {packages}.",
        "* **Planner**: " + ", ".join(f"{k} {_value(v)}" for k, v in r["planner"].items()) + ".",
        f"* **Planning limit**: {limit.get('max_sim_steps', 0):,} {limit.get('unit', '')}; a trial it stops "
        "is a failure unless its target is in the goal.",
        f"* **Command**: `{r['command']}`.",
        "",
    ]
    if len(runs) > 1:
        lines += [
            "The trials come from these runs (a run: one invocation of `lmjx evaluate`; a resumed evaluation is "
            "several):",
            "",
            "| run | started | host | device | part | trials held | command |",
            "| --- | --- | --- | --- | --- | ---: | --- |",
        ]
        for x in runs:
            part = "/".join(map(str, x.get("part", []))) or "-"
            lines.append(f"| {x['id']} | {x['started']} | {x['host']['hostname']} | {x['simulator']['device']} | "
                         f"{part} | {x['trials_held']} | `{x['command']}` |")  # fmt: skip
        lines.append("")
    return [*lines, *mixed_lines(results)]


def _trials(n: int) -> str:
    return f"{n} trial" + ("" if n == 1 else "s")


def _value(v: Any) -> str:
    return "none" if v is None else str(v).lower() if isinstance(v, bool) else str(v)
