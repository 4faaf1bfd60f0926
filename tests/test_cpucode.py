"""One map per command and seed on every x86-64 CPU: XLA's CPU code pinned (SSE4.2, no
platform-dependent math: `lmjx.runtime.cpucode`), and the shared small map's digest pinned."""

from __future__ import annotations

import os

from lmjx.mapfile.digest import stored_digest
from lmjx.runtime.cpucode import CPU_FLAGS, pin_cpu_code

# the tests' small map (conftest.SMALL_MAP: case 2, 3,000 edges, 5 cm cells, seed 1) as every
# x86-64 CPU builds it with the pinned code (first built on an AMD EPYC with AVX-512)
SMALL_MAP_DIGEST = "cb0d9a6002167a0aa91337fa597a795781349a8af77dd973f4dff92dcb990d9f"


def test_the_small_map_is_the_same_on_every_cpu(small_map):
    assert stored_digest(small_map) == SMALL_MAP_DIGEST


def test_xla_flags_pinned_unless_given_or_native(monkeypatch):
    assert all(f in os.environ["XLA_FLAGS"] for f in CPU_FLAGS)  # (importing lmjx pinned them)
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_max_isa=AVX2 --xla_force_host_platform_device_count=2")
    pin_cpu_code()
    assert os.environ["XLA_FLAGS"] == (  # the user's own ISA kept, the other flag added
        "--xla_cpu_max_isa=AVX2 --xla_force_host_platform_device_count=2 --xla_cpu_enable_platform_dependent_math=false"
    )
    monkeypatch.setenv("XLA_FLAGS", "")
    monkeypatch.setenv("LMJX_CPU_CODE", "native")
    pin_cpu_code()
    assert os.environ["XLA_FLAGS"] == ""
