"""One compilation of a program per machine (`lmjx.runtime.compilelock`): processes that
compile the same program take turns, different programs do not wait for each other, a
process killed while it holds the lock frees it, and without a cache folder nothing is held."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

HOLD = """
import sys, time
from lmjx.runtime.compilelock import compiling
with compiling(sys.argv[1]):
    start = time.time()
    print("holding", flush=True)
    time.sleep(float(sys.argv[2]))
    print(start, time.time(), flush=True)
"""


def _start(ident: str, hold: float, cache: str) -> subprocess.Popen:
    env = dict(os.environ, LMJX_CACHE_DIR=cache)
    return subprocess.Popen([sys.executable, "-c", HOLD, ident, str(hold)], stdout=subprocess.PIPE, text=True, env=env)


def _spans(procs: list[subprocess.Popen]) -> list[tuple[float, float]]:
    out = []
    for p in procs:
        lines = p.communicate(timeout=120)[0].split()
        out.append((float(lines[1]), float(lines[2])))
    return sorted(out)


def test_the_same_program_is_compiled_by_one_process_at_a_time(tmp_path: Path):
    cache = str(tmp_path / "cache")
    (_a0, a1), (b0, _b1) = _spans([_start("ab" * 32, 1.0, cache), _start("ab" * 32, 1.0, cache)])
    assert b0 >= a1 - 0.01  # the second began once the first had let go
    (_c0, c1), (d0, _d1) = _spans([_start("cd" * 32, 1.5, cache), _start("ef" * 32, 1.5, cache)])
    assert d0 < c1  # two programs: side by side
    assert sorted(os.listdir(Path(cache) / "locks")) == ["abababababababababababababababab.lock",
                                                         "cdcdcdcdcdcdcdcdcdcdcdcdcdcdcdcd.lock",
                                                         "efefefefefefefefefefefefefefefef.lock"]  # fmt: skip


def test_a_killed_holder_lets_go_and_no_cache_folder_holds_nothing(tmp_path: Path):
    cache = str(tmp_path / "cache")
    held = _start("12" * 32, 300.0, cache)
    assert held.stdout is not None and held.stdout.readline().strip() == "holding"
    held.kill()
    held.wait(timeout=60)
    t = time.time()
    (s0, _), = _spans([_start("12" * 32, 0.1, cache)])  # fmt: skip
    assert s0 - t < 30
    off = [_start("34" * 32, 1.0, "off"), _start("34" * 32, 1.0, "off")]
    (_a0, a1), (b0, _b1) = _spans(off)
    assert b0 < a1  # no folder: no lock, side by side
