"""Calibrate the paper task set (`lmjx.sim.scenarios.PAPER_TASKS`, `PAPER_BUDGET`) with Random only.

The paper gives no coordinates, goal sizes or budgets; it reports outcomes.  This script
chooses the paper set's goal distance (per scenario), goal size and action budget so that
the Random ASM, which simulates nothing, reaches the paper's reported case-1 outcome: the
weakest ASM, yet completing about two thirds of the tasks (its one case-1 figure: 66.7 % in
scenario 3), some in a single action.  No planner simulation is involved, and the seeds are
calibration seeds (`trial_seed(CAL_BASE, scenario, t)`: 7xx,xxx) that the evaluation
(base 0: 1,000-3,014) never uses.

Random's choices do not depend on the goal when lmjx's futile-edge filter is off (the paper's
settings, `--asm-settings paper`): it draws uniformly among the edges over the target.  So
each calibration trial is run once, with no goal and the largest budget, recording the
target after every action (observed and true); every (distance, goal size, budget) is then
scored offline, exactly as `Planner.trial` would end it: stop when the observed target is
1 cm inside the goal, success when the true target is in it.  Each trial starts where the
paper set's task starts (`paper_variant`: in scenarios 1 and 3 the hard task's start; in
scenario 2 the hard task's goal, the target then pushed through the tunnel), so one run per
failure and scenario serves every candidate.

    python benchmarks/calibrate_tasks.py --maps maps --trials 30 --out benchmarks/calibration.json

In parts, on many cores (each part a process; then merged and scored):

    python benchmarks/calibrate_tasks.py --maps maps --failures case1 --scenarios 2 --first 4 --trials 2 --out part.json
    python benchmarks/calibrate_tasks.py --from-runs part*.json --out calibration.json [--apply]

With `--one-action RATES.json` (`one_action_rate.py`'s --out on the same calibration starts)
each candidate also gets p1, its one-action rate from many first actions per start, and the
rule that chose the present paper tasks applies instead: the chance of at least one one-action
success in case 1's 3 x 15 trials, 1 - prod(1 - p1)^15, at least 0.95 (a single trial per
start makes the one-action count a rare, noisy event); then the smallest total gap to 2/3, the
shorter distances, and the goal size and budget (0.10, 30) if among the best:

    python benchmarks/calibrate_tasks.py --from-runs calibration.json --one-action rates.json --out choice.json

Selection rule (fixed before looking at the results): a goal size and a budget common to
the three scenarios, a distance per scenario; the start never inside the goal (distance at
least the goal's half size + 3 cm, the layouts' jitter; in the tunnel the goal region wholly
past the wall); in every scenario at least one
case-1 trial succeeds in one action; then the smallest total gap between case 1's Random
success and 2/3 (in trials), then the shorter distances, then the hard set's
goal size (12 cm square) and budget (30) if they are among the best, else the smaller
ones.
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from lmjx.errors import LmjxError
from lmjx.evaluation.evaluate import trial_seed
from lmjx.evaluation.lockstep import run_lockstep
from lmjx.mapfile.read import load_map
from lmjx.model.robot import load_robot
from lmjx.planner.edge_planner import Planner
from lmjx.planner.transit import TransitPlanner
from lmjx.runtime.cores import usable_cores
from lmjx.sim.realworld import SimulatedRealWorld
from lmjx.sim.scenarios import SCENARIOS, PaperTask, Scenario, in_goal, paper_variant, sample_layout, scenario
from lmjx.types import PlannerConfig

CAL_BASE = 7  # calibration trials' seed base (the evaluation's is 0)
GOAL_MARGIN = PlannerConfig().goal_margin
DISTANCES = np.round(np.arange(0.07, 0.305, 0.02), 3)
ANGLES = tuple(range(0, 360, 45))  # the goal's direction from the target's start [deg]
HALVES = (0.05, 0.06, 0.08, 0.10)
BUDGETS = (5, 10, 15, 20, 30)


class Recording(SimulatedRealWorld):
    """The "real" world, keeping the target's observed and true pose after every action."""

    def __init__(self, robot, seed):
        super().__init__(robot, seed)
        self.track: list[tuple[list[float], list[float], float]] = []

    def reset(self, layout, robot_q):
        obs = super().reset(layout, robot_q)
        self.track = [(obs.objects[0, :2].tolist(), self.truth()[0, :2].tolist(), float(self.truth()[0, 2]))]
        return obs

    def execute(self, action):
        obs = super().execute(action)
        self.track.append((obs.objects[0, :2].tolist(), self.truth()[0, :2].tolist(), float(self.truth()[0, 2])))
        return obs


def run_trials(robot, m, number: int, trials: int, budget: int, first: int = 0) -> list[dict]:
    """Random trials `first` ... `first + trials - 1` from the paper set's start, without a
    goal: the target's track and how each ended."""
    sc = scenario(number, robot.profile.task_scale, "paper")
    sc = replace(sc, goal_center=(3.0, -3.0), budget=budget)  # never reached (and under TARGET_LOST away)
    cfg = PlannerConfig(asm="random", max_actions=budget).paper()
    transits = TransitPlanner(robot, m.failure)
    planner_trials, worlds, out = [], [], {}
    for t in range(first, first + trials):
        seed = trial_seed(CAL_BASE, number, t)
        planner = Planner(robot, m.failure, m.reach, m.edges, sc, None, cfg, transits)
        world = Recording(robot, seed)
        planner_trials.append((planner.trial(world, sample_layout(sc, seed), seed * 7), world))
        worlds.append((seed, world))

    def done(i, res):
        seed, world = worlds[i]
        out[i] = {"seed": seed, "end": res.reason, "actions": res.actions, "track": world.track}

    run_lockstep(planner_trials, None, done, threads=usable_cores())
    return [out[i] for i in range(trials)]


def outcome(track: list, task: Scenario, budget: int) -> tuple[bool, int]:
    """(success, actions) of a trial on `task` with this budget, as `Planner.trial` ends it."""
    last = min(budget, len(track) - 1)
    for k in range(last + 1):
        obs, true, z = track[k]
        if k < budget and in_goal(task, np.array(obs), GOAL_MARGIN):
            return in_goal(task, np.array(true)) and z > -0.02, k
    obs, true, z = track[last]
    return in_goal(task, np.array(true)) and z > -0.02, last


def grid(runs: dict) -> list[dict]:
    """Every (failure, scenario, angle, distance, half, budget): Random's successes and one-action
    ones.  The start's jitter box never overlaps the goal (3 cm apart along x or y); in the
    tunnel the goal lies straight through it (90 deg), wholly past the wall."""
    rows = []
    for (f, s), trials in runs.items():
        hard = scenario(s, 1.0, "hard")
        walls = [b.y + b.half[1] for b in hard.fixed]
        for a, d, h, b in itertools.product(ANGLES if not walls else (90,), DISTANCES, HALVES, BUDGETS):
            task = paper_variant(hard, PaperTask(float(d), h, float(a)), b)  # the task the evaluation would run
            offset = np.array(task.goal_center) - (task.target.x, task.target.y)
            if np.max(np.abs(offset)) < h + 0.03 or (walls and task.goal_center[1] - h < max(walls)):
                continue
            res = [outcome(tr["track"], task, b) for tr in trials]
            rows.append({"failure": f, "scenario": s, "angle": a, "distance": float(d), "half": h, "budget": b,
                         "trials": len(res), "successes": int(sum(ok for ok, _ in res)),
                         "one_action": int(sum(ok and n == 1 for ok, n in res)),
                         "mean_actions_success": float(np.mean([n for ok, n in res if ok])) if any(
                             ok for ok, _ in res) else None})  # fmt: skip
    return rows


def choose(rows: list[dict], trials: int) -> dict:
    """The selection rule of the module docstring, on case 1's rows."""
    aim = 2 / 3 * trials
    best = None
    for h, b in itertools.product(HALVES, BUDGETS):
        pick, gap = {}, 0.0
        for s in SCENARIOS:
            cand = [r for r in rows if (r["failure"], r["scenario"], r["half"], r["budget"]) == ("case1", s, h, b)]
            if not cand:
                break
            hard = scenario(s, 1.0, "hard")
            line = np.degrees(np.arctan2(hard.goal_center[1] - hard.target.y, hard.goal_center[0] - hard.target.x))

            def key(r, line=line, hard=hard):
                off = abs((r["angle"] - line + 180) % 360 - 180)
                return (r["one_action"] == 0 and not hard.fixed, abs(r["successes"] - aim), r["distance"], off)

            r = min(cand, key=key)
            pick[s] = r
            gap += abs(r["successes"] - aim) + (trials if r["one_action"] == 0 and not hard.fixed else 0)
        else:
            k = (round(gap, 6), (h, b) != (0.06, 30), h, b)
            if best is None or k < best[0]:
                best = (k, h, b, pick)
    if best is None:
        return {"none": "no candidates"}
    _, h, b, pick = best
    return {"half": h, "budget": b, "distances": {s: r["distance"] for s, r in pick.items()},
            "angles": {s: r["angle"] for s, r in pick.items()},
            "random_case1": {s: f"{r['successes']}/{r['trials']} ({r['one_action']} in one action)"
                             for s, r in pick.items()}}  # fmt: skip


def one_action_ends(path: Path) -> dict[int, list[list[dict]]]:
    """Scenario -> per start, the ends of its first actions (`one_action_rate.py`'s --out)."""
    from one_action_rate import read

    try:
        data = read(path)
        return {int(k): [st["ends"] for st in v["starts"]] for k, v in data["scenarios"].items()}
    except FileNotFoundError:
        raise SystemExit(f"calibrate_tasks: {path} does not exist") from None
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, OSError):
        raise SystemExit(f"calibrate_tasks: {path} is not an --out file of one_action_rate.py") from None


def add_p1(rows: list[dict], ends: dict[int, list[list[dict]]]) -> None:
    """Each case-1 row's p1: the mean over starts of their one-action rates on the row's task
    (`one_action_rate.start_rate`)."""
    from one_action_rate import start_rate

    memo: dict[tuple, float] = {}
    for r in rows:
        if r["failure"] != "case1" or r["scenario"] not in ends:
            continue
        key = (r["scenario"], r["angle"], r["distance"], r["half"])
        if key not in memo:
            hard = scenario(r["scenario"], 1.0, "hard")
            task = paper_variant(hard, PaperTask(r["distance"], r["half"], float(r["angle"])), r["budget"])
            memo[key] = float(np.mean([start_rate(task, st) for st in ends[r["scenario"]]]))
        r["p1"] = memo[key]


def choose_p1(rows: list[dict], trials: int, need: float = 0.95, per_cell: int = 15) -> dict:
    """The one-action rule (module docstring) on case 1's rows, which carry p1."""
    aim = 2 / 3 * trials
    best = None
    for h, b in itertools.product(HALVES, BUDGETS):
        cands = []
        for sc in SCENARIOS:
            c = [r for r in rows if (r["failure"], r["scenario"], r["half"], r["budget"]) == ("case1", sc, h, b)]
            if not c or any("p1" not in r for r in c):
                break
            cands.append(c)
        else:
            for combo in itertools.product(*cands):
                none = float(np.prod([(1.0 - r["p1"]) ** per_cell for r in combo]))
                if 1.0 - none < need:
                    continue
                gap = round(sum(abs(r["successes"] - aim) for r in combo), 6)
                k = (gap, round(sum(r["distance"] for r in combo), 6), (h, b) != (0.10, 30), h, b)
                if best is None or k < best[0]:
                    best = (k, h, b, combo, 1.0 - none)
    if best is None:
        return {"none": f"no candidate gives a one-action success in {per_cell} trials a scenario with chance {need}"}
    _, h, b, combo, chance = best
    return {"half": h, "budget": b, "distances": {r["scenario"]: r["distance"] for r in combo},
            "angles": {r["scenario"]: r["angle"] for r in combo}, "one_action_chance": round(chance, 4),
            "p1": {r["scenario"]: round(r["p1"], 4) for r in combo},
            "random_case1": {r["scenario"]: f"{r['successes']}/{r['trials']} ({r['one_action']} in one action)"
                             for r in combo}}  # fmt: skip


def apply(choice: dict, path: Path) -> None:
    """Write the choice into lmjx/sim/scenarios.py (PAPER_TASKS, PAPER_BUDGET)."""
    import re

    tasks = ", ".join(f"{s}: PaperTask({d:.2f}, {choice['half']:.2f}, {choice['angles'][s]:.1f})"
                      for s, d in sorted(choice["distances"].items()))  # fmt: skip
    text = path.read_text()
    text, n1 = re.subn(r"^PAPER_TASKS = \{.*\}.*$", f"PAPER_TASKS = {{{tasks}}}", text, flags=re.M)
    text, n2 = re.subn(r"^PAPER_BUDGET = .*$", f"PAPER_BUDGET = {choice['budget']}", text, flags=re.M)
    assert n1 == n2 == 1, "PAPER_TASKS / PAPER_BUDGET not found"
    path.write_text(text)


def _runs_of(path: Path) -> list[dict]:
    """The "runs" of an earlier --out file; a one-line exit for a missing or foreign file."""
    try:
        runs = json.loads(path.read_text())["runs"]
    except FileNotFoundError:
        raise SystemExit(f"calibrate_tasks: {path} does not exist") from None
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError):
        raise SystemExit(f"calibrate_tasks: {path} is not a calibration file (an --out file of this script)") from None
    return runs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--maps", default="maps", help="folder with case1.h5 and case2.h5")
    ap.add_argument("--trials", type=int, default=30, help="calibration trials per scenario (and distance)")
    ap.add_argument("--failures", default="case1,case2")
    ap.add_argument("--out", required=True, help="JSON file: the tracks, the grid and the choice")
    ap.add_argument("--apply", action="store_true", help="write the choice into lmjx/sim/scenarios.py")
    ap.add_argument(
        "--scenarios",
        default=",".join(map(str, SCENARIOS)),
        help="run only these scenarios (a part of one calibration, for --from-runs)",
    )
    ap.add_argument("--first", type=int, default=0,
                    help="the first calibration trial's index (a part of one calibration: trials FIRST ... "
                         "FIRST+TRIALS-1, merged with --from-runs)")  # fmt: skip
    ap.add_argument("--from-runs", nargs="+", metavar="FILE",
                    help="score the trials of earlier --out files again instead of running them (several: "
                         "the parts of one calibration, merged by trial seed)")  # fmt: skip
    ap.add_argument("--one-action", metavar="RATES",
                    help="one_action_rate.py's --out on the same calibration starts: the one-action "
                         "rule (a one-action success in case 1's 45 trials with chance 0.95)")  # fmt: skip
    args = ap.parse_args()
    robot = load_robot("panda")
    runs, t0 = {}, time.perf_counter()
    if args.from_runs:  # the trials of earlier runs (or of one run's parts), scored again
        merged: dict[tuple[str, int], dict[int, dict]] = {}
        for path in args.from_runs:
            for r in _runs_of(Path(path)):
                merged.setdefault((r["failure"], r["scenario"]), {}).update({tr["seed"]: tr for tr in r["trials"]})
        runs = {k: [v[seed] for seed in sorted(v)] for k, v in sorted(merged.items())}
        counts = {len(v) for (f, _), v in runs.items() if f == "case1"} or {len(v) for v in runs.values()}
        if len(counts) != 1:
            raise SystemExit(f"the runs hold different numbers of trials per scenario: {sorted(counts)}")
        args.trials = counts.pop()
        for (f, s), trials in runs.items():  # the parts must make up trials 0 ... N-1, no gap
            want = [trial_seed(CAL_BASE, s, t) for t in range(args.trials)]
            if [tr["seed"] for tr in trials] != want:
                raise SystemExit(f"{f} scenario {s}: the parts hold trial seeds other than {want[0]} ... {want[-1]}")
        print(
            f"{sum(map(len, runs.values()))} trials from {len(args.from_runs)} file(s): "
            + ", ".join(f"{f} scenario {s}: {len(v)}" for (f, s), v in runs.items())
        )
    for f in args.failures.split(","):
        if args.from_runs:
            break
        try:
            m = load_map(Path(args.maps) / f"{f}.h5", robot=robot)
        except LmjxError as e:
            raise SystemExit(f"calibrate_tasks: {e}") from None
        for s in (int(x) for x in args.scenarios.split(",")):
            runs[(f, s)] = run_trials(robot, m, s, args.trials, max(BUDGETS), args.first)
            acts = [tr["actions"] for tr in runs[(f, s)]]
            print(f"{f} scenario {s}: {sum(acts)} actions in {len(acts)} trials "
                  f"({time.perf_counter() - t0:.0f} s)", flush=True)  # fmt: skip
    rows = grid(runs)
    if args.one_action:
        add_p1(rows, one_action_ends(Path(args.one_action)))
        choice = choose_p1(rows, args.trials)
    else:
        choice = choose(rows, args.trials) if "case1" in args.failures else None
    print(json.dumps(choice, indent=1))
    out = {"trials": args.trials, "first": 0 if args.from_runs else args.first, "seed_base": CAL_BASE,
           "choice": choice, "grid": rows,
           "runs": [{"failure": f, "scenario": s, "trials": tr} for (f, s), tr in runs.items()],
           "seconds": round(time.perf_counter() - t0, 1)}  # fmt: skip
    Path(args.out).write_text(json.dumps(out) + "\n")
    if args.apply and choice and "none" not in choice:
        apply(choice, Path(__file__).resolve().parents[1] / "lmjx" / "scenarios.py")


if __name__ == "__main__":
    main()
