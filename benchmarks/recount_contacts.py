"""Replay finished trials in the "real" world and count their transits' contacts again.

A trial's record holds the edge of each executed action; the "real" world
(`lmjx.sim.realworld.SimulatedRealWorld`) is drawn from the trial's seed and its observations'
noise is drawn in the order of the executions.  Replaying the recorded edges in order (the
transit to each built by the same `TransitPlanner` from the same arm state, last edge and
trail, on the same scene as observed) therefore executes the same actions again: the replay
checks this per action (the target's displacement, the distance to the goal after it and the
transit's route and the edge's states executed must equal the record's, to its 0.1 mm
rounding; once an action departs, every later one counts as departed) and counts the transit's
contacts with the executor of this checkout, e.g. under a newer counting rule than the one
the trial ran with (`lmjx.sim.realworld.LEAVE_CLEAR`; docs/EVALUATION.md, "Protocol").  Planning is not repeated: no
simulator is needed, whatever ASM chose the edges.

    python benchmarks/recount_contacts.py docs/evaluation/paper_gpu/results.json ... \\
        --maps maps --out recount.json [--part K/N]

The maps must be those the trials ran on (`benchmarks/map_digest.py`).  Each record is
replayed once (records of the same trial in several files, e.g. Random's, shared by a GPU and
a CPU evaluation, count once).  `--part K/N` replays every N-th trial (split across
processes; merge with `--merge OUT FILE...`).  GPU runs' transits were checked with the
batched JAX kernel and are replayed with it (`TransitPlanner(batched=True)`), CPU runs' with
C MuJoCo.

`--combine RECOUNT` replays nothing: it counts every action of the results once, taking the
replay's count where RECOUNT replayed the record unchanged and the recorded one otherwise
(trials run after the replay, or run again):

    python benchmarks/recount_contacts.py --combine recount.json \\
        docs/evaluation/*/results.json --out combined.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from lmjx.errors import LmjxError
from lmjx.evaluation.evaluate import load_maps
from lmjx.evaluation.results import trials_of
from lmjx.model.robot import load_robot
from lmjx.planner.edge_planner import Planner
from lmjx.planner.records import StepRecord
from lmjx.planner.scoring import goal_distance
from lmjx.planner.transit import TransitPlanner
from lmjx.runtime.fileio import write_text_atomic
from lmjx.sim.realworld import SimulatedRealWorld
from lmjx.sim.scenarios import sample_layout, scenario
from lmjx.types import PlannerConfig

TOL = 1.5e-4  # [m] the records' rounding (0.1 mm) and a little


class Replay(Planner):
    """A planner whose decisions are the recorded edges, in order (then none)."""

    queue: list[int]

    def decide(self, obs, rng):
        self.transits.set_scene(self.sc, obs.objects)
        rec = StepRecord(-1, 0, 0, None, float(goal_distance(self.sc, obs.objects[0, :2])), 0.0, 0.0)
        if not self.queue:
            return None, rec
        edge = self.queue.pop(0)
        acts = self.transits.actions(self.bundle, np.array([edge]), obs.robot_q, 1, self.came_from, self.trail)
        rec.edge = edge if acts else -1
        return (acts[0] if acts else None), rec
        yield  # a generator, as `Planner.decide` (it asks for no simulation)


def key(r: dict) -> tuple:
    sim = "none" if r["asm"] == "random" else r.get("sim", "cpu")
    return (r.get("tasks", "hard"), sim, r["failure"], r["scenario"], r["asm"], r["seed"])


def replay(records: list[dict], maps_dir: Path, say) -> list[dict]:
    """Per record, per action: the replayed figures beside the recorded ones."""
    robot = load_robot(records[0].get("robot", "panda")) if records else None
    failures = tuple(sorted({r["failure"] for r in records}))
    maps = load_maps(robot, failures, maps_dir) if records else {}
    transits: dict[tuple, TransitPlanner] = {}
    out = []
    for i, r in enumerate(records):
        t0 = time.perf_counter()
        tasks, sim, f, s = r.get("tasks", "hard"), key(r)[1], r["failure"], r["scenario"]
        batched = sim == "gpu"
        tp = transits.setdefault((f, s, tasks, batched), TransitPlanner(robot, maps[f].failure, batched=batched))
        sc = scenario(s, robot.profile.task_scale, tasks)
        m = maps[f]
        planner = Replay(robot, m.failure, m.reach, m.edges, sc, None, PlannerConfig(asm="random"), tp)
        planner.queue = [int(st["edge"]) for st in r["steps"]]
        res = planner.run(SimulatedRealWorld(robot, r["seed"]), sample_layout(sc, r["seed"]), r["seed"] * 7)
        steps = []
        same = True  # until the first action that departs from its record (all after it differ)
        for k, st in enumerate(r["steps"]):
            new = res.steps[k] if k < len(res.steps) and res.steps[k].edge >= 0 else None
            same = bool(
                same
                and new is not None
                and new.edge == st["edge"]
                and new.edge_states == st["edge_states"]
                and abs(new.target_moved_m - st["target_moved_m"]) <= TOL
                and abs(new.distance_after - st["distance_after_m"]) <= TOL
                and new.transit_route == st["transit_route"]
            )
            steps.append(
                {
                    "edge": st["edge"],
                    "same": same,
                    "target_moved_m": None if new is None else round(new.target_moved_m, 4),
                    "recorded_target_moved_m": st["target_moved_m"],
                    "transit_contacts": None if new is None else list(new.transit_contacts),
                    "recorded_transit_contacts": st["transit_contacts"],
                    "transit_hit_fixed": None if new is None else new.transit_hit_fixed,
                }
            )
        out.append({"key": list(key(r)), "success": r["success"], "replayed_success": res.success, "steps": steps})
        n_same = sum(x["same"] for x in steps)
        took = time.perf_counter() - t0
        say(f"{i + 1}/{len(records)} {key(r)}: {n_same}/{len(steps)} actions the same ({took:.1f} s)")
    return out


def summary(trials: list[dict]) -> dict:
    """Counts over all replayed actions, and per simulator of the evaluation."""
    by: dict[str, dict] = defaultdict(lambda: defaultdict(int))
    for t in trials:
        sim = t["key"][1]
        for st in t["steps"]:
            for group in ("all", sim):
                c = by[group]
                c["actions"] += 1
                c["same"] += st["same"]
                if st["same"]:
                    c["touch_new"] += bool(st["transit_contacts"])
                    c["touch_recorded"] += bool(st["recorded_transit_contacts"])
                    c["contacts_as_recorded"] += st["transit_contacts"] == st["recorded_transit_contacts"]
                    c["hit_fixed"] += bool(st["transit_hit_fixed"])
    return {g: dict(c) for g, c in by.items()}


def combine(replayed: list[dict], results: list[Path]) -> dict:
    """Transit contacts over every trial of `results` once (a record in several files, e.g.
    Random's, counts once): a trial the recount replayed (the same key and the same edges)
    counts its actions replayed the same by the replay's rule and the others as recorded; a
    trial it did not replay (run later, or run again since) counts as recorded."""
    old = {tuple(t["key"]): t for t in replayed}
    recs = {key(r): r for p in results for r in trials_of(p)}
    c: dict[str, int] = defaultdict(int)
    for k, r in recs.items():
        t = old.get(k)
        if t is not None and [s["edge"] for s in t["steps"]] != [s["edge"] for s in r["steps"]]:
            t = None  # the trial ran again since the replay
        c["trials_replayed" if t else "trials_as_recorded"] += 1
        for i, st in enumerate(r["steps"]):
            c["actions"] += 1
            c["hit_fixed"] += bool(st["transit_hit_fixed"])
            if t is not None and t["steps"][i]["same"]:
                c["touch"] += bool(t["steps"][i]["transit_contacts"])
                c["actions_replayed_same"] += 1
            else:
                c["touch"] += bool(st["transit_contacts"])
    out = dict(c)
    out["touch_share"] = round(c["touch"] / max(c["actions"], 1), 4)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="*", type=Path, help="results.json files")
    ap.add_argument("--maps", type=Path, help="folder of <failure>.h5: the maps the trials ran on")
    ap.add_argument("--out", type=Path, required=True, help="JSON written: per trial and action, and the counts")
    ap.add_argument("--part", default="1/1", help="K/N: replay trials K, K+N, ... of the (deduplicated) records")
    ap.add_argument("--merge", nargs="+", type=Path, help="merge these outputs of parts into --out instead")
    ap.add_argument(
        "--combine",
        type=Path,
        metavar="RECOUNT",
        help="count every action of the results.json files once: from this recount where it replayed "
        "the same record, else as recorded; print the sums (and write them to --out)",
    )
    args = ap.parse_args()
    if args.combine:
        try:
            sums = combine(json.loads(args.combine.read_text())["trials"], args.results)
        except (OSError, ValueError, KeyError, TypeError, LmjxError) as e:  # a missing or foreign file: one line
            sys.exit(f"recount_contacts: --combine: {type(e).__name__}: {e}")
        write_text_atomic(args.out, json.dumps(sums, indent=1) + "\n")
        print(json.dumps(sums))
        return
    if args.merge:  # each trial once (a part given twice counts once)
        merged = {tuple(t["key"]): t for p in args.merge for t in json.loads(p.read_text())["trials"]}
        trials = [merged[k] for k in sorted(merged)]
    else:
        if args.maps is None or not args.results:
            sys.exit("recount_contacts: give the results.json files and --maps (the maps the trials ran on)")
        try:
            k, n = (int(x) for x in args.part.split("/"))
        except ValueError:
            k = n = 0
        if not 1 <= k <= n:
            sys.exit(f"recount_contacts: --part '{args.part}': give K/N with 1 <= K <= N")
        try:
            recs = {key(r): r for p in args.results for r in trials_of(p)}
        except LmjxError as e:  # not a results file: one line
            sys.exit(f"recount_contacts: {e}")
        if not recs:
            sys.exit("recount_contacts: no trials in " + ", ".join(map(str, args.results)))
        todo = [recs[x] for x in sorted(recs)][k - 1 :: n]
        try:
            trials = replay(todo, args.maps, lambda line: print(line, file=sys.stderr, flush=True))
        except LmjxError as e:  # a missing or corrupt map, another failure's map: one line
            sys.exit(f"recount_contacts: {e}")
    counts = summary(trials)
    write_text_atomic(args.out, json.dumps({"counts": counts, "trials": trials}, indent=0) + "\n")
    for g, c in counts.items():
        same = max(c.get("same", 0), 1)
        print(
            f"{g}: {c['actions']} actions, {c['same']} replayed the same; of those, transits touching a movable "
            f"object {c['touch_new']} ({100 * c['touch_new'] / same:.2f} %) now, {c['touch_recorded']} "
            f"({100 * c['touch_recorded'] / same:.2f} %) as recorded; the same objects as recorded in "
            f"{c['contacts_as_recorded']}; fixed obstacles {c['hit_fixed']}"
        )


if __name__ == "__main__":
    main()
