"""A registered evaluation is enforced: its page's block is read strictly (one line naming the
key that is missing or wrong); `lmjx evaluate --registered FILE` refuses, in one line and exit
status 2 before any trial, a run on another commit, a tree with changes, another map, other
levers, task set, seeds, trials, cells or simulator; and the acceptance checks hold every trial
record against the registration: commit, map digests, planner, seeds, task set, and exactly
one record per registered trial."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from conftest import benchmark_module, cli

import lmjx
from lmjx.errors import ConfigError, LmjxError
from lmjx.evaluation import provenance
from lmjx.evaluation.evaluate import EvalConfig, open_run, trial_seed
from lmjx.evaluation.registration import (
    LEVERS,
    Registration,
    RegistrationError,
    check_against,
    enforce,
    read_registration,
)
from lmjx.evaluation.results import Results, read_results, write_results
from lmjx.planner.levers import planner_config

ROOT = Path(__file__).resolve().parents[1]
HEAD = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=False).stdout
HEAD = HEAD.strip()
OTHER_COMMIT = "0123456789abcdef0123456789abcdef01234567"
DIGEST = "fc4682d5d2288debcd74e2f8088e606fe8a25e5618e470abb0f485bc9bd857f9"
# the tests' runs: Random alone, one trial of scenario 1 on the small case-2 map, one action
RUN = ("evaluate", "--failures", "case2", "--scenarios", "1", "--asms", "random", "--trials", "1",
       "--max-actions", "1")  # fmt: skip

needs_git = pytest.mark.skipif(len(HEAD) != 40, reason="not a git checkout: the registered commit is git's")


def toml(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if v is None:
        return '"none"'
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list | tuple):
        return "[" + ", ".join(map(toml, v)) + "]"
    return repr(v)


def block(reg: dict[str, Any]) -> str:
    """A registration as its page's toml block."""
    lines = [f"{k} = {toml(v)}" for k, v in reg.items() if k not in ("maps", "arms") or isinstance(v, str)]
    for failure, spec in reg.get("maps", {}).items():
        lines += ["", f"[maps.{failure}]", *(f"{k} = {toml(v)}" for k, v in spec.items())]
    for arm in reg.get("arms", []) if isinstance(reg.get("arms"), list) else []:
        lines += ["", "[[arms]]", *(f"{k} = {toml(v)}" for k, v in arm.items() if k != "levers")]
        if "levers" in arm:
            lines += ["[arms.levers]", *(f"{k} = {toml(v)}" for k, v in arm["levers"].items())]
    return "\n".join(lines)


def page(reg: dict[str, Any], path: Path, heading: str = "## Registration") -> Path:
    """A registration page: prose, a toml block elsewhere (not the registration's), the block."""
    path.write_text("# A registered evaluation\n\nWhat it is and why.\n\n```toml\npush_weight = 0.5\n```\n\n"
                    f"{heading}\n\nThe block:\n\n```toml\n{block(reg)}\n```\n\n## After\n\nMore words.\n")  # fmt: skip
    return path


def registration(digest: str, commit: str = HEAD, **arm: Any) -> dict[str, Any]:
    """The registration of the tests' run (RUN on the map of `digest`), `arm`'s keys replaced."""
    levers = provenance.planner_fields(planner_config("greedy", "cpu", {"max_actions": 1}))
    return {
        "commit": commit,
        "base_seed": 0,
        "rule": "Greedy 100 % in every scenario.",
        "maps": {"case2": {"command": "lmjx build-map --failure case2 --edges 3000", "digest": digest}},
        "arms": [{"name": "paper", "tasks": "paper", "trials": 1, "failures": ["case2"], "scenarios": [1],
                  "asms": ["random"], "sim": "cpu", "candidates": 32, "levers": levers} | arm],
    }  # fmt: skip


@pytest.fixture
def clean(monkeypatch):
    """The tree reads as clean (no tracked file differs from HEAD), whatever it holds now, and
    git's HEAD as it was when the tests started (a commit made in the checkout while they run
    changes nothing here)."""
    real = provenance._git

    def git(args: list[str], cwd: Path) -> bytes | None:
        return HEAD.encode() if args[:1] == ["rev-parse"] else real(args, cwd)

    monkeypatch.setattr(provenance, "_git", git)
    monkeypatch.setattr(provenance, "_tree_changes", lambda root: b"")


@pytest.fixture
def map_digest(small_map) -> str:
    with lmjx.load_map(small_map) as m:
        return provenance.map_entry(m)["digest"]


# ------------------------------------------------------------------------------ the page


def test_the_registration_block_is_read_strictly(tmp_path) -> None:
    reg = registration(DIGEST)
    r = read_registration(page(reg, tmp_path / "ok.md"))
    assert isinstance(r, Registration) and (r.commit, r.base_seed, r.path) == (HEAD, 0, str(tmp_path / "ok.md"))
    assert r.maps["case2"].digest == DIGEST and r.rule.startswith("Greedy 100 %")
    [arm] = r.arms
    assert (arm.name, arm.tasks, arm.trials, arm.failures, arm.scenarios, arm.asms, arm.sim, arm.candidates) == (
        "paper", "paper", 1, ("case2",), (1,), ("random",), "cpu", 32)  # fmt: skip
    assert set(arm.levers) == set(LEVERS) and arm.levers["greedy_fraction"] is None
    assert arm.levers["push_weight"] == 1.0 and arm.simulator() == "none" and r.arm_for("paper") is arm
    with pytest.raises(RegistrationError, match="registers no arm of"):
        r.arm_for("hard")

    def refused(reg: dict, message: str, heading: str = "## Registration") -> None:
        with pytest.raises(ConfigError) as e:
            read_registration(page(reg, tmp_path / "bad.md", heading))
        assert message in str(e.value) and "\n" not in str(e.value), str(e.value)

    refused(reg, "holds 0 ```toml blocks under a heading 'Registration'", heading="## Registered")
    two = tmp_path / "two.md"
    two.write_text(f"## Registration\n\n```toml\n{block(reg)}\n```\n\n```toml\n{block(reg)}\n```\n")
    with pytest.raises(ConfigError, match="holds 2 ```toml blocks"):
        read_registration(two)
    with pytest.raises(ConfigError, match="no such file"):
        read_registration(tmp_path / "missing.md")
    refused({k: v for k, v in reg.items() if k != "commit"}, "the registration lacks `commit`")
    refused(reg | {"commit": HEAD[:12]}, "`commit` must be the commit's 40-digit hash")
    refused(reg | {"base_seed": "31"}, "`base_seed` must be a whole number")
    refused(reg | {"rule": ""}, "`rule` must be the acceptance rule")
    refused(reg | {"comit": HEAD}, "unknown key `comit`")
    refused(reg | {"maps": {"case2": {"command": "lmjx build-map", "digest": DIGEST[:16]}}},
            "`maps.case2.digest` must be the map's 64-digit content digest")  # fmt: skip
    arm0 = reg["arms"][0]
    refused(reg | {"arms": "paper"}, "`arms` must be one [[arms]] table")
    refused(registration(DIGEST, tasks="easy"), "`arms[paper].tasks` must be paper or hard, got 'easy'")
    refused(registration(DIGEST, sim="tpu"), "`arms[paper].sim` must be gpu or cpu or cpu-near")
    refused(registration(DIGEST, failures=["case1"]), "`arms[paper].failures` must be a list of failures, each with")
    refused(registration(DIGEST, scenarios=[1, 4]), "`arms[paper].scenarios` must be a list of the scenarios")
    refused(registration(DIGEST, trials=True), "`arms[paper].trials` must be a whole number")
    refused(registration(DIGEST, candidates=1024), "`arms[paper].candidates` is 1024 but its levers")
    refused(reg | {"arms": [arm0, arm0 | {"name": "again"}]}, "two arms have the tasks 'paper'")
    refused(reg | {"arms": [{k: v for k, v in arm0.items() if k != "asms"}]}, "lacks `arms[paper].asms`")
    levers = dict(arm0["levers"])
    del levers["servo"]
    refused(registration(DIGEST, levers=levers), "lacks `arms[paper].levers.servo`")
    refused(registration(DIGEST, levers=arm0["levers"] | {"push_weight": "high"}), "push_weight takes a number")
    refused(registration(DIGEST, levers=arm0["levers"] | {"asm_settings": "paper"}), "unknown key `asm_settings`")


# ------------------------------------------------------------------------------ the refusal


@needs_git
def test_a_run_is_checked_against_its_arm(small_map, map_digest, tmp_path, clean, monkeypatch) -> None:
    """check_against names every difference of a run's entry, each with its fix; enforce
    refuses on the first; open_run refuses before reading or writing any result."""
    from lmjx.model.robot import load_robot

    reg = read_registration(page(registration(map_digest), tmp_path / "reg.md"))
    robot, maps = load_robot("panda"), {"case2": lmjx.load_map(small_map)}
    config = EvalConfig(failures=("case2",), scenarios=(1,), asms=("random",), trials=1,
                        planner=planner_config("greedy", "cpu", {"max_actions": 1}))  # fmt: skip
    run = provenance.new_run(robot, maps, config, "lmjx evaluate ...")
    assert check_against(reg, "paper", run, run["maps"]) == [] and enforce(reg, run).name == "paper"
    other = run | {"seed_base": 4, "trials_per_cell": 2, "planner": run["planner"] | {"servo": "playback"},
                   "cells": run["cells"] | {"scenarios": [1, 2]}}  # fmt: skip
    found = [str(d) for d in check_against(reg, "paper", other, other["maps"])]
    assert found == [
        "the scenarios are 1,2, the registration's 1; run with --scenarios 1",
        "the seed base is 4, the registration's 0; run with --seed 0",
        "the trials per cell is 2, the registration's 1; run with --trials 1",
        "the planner's servo is playback, the registration's robot; run with --set servo=robot (and no other "
        "option that sets it)",
    ], found
    wrong_map = {"case2": run["maps"]["case2"] | {"digest": DIGEST}}
    [d] = check_against(reg, "paper", run, wrong_map)
    assert str(d).startswith(f"the map {small_map} has digest fc4682d5d228..., the registration {map_digest[:12]}...")
    with pytest.raises(RegistrationError) as e:
        enforce(reg, other)
    assert str(e.value) == f"--registered {tmp_path / 'reg.md'}: {found[0]}"
    out = tmp_path / "out"
    assert open_run(robot, maps, config, out, registered=tmp_path / "reg.md")[1]["registered"] == {
        "page": str(tmp_path / "reg.md"), "arm": "paper"}  # fmt: skip
    with pytest.raises(RegistrationError, match="leave out --allow-mixed"):
        open_run(robot, maps, config, out, allow_mixed=True, registered=tmp_path / "reg.md")
    # without git: an unknown commit is refused; LMJX_COMMIT with the source files' digest is the registered commit
    monkeypatch.setattr(provenance, "_git", lambda args, cwd: None)
    with pytest.raises(RegistrationError, match="the code's commit is unknown"):
        open_run(robot, maps, config, out, registered=tmp_path / "reg.md")
    monkeypatch.setenv(provenance.COMMIT_ENV, HEAD)
    monkeypatch.setenv(provenance.SOURCE_ENV, provenance.source_digest())
    assert open_run(robot, maps, config, out, registered=tmp_path / "reg.md")[1]["lmjx"]["commit"] == HEAD
    monkeypatch.setenv(provenance.COMMIT_ENV, OTHER_COMMIT)
    with pytest.raises(RegistrationError, match=f"commit 0123456789ab \\(named by LMJX_COMMIT\\), the registration's "
                                                f"{HEAD[:12]}"):  # fmt: skip
        open_run(robot, maps, config, out, registered=tmp_path / "reg.md")
    assert not out.exists()


@needs_git
def test_evaluate_registered_refuses_any_other_run(small_map, map_digest, tmp_path, clean, monkeypatch) -> None:
    args = (*RUN, "--maps", small_map.parent)
    reg = page(registration(map_digest), tmp_path / "reg.md")
    out = tmp_path / "out"

    def refused(message: str, *more: object, registered: Path = reg) -> None:
        r = cli(*args, "--out", out, "--registered", registered, *more)
        r.one_line_error(f"--registered {registered}: {message}")
        assert not out.exists()  # nothing run, nothing written

    other_commit = page(registration(map_digest, commit=OTHER_COMMIT), tmp_path / "commit.md")
    refused(f"the code is at commit {HEAD[:12]} (git's), the registration's 0123456789ab; check out the registered "
            f"commit (git checkout {OTHER_COMMIT})", registered=other_commit)  # fmt: skip
    refused(f"the map {small_map} has digest {map_digest[:12]}..., the registration fc4682d5d228...",
            registered=page(registration(DIGEST), tmp_path / "map.md"))  # fmt: skip
    refused("the planner's push_weight is 0.0, the registration's 1.0; run with --set push_weight=1.0", "--set",
            "push_weight=0")  # fmt: skip
    refused("the task set is paper, which it registers no arm of (its arms: hard (tasks hard)); run with the --tasks "
            "of one", registered=page(registration(map_digest, name="hard", tasks="hard"), tmp_path / "hard.md"))
    refused("the seed base is 4, the registration's 0; run with --seed 0", "--seed", "4")
    refused("the trials per cell is 2, the registration's 1; run with --trials 1", "--trials", "2")
    refused("the asms are random,greedy, the registration's random; run with --asms random", "--asms",
            "random,greedy", "--sim", "cpu")  # fmt: skip
    refused("a registered run pools with no other conditions; leave out --allow-mixed", "--allow-mixed")
    monkeypatch.setattr(provenance, "_tree_changes", lambda root: b"diff --git a/lmjx/types.py b/lmjx/types.py")
    refused(f"tracked files differ from commit {HEAD[:12]} (their changes' digest ")
    monkeypatch.setattr(provenance, "_tree_changes", lambda root: b"")
    bad = tmp_path / "bad.md"
    bad.write_text("# No registration here\n")
    cli(*args, "--out", out, "--registered", bad).one_line_error("holds 0 ```toml blocks under a heading")
    # the registered run itself runs, and its entry names the page and the arm; it resumes, registered
    cli(*args, "--out", out, "--registered", reg).ok()
    [run] = read_results(out / "results.json").runs
    assert run["registered"] == {"page": str(reg), "arm": "paper"} and run["lmjx"]["commit"] == HEAD
    assert "resuming: 1 of 1 trials" in cli(*args, "--out", out, "--registered", reg).ok().stderr
    # a folder that holds trials of a run not registered takes no registered run
    plain = tmp_path / "plain"
    cli(*args, "--out", plain).ok()
    cli(*args, "--out", plain, "--registered", reg).one_line_error(
        f"--registered {reg}: {plain / 'results.json'} holds 1 trials of a run not registered as its arm paper")


# ------------------------------------------------------------------------------ the acceptance checks


def results_of(reg: dict[str, Any], base: int | None = None, commit: str | None = None) -> Results:
    """A results file of the registration's one arm made by hand: one record per registered trial."""
    arm = reg["arms"][0]
    base = reg["base_seed"] if base is None else base
    run = {k: v for k, v in provenance.unknown_run("r1").items() if k != "unrecorded"} | {
        "robot": "panda", "trials_per_cell": arm["trials"], "seed_base": base, "allow_mixed": False,
        "lmjx": {"version": lmjx.__version__, "commit": commit or reg["commit"], "commit_source": "git", "dirty": False,
                 "changes": None, "source_digest": "5" * 64},
        "maps": {f: {"path": f"maps/{f}.h5", "digest": reg["maps"][f]["digest"]} for f in arm["failures"]},
        "tasks": {"set": arm["tasks"], "digest": "0" * 16}, "planner": dict(arm["levers"]),
        "simulator": {"name": arm["sim"], "description": arm["sim"], "device": "a GPU"},
        "cells": {"failures": arm["failures"], "scenarios": arm["scenarios"], "asms": arm["asms"]},
        "registered": {"page": "docs/evaluation/REPLICATE.md", "arm": arm["name"]},
    }  # fmt: skip
    trials = []
    for f in arm["failures"]:
        for s in arm["scenarios"]:
            for a in arm["asms"]:
                for t in range(arm["trials"]):
                    trials.append({
                        "failure": f, "scenario": s, "asm": a, "seed": trial_seed(base, s, t), "tasks": arm["tasks"],
                        "success": True, "actions": 1, "steps": [], "run": "r1",
                        "provenance": {"commit": commit or reg["commit"], "dirty": False,
                                       "map": {"path": f"maps/{f}.h5", "digest": reg["maps"][f]["digest"]},
                                       "tasks": {"set": arm["tasks"], "digest": "0" * 16},
                                       "simulator": "none" if a == "random" else arm["sim"],
                                       "planner": {**arm["levers"], "asm": a}},
                    })  # fmt: skip
    run["trials_run"] = len(trials)
    return Results([run], trials)


def test_the_acceptance_checks_hold_every_record_against_the_registration(tmp_path) -> None:
    acceptance = benchmark_module("eval_acceptance")
    levers = provenance.planner_fields(planner_config("greedy", "gpu", {}))
    reg_dict = registration(DIGEST, commit=OTHER_COMMIT, failures=["case2"], scenarios=[1, 2],
                            asms=["random", "greedy"], trials=2, sim="gpu", candidates=1024,
                            levers=levers) | {"base_seed": 31}  # fmt: skip
    reg = read_registration(page(reg_dict, tmp_path / "reg.md"))

    def unmet(res: Results) -> list[str]:
        return [f"{name}: {why}" for name, ok, why in acceptance.registration_checks({"a.json": res}, reg) if not ok]

    whole = results_of(reg_dict)
    assert len(whole.trials) == 8 and unmet(whole) == []
    assert {r["seed"] for r in whole.trials} == {3101000, 3101001, 3102000, 3102001}
    other = results_of(reg_dict)
    other.trials[3]["provenance"]["commit"] = "f" * 40  # a record of another commit
    [line] = unmet(other)
    assert "at the registered commit 0123456789ab" in line and "at commit ffffffffffff" in line
    assert "1 of 8 records differ: a.json: case2/1/greedy/3101001 at commit" in line
    dirty = results_of(reg_dict)
    dirty.trials[0]["provenance"]["dirty"] = True
    assert len(unmet(dirty)) == 1
    missing = results_of(reg_dict)
    del missing.trials[5]
    [line] = unmet(missing)
    assert "exactly one record per failure, scenario, ASM and trial" in line and "1 missing, 0 twice" in line
    twice = results_of(reg_dict)
    twice.trials.append(dict(twice.trials[2]))
    [line] = unmet(twice)
    assert "8 registered, 9 held: 0 missing, 1 twice" in line
    rerun = results_of(reg_dict)
    rerun.replaced.append({"trial": ["case2", 1, "greedy", 3101000], "kept_run": "r2", "dropped_run": "r1",
                           "dropped_success": False})  # fmt: skip
    assert "1 replaced by a cell run again" in unmet(rerun)[0]
    seeds = unmet(results_of(reg_dict, base=0))  # the trials of another base seed
    assert len(seeds) == 2 and "every record of the registered cells and seeds (base 31, 2 a cell)" in seeds[0]
    assert "8 registered, 8 held: 8 missing, 0 twice, 8 not registered" in seeds[1]
    maps = results_of(reg_dict)
    maps.trials[1]["provenance"]["map"]["digest"] = "1" * 64
    assert "on the registered map of its failure" in unmet(maps)[0]
    planner = results_of(reg_dict)
    planner.trials[7]["provenance"]["planner"]["push_weight"] = 0.0
    [line] = unmet(planner)
    assert "of the registered planner configuration" in line and "planner push_weight 0.0" in line
    unregistered = results_of(reg_dict)
    del unregistered.runs[0]["registered"]  # a run of lmjx evaluate without --registered
    [line] = unmet(unregistered)
    assert "every run registered as the arm (lmjx evaluate --registered): a.json: run r1 (8 trials)" in line
    tasks = results_of(reg_dict)
    tasks.trials[0]["provenance"]["tasks"]["set"] = "hard"
    assert "of the task set paper and the simulator gpu" in unmet(tasks)[0]
    sim = results_of(reg_dict)
    sim.trials[1]["provenance"]["simulator"] = "cpu"
    assert "simulator cpu" in unmet(sim)[0]
    hard = results_of(registration(DIGEST, commit=OTHER_COMMIT, tasks="hard"))
    assert [x.split(":")[0] for x in unmet(hard)] == ["a.json", "arm paper"]  # the file of no arm; the arm of no file
    # the script: the checks printed, a page that is no registration refused in one line
    write_results(tmp_path / "a.json", other)
    script = [sys.executable, str(ROOT / "benchmarks" / "eval_acceptance.py"), "--paper", str(tmp_path / "a.json")]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run([*script, "--registered", str(tmp_path / "reg.md")], capture_output=True, text=True,
                       check=False, env=env)  # fmt: skip
    assert r.returncode == 0 and "[NOT met] arm paper" in r.stdout and "at commit ffffffffffff" in r.stdout, r.stderr
    assert "[met] arm paper" in r.stdout and "[met] no run pooled with --allow-mixed" in r.stdout
    (tmp_path / "none.md").write_text("# nothing\n")
    r = subprocess.run([*script, "--registered", str(tmp_path / "none.md")], capture_output=True, text=True,
                       check=False, env=env)  # fmt: skip
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1 and "holds 0 ```toml" in r.stderr, r.stderr


def test_registration_errors_are_lmjx_errors() -> None:
    assert issubclass(RegistrationError, LmjxError)
