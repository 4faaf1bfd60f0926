"""Progress on stderr for long work: a tqdm bar on a terminal; where stderr is a file or a
pipe (a log, CI, a job scheduler), a plain line every LINE_SECONDS at most, as tqdm does
when it is not on a terminal, but one line each time rather than carriage returns.
LMJX_PROGRESS=0 turns progress off; LMJX_PROGRESS=1 forces the bar even off a terminal."""

from __future__ import annotations

import os
import sys
import threading
import time

from tqdm import tqdm

ENV = "LMJX_PROGRESS"
LINE_SECONDS = 5.0  # off a terminal: a line at most this often (the first after this long)


def _rate(n: float, seconds: float, unit: str) -> str:
    r = n / seconds if seconds > 0 else 0.0
    for scale, prefix in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if r >= scale:
            return f"{r / scale:.1f}{prefix} {unit}/s"
    return f"{r:.1f} {unit}/s"


class Progress:
    """A thin tqdm wrapper whose methods are no-ops when disabled; `update` may be called
    from several threads."""

    def __init__(
        self, total: int | None, desc: str, enabled: bool = True, unit: str = "IK", steps_per_unit: int = 1
    ) -> None:
        """`total` units of `unit` (edges, trials, ...); `steps_per_unit`: how many `update`
        counts make one unit (a build counts each edge twice: its start solved, then its
        rollout), so the bar shows units."""
        setting = os.environ.get(ENV, "").strip()
        on = enabled and setting != "0"
        bar = on and (setting == "1" or sys.stderr.isatty())
        self.per = max(1, steps_per_unit)
        self._bar = None
        if bar:
            scale = True if self.per == 1 else 1 / self.per
            counts = None if total is None else total * self.per
            self._bar = tqdm(total=counts, desc=desc, unit=unit, unit_scale=scale, file=sys.stderr, dynamic_ncols=True,
                             leave=False)  # fmt: skip
        self._lines = on and not bar
        self.total, self.desc, self.unit = total, desc, unit
        self.n = 0  # counts (`update`'s), units times steps_per_unit
        self._printed = -1  # what the last line showed
        self._t0 = self._last = time.monotonic()
        self._lock = threading.Lock()

    def update(self, n: int) -> None:
        if self._bar is not None:
            with self._lock:
                self._bar.update(n)
        elif self._lines:
            with self._lock:
                self.n += n
                now = time.monotonic()
                if now - self._last >= LINE_SECONDS:
                    self._last = now
                    self._line(now)

    def _line(self, now: float) -> None:
        seconds = now - self._t0
        units = self.n // self.per
        done = f"{units:,}/{self.total:,} {self.unit}" if self.total else f"{units:,} {self.unit}"
        share = f" ({100 * units / self.total:.0f} %)" if self.total else ""
        print(f"{self.desc}: {done}{share}, {seconds:.0f} s, {_rate(units, seconds, self.unit)}", file=sys.stderr)
        sys.stderr.flush()
        self._printed = self.n

    def set_description(self, desc: str) -> None:
        self.desc = desc
        if self._bar is not None:
            self._bar.set_description(desc)

    def close(self) -> None:
        """End the bar; off a terminal, a last line where work ended since the last one (the
        total reached shows as 100 %)."""
        if self._bar is not None:
            self._bar.close()
        elif self._lines and self.n and self.n != self._printed and time.monotonic() - self._t0 >= LINE_SECONDS:
            self._line(time.monotonic())
