"""Carry runs' finished trials to the device, so that `eval_background.sh launch` resumes them.

For each run of a RUNS list (the same "NAME:SIM:TASKS:SCENARIOS:FAILURES:ASMS:CPUS[:K/N[:NICE]]" specs
`benchmarks/eval_background.sh launch` takes), the records of the given results.json files
that belong to it (its task set, failures, scenarios and ASMs; Random's records, which
simulate nothing, for any SIM; the others only for their own simulator) are written to
.evprev/NAME.json, which `launch` copies into the run's folder before it starts: `lmjx
evaluate` then runs only the trials not yet there.  Runs with no finished trial get no file.

    python benchmarks/evprev.py docs/eval_hard_gpu_1m/results.json --runs "hg22:gpu:hard:2:case2:greedy:- ..."

`--redo END` leaves out the trials that ended so (e.g. "planning time" on a starved host): they
run again, and `eval_acceptance.py --merge` puts their new records in place of the old.
`benchmarks/evparts.py` makes a RUNS list of parts that hold only the missing trials.

The maps must be the same as those the trials ran on (`benchmarks/map_digest.py`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from lmjx.runtime.fileio import write_text_atomic
from lmjx.types import ASMS


def belongs(rec: dict, sim: str, tasks: str, scen: str, fail: str, asms: str) -> bool:
    """Whether `rec` is a trial of the run with these fields ('-': the default, every one)."""
    if rec.get("tasks", "hard") != tasks:  # records from before task sets were named: the hard set
        return False
    if scen != "-" and rec["scenario"] not in {int(s) for s in scen.split(",")}:
        return False
    if fail != "-" and rec["failure"] not in fail.split(","):
        return False
    if rec["asm"] not in (ASMS if asms == "-" else asms.split(",")):
        return False
    return rec["asm"] == "random" or rec.get("sim") == sim


def read_records(paths: list[Path], redo: list[str], tool: str) -> dict[tuple, dict]:
    """The trials of the results.json files `paths`, each once (by task set, simulator, cell
    and seed; Random's for any simulator), but those that ended in a way `redo` names; a file
    that cannot be read stops `tool` in one line."""
    records = {}
    for p in paths:
        try:
            found = json.loads(p.read_text())
        except (OSError, ValueError) as e:
            sys.exit(f"{tool}: {p}: {e}")
        for r in found:
            if r["end"] in redo:
                continue
            sim = r.get("sim") if r["asm"] != "random" else "none"
            records[(r.get("tasks", "hard"), sim, r["failure"], r["scenario"], r["asm"], r["seed"])] = r
    return records


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", type=Path, help="results.json files (merged runs)")
    ap.add_argument("--runs", required=True, help="the RUNS list of eval_background.sh launch")
    ap.add_argument("--out", type=Path, default=Path(".evprev"), help="folder for NAME.json (default .evprev)")
    ap.add_argument(
        "--redo",
        action="append",
        default=[],
        help="leave out the trials that ended so, e.g. 'planning time' (they run again; repeatable)",
    )
    args = ap.parse_args()
    records = read_records(args.results, args.redo, "evprev")
    args.out.mkdir(parents=True, exist_ok=True)
    for spec in args.runs.split():
        fields = spec.split(":")
        if len(fields) not in (7, 8, 9):
            sys.exit(f"evprev: '{spec}' is not NAME:SIM:TASKS:SCENARIOS:FAILURES:ASMS:CPUS[:K/N[:NICE]]")
        name, sim, tasks, scen, fail, asms = fields[:6]  # a part (K/N) gets the whole cell's trials
        mine = [r for r in records.values() if belongs(r, sim, tasks, scen, fail, asms)]
        if mine:
            write_text_atomic(args.out / f"{name}.json", json.dumps(mine, indent=1) + "\n")
        print(f"{name}: {len(mine)} trials carried")


if __name__ == "__main__":
    main()
