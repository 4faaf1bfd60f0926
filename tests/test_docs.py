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
