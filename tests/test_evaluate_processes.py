"""`lmjx evaluate` split across processes (`--processes`, one per GPU by default) writes the
records one process writes: the same trials, decisions and outcomes, whichever process ran
each trial and whichever trials ran beside it."""

from __future__ import annotations

import json

from lmjx.evaluation.evaluate import EvalConfig, evaluate
from lmjx.evaluation.workers import deal
from lmjx.mapfile.read import load_map
from lmjx.types import PlannerConfig

# what differs between two runs of the same trials: wall times, and the run each belongs to
TIMES = {"planning_s", "compile_s", "latency_s", "phase_s", "shared_s"}


def _records(path) -> dict:
    out = {}
    for r in json.loads(path.read_text())["trials"]:
        r = {k: v for k, v in r.items() if k not in TIMES | {"run"}}
        r["steps"] = [{k: v for k, v in s.items() if k not in TIMES} for s in r["steps"]]
        out[(r["failure"], r["scenario"], r["asm"], r["seed"])] = r
    return out


def test_two_processes_write_the_records_of_one(robot, plan_map, tmp_path):
    folder = tmp_path / "maps"
    folder.mkdir()
    (folder / "case2.h5").symlink_to(plan_map)
    maps = {"case2": load_map(folder / "case2.h5", robot)}
    config = EvalConfig(failures=("case2",), scenarios=(1, 2), asms=("random", "lazy", "greedy"), trials=2,
                        planner=PlannerConfig(max_actions=1, greedy_candidates=4, lazy_tries=3))  # fmt: skip
    evaluate(robot, maps, config, tmp_path / "one", progress=False, processes=1)
    evaluate(robot, maps, config, tmp_path / "two", progress=False, processes=2)
    one, two = _records(tmp_path / "one" / "results.json"), _records(tmp_path / "two" / "results.json")
    assert len(one) == 12 and one == two
    # the file lists the trials in the order one process ends them (a resumed run finds them)
    keys = [(r["failure"], r["scenario"], r["asm"], r["seed"]) for r in json.loads((tmp_path / "two" /
            "results.json").read_text())["trials"]]  # fmt: skip
    assert keys == list(one)


def test_trials_are_dealt_scenario_by_scenario():
    keys = [("case1", s, a, t) for s in (1, 2) for a in ("random", "greedy") for t in range(3)]
    shares = deal(keys, 4)
    assert sorted(k for s in shares for k in s) == sorted(keys) and len(shares) == 4
    for share in shares:  # every share holds a part of every scenario, in the order given
        assert {k[1] for k in share} == {1, 2} and share == sorted(share, key=keys.index)
