"""The evaluation's acceptance checks (docs/EVALUATION.md, "Protocol"), computed from `lmjx evaluate`
results (results.json files).

    python benchmarks/eval_acceptance.py --paper docs/evaluation/paper_gpu/results.json \
        --hard docs/evaluation/hard_gpu/results.json [--paper docs/evaluation/paper_cpu/results.json ...] \
        [--json OUT.json] [--report DIR]

Prints, per run, the success and mean actions per successful trial of every cell, and then
each acceptance item with the figures it rests on: the paper set's case-1 ordering (Greedy
100 %, Random lowest and >= 40 % in two scenarios, Lazy between, Greedy the fewest actions, a
one-action Random success), case 2's Greedy >= 70.6 %, the hard set's Greedy against the
figures before the executable actions, and over every executed action of every run: transits
that touched a fixed obstacle, transits that touched a movable object, and Random's actions
that moved the target 1 cm or more.  --report DIR rewrites report.md and the plots of a
results file in DIR (for a run that was stopped before its last trial); --merge DEST DIR...
joins the results of runs split in parts (`lmjx evaluate --part K/N`, one cell a process) into
DEST and rewrites its report."""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

HARD_BEFORE = {"case1": {1: 1.0, 2: 1.0, 3: 1.0}, "case2": {1: 1.0, 2: 14 / 15, 3: 1.0}}
PAPER_CASE2_GREEDY = 0.706
TRIALS = 15  # a cell is complete with this many trials; the checks use complete cells only
ASMS = ("random", "lazy", "greedy")


def cells(records: list[dict]) -> dict[tuple, dict]:
    """(failure, scenario, asm) -> trials, success rate, mean actions of the successes."""
    by = defaultdict(list)
    for r in records:
        by[(r["failure"], r["scenario"], r["asm"])].append(r)
    out = {}
    for k, rs in sorted(by.items()):
        ok = [r for r in rs if r["success"]]
        out[k] = {
            "trials": len(rs),
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


def read_results(path: Path, flag: str) -> list[dict]:
    """The trials of a results.json, or a one-line exit naming `flag` where it cannot be read."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as e:
        sys.exit(f"eval_acceptance: {flag}: cannot read {path}: {e}")


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
        "trials are kept unless a later DIR holds the same trial (a later DIR's record wins)",
    )
    ap.add_argument(
        "--simulator",
        help="the simulator's description for a rewritten report (default: this machine's; give it when "
        "rewriting a GPU run's report elsewhere, e.g. 'gpu: MuJoCo Warp on NVIDIA H100 80GB HBM3, whole scene')",
    )
    args = ap.parse_args()
    if args.merge:
        dest, *srcs = (Path(d) for d in args.merge)
        merged: dict = {}
        # DEST's own trials first, so that merging new runs into it never drops what it held
        own = (dest / "results.json").exists() and dest.resolve() not in {d.resolve() for d in srcs}
        kept = [dest] if own else []
        for d in kept + srcs:
            if not (d / "results.json").exists():  # a run stopped before its first trial ended
                print(f"{d}: no trials")
                continue
            for r in read_results(d / "results.json", "--merge"):
                merged[(r["failure"], r["scenario"], r["asm"], r["seed"])] = r
        if not merged:
            sys.exit(f"eval_acceptance: --merge: no trials in {', '.join(str(d) for d in kept + srcs) or 'no folder'}")
        recs = sorted(
            merged.values(),
            key=lambda r: (r["failure"], r["scenario"], ["random", "lazy", "greedy"].index(r["asm"]), r["seed"]),
        )
        dest.mkdir(parents=True, exist_ok=True)
        from lmjx.runtime.fileio import write_text_atomic

        write_text_atomic(dest / "results.json", json.dumps(recs, indent=1) + "\n")
        print(f"{dest}/results.json: {len(recs)} trials from {len(srcs)} runs" + (" and its own" if kept else ""))
        args.report = str(dest)
    if args.report:
        from lmjx.evaluation.evaluate import EvalConfig, plots, report_markdown, simulator_description
        from lmjx.model.robot import load_robot
        from lmjx.runtime.fileio import write_text_atomic
        from lmjx.types import PlannerConfig

        d = Path(args.report)
        recs = read_results(d / "results.json", "--report")
        if not recs:
            sys.exit(f"eval_acceptance: --report: {d / 'results.json'} holds no trials")
        sim = next((r["sim"] for r in recs if r["sim"] != "none"), "cpu")
        cand = next((r["candidates"] for r in recs if r["candidates"]), 32)
        config = EvalConfig(tasks=recs[0]["tasks"], planner=PlannerConfig(greedy_candidates=cand))
        robot = load_robot(recs[0].get("robot", "panda"))
        write_text_atomic(
            d / "report.md", report_markdown(recs, config, args.simulator or simulator_description(sim), robot)
        )
        plots(recs, d)
        print(f"{d}: {len(recs)} trials, report.md and plots rewritten")
        return
    result: dict = {"runs": {}, "checks": []}
    total = defaultdict(int)
    for kind, paths in (("paper", args.paper), ("hard", args.hard)):
        for p in paths:
            recs = read_results(Path(p), f"--{kind}")
            c = cells(recs)
            fig = action_figures(recs)
            for k, v in fig.items():
                total[k] += v
            result["runs"][p] = {"tasks": kind, "trials": len(recs), "actions": fig}
            print(f"\n{p} ({kind}, {len(recs)} trials)")
            for (f, s, a), v in c.items():
                acts = "-" if v["actions"] is None else f"{v['actions']:.1f}"
                print(f"  {f} s{s} {a:6s} {v['trials']:3d} trials {100 * v['success']:5.1f} %  actions {acts}")
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
    print("\nacross every run given:")
    for name, ok, why in overall:
        print(f"  [{'met' if ok else 'NOT met'}] {name}: {why}")
        result["checks"].append({"run": "all", "check": name, "met": ok, "figures": why})
    result["totals"] = t
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
