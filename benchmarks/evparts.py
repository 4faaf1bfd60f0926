"""Split unfinished evaluation cells into parts by the trials they still miss: a RUNS list for
`benchmarks/eval_background.sh launch`.

Each cell "NAME:SIM:TASKS:SCENARIO:FAILURE:ASM:PROCS" (one scenario, one failure, one ASM)
gets up to PROCS runs "NAMEa:SIM:TASKS:SCENARIO:FAILURE:ASM:-:K/N:NICE" (`lmjx evaluate
--part K/N` runs the trials t with t % N == K - 1): the smallest N whose parts spread the
cell's missing trials over PROCS runs (or over as many as there are trials) with none
holding more than its share, and only the parts that hold a missing trial.  A trial is
missing when the results hold no record of it or one that ended in a way given by --redo
(e.g. "planning time" on a starved host); carry the others with `benchmarks/evprev.py
--redo ...` (the same --redo), so that the runs do only the missing ones:

    python benchmarks/evparts.py docs/eval_hard_cpu_1m/results.json --redo "planning time" \\
        --cells "kg22:cpu:hard:2:case2:greedy:8 kl11:cpu:hard:1:case1:lazy:2" > runs.txt
    python benchmarks/evprev.py docs/eval_hard_cpu_1m/results.json --redo "planning time" --runs "$(cat runs.txt)"

The trials each run will do are printed on stderr.  Random's records count for any SIM.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from evprev import belongs, read_records

from lmjx.evaluation.evaluate import trial_seed

PART_NAMES = "abcdefghijklmnopqrstuvwxyz"


def missing(records: list[dict], sim: str, tasks: str, scenario: int, failure: str, asm: str, trials: int,
            seed: int = 0) -> list[int]:  # fmt: skip
    """The trial indices of the cell with no record among `records` (`evprev.read_records`,
    which leaves out those to run again)."""
    done = {r["seed"] for r in records if belongs(r, sim, tasks, str(scenario), failure, asm)}
    return [t for t in range(trials) if trial_seed(seed, scenario, t) not in done]


def split(todo: list[int], procs: int, trials: int) -> tuple[int, dict[int, list[int]]]:
    """(N, {K: trials}) for the smallest N >= procs spreading `todo` over min(procs, len(todo))
    parts with at most ceil(len(todo) / procs) trials each (N = trials always does)."""
    share = math.ceil(len(todo) / procs)
    for n in range(procs, trials + 1):
        parts: dict[int, list[int]] = {}
        for t in todo:
            parts.setdefault(t % n + 1, []).append(t)
        if len(parts) >= min(procs, len(todo)) and max(map(len, parts.values())) <= share:
            return n, parts
    return trials, {t + 1: [t] for t in todo}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", type=Path, help="results.json files (merged runs)")
    ap.add_argument("--cells", required=True, help='"NAME:SIM:TASKS:SCENARIO:FAILURE:ASM:PROCS ..."')
    ap.add_argument("--redo", action="append", default=[], help="run again the trials that ended so (repeatable)")
    ap.add_argument("--trials", type=int, default=15, help="trials per cell (default 15)")
    ap.add_argument("--nice", type=int, default=0, help="the runs' scheduling priority (default 0)")
    args = ap.parse_args()
    records = list(read_records(args.results, args.redo, "evparts").values())
    runs = []
    for spec in args.cells.split():
        f = spec.split(":")
        if len(f) != 7 or not f[3].isdigit() or not f[6].isdigit() or int(f[6]) < 1 or len(f[0]) == 0:
            sys.exit(f"evparts: '{spec}' is not NAME:SIM:TASKS:SCENARIO:FAILURE:ASM:PROCS (one of each, PROCS >= 1)")
        name, sim, tasks, scen, fail, asm, procs = f[0], f[1], f[2], int(f[3]), f[4], f[5], int(f[6])
        todo = missing(records, sim, tasks, scen, fail, asm, args.trials)
        if not todo:
            print(f"{name}: complete", file=sys.stderr)
            continue
        cell = f"{sim}:{tasks}:{scen}:{fail}:{asm}:-"
        if procs == 1:
            runs.append(f"{name}:{cell}:-:{args.nice}")
            print(f"{name}: trials {todo}", file=sys.stderr)
            continue
        n, parts = split(todo, procs, args.trials)
        if len(parts) > len(PART_NAMES):
            sys.exit(f"evparts: {name}: {len(parts)} parts; at most {len(PART_NAMES)}")
        for letter, k in zip(PART_NAMES, sorted(parts), strict=False):
            runs.append(f"{name}{letter}:{cell}:{k}/{n}:{args.nice}")
            print(f"{name}{letter} (part {k}/{n}): trials {parts[k]}", file=sys.stderr)
    print(" ".join(runs))


if __name__ == "__main__":
    main()
