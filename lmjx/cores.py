"""How many CPU cores this process may run on: its affinity (`taskset`, a container's cpuset),
not the host's count, so that runs sharing a machine (`taskset -c 0-7 lmjx evaluate ...`
beside GPU processes) size their thread pools and trial windows to their own share."""

from __future__ import annotations

import os


def usable_cores() -> int:
    """Cores this process may use (at least 1)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity on this platform
        return max(1, os.cpu_count() or 1)
