"""The command line: contracts, one-line errors with exit 2, atomic outputs, interrupts."""

from __future__ import annotations

import json
import shutil
import signal

import pytest
from conftest import Collected, cli, cli_process, wait_for

from lmjx.evaluation.results import trials_of


@pytest.mark.parametrize(
    "args, message",
    [
        (["reach", "--failure", "J9=0"], "J9 does not exist"),
        (["reach", "--failure", "J4=0.5"], "outside the joint's limits"),
        (["reach", "--failure", "case2", "--cell", "0"], "--cell"),
        (["reach", "--failure", "case2", "--out", "/proc/nope/map.h5"], "cannot"),
        (["reach", "--failure", "case2", "--out", "/"], "directory"),
        (["reach", "--failure"], "expected one argument"),
        (["reach", "--failure", "none", "--ips", "nose"], "unknown interaction point"),
        (["info", "/nonexistent.h5"], "does not exist"),
        (["lock-search", "--joints", "J8"], "J8"),
        (["bench", "--sizes", "a,b"], "--sizes"),
        (["frobnicate"], "invalid choice"),
    ],
)
def test_bad_input_one_line_exit_2(args, message):
    cli(*args).one_line_error(message)


def test_reach_json_contract_and_outputs(tmp_path):
    out, png = tmp_path / "m.h5", tmp_path / "m.png"
    r = cli("reach", "--failure", "case1", "--cell", "0.1", "--out", out, "--png", png, "--json").ok()
    s = json.loads(r.stdout)
    assert s["failure"] == "case1" and s["cell_m"] == 0.1
    assert set(s["area_m2"]) == {"pm", "npm_pm"}
    assert isinstance(s["seconds"], float) and s["device"].startswith("cpu")
    assert out.stat().st_size > 0 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp files left
    info = cli("info", out, "--json").ok()
    assert json.loads(info.stdout)["reach"]["area_m2"] == s["area_m2"]
    assert "case1" in cli("info", out).ok().stdout


def test_interrupt_leaves_no_file(tmp_path):
    """Ctrl-C while the map is being computed (minutes of work: 48,000 cells x 32 restarts):
    exit 130, one line, nothing at --out."""
    out = tmp_path / "map.h5"
    p = cli_process("reach", "--failure", "case2", "--cell", "0.005", "--restarts", "32", "--out", out,
                    env={"LMJX_PROGRESS": "1"})  # fmt: skip
    err = Collected(p.stderr)
    wait_for(lambda: "reach case2 attempt 1/10" in err.text, p, "the first progress line")
    p.send_signal(signal.SIGINT)
    p.wait(timeout=120)
    text = err.finish()
    assert p.returncode == 130, text
    assert "interrupted" in text and "Traceback" not in text
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_help_explains():
    r = cli("reach", "--help")
    assert r.returncode == 0
    for word in ("--failure", "case2", "J2=0.3,J4=-1.5", "--out", "--png", "--json"):
        assert word in r.stdout


def test_build_map_bad_input():
    # (Ctrl-C during a build: tests/test_edgestream.py)
    for args, message in (
        (["build-map", "--failure", "J9=0"], "J9 does not exist"),
        (["build-map", "--failure", "case2", "--edges", "0"], "--edges"),
        (["build-map", "--failure", "case2", "--out", "/proc/x/map.h5"], "cannot"),
    ):
        cli(*args).one_line_error(message)


@pytest.mark.parametrize("kind", ["truncated", "not_hdf5", "schema", "model"])
def test_info_refuses_bad_files(tmp_path, small_map, kind):
    import h5py

    path = tmp_path / "m.h5"
    shutil.copy(small_map, path)
    if kind == "truncated":
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 3])
    elif kind == "not_hdf5":
        path.write_text("hello")
    else:
        with h5py.File(path, "a") as f:
            if kind == "schema":
                f.attrs["schema_version"] = 7
            else:
                f.attrs["robot_model_hash"] = "f" * 64
    r = cli("info", path)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr


# ------------------------------------------------------------------------------ the planner's levers


def _old_planner_config(asm, sim, max_actions=None, candidates=None, asm_settings="lmjx", when_stuck="best",
                        late_start=False, push_weight=None, rescore_top=None, rescore_draws=8,
                        servo="robot"):  # fmt: skip
    """The planner's configuration as the options that each set one lever made it: the
    reference the keys (--set, --planner-config) must give again."""
    from dataclasses import replace

    from lmjx.types import PlannerConfig

    candidates = candidates or (1024 if sim == "gpu" else 32)
    config = PlannerConfig(asm=asm, max_actions=max_actions, greedy_candidates=candidates, when_stuck=when_stuck,
                           late_start=late_start, rescore_draws=rescore_draws, servo=servo)  # fmt: skip
    if asm_settings == "paper":
        config = config.paper()
    if rescore_top is not None:
        config = replace(config, rescore_top=rescore_top)
    if push_weight is not None:
        config = replace(config, push_weight=push_weight)
    return config


def _levers_config(command: str, asm: str, sim: str, *args: str):
    """The PlannerConfig the command line `args` of `command` gives (parsed, not run)."""
    from lmjx.cli import build_parser
    from lmjx.cli.plan import planner_levers
    from lmjx.planner.levers import planner_config

    base = (
        ["plan", "--map", "m.h5", "--scenario", "1", "--asm", asm] if command == "plan" else ["evaluate", "--out", "e"]
    )
    return planner_config(asm, sim, planner_levers(build_parser().parse_args([*base, *args])))


@pytest.mark.parametrize("command", ["plan", "evaluate"])
def test_plan_and_evaluate_help_fits_a_screen(command):
    """Everyday options in --help (at most 60 lines on an 80-column terminal); the levers
    listed by --help-levers, each with its default; the options that moved not shown."""
    from lmjx.cli.plan import MOVED
    from lmjx.planner.levers import keys

    r = cli(command, "--help", env={"COLUMNS": "80"}).ok()
    assert len(r.stdout.splitlines()) <= 60, r.stdout
    for option in ("--tasks", "--max-actions", "--candidates", "--sim", "--planner-config", "--set", "--help-levers"):
        assert option in r.stdout, option
    for option, _, _ in MOVED:
        assert option not in r.stdout, option
    levers = cli(command, "--help-levers").ok().stdout
    for key, default in (("asm_settings", '"lmjx"'), ("push_weight", "1"), ("rescore_top", "8"), ("servo", '"robot"')):
        assert f"\n{key} = {default}\n" in levers, key
    assert all(f"\n{key} = " in levers for key in keys()) and "asm = " not in levers


def test_set_and_planner_config_give_the_old_options_config(tmp_path):
    levers = tmp_path / "levers.toml"
    levers.write_text(
        '# Greedy without the push weight\npush_weight = 0.5\nrescore_top = 9\nrescore_draws = 3\nservo = "playback"\n'
    )
    paper = tmp_path / "paper.toml"
    paper.write_text('asm_settings = "paper"\n')
    for command in ("plan", "evaluate"):
        cases = [
            ("greedy", "cpu", {}, [], []),
            ("lazy", "cpu", {"asm_settings": "paper", "when_stuck": "options", "late_start": True},
             ["--asm-settings", "paper", "--when-stuck", "options", "--late-start"],
             ["--set", "asm_settings=paper", "--set", "when_stuck=options", "--set", "late_start=true"]),
            ("greedy", "gpu", {"push_weight": 0.5, "rescore_top": 2, "rescore_draws": 3, "servo": "playback",
                               "candidates": 4, "max_actions": 2},
             ["--push-weight", "0.5", "--rescore-top", "2", "--rescore-draws", "3", "--servo", "playback",
              "--candidates", "4", "--max-actions", "2"],
             # --set wins over the file, --candidates and --max-actions over --set
             ["--planner-config", str(levers), "--set", "rescore_top=2", "--set", "greedy_candidates=7",
              "--candidates", "4", "--set", "max_actions=none", "--max-actions", "2"]),
            ("greedy", "gpu", {"asm_settings": "paper", "rescore_top": 4},
             ["--asm-settings", "paper", "--rescore-top", "4"],
             ["--planner-config", str(paper), "--set", "rescore_top=4"]),
        ]  # fmt: skip
        for asm, sim, old_kwargs, old_args, new_args in cases:
            want = _old_planner_config(asm, sim, **old_kwargs)
            assert _levers_config(command, asm, sim, *old_args) == want, (command, old_args)
            assert _levers_config(command, asm, sim, *new_args) == want, (command, new_args)


def test_a_moved_option_says_where_it_moved_and_works_as_before(small_map, tmp_path):
    def no_wall_time(summary: dict) -> dict:
        wall = {"planning_s": 0, "compile_s": 0}
        each = wall | {"latency_s": 0, "phase_s": 0, "shared_s": 0}  # (and each decision's times)
        return summary | wall | {"steps": [s | each for s in summary["steps"]]}

    # (no push weight: its counts are not needed)
    args = ("plan", "--map", small_map, "--scenario", "1", "--asm", "greedy", "--candidates", "4", "--max-actions",
            "1", "--json")  # fmt: skip
    old = cli(*args, "--push-weight", "0", "--rescore-top", "2").ok()
    new = cli(*args, "--set", "push_weight=0", "--set", "rescore_top=2").ok()
    notes = [line for line in old.stderr.splitlines() if "note:" in line]
    assert notes == ["lmjx plan: note: --push-weight moved to --set push_weight=0",
                     "lmjx plan: note: --rescore-top moved to --set rescore_top=2"]  # fmt: skip
    assert "note:" not in new.stderr
    a, b = json.loads(old.stdout), json.loads(new.stdout)
    assert a["asm_settings"]["rescore"] == "best 2, 8 starts" and a["asm_settings"]["push_weight"] == 0.0
    assert no_wall_time(a) == no_wall_time(b)
    args = ("evaluate", "--failures", "case2", "--scenarios", "1", "--asms", "random", "--trials", "1",
            "--max-actions", "1", "--maps", small_map.parent)  # fmt: skip
    r = cli(*args, "--out", tmp_path / "old", "--late-start").ok()
    assert r.stderr.splitlines().count("lmjx evaluate: note: --late-start moved to --set late_start=true") == 1
    cli(*args, "--out", tmp_path / "new", "--set", "late_start=true").ok()
    old_records, new_records = (trials_of(tmp_path / d / "results.json") for d in ("old", "new"))
    assert old_records[0]["asm_settings"]["late_start"] is True
    # (each its own run: the run's id differs, what the trials did and were given does not)
    assert [no_wall_time(r) | {"run": 0} for r in old_records] == [no_wall_time(r) | {"run": 0} for r in new_records]


@pytest.mark.parametrize(
    "args, message",
    [
        (["--set", "push_wieght=1"], "unknown key 'push_wieght' (did you mean push_weight?)"),
        (["--set", "push_weight=heavy"], "--set push_weight=heavy: push_weight takes a number at least 0, got 'heavy'"),
        (["--set", "rescore_draws=1"], "rescore_draws takes a whole number at least 2, got '1'"),
        (["--set", "servo=stiff"], "servo takes playback or robot"),
        (["--set", "late_start=maybe"], "late_start takes true or false"),
        (["--set", "late_start"], "give KEY=VALUE"),
        (["--set", "asm=lazy"], "asm is not a lever"),
        (["--planner-config", "missing.toml"], "no such file"),
        (["--planner-config", "bad.toml"], "not TOML"),
        (["--planner-config", "typed.toml"], "rescore_top takes a whole number at least 0, got 'four'"),
    ],
)
def test_a_bad_lever_is_one_line_and_exit_2(args, message, tmp_path):
    (tmp_path / "bad.toml").write_text("push_weight 0.5\n")
    (tmp_path / "typed.toml").write_text('rescore_top = "four"\n')
    args = [str(tmp_path / a) if a.endswith(".toml") else a for a in args]
    cli("plan", "--map", tmp_path / "m.h5", "--scenario", "1", "--asm", "greedy", *args).one_line_error(message)
    cli("evaluate", "--out", tmp_path / "e", *args).one_line_error(message)
    assert not (tmp_path / "e").exists()
