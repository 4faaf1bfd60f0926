"""The same map from the same command on every x86-64 CPU: XLA's CPU code made the same way.

XLA compiles lmjx's kernels for the CPU it runs on: with AVX-512 or AVX2 its vectors are wider
and it fuses multiplications and additions (FMA), and its fast reciprocal and square-root
estimates differ between CPU makers.  A rollout's joint states then differ in their last bits
from one CPU to another, and a map built with the same command and seed had another content
digest on another 2-core x86-64 machine (measured: the make run map's states differed in 97,177
of 126,810 rows, by up to 1.6e-4 rad/s, between AVX-512 and AVX2 code on one machine, with the
same edges kept).  `pin_cpu_code` caps XLA's CPU code at SSE4.2 (every x86-64 CPU since 2008
runs it, without FMA) and turns its platform-dependent math off, before JAX starts: the same
instructions, so the same bits, everywhere.  Measured cost on the 2-core CPU: none that shows
(the make run map's rollouts 12.5 s against 12.0 s).  GPUs' code is not affected.
LMJX_CPU_CODE=native keeps XLA's own choice (faster on some CPUs, its maps that CPU's own).
"""

from __future__ import annotations

import os

ENV = "LMJX_CPU_CODE"
CPU_FLAGS = ("--xla_cpu_max_isa=SSE4_2", "--xla_cpu_enable_platform_dependent_math=false")


def pin_cpu_code() -> None:
    """Add CPU_FLAGS to XLA_FLAGS (each unless XLA_FLAGS sets its option already), unless
    LMJX_CPU_CODE is "native".  Effective when JAX's CPU backend starts after this."""
    if os.environ.get(ENV, "").strip().lower() == "native":
        return
    flags = os.environ.get("XLA_FLAGS", "")
    add = [f for f in CPU_FLAGS if f.split("=")[0] not in flags]
    if add:
        os.environ["XLA_FLAGS"] = " ".join([flags, *add]).strip()
