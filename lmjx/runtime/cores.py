"""How many CPU cores this process may run on: its affinity (`taskset`, a container's cpuset),
not the host's count, so that runs sharing a machine (`taskset -c 0-7 lmjx evaluate ...`
beside GPU processes) size their thread pools and trial windows to their own share.

`LMJX_CORES=N` caps that at N without pinning: many runs sharing a large host (dozens of
evaluations on 64 cores) each keep small pools while the operating system moves them to
whichever cores are idle."""

from __future__ import annotations

import os

from lmjx.errors import ConfigError

ENV = "LMJX_CORES"


def usable_cores() -> int:
    """Cores this process may use (at least 1): its affinity, capped by LMJX_CORES."""
    try:
        mine = max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity on this platform
        mine = max(1, os.cpu_count() or 1)
    cap = os.environ.get(ENV, "").strip()
    if not cap:
        return mine
    if not cap.isdigit() or int(cap) < 1:
        raise ConfigError(f"{ENV} must be a whole number of cores (1 or more), not {cap!r}")
    return min(mine, int(cap))
