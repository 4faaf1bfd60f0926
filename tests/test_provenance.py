"""Where an evaluation's trials come from, and whether they may be pooled: every trial records
its code, map digest, simulator, host and planner configuration; resuming or merging trials of
other conditions is refused in one line unless allowed, and the report then says so; maps
carry their content digest; success rates come with Wilson 95 % intervals."""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import socket
import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import h5py
import pytest
from conftest import cli

import lmjx
from lmjx.errors import ConfigError, MixedRunsError
from lmjx.evaluation import provenance
from lmjx.evaluation.results import Results, merge, read_results, write_results
from lmjx.evaluation.stats import rate_text, wilson
from lmjx.mapfile.digest import DIGEST_ATTR, content_digest, store_digest, stored_digest
from lmjx.types import MAX_SIM_STEPS, PlannerConfig

ROOT = Path(__file__).resolve().parents[1]


def _score_interval(k: int, n: int, z: float) -> tuple[float, float]:
    """The rates p whose score test accepts k of n: the roots of (k - n p)^2 = z^2 n p (1 - p),
    found by bisection (an independent reference for `wilson`'s closed form)."""
    from scipy.optimize import brentq

    def f(p: float) -> float:
        return (k - n * p) ** 2 - z * z * n * p * (1 - p)

    inside = min(max(k / n, 1e-12), 1 - 1e-12)  # where f < 0 (the observed rate, off the ends)
    lo = 0.0 if k == 0 else brentq(f, 1e-15, inside)
    hi = 1.0 if k == n else brentq(f, inside, 1 - 1e-15)
    return lo, hi


def test_wilson_intervals_against_known_values() -> None:
    # Newcombe (1998), Statistics in Medicine 17:857, Table I, method 3 (the score interval)
    for (k, n), want in {(81, 263): (0.2553, 0.3662), (15, 148): (0.0624, 0.1605), (0, 20): (0.0, 0.1611),
                         (1, 29): (0.0061, 0.1718)}.items():  # fmt: skip
        assert wilson(k, n) == pytest.approx(want, abs=5e-5), (k, n)
    for n in (1, 2, 15, 30, 270):
        for k in range(n + 1):
            assert wilson(k, n) == pytest.approx(_score_interval(k, n, 1.959963984540054), abs=1e-9), (k, n)
    assert rate_text(10, 15) == "10/15 (66.7 %, 95 % CI 41.7-84.8 %)"
    assert rate_text(15, 15) == "15/15 (100 %, 95 % CI 79.6-100 %)" and rate_text(0, 15).endswith("CI 0-20.4 %)")
    with pytest.raises(ValueError):
        wilson(3, 2)


def test_maps_carry_their_content_digest(small_map, tmp_path) -> None:
    """The build stores the map's content digest; the push counts (a derived group) and the
    attributes are left out of it, every dataset of the content is in it; map_digest.py
    computes it and says whether the stored one agrees."""
    digest, n = content_digest(small_map)
    assert stored_digest(small_map) == digest and n > 20
    # the states decompressed on all cores, in blocks that start and end inside HDF5 chunks,
    # hash as h5py's reads do
    each, each_h5py = {}, {}
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("lmjx.mapfile.digest.ROWS", 1000)
        assert content_digest(small_map, each) == content_digest(small_map, each_h5py, parallel=False) == (digest, n)
    assert each == each_h5py
    with h5py.File(small_map) as f:
        from lmjx.mapfile.lazystates import StateReader

        assert len(f["edges/q"]) > 3000 and StateReader(f["edges/q"]).fast  # (the parallel reads were taken)
    assert provenance.map_entry(lmjx.load_map(small_map))["digest_source"] == "stored"
    copy = tmp_path / "case2.h5"
    shutil.copy(small_map, copy)
    with h5py.File(copy, "r+") as f:
        f["edges/push/counts"][...] = f["edges/push/counts"][...] + 1  # other push counts: derived, not content
        f.attrs["note"] = "an attribute"
    assert content_digest(copy)[0] == digest
    with h5py.File(copy, "r+") as f:
        del f.attrs[DIGEST_ATTR]
        f["reach/pos_err"][0, 0] = f["reach/pos_err"][0, 0] + 1e-4
    assert stored_digest(copy) is None and content_digest(copy)[0] != digest
    entry = provenance.map_entry(lmjx.load_map(copy))
    assert entry["digest_source"] == "computed" and entry["digest"] == content_digest(copy)[0]
    assert store_digest(copy) == content_digest(copy)[0] == stored_digest(copy)
    with h5py.File(copy, "r+") as f:
        f["reach/pos_err"][0, 0] = f["reach/pos_err"][0, 0] + 1e-4  # the stored digest now stale
    script = [sys.executable, str(ROOT / "benchmarks" / "map_digest.py")]
    ok = subprocess.run([*script, str(small_map)], capture_output=True, text=True, check=False)
    assert ok.returncode == 0 and ok.stdout.startswith(digest) and "as stored" in ok.stdout, ok.stderr
    stale = subprocess.run([*script, str(copy)], capture_output=True, text=True, check=False)
    assert stale.returncode == 1 and "NOT the stored" in stale.stdout, stale.stdout


def test_the_commit_comes_from_git_or_the_environment(monkeypatch) -> None:
    """git's commit in a checkout; on a copy without .git, LMJX_COMMIT only together with
    LMJX_SOURCE_DIGEST, which must be the digest of the files there; without either, unknown."""
    here = provenance.code_version()
    assert here["source_digest"] == provenance.source_digest() and len(here["source_digest"]) == 64
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=False)
    if head.returncode == 0:  # a checkout: git's commit, and whether tracked files differ from it
        assert here["commit"] == head.stdout.strip() and here["commit_source"] == "git"
        assert isinstance(here["dirty"], bool) and (here["changes"] is not None) == here["dirty"]
    monkeypatch.setattr(provenance, "_git", lambda args, cwd: None)  # a copy without its .git folder
    commit, digest = "0123abc" * 5 + "01234", provenance.source_digest()
    monkeypatch.setenv(provenance.COMMIT_ENV, commit)
    with pytest.raises(ConfigError, match="LMJX_COMMIT is set without LMJX_SOURCE_DIGEST"):
        provenance.code_version()  # the commit alone says nothing of the files
    monkeypatch.setenv(provenance.SOURCE_ENV, digest)
    named = provenance.code_version()
    assert (named["commit"], named["commit_source"], named["dirty"]) == (commit, "LMJX_COMMIT", None)
    monkeypatch.setenv(provenance.SOURCE_ENV, "f" * 64)  # files other than the commit's
    with pytest.raises(ConfigError, match=f"LMJX_SOURCE_DIGEST=ffffffffffffffff... but the source files here "
                                          f"digest to {digest[:16]}...: they are not those of commit 0123abc0123a"):
        provenance.code_version()  # fmt: skip
    monkeypatch.setenv(provenance.SOURCE_ENV, digest)
    monkeypatch.setenv(provenance.COMMIT_ENV, "0123abc")
    with pytest.raises(ConfigError, match="full 40-digit hash"):
        provenance.code_version()
    monkeypatch.delenv(provenance.COMMIT_ENV)
    with pytest.raises(ConfigError, match="LMJX_SOURCE_DIGEST is set without LMJX_COMMIT"):
        provenance.code_version()
    monkeypatch.delenv(provenance.SOURCE_ENV)
    alone = provenance.code_version()
    assert (alone["commit"], alone["commit_source"], alone["version"]) == ("unknown", "unknown", lmjx.__version__)


def test_the_source_digest_covers_the_code_and_its_data(tmp_path) -> None:
    """SHA-256 over the sorted relative paths, lengths and bytes of lmjx/**/*.py,
    kernels/**/*.py, the robots' models, the task sets' scenes and pyproject.toml; nothing
    else there counts."""
    files = {"pyproject.toml": b"[project]\n", "lmjx/__init__.py": b"", "lmjx/evaluation/a.py": b"x = 1\n",
             "kernels/k.py": b"y = 2\n", "lmjx/model/assets/arm.xml": b"<mujoco/>",
             "lmjx/sim/scenes/s.toml": b"a = 1"}  # fmt: skip
    for name, data in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(data)
    h = hashlib.sha256()
    for name in sorted(files):
        h.update(name.encode() + b"\0" + str(len(files[name])).encode() + b"\0" + files[name])
    digest = provenance.source_digest(tmp_path)
    assert digest == h.hexdigest()
    for other in ("README.md", "lmjx/notes.txt", "tests/test_x.py", "lmjx/__pycache__/a.cpython-311.pyc"):
        (tmp_path / other).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / other).write_text("not source")
    assert provenance.source_digest(tmp_path) == digest
    (tmp_path / "kernels" / "k.py").write_bytes(b"y = 3\n")  # a byte changed
    changed = provenance.source_digest(tmp_path)
    (tmp_path / "kernels" / "k.py").rename(tmp_path / "kernels" / "j.py")  # the same bytes, renamed
    assert len({digest, changed, provenance.source_digest(tmp_path)}) == 3
    (tmp_path / "lmjx" / "stray.py").write_text("")  # an added file, empty
    assert provenance.source_digest(tmp_path) not in {digest, changed}


def test_the_commit_named_for_a_copy_comes_from_a_clean_checkout(monkeypatch) -> None:
    """`python -m lmjx.evaluation.provenance` prints LMJX_COMMIT and LMJX_SOURCE_DIGEST of a clean
    checkout, which a copy without .git then accepts; a tree with changes or untracked source
    files is refused."""
    if subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, check=False).returncode:
        pytest.skip("not a git checkout")
    monkeypatch.setattr(provenance, "_tree_changes", lambda root: b"")
    real = provenance._git
    status = {"out": b""}
    monkeypatch.setattr(provenance, "_git", lambda args, cwd: status["out"] if args[0] == "status" else real(args, cwd))
    line = provenance.commit_environment()
    values = dict(x.split("=", 1) for x in line.split())
    assert set(values) == {"LMJX_COMMIT", "LMJX_SOURCE_DIGEST"} and values["LMJX_COMMIT"] == provenance.code_version()[
        "commit"]  # fmt: skip
    monkeypatch.setattr(provenance, "_git", lambda args, cwd: None)  # the copy, without .git
    for k, v in values.items():
        monkeypatch.setenv(k, v)
    assert provenance.code_version()["commit"] == values["LMJX_COMMIT"]
    monkeypatch.setattr(provenance, "_git", lambda args, cwd: status["out"] if args[0] == "status" else real(args, cwd))
    status["out"] = b"?? lmjx/stray.py\n"
    with pytest.raises(ConfigError, match="the source files differ from the commit"):
        provenance.commit_environment()
    status["out"] = b""
    monkeypatch.setattr(provenance, "_tree_changes", lambda root: b"diff")
    with pytest.raises(ConfigError, match="the source files differ from the commit"):
        provenance.commit_environment()
    r = subprocess.run([sys.executable, "-m", "lmjx.evaluation.provenance"], cwd=ROOT, capture_output=True, text=True,
                       check=False)  # fmt: skip
    if r.returncode == 0:  # this checkout is clean
        assert r.stdout.startswith("LMJX_COMMIT=") and " LMJX_SOURCE_DIGEST=" in r.stdout
    else:
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "error: " in r.stderr, r.stderr


def test_an_unknown_commit_pools_with_nothing(small_map, monkeypatch) -> None:
    """Two runs whose commits are unknown differ (nothing says their code was the same): resuming
    and merging are refused, naming the variables that name a commit; a run matches itself."""
    from lmjx.evaluation.evaluate import EvalConfig
    from lmjx.evaluation.results import check_conditions
    from lmjx.model.robot import load_robot

    monkeypatch.setattr(provenance, "_git", lambda args, cwd: None)
    for k in (provenance.COMMIT_ENV, provenance.SOURCE_ENV):
        monkeypatch.delenv(k, raising=False)
    robot, maps = load_robot("panda"), {"case2": lmjx.load_map(small_map)}
    config = EvalConfig(failures=("case2",), scenarios=(1,), asms=("random",), trials=1)
    a, b = (provenance.new_run(robot, maps, config, "lmjx evaluate ...") for _ in range(2))
    assert a["lmjx"]["commit"] == b["lmjx"]["commit"] == "unknown"
    assert provenance.differences(a, b) == [("commit", "unknown", "unknown")] and provenance.differences(a, a) == []
    held = Results([a | {"trials_run": 1}], [{"failure": "case2", "scenario": 1, "asm": "random", "seed": 0,
                                             "success": True, "run": a["id"]}])  # fmt: skip
    with pytest.raises(MixedRunsError, match="commit \\(there unknown; here unknown\\); name the commit with "
                                             "LMJX_COMMIT and LMJX_SOURCE_DIGEST"):  # fmt: skip
        check_conditions(held, b, False, "out/results.json")
    other = Results([b | {"trials_run": 1}], [{**held.trials[0], "seed": 1, "run": b["id"]}])
    with pytest.raises(MixedRunsError, match="commit \\(before unknown; its unknown\\); run them where git"):
        merge([("a", held), ("b", other)])
    assert len(merge([("a", held), ("a again", held)]).trials) == 1
    # named commits pool as before; the same commit with other source files does not
    named = [r | {"lmjx": r["lmjx"] | {"commit": "1" * 40}} for r in (a, b)]
    assert provenance.differences(*named) == []
    named[1]["lmjx"]["source_digest"] = "2" * 64
    assert provenance.differences(*named) == [("source files", a["lmjx"]["source_digest"][:12], "2" * 12)]


def test_every_trial_records_its_provenance_and_other_conditions_are_refused(small_map, tmp_path) -> None:
    args = ("evaluate", "--failures", "case2", "--scenarios", "1", "--asms", "random", "--trials", "1",
            "--max-actions", "1", "--maps", small_map.parent)  # fmt: skip
    out = tmp_path / "ev"
    cli(*args, "--out", out).ok()
    res = read_results(out / "results.json")
    [run], [rec] = res.runs, res.trials
    digest = content_digest(small_map)[0]
    p = rec["provenance"]
    assert rec["run"] == run["id"] and rec["sim_steps"] == 0  # (Random simulates nothing)
    assert p["map"] == {"path": str(small_map), "digest": digest} and run["maps"]["case2"]["digest_source"] == "stored"
    assert (p["lmjx"], p["commit"]) == (lmjx.__version__, provenance.code_version()["commit"])
    assert (p["host"], p["simulator"], p["tasks"]["set"]) == (socket.gethostname(), "none", "paper")
    assert p["device"] == run["simulator"]["device"] == "none"  # Random ran nothing on a device
    assert p["source_digest"] == run["lmjx"]["source_digest"] == provenance.source_digest()
    assert set(p["planner"]) == {f.name for f in fields(PlannerConfig)} and p["planner"]["asm"] == "random"
    assert p["planner"]["max_sim_steps"] == MAX_SIM_STEPS == run["planning_limit"]["max_sim_steps"]
    assert run["command"] == "lmjx " + " ".join(map(str, (*args, "--out", out)))
    assert (run["trials_per_cell"], run["seed_base"], run["trials_run"], run["robot"]) == (1, 0, 1, "panda")
    report = (out / "report.md").read_text()
    assert report.index("## Provenance") < report.index("## Results") and f"digest `{digest}`" in report
    assert run["lmjx"]["commit"] in report and f"`{run['command']}`" in report and "max_sim_steps" in report
    assert rate_text(int(rec["success"]), 1) in report and "1 trial (1 per cell)" in report
    assert "resuming: 1 of 1 trials" in cli(*args, "--out", out).ok().stderr
    # other conditions: one line, nothing run
    cli(*args, "--out", out, "--set", "push_weight=0").one_line_error("planner's push_weight (there 1.0; here 0.0)")
    cli(*args, "--out", out, "--trials", "2").one_line_error("trials per cell (there 1; here 2)")
    cli(*args, "--out", out, "--seed", "4").one_line_error("--allow-mixed")
    other = tmp_path / "other"
    other.mkdir()
    shutil.copy(small_map, other / "case2.h5")
    with h5py.File(other / "case2.h5", "r+") as f:
        f["reach/pos_err"][0, 0] = f["reach/pos_err"][0, 0] + 1e-4
    store_digest(other / "case2.h5")
    cli(*args, "--out", out, "--maps", other).one_line_error(f"map of case2 (there {digest[:12]}; here ")
    data = json.loads((out / "results.json").read_text())
    data["runs"][0]["lmjx"]["commit"] = "0" * 40  # as another checkout wrote it
    (out / "results.json").write_text(json.dumps(data))
    cli(*args, "--out", out).one_line_error("commit (there 000000000000")
    unrecorded = tmp_path / "unrecorded"
    unrecorded.mkdir()
    plain = [{k: v for k, v in rec.items() if k not in ("run", "provenance")}]
    (unrecorded / "results.json").write_text(json.dumps(plain))
    cli(*args, "--out", unrecorded).one_line_error("provenance (there not recorded; here recorded)")
    assert read_results(unrecorded / "results.json").trials == plain
    assert len(read_results(out / "results.json").trials) == 1  # nothing was run by a refusal
    # --allow-mixed pools them, and the report says which runs and how many trials each
    cli(*args, "--out", out, "--trials", "2", "--set", "push_weight=0", "--allow-mixed").ok()
    res = read_results(out / "results.json")
    assert len(res.runs) == 2 and len(res.trials) == 2 and res.runs[1]["allow_mixed"]
    report = (out / "report.md").read_text()
    assert "**Mixed runs**" in report and "2 trials (2 per cell)" in report
    assert f"run {res.runs[0]['id']}: 1 trial" in report and f"run {res.runs[1]['id']}: 1 trial;" in report
    assert "commit (the first 000000000000" in report and "planner's push_weight (the first 1.0" in report


def test_a_merge_pools_only_trials_of_one_runs_conditions(small_map, tmp_path) -> None:
    """Parts of one evaluation merge; a part of other conditions, or a trial in two parts with
    different records (run twice), is refused unless allowed, and then the file says which
    record was replaced; a part given twice counts once."""
    from lmjx.evaluation.evaluate import EvalConfig
    from lmjx.model.robot import load_robot

    robot = load_robot("panda")
    maps = {"case2": lmjx.load_map(small_map)}
    config = EvalConfig(failures=("case2",), scenarios=(1,), asms=("random",), trials=2)

    def part(seeds: list[int], success: bool, **planner) -> Results:
        cfg = config if not planner else EvalConfig(**{**config.__dict__, "planner": PlannerConfig(**planner)})
        run = provenance.new_run(robot, maps, cfg, "lmjx evaluate ...") | {"trials_run": len(seeds)}
        trials = [{"failure": "case2", "scenario": 1, "asm": "random", "seed": s, "success": success, "run": run["id"]}
                  for s in seeds]  # fmt: skip
        return Results([run], trials)

    a, b = part([1000], True), part([1001], False)
    whole = merge([("a", a), ("b", b), ("a again", a)])
    assert [t["seed"] for t in whole.trials] == [1000, 1001] and len(whole.runs) == 2 and not whole.replaced
    with pytest.raises(MixedRunsError, match=re.escape("planner's push_weight (before 1.0; its 0.0)")):
        merge([("a", a), ("c", part([1001], False, push_weight=0.0))])
    twice = part([1000], False)
    with pytest.raises(MixedRunsError, match="holds trial case2/1/random/1000 again, with another record than a's"):
        merge([("a", a), ("twice", twice)])
    kept = merge([("a", a), ("twice", twice)], allow_mixed=True)
    assert [t["success"] for t in kept.trials] == [False]
    assert kept.replaced == [{"trial": ["case2", 1, "random", 1000], "kept_run": twice.runs[0]["id"],
                              "dropped_run": a.runs[0]["id"], "dropped_success": True}]  # fmt: skip
    # the script: the same refusal in one line, nothing written
    for name, res in (("a", a), ("twice", twice)):
        (tmp_path / name).mkdir()
        write_results(tmp_path / name / "results.json", res)
    script = [sys.executable, str(ROOT / "benchmarks" / "eval_acceptance.py"), "--merge", str(tmp_path / "dest")]
    r = subprocess.run([*script, str(tmp_path / "a"), str(tmp_path / "twice")], capture_output=True, text=True,
                       check=False, env={**os.environ, "PYTHONPATH": str(ROOT)})  # fmt: skip
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1 and "run twice" in r.stderr, r.stderr
    assert not (tmp_path / "dest" / "results.json").exists()
