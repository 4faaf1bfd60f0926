"""How many CPU cores this process may run on: its affinity (`taskset`, a container's cpuset),
not the host's count, so that runs sharing a machine (`taskset -c 0-7 lmjx evaluate ...`
beside GPU processes) size their thread pools and trial windows to their own share.

`LMJX_CORES=N` caps that at N without pinning: many runs sharing a large host (dozens of
evaluations on 64 cores) each keep small pools while the operating system moves them to
whichever cores are idle.  XLA's CPU client sizes its own thread pool by the affinity alone;
`LMJX_CORES=1` keeps it to one thread too (`cap_xla_threads`, before JAX starts a backend).
XLA has no flag for N threads: with N > 1, pin the run (`taskset`) to cap XLA as well."""

from __future__ import annotations

import os

from .errors import ConfigError

ENV = "LMJX_CORES"
ONE_THREAD_XLA = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"


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


def cap_xla_threads() -> bool:
    """With LMJX_CORES=1 on a process allowed more cores, keep XLA's CPU client to one thread
    (appended to XLA_FLAGS; it must run before JAX starts a backend).  Without it each of 30
    unpinned runs of LMJX_CORES=1 on a 32-core host ran XLA on every core (load average 50-79,
    2026-11-27).  Returns whether it set the flags."""
    if usable_cores() != 1 or not os.environ.get(ENV, "").strip():
        return False
    flags = os.environ.get("XLA_FLAGS", "")
    if ONE_THREAD_XLA in flags:
        return False
    os.environ["XLA_FLAGS"] = " ".join(x for x in (flags, ONE_THREAD_XLA) if x)
    return True
