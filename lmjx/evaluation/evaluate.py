"""`lmjx evaluate`: trials over failures x scenarios x ASMs, the paper's Section V.

Results are written after every trial (`results.json`, atomically, with the provenance of
every trial: `lmjx.evaluation.results`), so an interrupted evaluation loses nothing and a
rerun with the same arguments continues where it stopped; a rerun under other conditions
(another commit, other maps, another planner configuration, ...) is refused unless allowed.
At the end: `report.md` (the provenance, then a table with 95 % intervals beside the paper's
figures), `bubble.png` (success and task time per cell, as the paper's bubble chart) and
`actions.png` (distributions of actions per successful task).
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lmjx.errors import ConfigError
from lmjx.evaluation.provenance import new_run
from lmjx.evaluation.registration import RegistrationError, enforce, read_registration
from lmjx.evaluation.results import Results, check_conditions, provenance_lines, read_results, write_results
from lmjx.evaluation.stats import rate_text, wilson
from lmjx.evaluation.workers import run_in_processes, run_trials
from lmjx.mapfile.read import MapFile, load_map
from lmjx.model.robot import Robot
from lmjx.runtime.cores import usable_cores
from lmjx.runtime.fileio import atomic_path
from lmjx.runtime.progress import Progress
from lmjx.sim.scenarios import TASK_SETS, Task, resolve_task, scenario
from lmjx.types import ASMS, PlannerConfig

ASM_COLORS = {"random": "#0072B2", "lazy": "#E69F00", "greedy": "#009E73"}  # the same in every panel
CORES_PER_PROCESS = 4  # an evaluation on GPUs: a process per this many cores (`default_processes`)
RECORD_KEYS = ("failure", "scenario", "asm", "seed", "success", "actions", "planning_s", "execution_s")

# The paper's figures (Section V), for the report.
PAPER_NOTES = (
    "Greedy: 100 % success in every scenario of case 1; in case 2, 70.6 % in scenario 1 (its best case-2 "
    "cell); Lazy: case-2 successes in scenarios 2 and 3 (up to 88.9 %); case 1 scenario 3: Lazy 73.3 %, "
    "Random 66.7 %.  Task times: Greedy the longest (up to 307.5 s), Random the shortest (down to 37.5 s), "
    "Lazy 47.3-82.7 s.  267 real-robot trials."
)


@dataclass(frozen=True)
class EvalConfig:
    failures: tuple[str, ...] = ("case1", "case2")
    scenarios: tuple[int, ...] = (1, 2, 3)
    asms: tuple[str, ...] = ASMS
    trials: int = 15
    seed: int = 0
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    backend: str = "cpu"
    tasks: str = "paper"  # the task set (lmjx.sim.scenarios.TASK_SETS; with scenes: theirs, joined by "+")
    part: tuple[int, int] = (1, 1)  # (K, N): only trials t with t % N == K - 1 (a run split in N parts)
    # tasks from scene files (`lmjx evaluate --scenes`), resolved for the robot, numbered as
    # `scenarios` lists them; empty: the shipped scenarios `scenarios` of the task set `tasks`
    scenes: tuple[Task, ...] = ()

    def validate(self) -> None:
        for a in self.asms:
            if a not in ASMS:
                raise ConfigError(f"unknown ASM '{a}'; use random, lazy, greedy")
        if self.scenes:
            if tuple(t.number for t in self.scenes) != self.scenarios or len(set(self.scenarios)) < len(self.scenes):
                raise ConfigError("the scenes need distinct numbers (a scene file's `number`), listed in scenarios")
        else:
            for s in self.scenarios:
                if s not in (1, 2, 3):
                    raise ConfigError(f"unknown scenario {s}; the scenarios are 1, 2 and 3")
            if self.tasks not in TASK_SETS:
                raise ConfigError(f"unknown task set '{self.tasks}'; use paper or hard")
        if self.trials < 1:
            raise ConfigError("--trials must be at least 1")
        k, n = self.part
        if not 1 <= k <= n:
            raise ConfigError(f"--part {k}/{n}: K/N needs 1 <= K <= N (e.g. 2/4: the second of four parts)")
        if k > self.trials:
            raise ConfigError(f"--part {k}/{n} holds no trial of {self.trials} per cell (its first is trial {k})")

    def task(self, number: int, robot: Robot) -> Task:
        """The task of scenario `number`: the scene of that number, else the shipped scenario
        of the task set, placed for `robot`."""
        for t in self.scenes:
            if t.number == number:
                return t
        return resolve_task(number, robot, self.tasks)


def trial_seed(base: int, scenario: int, trial: int) -> int:
    """The same seed for a (scenario, trial) across failures and ASMs: the same layouts and
    the same "real" world perturbations for everyone."""
    return base * 100_000 + scenario * 1000 + trial


def _num(x: float | None) -> str:
    return "–" if x is None else f"{x:.1f}"


def open_run(
    robot: Robot,
    maps: dict[str, MapFile],
    config: EvalConfig,
    out: Path,
    command: str | None = None,
    allow_mixed: bool = False,
    registered: str | Path | None = None,
) -> tuple[Results, dict]:
    """The results already in `out` and this run's entry (`provenance.new_run`); refused
    (`MixedRunsError`, one line) where the trials held ran under other conditions, unless
    `allow_mixed`.  `registered`: the page of a registered evaluation
    (`lmjx.evaluation.registration`): refused (`RegistrationError`, one line) unless this run
    is its arm's as registered (commit, clean tree, maps, levers, task set, seed base, trials,
    cells, simulator), never with `allow_mixed`, and never into an `out` that holds trials of
    a run not registered as the same arm; the run's entry then names the page and the arm.
    Nothing is written."""
    config.validate()
    registration = None if registered is None else read_registration(registered)
    if registration is not None and allow_mixed:
        raise RegistrationError(f"--registered {registered}: a registered run pools with no other conditions; "
                                "leave out --allow-mixed")  # fmt: skip
    results = read_results(out / "results.json")
    run = new_run(robot, maps, config, command, allow_mixed)
    if registration is not None:
        arm = enforce(registration, run)
        run["registered"] = {"page": str(registered), "arm": arm.name}
        other = [r for r in results.runs_used() if (r.get("registered") or {}).get("arm") != arm.name]
        if other:
            raise RegistrationError(
                f"--registered {registered}: {out / 'results.json'} holds {other[0]['trials_held']} trials of a run "
                f"not registered as its arm {arm.name} (run {other[0]['id']}); give a fresh --out"
            )
    check_conditions(results, run, allow_mixed, str(out / "results.json"))
    return results, run


def evaluate(
    robot: Robot,
    maps: dict[str, MapFile],
    config: EvalConfig,
    out: Path,
    progress: bool = True,
    say: Callable[[str], None] | None = None,
    command: str | None = None,
    allow_mixed: bool = False,
    opened: tuple[Results, dict] | None = None,
    processes: int | None = None,
) -> Results:
    """Run every missing trial; return the results (also in out/results.json): every trial's
    record and the runs that made them.  `say` is told in one line when trials of an earlier
    run are kept (a resumed run); `command`: the command line, for the provenance.  Trials
    held from a run under other conditions are refused before anything runs (`open_run`;
    `opened`: what it returned, where the caller called it) unless `allow_mixed`.

    The trials of a scenario run together (`lmjx.evaluation.lockstep`): side by side, each on
    a thread of its own; on a GPU their candidates are simulated in shared batches; on the CPU
    as many trials as cores are in flight at once.  `processes`: the trials split across that
    many processes (`lmjx.evaluation.workers`; default: one per GPU where the planner simulates
    on GPUs, else one).  Each trial makes the decisions it would make alone.  A record is
    written as soon as its trial ends."""
    results, run = opened or open_run(robot, maps, config, out, command, allow_mixed)
    results_path = out / "results.json"
    out.mkdir(parents=True, exist_ok=True)
    records = results.trials
    done = {(r["failure"], r["scenario"], r["asm"], r["seed"]) for r in records}
    todo = [
        (f, s, a, trial_seed(config.seed, s, t))
        for f in config.failures
        for s in config.scenarios
        for a in config.asms
        for t in range(config.trials)
        if t % config.part[1] == config.part[0] - 1
    ]
    rank = {k: i for i, k in enumerate(todo)}
    todo = [k for k in todo if k not in done]
    if say is not None and len(todo) < len(rank) and done:
        say(f"resuming: {len(rank) - len(todo)} of {len(rank)} trials already in {results_path}")
    bar = Progress(total=len(todo), desc="trials", enabled=progress, unit="trial")

    def keep(record: dict) -> None:  # a trial's record, written as soon as it ends
        records.append(record)
        if run not in results.runs:
            results.runs.append(run)
        run["trials_run"] += 1
        records.sort(key=lambda r: rank.get((r["failure"], r["scenario"], r["asm"], r["seed"]), len(rank)))
        write_results(results_path, results)
        bar.update(1)

    n = min(processes or default_processes(config.backend), max(1, len(todo)))
    if n > 1:
        bar.set_description(f"{len(todo)} trials in {n} processes")
        run_in_processes(robot, maps, config, run, todo, n, keep)
    else:
        run_trials(robot, maps, config, run, todo, keep,
                   on_group=lambda s, k: bar.set_description(f"scenario {s}: {k} trials together"))  # fmt: skip
    bar.close()
    return results


def default_processes(backend: str) -> int:
    """Processes an evaluation runs its trials in by default where the planner simulates on
    GPUs (MuJoCo Warp's count of CUDA devices): every GPU, each shared by as many processes as
    it has CORES_PER_PROCESS cores (the trials' host work runs under one interpreter lock per
    process: sixteen trials on threads of one process ran 0.18 trials a second on a 16-core
    host, their planning and executions waiting for the lock); else one."""
    if backend != "gpu":
        return 1
    import warp as wp

    gpus = max(1, wp.get_cuda_device_count())
    return gpus * max(1, usable_cores() // (CORES_PER_PROCESS * gpus))


def summarize(records: list[dict]) -> list[dict]:
    """Per (failure, scenario, asm): trials, successes, success rate with its Wilson 95 %
    interval (`lmjx.evaluation.stats`), mean actions/times."""
    out = []
    for (f, s, a), rs in _cells(records):
        ok = [r for r in rs if r["success"]]
        out.append(
            {
                "failure": f,
                "scenario": s,
                "asm": a,
                "trials": len(rs),
                "successes": len(ok),
                "success_rate": len(ok) / len(rs),
                "success_ci95": [round(x, 4) for x in wilson(len(ok), len(rs))],
                "actions_mean_success": float(np.mean([r["actions"] for r in ok])) if ok else None,
                "planning_s_mean": float(np.mean([r["planning_s"] for r in rs])),
                "execution_s_mean": float(np.mean([r["execution_s"] for r in rs])),
                "task_s_mean": float(np.mean([r["planning_s"] + r["execution_s"] for r in rs])),
            }
        )
    return out


def _settings_lines(records: list[dict], config: EvalConfig) -> list[str]:
    """The ASM settings the trials ran with, as their records say (a report rewritten from
    merged runs: each distinct set with its ASMs), else this run's config's."""
    by: dict[str, tuple[dict, set[str]]] = {}  # settings (by content) -> (as recorded, the ASMs)
    for r in records:
        if "asm_settings" in r:
            by.setdefault(json.dumps(r["asm_settings"], sort_keys=True), (r["asm_settings"], set()))[1].add(r["asm"])
    if not by:
        by = {"": (config.planner.settings(), set())}

    def line(settings: dict) -> str:
        return ", ".join(f"{k} {_onoff(v)}" for k, v in settings.items())

    if len(by) == 1:
        return [f"ASM settings: {line(next(iter(by.values()))[0])}."]
    return [f"ASM settings ({', '.join(sorted(asms))}): {line(st)}." for st, asms in by.values()]


def report_markdown(
    results: Results | list[dict], config: EvalConfig, simulator: str, robot: Robot | None = None
) -> str:
    """report.md: the provenance of the trials (`results.provenance_lines`), then per cell the
    success with its Wilson 95 % interval, actions and times, the ASM settings, how the trials
    ended.  The header's counts are the records' (trials per cell as the table holds them);
    the simulator, planner and task set are the runs' as recorded, `config` and `simulator`
    where the trials carry no provenance."""
    if isinstance(results, list):
        results = Results([], results)
    records = results.trials
    rows = summarize(records)
    runs = [r for r in results.runs_used() if not r.get("unrecorded")]
    counts = sorted({r["trials"] for r in rows})
    per_cell = "0" if not counts else str(counts[0]) if len(counts) == 1 else f"{counts[0]} to {counts[-1]}"
    planned = _planned(runs, config)
    names = scene_names(records)
    scenes_said = []
    if names:
        each = (f"scenario {n} is {name}" + (f" ({file})" if file else "") for n, (name, file) in sorted(names.items()))
        scenes_said = [f"Scenes (from scene files; each trial's record keeps the file's text): {'; '.join(each)}.", ""]
    tasks = ", ".join(sorted({str(r.get("tasks", config.tasks)) for r in records})) or config.tasks
    sims = sorted({r["simulator"]["description"] for r in runs if r["simulator"]["name"] != "none"})
    planner = runs[0]["planner"] if runs else {k: v for k, v in config.planner.__dict__.items() if k != "asm"}
    budget = planner["max_actions"] or _budget(config)
    lines = [
        "# lmjx evaluation" + (f": {robot.profile.description or robot.key}" if robot is not None else ""),
        "",
        *provenance_lines(results),
        "## Results",
        "",
        f"{_trials(len(records))} ({per_cell} per cell"
        + (f"; a partial run: {planned - len(records)} of {planned} not run yet" if len(records) < planned else "")
        + f"), task set '{tasks}', simulator {'; '.join(sims) or simulator}; "
        f"planner: greedy {planner['greedy_candidates']} candidates, lazy up to {planner['lazy_tries']} "
        f"tries, at most {budget} actions per task, a planning limit of "
        f"{planner.get('max_sim_steps', config.planner.max_sim_steps):,} simulated control steps per trial.",
        "",
        "The trials of a scenario run together; on a GPU their candidates share batches, and a batch's seconds "
        "are charged to each trial in proportion to its candidates (its planning time).  Success: successes of "
        "trials, the rate and its Wilson 95 % interval.",
        "",
        *scenes_said,
        "| failure | scenario | ASM | success | actions (mean, successes) | planning s | execution s | task s |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        lines.append(
            f"| {r['failure']} | {scenario_label(r['scenario'], names)} | {r['asm']} | "
            f"{rate_text(r['successes'], r['trials'])} | "
            f"{_num(r['actions_mean_success'])} | {r['planning_s_mean']:.1f} | {r['execution_s_mean']:.1f} | "
            f"{r['task_s_mean']:.1f} |"
        )
    lines += ["", *_settings_lines(records, config), ""]
    lines += [
        'How the trials ended, and what their executed actions did in the "real" world (the target moved by '
        "1 cm or more; a transit touched a movable object; a transit touched a fixed obstacle):",
        "",
        "| failure | scenario | ASM | ends | actions | target moved >= 1 cm | transit touched an object "
        "| transit hit a fixed obstacle |",
        "| --- | --- | --- | --- | ---: | ---: | ---: | ---: |",
    ]
    for (f, sc, a), rs in _cells(records):
        ends = Counter(_end_label(r) for r in rs)
        acts = [x for r in rs for x in r.get("steps", [])]
        moved = [x for x in acts if x.get("target_moved_m") is not None]
        lines.append(
            f"| {f} | {scenario_label(sc, names)} | {a} | "
            f"{', '.join(f'{n} {e}' for e, n in sorted(ends.items(), key=lambda kv: -kv[1]))} "
            f"| {len(acts)} | {_share(sum(x['target_moved_m'] >= 0.01 for x in moved), len(moved))} "
            f"| {_share(sum(bool(x.get('transit_contacts')) for x in acts), len(acts))} "
            f"| {_share(sum(bool(x.get('transit_hit_fixed')) for x in acts), len(acts))} |"
        )
    lines += ["", f"The paper (real robot): {PAPER_NOTES}", "", "![](bubble.png)", "", "![](actions.png)", ""]
    return "\n".join(lines)


def scene_names(records: list[dict]) -> dict[int, tuple[str, str | None]]:
    """The scenarios that came from scene files (`lmjx evaluate --scenes`), by number: the
    scene's name and its file where the record keeps it.  Shipped scenarios are left out:
    their numbers name them."""
    out: dict[int, tuple[str, str | None]] = {}
    for r in records:
        sc = r.get("scene")
        if isinstance(sc, dict) and sc.get("kind") == "scene":
            out.setdefault(int(r["scenario"]), (str(sc.get("name") or "scene"), sc.get("file") or None))
    return out


def scenario_label(scenario: int, names: dict[int, tuple[str, str | None]]) -> str:
    """A scenario as tables name it: its number, with its scene's name where it has one."""
    return f"{scenario} ({names[scenario][0]})" if scenario in names else str(scenario)


def _trials(n: int) -> str:
    return f"{n} trial" + ("" if n == 1 else "s")


def _budget(config: EvalConfig) -> int:
    if config.scenes:
        return config.planner.max_actions or config.scenes[0].budget
    return config.planner.max_actions or scenario(config.scenarios[0], tasks=config.tasks).budget


def _planned(runs: list[dict], config: EvalConfig) -> int:
    """The trials the runs set out to make (their cells x trials per cell; `config`'s where
    none is recorded)."""
    cells, per = set(), 0
    for r in runs:
        c = r.get("cells", {})
        cells |= {(f, s, a) for f in c.get("failures", []) for s in c.get("scenarios", []) for a in c.get("asms", [])}
        per = max(per, int(r["trials_per_cell"]))
    if not cells:
        return config.trials * len(config.failures) * len(config.scenarios) * len(config.asms)
    return per * len(cells)


def _end_label(r: dict) -> str:
    """How a trial ended, for the report: 'goal' for every success (records written before the
    'stopped' field kept the planner's reason as their end), with what stopped the planner when
    that differs (it stops only once the observed target is `goal_margin` inside the goal)."""
    end = "goal" if r["success"] else r["end"]
    stopped = r.get("stopped") or r["end"]
    return end if stopped == end else f"{end} (then {stopped})"


def _share(n: int, d: int) -> str:
    return f"{100 * n / d:.1f} %" if d else "-"


def _onoff(v) -> str:
    return "on" if v is True else "off" if v is False else "none" if v is None else str(v)


def _cells(records: list[dict]) -> list[tuple[tuple, list[dict]]]:
    cells: dict[tuple, list[dict]] = {}
    for r in records:
        cells.setdefault((r["failure"], r["scenario"], r["asm"]), []).append(r)
    return sorted(cells.items(), key=lambda kv: (kv[0][0], kv[0][1], ASMS.index(kv[0][2])))


def plots(records: list[dict], out: Path) -> None:
    """bubble.png (success and task time per cell) and actions.png (actions to complete, per
    ASM, over the successful trials); both hold up when few or no trials succeed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = summarize(records)
    most = max((r["trials"] for r in rows), default=0)  # a cell with fewer (a partial run) says how many
    failures = sorted({r["failure"] for r in rows})
    scenarios = sorted({r["scenario"] for r in rows})
    asms = [a for a in ASMS if any(r["asm"] == a for r in rows)]
    times = [r["task_s_mean"] for r in rows]
    vmin, vmax = (min(times), max(times)) if times else (0, 1)
    if vmax <= vmin:
        vmax = vmin + 1.0
    fig, axes = plt.subplots(
        1, max(1, len(failures)), figsize=(5.5 * max(1, len(failures)), 4.4), squeeze=False, layout="constrained"
    )
    for ax, f in zip(axes[0], failures, strict=True):
        sc = None
        for r in rows:
            if r["failure"] != f:
                continue
            x, y = scenarios.index(r["scenario"]), asms.index(r["asm"])
            size = 60 + 2400 * r["success_rate"]
            sc = ax.scatter(x, y, s=size, c=[r["task_s_mean"]], cmap="RdYlGn_r", vmin=vmin, vmax=vmax,
                            edgecolors="black")  # fmt: skip
            # beside the circle (its radius is sqrt(size)/2 points), not on it
            label = f"{r['success_rate'] * 100:.0f}%" + (f"\nn={r['trials']}" if r["trials"] < most else "")
            ax.annotate(label, (x, y), xytext=(np.sqrt(size) / 2 + 3, 0),
                        textcoords="offset points", ha="left", va="center", fontsize=9)  # fmt: skip
        ax.set_xticks(range(len(scenarios)), [f"scenario {s}" for s in scenarios])
        ax.set_yticks(range(len(asms)), asms)
        ax.set_xlim(-0.6, len(scenarios) - 0.2)
        ax.set_ylim(-0.6, len(asms) - 0.4)
        ax.set_title(f"failure {f}")
        if sc is not None:
            fig.colorbar(sc, ax=ax, label="mean task time [s]")
    fig.suptitle("Success (circle size, share beside it) and task time (colour) per action selection mechanism")
    with atomic_path(out / "bubble.png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)

    fig, axes = plt.subplots(
        max(1, len(failures)), max(1, len(scenarios)), figsize=(4 * max(1, len(scenarios)),
        3 * max(1, len(failures))), squeeze=False, layout="constrained",
    )  # fmt: skip
    for i, f in enumerate(failures):
        for j, s in enumerate(scenarios):
            ax = axes[i][j]
            drawn = False
            for a in asms:
                n = [
                    r["actions"]
                    for r in records
                    if (r["failure"], r["scenario"], r["asm"], r["success"]) == (f, s, a, True)
                ]
                if n:
                    ax.hist(n, bins=np.arange(0.5, max(n) + 1.5), histtype="step", density=True, label=a,
                            linewidth=1.8, color=ASM_COLORS.get(a))  # fmt: skip
                    drawn = True
            ax.set_title(f"{f}, scenario {s}", fontsize=10)
            ax.set_xlabel("actions to complete")
            if j == 0:
                ax.set_ylabel("density")
            if drawn:
                ax.legend(fontsize=8)
            else:
                ax.set_xticks([])
                ax.set_yticks([])
                ax.text(0.5, 0.5, "no trial succeeded", transform=ax.transAxes, ha="center", va="center",
                        fontsize=9, color="0.4")  # fmt: skip
    with atomic_path(out / "actions.png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def load_maps(robot: Robot, failures: tuple[str, ...], folder: Path) -> dict[str, MapFile]:
    """maps/<failure>.h5 for each failure, checked to hold that failure with edges."""
    from lmjx.model.failure import parse_failure

    out = {}
    for f in failures:
        want = parse_failure(f, robot)
        path = folder / f"{f}.h5"
        m = load_map(path, robot)
        if m.failure.locked != want.locked:
            raise ConfigError(f"{path} holds a map of failure {m.failure.spec}, not {f}")
        if m.edges is None or m.reach is None:
            raise ConfigError(f"{path} has no edges; build it with: lmjx build-map --failure {f} --out {path}")
        out[f] = m
    return out
