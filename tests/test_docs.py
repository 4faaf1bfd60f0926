"""Every ```python block of README.md and maps/README.md runs as written.

The blocks of one page run in order, in one namespace, in a temporary working directory.
The files the text says a command writes are put there first, smaller but made the same
way: `maps/case2.h5` (what `make run` writes: `lmjx build-map --failure case2`) is the
test run's shared case-2 map (`small_map`: the same command with 5 cm cells and 3,000 edges),
and `maps/atlas.h5` (what `lmjx atlas` writes) the four-joint test arm's small atlas
(`tiny_atlas`).  Blocks that compute run on the small settings their text gives (10 cm
cells, 200 edges, a budget of 3 actions).  Shell commands are in ```bash blocks and are not
run here.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest
from conftest import cli

ROOT = Path(__file__).resolve().parent.parent
PYTHON_BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)
PAGES = ("README.md", "maps/README.md")


def python_blocks(page: str) -> list[str]:
    return PYTHON_BLOCK.findall((ROOT / page).read_text())


@pytest.fixture
def docs_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, plan_map: Path, tiny_atlas: Path) -> Path:
    """A folder like the one `make run` leaves: maps/case2.h5 a case-2 map of the default
    settings (plan_map: 6,000 edges where make run samples 10,000), and an atlas."""
    maps = tmp_path / "maps"
    maps.mkdir()
    shutil.copy(plan_map, maps / "case2.h5")
    shutil.copy(tiny_atlas, maps / "atlas.h5")
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize("page", PAGES)
def test_python_blocks_run_as_written(page: str, docs_dir: Path) -> None:
    blocks = python_blocks(page)
    assert blocks, f"{page} has no python blocks"
    namespace: dict = {"__name__": "__main__"}
    for i, block in enumerate(blocks, 1):
        exec(compile(block, f"{page}, python block {i}", "exec"), namespace)


def test_readme_is_a_first_page() -> None:
    """Short, with the sections a newcomer looks for, and no measurement history."""
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 250
    headings = re.findall(r"^## (.+)$", text, re.M)
    for want in ("Quick start", "Concepts", "The paper's results beside ours", "Your own robot", "Python", "GPU"):
        assert want in headings, want
    quick = text[text.index("## Quick start") : text.index("## Concepts")]
    assert "make run" in quick and "make test" in quick and ". .venv/bin/activate" in quick
    assert "LMJX_PROGRESS" in text
    for term in ("**PM**", "**NPM**", "**Failure**", "**Edge**", "**ASM**"):
        assert text.index(term) < text.index("## The paper's results"), term
    # every link to a file of the repository points at one that exists
    for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", text):
        assert (ROOT / target).exists(), target


# Exported functions whose docstring example computes a map: README.md's blocks run the same
# calls (a map of 10 cm cells; build_map with 200 edges), so they are not run twice here.
RUN_BY_THE_README = {"reach_map", "write_reach_map", "build_map"}


def test_api_docstring_examples_run(docs_dir: Path) -> None:
    """The runnable example in the docstring of every function the package exports (those
    that build maps: through README.md's identical blocks)."""
    import doctest

    import lmjx

    readme = (ROOT / "README.md").read_text()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    finder = doctest.DocTestFinder(recurse=False)
    tried = 0
    for name in lmjx.__all__:
        obj = getattr(lmjx, name, None)
        if not callable(obj) or isinstance(obj, type):
            continue
        if name in RUN_BY_THE_README:
            assert f"lmjx.{name}(" in readme and ">>> " in (obj.__doc__ or ""), name
            continue
        for test in finder.find(obj, name, globs={}):
            tried += len(test.examples)
            runner.run(test)
    assert tried > 0 and runner.failures == 0, f"{runner.failures} of {tried} examples failed (see the output)"


# ------------------------------------------------------------------ links and the tree's words

# The pages whose relative links (files, images, `#anchor`s) must resolve.
LINKED_PAGES = (
    "README.md",
    "docs/DETAILS.md",
    "docs/ROBOTS.md",
    "docs/EVALUATION.md",
    "docs/evaluation/README.md",
    "docs/SCENES.md",
    "docs/API.md",
    "maps/README.md",
    "benchmarks/README.md",
)
FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)
INDENTED_CODE = re.compile(r"(?:^(?: {4}|\t).*\n)+", re.M)
CODE_SPAN = re.compile(r"`[^`\n]*`")
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(([^()\s]+)(?:\s+\"[^\"]*\")?\)")


def github_slug(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation but '-' and '_' dropped,
    spaces to '-'."""
    text = re.sub(r"[`*]", "", heading.strip()).lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """Every heading's anchor on a page (a repeated heading gets -1, -2, ... as on GitHub)."""
    out: set[str] = set()
    for heading in re.findall(r"^#{1,6} +(.+?) *#*$", FENCE.sub("", page.read_text()), re.M):
        slug, n = github_slug(heading), 1
        while slug in out:
            slug = f"{github_slug(heading)}-{n}"
            n += 1
        out.add(slug)
    return out


def relative_links(page: Path) -> list[str]:
    """The link and image targets of a page's text (code blocks and code spans left out),
    other than web and mail addresses."""
    text = CODE_SPAN.sub("", INDENTED_CODE.sub("", FENCE.sub("", page.read_text())))
    return [t for t in LINK.findall(text) if not re.match(r"[a-z][a-z0-9+.-]*:", t)]


def test_github_slugs_and_link_parsing() -> None:
    """The checker itself: slugs as GitHub makes them, links found in text and not in code."""
    assert github_slug("Table I, reproduced") == "table-i-reproduced"
    assert github_slug("The test suite and `make run`") == "the-test-suite-and-make-run"
    assert github_slug("Deviations from the paper, and why") == "deviations-from-the-paper-and-why"
    assert github_slug("Maps of 1,000,000 edges (2026-11-25)") == "maps-of-1000000-edges-2026-11-25"
    page = "see [a](x.md#b), ![img](img/y.png), [web](https://e.org)\n\n    [code](no.md)\n\n`[span](no.md)`\n"
    text = CODE_SPAN.sub("", INDENTED_CODE.sub("", FENCE.sub("", page)))
    assert LINK.findall(text) == ["x.md#b", "img/y.png", "https://e.org"]


@pytest.mark.parametrize("page", LINKED_PAGES)
def test_relative_links_resolve(page: str) -> None:
    """Every relative link and image of the page names a file of the repository, and every
    `#anchor` a heading of the page it points into."""
    path = ROOT / page
    links = relative_links(path)
    assert links, f"{page} has no relative links"
    broken = []
    for link in links:
        target, _, anchor = link.partition("#")
        dest = (path.parent / target).resolve() if target else path
        if not dest.exists():
            broken.append(f"{link}: no such file")
        elif anchor and (dest.suffix != ".md" or anchor not in anchors(dest)):
            broken.append(f"{link}: no heading '{anchor}' in {dest.relative_to(ROOT)}")
    assert not broken, f"{page}: " + "; ".join(broken)


# How the project was developed is not the product's business: code, help, tests and docs say
# what the software does and why (commit messages keep the history).  The words that tell of
# it, as the project's acceptance greps for them, case-insensitive:
HISTORY = re.compile(
    r"session|issue ?#?[0-9]|device machine|device time|calibration (seven|seventh|sixth|fifth)"
    r"|the [a-z]+th session|since 2026|before 2026",
    re.I,
)
SCANNED = (".py", ".md", ".sh", ".toml")
# What the word "session" may still mean, each where it is used: (files, the phrase).  Every
# allowance must be in use (an unused one is to be removed).
ALLOWED = (
    ("tests/*.py", r'scope="session"'),  # pytest's fixture scope
    ("docs/DETAILS.md", r'scope="session"'),
    ("tests/conftest.py", r"request\.session\."),  # pytest's Session
    ("lmjx/runtime/child.py", r"start_new_session=True"),  # an OS process session (setsid)
    # the atlas file's run record: `sessions`, one entry per process run that built part of it
    ("lmjx/reach/atlas.py", r'"sessions"|\bsession\b'),
    ("lmjx/cli/atlas.py", r'"sessions"|\bsession\b'),
    ("maps/README.md", r"`sessions`"),
)
THIS_FILE = Path(__file__).resolve()


def scanned_files() -> list[Path]:
    """The repository's source and documentation files (git's tracked and untracked-but-not-
    ignored files where git is there, else every file outside virtual environments and caches)."""
    import subprocess

    try:
        names = subprocess.run(
            ["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.splitlines()
        files = [ROOT / n for n in names]
    except (OSError, subprocess.CalledProcessError):
        skip = {".git", ".venv", "venv", "__pycache__", ".pytest_cache", ".ruff_cache", "build", "dist"}
        files = [p for p in ROOT.rglob("*") if not skip & set(p.relative_to(ROOT).parts)]
    return sorted(p for p in files if p.suffix in SCANNED and p.is_file() and p.resolve() != THIS_FILE)


def history_hits(files: list[Path]) -> tuple[list[str], set[int]]:
    """Lines that still match HISTORY once the allowed phrases of their file are taken out,
    and which allowances were used."""
    hits, used = [], set()
    for path in files:
        rel = path.relative_to(ROOT).as_posix()
        mine = [(i, a) for i, (glob, a) in enumerate(ALLOWED) if Path(rel).match(glob)]
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if not HISTORY.search(line):
                continue
            rest = line
            for i, allowed in mine:
                rest, k = re.subn(allowed, "", rest)
                if k:
                    used.add(i)
            if HISTORY.search(rest):
                hits.append(f"{rel}:{n}: {line.strip()[:120]}")
    return hits, used


def test_no_development_history_in_the_tree() -> None:
    """No "session", "issue N", "device time", "the seventh calibration", "since 2026-..." in
    the code, help, tests or docs, but for pytest's session scope, OS process sessions and the
    atlas file's record of its runs; every allowance is in use and the words are found where
    they are planted."""
    for planted in ("the seventeenth session", "Issue 19's acceptance", "issue #7", "1,279 s of device time",
                    "the calibration seventh", "the default since 2026-11-27", "on the device machine"):  # fmt: skip
        assert HISTORY.search(planted), planted
    files = scanned_files()
    names = {p.relative_to(ROOT).as_posix() for p in files}
    assert len(files) > 150 and {"README.md", "lmjx/types.py", "tests/conftest.py", "pyproject.toml"} <= names
    hits, used = history_hits(files)
    assert not hits, "development history in the tree:\n" + "\n".join(hits)
    unused = [ALLOWED[i] for i in range(len(ALLOWED)) if i not in used]
    assert not unused, f"allowances no longer in use (remove them): {unused}"


def test_planner_page_lists_every_lever() -> None:
    """docs/PLANNER.md has a row for every key of the planner's configuration, with its default
    as `--help-levers` gives it, and every option that moved."""
    from dataclasses import fields

    from lmjx.cli.plan import MOVED
    from lmjx.planner.levers import keys, toml_text
    from lmjx.types import PlannerConfig

    text = (ROOT / "docs" / "PLANNER.md").read_text()
    defaults = {f.name: f.default for f in fields(PlannerConfig)} | {"asm_settings": "lmjx"}
    for key in keys():
        assert f"| `{key}` | `{toml_text(defaults[key])}` |" in text, key
    for option, key, _ in MOVED:
        assert f"| `{option}" in text and f"`--set {key}=" in text, option


# ------------------------------------------------------------------ what the docs say, against the program

DOCS = ("README.md", *sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "docs").glob("*.md")))


def page(name: str) -> str:
    return (ROOT / name).read_text()


def test_grid_is_counted_ny_by_nx_everywhere(plan_map: Path) -> None:
    """The reach grid's cell counts read ny x nx (a row per y, a column per x: the shape of the
    map file's per-cell arrays) in `lmjx info`, in a map's and a reach result's one-line print,
    and in the pages that give the convention."""
    import lmjx

    with lmjx.load_map(plan_map) as m:
        assert m.reach is not None
        ny, nx = m.reach.labels_smooth.shape
        assert (len(m.reach.ys), len(m.reach.xs)) == (ny, nx) == (60, 50)  # 2 cm cells, 1.2 m of y, 1.0 m of x
        printed = [repr(m), repr(m.reach)]
    printed.append(cli("info", plan_map).ok().stdout)
    for text in printed:
        assert f"{ny} x {nx} cells" in text and f"{nx} x {ny} cells" not in text, text
    for name in ("README.md", "maps/README.md", "docs/DETAILS.md"):
        text = page(name)
        assert "ny x nx" in text and "60 x 50 cells" in text and "50 x 60" not in text, name


def test_docs_write_the_key_of_a_moved_option() -> None:
    """README.md and docs/*.md write `--set asm_settings=paper`, as the CLI's note for
    `--asm-settings` says; only docs/PLANNER.md's table of moved options names the old spelling."""
    import argparse

    from lmjx.cli.plan import MOVED, moved_notes

    args = argparse.Namespace(command="plan", **{key: None for _, key, _ in MOVED})
    args.asm_settings = "paper"
    assert moved_notes(args) == ["lmjx plan: note: --asm-settings moved to --set asm_settings=paper"]
    hits, table_rows = [], 0
    for name in DOCS:
        for n, line in enumerate(page(name).splitlines(), 1):
            if "--asm-settings" not in line:
                continue
            if name == "docs/PLANNER.md" and line.startswith("| `--asm-settings paper` | `--set asm_settings=paper` |"):
                table_rows += 1
            else:
                hits.append(f"{name}:{n}: {line.strip()}")
    assert not hits, "--asm-settings outside docs/PLANNER.md's table of moved options:\n" + "\n".join(hits)
    assert table_rows == 1
    assert "--set asm_settings=paper" in page("README.md") and "--set asm_settings=paper" in page("docs/DETAILS.md")


def test_readme_counts_usable_edges_as_the_results_do() -> None:
    """The README's 0-8 of the 270-430 edges over a target are the usable ones (they start clear
    and act on the target), as benchmarks/RESULTS.md and docs/EVALUATION.md count them."""
    results, evaluation = page("benchmarks/RESULTS.md"), page("docs/EVALUATION.md")
    assert "270-430 edges over the target" in results and "leaving 0-8 usable" in results
    assert "leaving 0-8 usable" in evaluation
    readme = " ".join(page("README.md").split())
    assert "of the 270-430 edges over a target only 0-8 are usable: start clear and act on the target" in readme
    assert "0-8 start clear" not in readme


PROGRESS_LINE = re.compile(
    r"lmjx plan: action (\d+)/(\d+): target \d+\.\d cm from the goal's centre, decided in \d+\.\d s"
)


@pytest.fixture(scope="module")
def random_plan(plan_map: Path):
    """`lmjx plan` of one Random action (it simulates nothing: seconds), with its progress
    lines and with LMJX_PROGRESS=0."""
    args = ("plan", "--map", plan_map, "--scenario", "1", "--asm", "random", "--seed", "0", "--max-actions", "1")
    return cli(*args, env={"LMJX_PROGRESS": ""}).ok(), cli(*args, env={"LMJX_PROGRESS": "0"}).ok()


def test_plan_prints_a_line_per_action_as_the_docs_say(random_plan) -> None:
    """`lmjx plan` prints a line per executed action on stderr, as README.md and docs/DETAILS.md
    describe it (DETAILS's example line in the program's form); LMJX_PROGRESS=0 silences it."""
    loud, quiet = random_plan
    assert "after 1 action" in loud.stdout, loud.stdout  # (the test map's seed 0 acts at once)
    lines = [ln for ln in loud.stderr.splitlines() if ln.startswith("lmjx plan: action")]
    assert len(lines) == 1 and PROGRESS_LINE.fullmatch(lines[0]) and lines[0].startswith("lmjx plan: action 1/1:")
    assert "lmjx plan: action" not in quiet.stderr and quiet.stdout.splitlines()[0] == loud.stdout.splitlines()[0]
    readme, details = " ".join(page("README.md").split()), " ".join(page("docs/DETAILS.md").split())
    assert "on stderr a line per action" in readme and "LMJX_PROGRESS=0" in readme
    example = re.search(r"`(lmjx plan: action [^`]*)`", details)
    assert example and PROGRESS_LINE.fullmatch(example.group(1)), "docs/DETAILS.md: the progress line's example"
    assert "LMJX_PROGRESS=0" in details and "a line per executed action" in details


def test_docs_give_egl_and_osmesa_for_rendering() -> None:
    """Rendering on a headless machine: EGL where available (a GPU's, or Mesa's without a GPU),
    OSMesa otherwise, in README.md and docs/DETAILS.md."""
    for name in ("README.md", "docs/DETAILS.md"):
        text = " ".join(page(name).split())
        assert "MUJOCO_GL=egl" in text and "MUJOCO_GL=osmesa" in text, name
        assert "without a GPU" in text and "libegl-mesa0" in text and "libosmesa6" in text, name
        at = text.index("needs OpenGL")  # where the page says what rendering needs: EGL first, OSMesa otherwise
        assert at < text.index("MUJOCO_GL=egl", at) < text.index("MUJOCO_GL=osmesa", at), name


def test_every_end_is_explained_in_help_and_details() -> None:
    """Each end a trial reports (`ENDS`, and each label `Planner.trial` sets is one of them) is
    explained by `lmjx plan --help-ends`, named in --help's epilog, and in docs/DETAILS.md."""
    from lmjx.cli.plan import END_MEANINGS
    from lmjx.planner.records import ENDS

    source = (ROOT / "lmjx" / "planner" / "edge_planner.py").read_text()
    assert set(re.findall(r'reason = "([^"]+)"', source)) == set(ENDS) == set(END_MEANINGS)
    ends = cli("plan", "--help-ends").ok().stdout
    assert "--help-ends" in cli("plan", "--help", env={"COLUMNS": "80"}).ok().stdout
    details = page("docs/DETAILS.md")
    for end in ENDS:
        assert re.search(rf"^{re.escape(end)}: \S", ends, re.M), end
        assert f"* **{end}**: " in details, end


def test_plan_summary_gives_the_goal_size_and_plurals(random_plan) -> None:
    """The summary gives the target's distance from the goal's centre beside the goal region's
    size, and counts in the singular for one; so do the records' one-line prints."""
    import argparse

    from lmjx.cli.plan import goal_size
    from lmjx.planner.records import StepRecord, TrialResult
    from lmjx.sim.scenefile import shipped_scene

    loud, _ = random_plan
    assert "cm from the centre of the 16 x 16 cm goal" in loud.stdout, loud.stdout  # the paper set's goal squares
    assert goal_size(argparse.Namespace(scene=shipped_scene(2, "hard"), scenario=None), "paper") == "12 x 12 cm"
    assert goal_size(argparse.Namespace(scene=None, scenario=3), "hard") == "12 x 12 cm"
    for n, word in ((0, "actions"), (1, "action"), (2, "actions")):
        text = repr(TrialResult(n == 1, n, 0.4, 3.0, 0.076, reason="goal"))
        assert f"after {n} {word};" in text, text
    assert "of 1 candidate (" in repr(StepRecord(3, 1, 1, None, 0.2, 0.1, 0.0))
    assert re.search(r"after \d+ actions?\b", loud.stdout) and "after 1 actions" not in loud.stdout


def test_step_record_says_candidates_include_turned_copies() -> None:
    """A step's print says its edge's turn and that its candidates are the map's edges over the
    target and turned copies (so they can outnumber the map's edges); docs/DETAILS.md explains
    the same output."""
    from lmjx.planner.records import StepRecord

    step = StepRecord(1095, 4833, 17, None, 0.033, 4.5, 4.1, target_moved_m=0.09, turn_deg=126)
    text = repr(step)
    assert text.startswith("StepRecord(edge 1095 (turned 126 deg) of 4,833 candidates (the map's edges over the "
                           "target and any turned copies of its edges), 17 simulated;"), text  # fmt: skip
    assert "no action among 5 candidates" in repr(StepRecord(-1, 5, 0, None, 0.2, 0.1, 0.0))
    details = " ".join(page("docs/DETAILS.md").split())
    assert text.split(";")[0] in details  # the line DETAILS shows
    assert "4,833 candidates on the 2,485-edge map" in details


def test_write_reach_map_refuses_an_existing_file(plan_map: Path, tmp_path: Path) -> None:
    """`lmjx.write_reach_map` refuses a file already at its path in one line naming
    overwrite=True, leaving it as it was, and replaces it with overwrite=True; documented."""
    import lmjx
    from lmjx.errors import LmjxError, OutputPathError

    with lmjx.load_map(plan_map) as m:
        reach = m.reach
    path = tmp_path / "new" / "reach.h5"  # (its folder made)
    lmjx.write_reach_map(path, reach)
    before = path.read_bytes()
    with pytest.raises(OutputPathError) as refused:
        lmjx.write_reach_map(path, reach)
    message = str(refused.value)
    assert isinstance(refused.value, LmjxError) and "\n" not in message
    assert str(path) in message and "overwrite=True" in message
    assert path.read_bytes() == before
    lmjx.write_reach_map(path, reach, overwrite=True)
    with lmjx.load_map(path) as m:
        assert m.edges is None and (m.reach.labels_smooth == reach.labels_smooth).all()
    assert "overwrite" in (lmjx.write_reach_map.__doc__ or "")
    assert "overwrite=True" in page("README.md") and "overwrite=True" in page("docs/DETAILS.md")


BASH_BLOCK = re.compile(r"^```bash\n(.*?)^```", re.S | re.M)
WRITES = {"--out", "--png", "--render", "--summary", "--html", ">", ">>"}  # what names a file or folder written
PY_WRITES = re.compile(r"""(?:write_reach_map\(|\bout=|\.write\()\s*["']([^"']+)["']""")


def readme_writes(text: str) -> list[str]:
    """The paths the README's example commands write: the argument of each writing option or
    redirection in its ```bash blocks and its `lmjx ...` code spans, and the paths its
    ```python blocks hand to a writer."""
    import shlex

    commands = [ln for block in BASH_BLOCK.findall(text) for ln in block.splitlines()]
    commands += [span for span in re.findall(r"`(lmjx [^`]+)`", text)]
    out = []
    for command in commands:
        words = shlex.split(command, comments=True)
        out += [words[i + 1] for i, w in enumerate(words[:-1]) if w in WRITES]
    out += [path for block in PYTHON_BLOCK.findall(text) for path in PY_WRITES.findall(block)]
    return out


def test_readme_examples_write_under_out_and_maps() -> None:
    """Every example of README.md writes under out/ (ignored by git) or maps/, never into the
    repository's other folders; out/ needs no mkdir but for a shell redirection, which the text
    precedes with `mkdir -p out`."""
    assert readme_writes("```bash\nlmjx reach --png a.png --out out/b.h5  # --out c\necho > d\n```\n") == [
        "a.png", "out/b.h5", "d"]  # fmt: skip
    text = page("README.md")
    written = readme_writes(text)
    assert len(written) >= 10 and "out/case1.png" in written and "out/case2_reach.h5" in written
    stray = [p for p in written if not p.startswith(("out/", "maps/"))]
    assert not stray, f"README examples write outside out/ and maps/: {stray}"
    assert "/out/" in page(".gitignore").split()
    if "> out/" in text:
        assert "mkdir -p out" in text


def test_venv_is_ignored_as_a_folder_or_a_link(tmp_path: Path) -> None:
    """.gitignore's `/.venv` ignores a virtual environment at the top whether it is a folder or
    a symbolic link to one (`.venv/` would miss the link): git itself says so."""
    import subprocess

    if shutil.which("git") is None:
        pytest.skip("git is not installed")
    assert "/.venv" in page(".gitignore").splitlines()
    for kind in ("folder", "link"):
        repo = tmp_path / kind
        repo.mkdir()
        subprocess.run(["git", "init", "-q"], cwd=repo, check=True)
        shutil.copy(ROOT / ".gitignore", repo / ".gitignore")
        if kind == "folder":
            (repo / ".venv").mkdir()
            (repo / ".venv" / "pyvenv.cfg").write_text("home = /usr/bin\n")
        else:
            (tmp_path / "env").mkdir(exist_ok=True)
            (repo / ".venv").symlink_to(tmp_path / "env")
        r = subprocess.run(["git", "check-ignore", "-q", ".venv"], cwd=repo)
        assert r.returncode == 0, f"a .venv {kind} is not ignored"


def lock_pins(name: str) -> dict[str, str]:
    """A lock file's pins, by normalized name."""
    pins = {}
    for line in page(name).splitlines():
        line = line.split("#")[0].strip()
        if line:
            package, version = line.split("==")
            pins[re.sub(r"[-_.]+", "-", package).lower()] = version
    return pins


def test_gpu_lock_pins_what_the_gpu_extra_adds() -> None:
    """requirements-gpu.lock pins what pyproject.toml's `gpu` extra adds to requirements.lock for
    CUDA 12: JAX's CUDA 12 plugin at the lock's JAX version, its CUDA 12 libraries and warp-lang
    1.18.0, nothing the lock pins already; the README and docs/DETAILS.md install the two."""
    import tomllib

    lock, gpu = lock_pins("requirements.lock"), lock_pins("requirements-gpu.lock")
    assert not set(lock) & set(gpu)  # additions only: the two together, installed with --no-deps
    assert gpu["jax-cuda12-plugin"] == gpu["jax-cuda12-pjrt"] == lock["jax"] == lock["jaxlib"]
    assert gpu["warp-lang"] == "1.18.0" and lock["mujoco-mjx"] == "3.17.0"
    nvidia = [p for p in gpu if p.startswith("nvidia-")]
    assert nvidia and all(p.endswith("-cu12") for p in nvidia)
    assert set(gpu) == {"jax-cuda12-plugin", "jax-cuda12-pjrt", "warp-lang", *nvidia}
    extras = tomllib.loads(page("pyproject.toml"))["project"]["optional-dependencies"]
    assert "mujoco-mjx[warp]==3.17.0" in extras["gpu"] and any(r.startswith("jax[cuda12]") for r in extras["gpu"])
    assert "warp-lang==1.18.0" in extras["test"]
    install = "pip install --no-deps -r requirements.lock -r requirements-gpu.lock"
    readme, details = page("README.md"), page("docs/DETAILS.md")
    assert install in readme[readme.index("## GPU") :] and install in details[details.index("## GPU") :]
    assert "requirements-gpu.lock" in details[details.index("## Development") :]
