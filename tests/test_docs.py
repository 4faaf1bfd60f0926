"""Every ```python block of README.md and maps/README.md runs as written.

The blocks of one page run in order, in one namespace, in a temporary working directory.
The files the text says a command writes are put there first, smaller but made the same
way: `maps/case2.h5` (what `make run` writes: `lmjx build-map --failure case2`) is the
session's shared case-2 map (`small_map`: the same command with 5 cm cells and 3,000 edges),
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
def docs_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, small_map: Path, tiny_atlas: Path) -> Path:
    maps = tmp_path / "maps"
    maps.mkdir()
    shutil.copy(small_map, maps / "case2.h5")
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


def test_planner_page_lists_every_lever() -> None:
    """docs/PLANNER.md has a row for every key of the planner's configuration, with its default
    as `--help-levers` gives it, and every option that moved."""
    from dataclasses import fields

    from lmjx.cli.plan import MOVED
    from lmjx.evaluation.levers import keys, toml_text
    from lmjx.types import PlannerConfig

    text = (ROOT / "docs" / "PLANNER.md").read_text()
    defaults = {f.name: f.default for f in fields(PlannerConfig)} | {"asm_settings": "lmjx"}
    for key in keys():
        assert f"| `{key}` | `{toml_text(defaults[key])}` |" in text, key
    for option, key, _ in MOVED:
        assert f"| `{option}" in text and f"`--set {key}=" in text, option
