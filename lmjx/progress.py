"""Progress bars on stderr for long work (tqdm), off when disabled or when stderr is not a
terminal, unless LMJX_PROGRESS=1 forces them on."""

from __future__ import annotations

import os
import sys
import threading

from tqdm import tqdm


class Progress:
    """A thin tqdm wrapper whose methods are no-ops when disabled; `update` may be called
    from several threads."""

    def __init__(self, total: int | None, desc: str, enabled: bool = True, unit: str = "IK") -> None:
        forced = os.environ.get("LMJX_PROGRESS") == "1"
        on = enabled and (forced or sys.stderr.isatty())
        self._bar = (
            tqdm(
                total=total,
                desc=desc,
                unit=unit,
                unit_scale=True,
                file=sys.stderr,
                dynamic_ncols=True,
                leave=False,
            )
            if on
            else None
        )
        self._lock = threading.Lock()

    def update(self, n: int) -> None:
        if self._bar is not None:
            with self._lock:
                self._bar.update(n)

    def set_description(self, desc: str) -> None:
        if self._bar is not None:
            self._bar.set_description(desc)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
