"""lmjx.runtime.threadprof: the sampler attributes each thread's time to where it stands, grouped by
thread name (a sleeping thread is found in the function that sleeps)."""

from __future__ import annotations

import threading
import time

from lmjx.runtime.threadprof import ThreadSampler, _group


def _wait_here(seconds: float) -> None:
    time.sleep(seconds)


def test_a_waiting_thread_is_found_where_it_waits():
    sampler = ThreadSampler(interval=0.002).start()
    workers = [threading.Thread(target=_wait_here, args=(0.3,), name=f"lmjx-demo_{i}") for i in range(2)]
    for t in workers:
        t.start()
    for t in workers:
        t.join()
    report = sampler.stop()
    demo = report["groups"]["lmjx-demo"]  # both threads in one group
    assert demo["samples"] >= 50
    where, share = demo["top"][0]
    assert where.startswith("test_threadprof.py:_wait_here:") and share > 0.9
    assert "lmjx-sampler" not in report["groups"]


def test_thread_groups_drop_pool_numbering():
    assert _group("lmjx-pack_3") == "lmjx-pack"
    assert _group("ThreadPoolExecutor-2_11") == "ThreadPoolExecutor"
    assert _group("MainThread") == "MainThread"
