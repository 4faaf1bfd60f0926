"""Trials as their records tell them: a `lmjx plan --json` output, or one trial of an
evaluation's results.json (`--trial failure/scenario/asm/seed`; the file as `lmjx evaluate`
writes it, `lmjx.evaluation.results`: an object whose `trials` lists the records, or a bare
list of records), read and checked; the task a trial ran (`trial_task`: the record's `scene`,
`lmjx.sim.scenefile.record_task`, a shipped scenario or a scene file's text; the scenario's
number for a record without one); and which map a trial ran on (the records do not name it:
--map, else where lmjx build-map writes the failure's map).  Every mistake is a one-line
`ConfigError` (a scene that cannot be read, a `SceneError`)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lmjx.errors import ConfigError

if TYPE_CHECKING:
    from lmjx.model.robot import Robot
    from lmjx.sim.scenarios import Task


@dataclass(frozen=True)
class TrialRecord:
    """What replaying and showing a trial needs of its record."""

    robot: str
    failure: str
    scenario: int
    tasks: str
    asm: str
    seed: int
    steps: tuple[dict, ...]  # the executed actions (edge >= 0), in order: edge, transit_route, target_moved_m, ...
    late_start: bool = False
    batched: bool = False  # its planner's simulator was the GPU's (transits checked by the batched kernel)
    success: bool | None = None
    end: str = ""
    final_distance_m: float | None = None
    source: str = ""  # where it was read
    scene: dict | None = field(default=None, compare=False)  # the record's scene (`scene_record`); None: not kept
    extra: dict = field(default_factory=dict, compare=False)

    @property
    def key(self) -> str:
        return f"{self.failure}/{self.scenario}/{self.asm}/{self.seed}"

    def title(self) -> str:
        end = "" if self.success is None else (" success" if self.success else f" failure ({self.end})")
        return f"{self.key} ({self.tasks} tasks):{end}, {len(self.steps)} actions"


def from_dict(r: dict, source: str) -> TrialRecord:
    """A record (a plan's JSON or one entry of results.json) as a TrialRecord."""
    try:
        steps = r["steps"]
        return TrialRecord(
            robot=str(r.get("robot", "panda")),
            failure=str(r["failure"]),
            scenario=int(r["scenario"]),
            tasks=str(r.get("tasks", "hard")),  # records from before task sets were named: the hard set's
            asm=str(r["asm"]),
            seed=int(r["seed"]),
            steps=tuple(s for s in steps if int(s.get("edge", -1)) >= 0),
            late_start=bool((r.get("asm_settings") or {}).get("late_start", False)),
            batched=str(r.get("sim", r.get("simulator", ""))) == "gpu",
            success=bool(r["success"]) if "success" in r else None,
            end=str(r.get("end", "")),
            final_distance_m=r.get("final_distance_m"),
            source=source,
            scene=r["scene"] if isinstance(r.get("scene"), dict) else None,
        )
    except KeyError as e:
        if e.args and e.args[0] == "steps":
            raise ConfigError(
                f"{source} does not list the trial's actions (lmjx plan --json and lmjx evaluate record them); run the "
                "trial again with either"
            ) from None
        raise ConfigError(f"{source} is not a trial record: it lacks '{e.args[0]}'") from None
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{source} is not a trial record ({e})") from None


def read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"cannot read {path}: {getattr(e, 'strerror', None) or e}") from None
    except json.JSONDecodeError as e:
        raise ConfigError(f"{path} is not JSON ({e.msg} at line {e.lineno})") from None


def parse_trial_key(text: str) -> tuple[str, int, str, int]:
    """'failure/scenario/asm/seed' -> its parts (the failure may hold '/'-free specs only)."""
    parts = text.split("/")
    try:
        if len(parts) != 4:
            raise ValueError
        return parts[0], int(parts[1]), parts[2], int(parts[3])
    except ValueError:
        raise ConfigError(f"--trial {text!r}: give failure/scenario/asm/seed, e.g. case2/1/greedy/1000") from None


def is_results(data: Any) -> bool:
    """Whether JSON `data` is an evaluation's results (`lmjx.evaluation.results`: the object
    `lmjx evaluate` writes, or a bare list of trial records)."""
    from lmjx.evaluation.results import FORMAT

    return isinstance(data, list) or (isinstance(data, dict) and data.get("format") == FORMAT)


def records_of(data: Any, path: Path) -> list[dict]:
    """The trial records of an evaluation's results (`is_results`), checked."""
    from lmjx.evaluation.results import FORMAT, FORMAT_VERSION

    if isinstance(data, dict) and data.get("format") == FORMAT:
        if data.get("format_version") != FORMAT_VERSION:
            raise ConfigError(f"{path} is a results file of format {data.get('format_version')!r}; this lmjx reads "
                              f"format {FORMAT_VERSION}: view it with the lmjx that wrote it")  # fmt: skip
        data = data.get("trials")
    if not isinstance(data, list) or not all(isinstance(r, dict) for r in data):
        raise ConfigError(f"{path} is not an evaluation's results.json (lmjx evaluate --out writes one)")
    return data


def results_records(path: Path) -> list[dict]:
    """The trial records of an evaluation's results.json."""
    return records_of(read_json(path), path)


def pick_trial(records: list[dict], key: str, source: Path) -> TrialRecord:
    """The trial `key` (failure/scenario/asm/seed) of an evaluation's records."""
    f, s, a, seed = parse_trial_key(key)
    for r in records:
        if (str(r.get("failure")), r.get("scenario"), str(r.get("asm")), r.get("seed")) == (f, s, a, seed):
            return from_dict(r, f"{source} ({key})")
    some = ", ".join(f"{r.get('failure')}/{r.get('scenario')}/{r.get('asm')}/{r.get('seed')}" for r in records[:3])
    raise ConfigError(
        f"no trial {key} in {source}; it holds {len(records)} trials" + (f", e.g. {some}" if some else "")
    )


def read_trial(path: Path, trial: str | None) -> TrialRecord:
    """A plan's JSON (`trial` None) or the trial `trial` of a results.json."""
    data = read_json(path)
    if is_results(data):
        records = records_of(data, path)
        if trial is None:
            raise ConfigError(f"{path} holds an evaluation's {len(records)} trials; choose one with --trial "
                              "F/S/ASM/SEED")  # fmt: skip
        return pick_trial(records, trial, path)
    if not isinstance(data, dict):
        raise ConfigError(f"{path} is neither a trial record (lmjx plan --json) nor an evaluation's results.json")
    if trial is not None:
        raise ConfigError(f"--trial picks a trial of an evaluation's results.json; {path} holds one trial")
    return from_dict(data, str(path))


def map_for(record: TrialRecord, maps: list[str] | None) -> Path:
    """The map file the trial ran on: the --map given for its failure (one --map: that one),
    else where lmjx build-map writes the failure's map (maps/<failure>.h5 under the working
    folder, another robot's maps/<robot>/<failure>.h5)."""
    from lmjx.api import default_map_path
    from lmjx.model.failure import as_failure
    from lmjx.model.robot import load_robot

    if maps and len(maps) == 1:
        return Path(maps[0])
    if maps:
        from lmjx.view.mapdata import MapData

        for m in maps:
            with MapData(m) as opened:  # (its header and reach map: at once, whatever its size)
                if opened.failure.spec == record.failure:
                    return Path(m)
        raise ConfigError(f"none of the --map files holds the failure {record.failure} of trial {record.key}")
    robot = load_robot(record.robot)
    path = default_map_path(as_failure(record.failure, robot), robot)
    if not path.exists():
        raise ConfigError(
            f"trial {record.key} ran on a map of failure {record.failure}; none at {path}: give it with --map PATH"
        )
    return path


def trial_task(record: TrialRecord, robot: Robot) -> tuple[Task, bool]:
    """The task trial `record` ran, placed for `robot`, and whether it is the task the record
    describes: from the record's scene (`record_task`: False where its definition's digest
    differs from the record's), else, for a record that keeps no scene, the shipped scenario
    of its number and task set (True)."""
    from lmjx.sim.scenarios import SCENARIOS, TASK_SETS, resolve_task
    from lmjx.sim.scenefile import record_task

    if record.scene is not None:
        return record_task(record.scene, robot, record.source)
    if record.scenario not in SCENARIOS or record.tasks not in TASK_SETS:
        raise ConfigError(
            f"{record.source} keeps no scene and names scenario {record.scenario} of the task set {record.tasks!r}, "
            "which lmjx does not ship; plan the trial again with lmjx plan --json or lmjx evaluate"
        )
    return resolve_task(record.scenario, robot, record.tasks), True
