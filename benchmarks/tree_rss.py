"""Peak resident memory of a command and all its descendants together (sampled every
0.1 s from /proc), for builds that run more than one process (`lmjx build-map` writes its
map in a process of its own, lmjx/edges/mapwriter.py).  GNU time's "Maximum resident set size"
is the largest single process's, not the sum.

    python benchmarks/tree_rss.py -- lmjx build-map --failure case2 --edges 5000000
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
import time
from pathlib import Path

PAGE = 4096


def _children() -> dict[int, list[int]]:
    kids: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            kids.setdefault(ppid, []).append(int(d.name))
    return kids


def tree_rss(pid: int) -> int:
    """Resident bytes of `pid` and its descendants."""
    kids, total, todo = _children(), 0, [pid]
    while todo:
        p = todo.pop()
        with contextlib.suppress(OSError, IndexError, ValueError):
            total += int(Path(f"/proc/{p}/statm").read_text().split()[1]) * PAGE
        todo += kids.get(p, [])
    return total


def main() -> int:
    args = sys.argv[1:]
    if not args or args[0] != "--" or len(args) < 2:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    proc = subprocess.Popen(args[1:])
    peak = 0
    while proc.poll() is None:
        peak = max(peak, tree_rss(proc.pid))
        time.sleep(0.1)
    print(f"tree_rss: peak resident memory of the command's processes together: {peak / 1e9:.2f} GB", file=sys.stderr)
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main())
