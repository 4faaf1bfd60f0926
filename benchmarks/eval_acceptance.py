"""The evaluation's acceptance checks (docs/EVALUATION.md, "Protocol"), computed from `lmjx evaluate`
results (results.json files).

    python benchmarks/eval_acceptance.py --paper docs/evaluation/paper_gpu/results.json \
        --hard docs/evaluation/hard_gpu/results.json [--paper docs/evaluation/paper_cpu/results.json ...] \
        [--replicate BASE] [--registered PAGE.md] [--json OUT.json] [--report DIR]

Prints, per run, the success (with its Wilson 95 % interval) and mean actions per successful
trial of every cell, and then each acceptance item with the figures it rests on: the paper
set's case-1 ordering (Greedy 100 %, Random lowest and >= 40 % in two scenarios, Lazy between,
Greedy the fewest actions, a one-action Random success), case 2's Greedy >= 70.6 %, the hard
set's Greedy against the figures before the executable actions, and over every executed action
of every run: transits that touched a fixed obstacle, transits that touched a movable object,
and Random's actions that moved the target 1 cm or more.  --replicate BASE adds the checks of a
registered replicate (docs/evaluation/REPLICATE.md): every cell complete with the trial seeds
of that base, every trial of one run's conditions (commit, maps, planner, simulator), no trial
dropped or run twice, one kind of device.  --registered FILE checks every trial record against
the registration on that page (`lmjx.evaluation.registration`): the registered commit with a
clean tree, map digests, planner configuration, task set, simulator and seeds, and exactly one
record per registered trial (none missing, twice, or replaced by a cell run again), every run
registered as its arm (`lmjx evaluate --registered`), with the runs' checks.  --report DIR
rewrites report.md and the plots of a results file in DIR (for a run that was stopped before
its last trial); --merge DEST DIR... joins the results of runs split in parts (`lmjx evaluate
--part K/N`, one cell a process) into DEST and rewrites its report: parts of other conditions
(commit, maps, planner, ...) and a trial found twice with different records are refused in one
line unless --allow-mixed (the report then says so)."""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter, defaultdict
from collections.abc import Callable
from pathlib import Path

from lmjx.errors import LmjxError
from lmjx.evaluation.registration import Arm, Registration, read_registration
from lmjx.evaluation.results import Results, merge, write_results
from lmjx.evaluation.results import read_results as load
from lmjx.evaluation.stats import rate_text

HARD_BEFORE = {"case1": {1: 1.0, 2: 1.0, 3: 1.0}, "case2": {1: 1.0, 2: 14 / 15, 3: 1.0}}
PAPER_CASE2_GREEDY = 0.706
TRIALS = 15  # a cell is complete with this many trials; the checks use complete cells only
ASMS = ("random", "lazy", "greedy")


def cells(records: list[dict]) -> dict[tuple, dict]:
    """(failure, scenario, asm) -> trials, successes, success rate, mean actions of the successes."""
    by = defaultdict(list)
    for r in records:
        by[(r["failure"], r["scenario"], r["asm"])].append(r)
    out = {}
    for k, rs in sorted(by.items()):
        ok = [r for r in rs if r["success"]]
        out[k] = {
            "trials": len(rs),
            "successes": len(ok),
            "success": len(ok) / len(rs),
            "actions": sum(r["actions"] for r in ok) / len(ok) if ok else None,
            "one_action_successes": sum(1 for r in ok if r["actions"] == 1),
        }
    return out


def action_figures(records: list[dict]) -> dict:
    steps = [(r["asm"], s) for r in records for s in r["steps"]]
    rnd = [s for a, s in steps if a == "random"]
    moved = [s for s in rnd if s.get("target_moved_m") is not None and s["target_moved_m"] >= 0.01]
    return {
        "actions": len(steps),
        "transit_hit_fixed": sum(1 for _, s in steps if s.get("transit_hit_fixed")),
        "transit_touched_object": sum(1 for _, s in steps if s.get("transit_contacts")),
        "random_actions": len(rnd),
        "random_moved_1cm": len(moved),
    }


def paper_checks(c: dict) -> list[tuple[str, bool, str]]:
    out = []
    # a partial run: the checks over its complete scenarios (every ASM of both failures recorded)
    scen = sorted(
        s
        for s in {k[1] for k in c}
        if all(c.get((f, s, a), {}).get("trials", 0) >= TRIALS for f in ("case1", "case2") for a in ASMS)
    )
    if not scen:  # no scenario complete for every ASM and both failures: nothing to judge
        return [("paper set: a complete scenario (15 trials of every ASM, both failures)", False, "none")]
    g = {s: c[("case1", s, "greedy")]["success"] for s in scen}
    lz = {s: c[("case1", s, "lazy")]["success"] for s in scen}
    rd = {s: c[("case1", s, "random")]["success"] for s in scen}
    pct = lambda d: "/".join(f"{100 * d[s]:.1f}" for s in scen)  # noqa: E731
    out.append(("case 1: Greedy 100 % in every scenario", all(v == 1.0 for v in g.values()), pct(g)))
    out.append(
        (
            "case 1: Random the lowest ASM in every scenario",
            all(rd[s] <= min(g[s], lz[s]) for s in scen),
            f"Random {pct(rd)}, Lazy {pct(lz)}",
        )
    )
    out.append(("case 1: Random >= 40 % in at least two scenarios", sum(v >= 0.4 for v in rd.values()) >= 2, pct(rd)))
    out.append(
        ("case 1: Lazy between Random and Greedy (or = Greedy)", all(rd[s] <= lz[s] <= g[s] for s in scen), pct(lz))
    )
    fewest, cells_with = 0, 0
    for f in ("case1", "case2"):
        for s in scen:
            acts = {a: c[(f, s, a)]["actions"] for a in ("random", "lazy", "greedy")}
            if acts["greedy"] is None:
                continue
            cells_with += 1
            others = [v for a, v in acts.items() if a != "greedy" and v is not None]
            fewest += all(acts["greedy"] < v for v in others)
    out.append(
        (
            "Greedy strictly the fewest mean actions per success in >= 5 of 6 cells",
            fewest >= 5,
            f"{fewest} of the {cells_with} cells where Greedy succeeded",
        )
    )
    ones = sum(c[("case1", s, "random")]["one_action_successes"] for s in scen)
    out.append(("case 1: a Random success in a single action", ones >= 1, f"{ones} one-action Random successes"))
    g2 = {s: c[("case2", s, "greedy")]["success"] for s in scen}
    out.append(
        ("case 2: Greedy >= 70.6 % in every scenario", all(v >= PAPER_CASE2_GREEDY for v in g2.values()), pct(g2))
    )
    return out


def hard_checks(c: dict) -> list[tuple[str, bool, str]]:
    out = []
    for f, want in HARD_BEFORE.items():
        if any(c.get((f, s, "greedy"), {}).get("trials", 0) < TRIALS for s in want):
            have = "/".join(
                f"{100 * c[(f, s, 'greedy')]['success']:.1f} of {c[(f, s, 'greedy')]['trials']}"
                if (f, s, "greedy") in c
                else "-"
                for s in want
            )
            out.append((f"hard set, {f}: Greedy at least as high as before", False, f"{have} (partial run)"))
            continue
        got = {s: c[(f, s, "greedy")]["success"] for s in want}
        out.append(
            (
                f"hard set, {f}: Greedy at least as high as before",
                all(got[s] >= want[s] - 1e-9 for s in want),
                "/".join(f"{100 * got[s]:.1f}" for s in want)
                + " (before: "
                + "/".join(f"{100 * want[s]:.1f}" for s in want)
                + ")",
            )
        )
    return out


def replicate_checks(runs: dict[str, Results], base: int) -> list[tuple[str, bool, str]]:
    """The registered replicate's own checks (docs/evaluation/REPLICATE.md), over its results
    files (`runs`: path -> results): each task set complete (2 failures x 3 scenarios x 3 ASMs
    x 15 trials, the trial seeds of `base`), then `run_checks`."""
    from lmjx.evaluation.evaluate import trial_seed

    out = []
    want = {(f, s, a, trial_seed(base, s, t)) for f in ("case1", "case2") for s in (1, 2, 3) for a in ASMS
            for t in range(TRIALS)}  # fmt: skip
    for path, res in runs.items():
        have = [(r["failure"], r["scenario"], r["asm"], r["seed"]) for r in res.trials]
        missing, extra = len(want - set(have)), len(set(have) - want)
        complete = not missing and not extra and len(have) == len(want)
        out.append((f"{path}: complete, {len(want)} trials of seed base {base}", complete,
                    f"{len(have)} trials, {missing} missing, {extra} not of the design"))  # fmt: skip
    return out + run_checks(runs)


def run_checks(runs: dict[str, Results]) -> list[tuple[str, bool, str]]:
    """The runs' checks, over results files (`runs`: path -> results): every trial of one run's
    conditions (the task sets aside), no trial dropped or run twice, no run pooled with
    --allow-mixed, one kind of device."""
    from lmjx.evaluation.provenance import differences, differences_text

    out = []
    used = [(p, run) for p, res in runs.items() for run in res.runs_used()]
    recorded = [run for _, run in used if not run.get("unrecorded")]
    diffs = []
    for p, run in used:
        if run.get("unrecorded"):
            diffs.append(f"{p}: trials without provenance")
            continue
        d = [x for x in differences(recorded[0], run) if x[0] != "task set"]  # (the sets differ in their tasks)
        if d:
            diffs.append(f"{p} run {run['id']}: {differences_text(d, 'first', 'its')}")
    out.append(("every trial of one run's conditions (commit, maps, planner, simulator, trials, seed base)",
                bool(used) and not diffs, "; ".join(diffs) or f"{len(used)} runs, the same conditions"))  # fmt: skip
    dropped = []
    for p, res in runs.items():
        ran = sum(int(run.get("trials_run", 0)) for run in res.runs if not run.get("unrecorded"))
        if ran != len(res.trials) or res.replaced:
            dropped.append(f"{p}: {ran} trials run, {len(res.trials)} held, {len(res.replaced)} run twice")
    out.append(("no trial dropped or run twice (the trials each run ran = the trials held)", not dropped,
                "; ".join(dropped) or "each run's trials all held"))  # fmt: skip
    mixed = [f"{p} run {run['id']}" for p, run in used if run.get("allow_mixed")]
    out.append(("no run pooled with --allow-mixed", not mixed, ", ".join(mixed) or "none"))
    devices = sorted({run["simulator"]["device"] for run in recorded if run["simulator"]["name"] != "none"})
    out.append(("one kind of device", len(devices) == 1 and len(recorded) == len(used),
                "; ".join(devices) or "none recorded"))  # fmt: skip
    return out


def registration_checks(runs: dict[str, Results], registration: Registration) -> list[tuple[str, bool, str]]:
    """Every trial record of the results files (`runs`: path -> results) against the
    registration (`lmjx.evaluation.registration`): each file is the arm of its records' task
    set, and each arm has its files; every run that made them registered as that arm (`lmjx
    evaluate --registered`); every record at the registered commit with a clean tree,
    its map of the registered digest, the arm's planner configuration, task set and simulator,
    a seed of the registered base seed and trials (`trial_seed`) in one of the arm's cells;
    exactly one record per (failure, scenario, ASM, trial): none missing, none twice, none
    replaced by a cell run again."""
    by_arm: dict[str, list[str]] = defaultdict(list)
    out = []
    for path, res in runs.items():
        sets = sorted({str(r.get("tasks", "unknown")) for r in res.trials})
        arm = next((a for a in registration.arms if sets == [a.tasks]), None)
        if arm is None:
            out.append((f"{path}: the trials of a registered arm", False, f"task sets {', '.join(sets) or 'none'}; "
                        "registered: " + ", ".join(f"{a.name} ({a.tasks})" for a in registration.arms)))  # fmt: skip
            continue
        by_arm[arm.name].append(path)
    for arm in registration.arms:
        paths = by_arm.get(arm.name, [])
        if not paths:
            out.append((f"arm {arm.name}: its results given", False, f"no results file of task set {arm.tasks}"))
            continue
        where = ", ".join(paths)
        other = [f"{p}: run {run['id']} ({run['trials_held']} trials)" for p in paths for run in runs[p].runs_used()
                 if (run.get("registered") or {}).get("arm") != arm.name]  # fmt: skip
        out.append((f"arm {arm.name} ({where}): every run registered as the arm (lmjx evaluate --registered)",
                    not other, "; ".join(other) or "all"))  # fmt: skip
        out += _arm_checks(arm, registration, [(p, r) for p in paths for r in runs[p].trials],
                           sum(len(runs[p].replaced) for p in paths), where)  # fmt: skip
    return out


def _arm_checks(arm: Arm, registration: Registration, records: list[tuple[str, dict]], replaced: int,
                where: str) -> list[tuple[str, bool, str]]:  # fmt: skip
    """`registration_checks` for one arm's records (each with its file)."""
    from lmjx.evaluation.evaluate import trial_seed

    seeds = {s: {trial_seed(registration.base_seed, s, t): t for t in range(arm.trials)} for s in arm.scenarios}

    def name(r: dict) -> str:
        return f"{r['failure']}/{r['scenario']}/{r['asm']}/{r['seed']}"

    def prov(r: dict) -> dict:
        return r.get("provenance") or {}

    def check(what: str, wrong: Callable[[dict], str | None]) -> tuple[str, bool, str]:
        bad = [(p, r, why) for p, r in records if (why := wrong(r)) is not None]
        shown = "; ".join(f"{p}: {name(r)} {why}" for p, r, why in bad[:3]) + ("; ..." if len(bad) > 3 else "")
        figures = f"{len(bad)} of {len(records)} records differ: {shown}" if bad else f"{len(records)} records"
        return f"arm {arm.name} ({where}): every record {what}", not bad and bool(records), figures

    def commit(r: dict) -> str | None:
        c, dirty = prov(r).get("commit", "unknown"), prov(r).get("dirty")
        return None if c == registration.commit and dirty is not True else f"at commit {str(c)[:12]}, dirty {dirty}"

    def digest(r: dict) -> str | None:
        d, want = prov(r).get("map", {}).get("digest", "unknown"), registration.maps.get(r["failure"])
        return None if want is not None and d == want.digest else f"map digest {str(d)[:12]}"

    def planner(r: dict) -> str | None:
        have = prov(r).get("planner") or {}
        want = {**arm.levers, "asm": r["asm"]}
        keys = [k for k in sorted(set(have) | set(want)) if have.get(k, "unrecorded") != want.get(k, "unregistered")]
        return None if have and not keys else "planner " + ", ".join(f"{k} {have.get(k, 'unrecorded')}" for k in keys)

    def tasks(r: dict) -> str | None:
        t, sim = (r.get("tasks"), prov(r).get("tasks", {}).get("set")), prov(r).get("simulator")
        ok = t == (arm.tasks, arm.tasks) and sim == arm.simulator((r["asm"],))
        return None if ok else f"task set {t[0]} (provenance {t[1]}), simulator {sim}"

    def seed(r: dict) -> str | None:
        cell = r["failure"] in arm.failures and r["asm"] in arm.asms and r["scenario"] in seeds
        return None if cell and r["seed"] in seeds[r["scenario"]] else "not of the registered cells and seeds"

    out = [
        check(f"at the registered commit {registration.commit[:12]}, its tree clean", commit),
        check("on the registered map of its failure", digest),
        check("of the registered planner configuration", planner),
        check(f"of the task set {arm.tasks} and the simulator {arm.sim}", tasks),
        check(f"of the registered cells and seeds (base {registration.base_seed}, {arm.trials} a cell)", seed),
    ]
    want = {(f, s, a, t) for f in arm.failures for s in arm.scenarios for a in arm.asms for t in range(arm.trials)}

    def trial(r: dict) -> tuple:  # a trial by its number in the cell; a seed no registered trial has, by the seed
        return r["failure"], r["scenario"], r["asm"], seeds.get(r["scenario"], {}).get(r["seed"], f"seed {r['seed']}")

    held = Counter(trial(r) for _, r in records)
    missing, twice = len(want - set(held)), sum(n - 1 for n in held.values() if n > 1)
    out.append((f"arm {arm.name} ({where}): exactly one record per failure, scenario, ASM and trial",
                not missing and not twice and not replaced and set(held) <= want,
                f"{len(want)} registered, {len(records)} held: {missing} missing, {twice} twice, "
                f"{len(set(held) - want)} not registered, {replaced} replaced by a cell run again"))  # fmt: skip
    return out


def read_results(path: Path, flag: str) -> Results:
    """The results of a results.json, or a one-line exit naming `flag` where it cannot be read."""
    if not path.exists():
        sys.exit(f"eval_acceptance: {flag}: {path} does not exist")
    try:
        return load(path)
    except LmjxError as e:
        sys.exit(f"eval_acceptance: {flag}: {e}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--paper", action="append", default=[], help="results.json of a paper-set run")
    ap.add_argument("--hard", action="append", default=[], help="results.json of a hard-set run")
    ap.add_argument("--json", help="write the figures here too")
    ap.add_argument("--report", help="rewrite report.md, bubble.png, actions.png of DIR/results.json and stop")
    ap.add_argument(
        "--merge",
        nargs="+",
        metavar="DIR",
        help="write DEST/results.json (the first DIR) from the results.json of the others (runs of one task set "
        "split by cell or part, e.g. lmjx evaluate --part K/N), then rewrite DEST's report and stop; DEST's own "
        "trials are kept; parts of other conditions and a trial found twice with different records are refused "
        "unless --allow-mixed",
    )
    ap.add_argument(
        "--allow-mixed",
        action="store_true",
        help="--merge: pool parts of other conditions, and keep the later record of a trial found twice (the "
        "report says so)",
    )
    ap.add_argument("--replicate", type=int, metavar="BASE", help="add the checks of a registered replicate of "
                    "seed base BASE (docs/evaluation/REPLICATE.md)")  # fmt: skip
    ap.add_argument("--registered", metavar="FILE", help="add the checks of every trial record against the "
                    "registration on the page FILE (docs/evaluation/REPLICATE.md), and the runs' checks")  # fmt: skip
    ap.add_argument(
        "--simulator",
        help="the simulator's description for a rewritten report of trials without provenance (default: this "
        "machine's; e.g. 'gpu: MuJoCo Warp on NVIDIA H100 80GB HBM3, whole scene')",
    )
    args = ap.parse_args()
    try:
        registration = None if args.registered is None else read_registration(args.registered)
    except LmjxError as e:
        sys.exit(f"eval_acceptance: {e}")
    if args.merge:
        dest, *srcs = (Path(d) for d in args.merge)
        # DEST's own trials first, so that merging new runs into it never drops what it held
        own = (dest / "results.json").exists() and dest.resolve() not in {d.resolve() for d in srcs}
        kept = [dest] if own else []
        parts = []
        for d in kept + srcs:
            if not (d / "results.json").exists():  # a run stopped before its first trial ended
                print(f"{d}: no trials")
                continue
            parts.append((str(d), read_results(d / "results.json", "--merge")))
        try:
            merged = merge(parts, args.allow_mixed)
        except LmjxError as e:
            sys.exit(f"eval_acceptance: --merge: {e}")
        if not merged.trials:
            sys.exit(f"eval_acceptance: --merge: no trials in {', '.join(str(d) for d in kept + srcs) or 'no folder'}")
        merged.trials.sort(key=lambda r: (r["failure"], r["scenario"], ASMS.index(r["asm"]), r["seed"]))
        dest.mkdir(parents=True, exist_ok=True)
        write_results(dest / "results.json", merged)
        print(
            f"{dest}/results.json: {len(merged.trials)} trials from {len(srcs)} runs" + (" and its own" if kept else "")
        )
        args.report = str(dest)
    if args.report:
        from lmjx.evaluation.evaluate import EvalConfig, plots, report_markdown
        from lmjx.evaluation.provenance import simulator_description
        from lmjx.model.robot import load_robot
        from lmjx.runtime.fileio import write_text_atomic
        from lmjx.types import PlannerConfig

        d = Path(args.report)
        res = read_results(d / "results.json", "--report")
        recs = res.trials
        if not recs:
            sys.exit(f"eval_acceptance: --report: {d / 'results.json'} holds no trials")
        sim = next((r["sim"] for r in recs if r["sim"] != "none"), "cpu")
        cand = next((r["candidates"] for r in recs if r["candidates"]), 32)
        config = EvalConfig(tasks=recs[0]["tasks"], planner=PlannerConfig(greedy_candidates=cand))
        robot = load_robot(recs[0].get("robot", "panda"))
        recorded = all(not run.get("unrecorded") for run in res.runs_used())
        simulator = args.simulator or ("" if recorded else simulator_description(sim))
        write_text_atomic(d / "report.md", report_markdown(res, config, simulator, robot))
        plots(recs, d)
        print(f"{d}: {len(recs)} trials, report.md and plots rewritten")
        return
    result: dict = {"runs": {}, "checks": []}
    total = defaultdict(int)
    given: dict[str, Results] = {}
    for kind, paths in (("paper", args.paper), ("hard", args.hard)):
        for p in paths:
            given[p] = read_results(Path(p), f"--{kind}")
            recs = given[p].trials
            c = cells(recs)
            fig = action_figures(recs)
            for k, v in fig.items():
                total[k] += v
            result["runs"][p] = {"tasks": kind, "trials": len(recs), "actions": fig}
            print(f"\n{p} ({kind}, {len(recs)} trials)")
            for (f, s, a), v in c.items():
                acts = "-" if v["actions"] is None else f"{v['actions']:.1f}"
                print(f"  {f} s{s} {a:6s} {rate_text(v['successes'], v['trials']):34s} actions {acts}")
            checks = paper_checks(c) if kind == "paper" else hard_checks(c)
            if kind == "paper" and len({k[1] for k in c}) * 18 * 15 // 3 != len(recs):
                checks = [(n, ok, why + " (partial run: complete scenarios only)") for n, ok, why in checks]
            for name, ok, why in checks:
                print(f"  [{'met' if ok else 'NOT met'}] {name}: {why}")
                result["checks"].append({"run": p, "check": name, "met": ok, "figures": why})
    t = dict(total)
    overall = [
        (
            "no transit touches a fixed obstacle",
            t.get("transit_hit_fixed", 0) == 0,
            f"{t.get('transit_hit_fixed', 0)} of {t.get('actions', 0)} actions",
        ),
        (
            "a transit touches a movable object in at most 2 % of actions",
            t.get("transit_touched_object", 0) <= 0.02 * t.get("actions", 0),
            f"{t.get('transit_touched_object', 0)} of {t.get('actions', 0)}"
            f" ({100 * t.get('transit_touched_object', 0) / max(t.get('actions', 0), 1):.1f} %)",
        ),
        (
            ">= 80 % of Random's actions move the target 1 cm or more",
            t.get("random_moved_1cm", 0) >= 0.8 * t.get("random_actions", 0),
            f"{t.get('random_moved_1cm', 0)} of {t.get('random_actions', 0)}"
            f" ({100 * t.get('random_moved_1cm', 0) / max(t.get('random_actions', 0), 1):.1f} %)",
        ),
    ]
    if args.replicate is not None:
        overall += replicate_checks(given, args.replicate)
    if registration is not None:
        overall += registration_checks(given, registration) + ([] if args.replicate is not None else run_checks(given))
    print("\nacross every run given:")
    for name, ok, why in overall:
        print(f"  [{'met' if ok else 'NOT met'}] {name}: {why}")
        result["checks"].append({"run": "all", "check": name, "met": ok, "figures": why})
    result["totals"] = t
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
