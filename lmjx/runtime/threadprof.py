"""Where a many-threaded command's threads spend their time: a sampling profiler for
developers (`LMJX_THREAD_PROFILE=report.json lmjx build-map ...`).

Every few milliseconds it looks at each thread's Python stack (`sys._current_frames`) and
counts where it stands: the innermost lmjx frame (file, function, line) and the innermost
frame of all (often a library call: a lock wait, an h5py write, a compressor).  Threads are
grouped by name (the digits of pool threads dropped).  A thread blocked in C code shows the
Python line that called it, so the report tells waiting from working: `result` or
`acquire` is waiting, a compressor or `write_direct_chunk` is working.
"""

from __future__ import annotations

import collections
import json
import os
import re
import sys
import threading
import time
from pathlib import Path

_HERE = str(Path(__file__).parents[1])  # lmjx's own frames


def _group(name: str) -> str:
    """A thread's group: its name without pool numbering ("lmjx-pack_3" -> "lmjx-pack")."""
    return re.sub(r"[-_]\d+$", "", re.sub(r"_\d+$", "", name))


def _where(frame) -> str:
    """The innermost lmjx frame, then (" > ") the innermost frame when that is elsewhere."""
    inner = f"{Path(frame.f_code.co_filename).name}:{frame.f_code.co_name}"
    f = frame
    while f is not None and not f.f_code.co_filename.startswith(_HERE):
        f = f.f_back
    if f is None or f is frame:
        return f"{inner}:{frame.f_lineno}"
    return f"{Path(f.f_code.co_filename).name}:{f.f_code.co_name}:{f.f_lineno} > {inner}"


class ThreadSampler:
    """Samples every thread's stack each `interval` seconds between `start` and `stop`."""

    def __init__(self, interval: float = 0.005) -> None:
        self.interval = interval
        self.counts: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="lmjx-sampler", daemon=True)
        self.seconds = 0.0

    def start(self) -> ThreadSampler:
        self._t0 = time.perf_counter()
        self._thread.start()
        return self

    def _run(self) -> None:
        me = threading.get_ident()
        while not self._stop.wait(self.interval):
            names = {t.ident: t.name for t in threading.enumerate()}
            for ident, frame in sys._current_frames().items():
                if ident != me:
                    self.counts[_group(names.get(ident, "?"))][_where(frame)] += 1

    def stop(self, top: int = 12) -> dict:
        """The report: per thread group, its samples and the `top` places with their share."""
        self._stop.set()
        self._thread.join()
        self.seconds = time.perf_counter() - self._t0
        report = {"interval_s": self.interval, "seconds": round(self.seconds, 3), "groups": {}}
        for group, counter in sorted(self.counts.items()):
            n = sum(counter.values())
            report["groups"][group] = {
                "samples": n,
                "top": [[where, round(k / n, 4)] for where, k in counter.most_common(top)],
            }
        return report


def from_environment() -> ThreadSampler | None:
    """A started sampler when LMJX_THREAD_PROFILE names a report file, else None."""
    return ThreadSampler().start() if os.environ.get("LMJX_THREAD_PROFILE") else None


def write_report(sampler: ThreadSampler | None, other: dict | None = None) -> None:
    """Stop `sampler` and write its report where LMJX_THREAD_PROFILE says (atomically);
    `other`: another process's report (lmjx.edges.mapwriter's), whose groups are added with
    "<process>/" before their names."""
    if sampler is None:
        return
    report = sampler.stop()
    if other is not None:
        report["groups"] |= {f"{other.get('process', 'other')}/{g}": v for g, v in other["groups"].items()}
    path = Path(os.environ["LMJX_THREAD_PROFILE"])
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(report, indent=1))
    os.replace(tmp, path)
