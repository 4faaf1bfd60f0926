"""Ctrl-C in the Python API, also while XLA compiles: the program ends with KeyboardInterrupt,
never with a crash in the interpreter's teardown (a process that ended while XLA still
compiled or computed for it could fault there)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from conftest import TINY_ARM

PROGRAM = f"""
import sys
import lmjx
print("computing", flush=True)
lmjx.reach_map("J4=0.5", lmjx.ReachConfig(cell=0.05), robot={str(TINY_ARM)!r})
print("finished", flush=True)
"""


def test_ctrl_c_while_the_api_compiles_ends_with_keyboard_interrupt(tmp_path):
    ends = []
    for delay in (1.0, 3.0):  # (while tracing and lowering; while XLA compiles)
        # an empty compile cache of its own (not the run's, where these programs may be kept):
        # the reach map compiles for seconds, so the interrupt lands in its work
        cache = tmp_path / f"cache{delay}"
        env = dict(os.environ, LMJX_CACHE_DIR=str(cache), JAX_COMPILATION_CACHE_DIR=str(cache / "jax"),
                   PYTHONFAULTHANDLER="1")  # fmt: skip
        p = subprocess.Popen([sys.executable, "-c", PROGRAM], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             env=env)  # fmt: skip
        assert p.stdout is not None and p.stdout.readline().strip() == "computing"
        time.sleep(delay)
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=300)
        ends.append((p.returncode, "finished" in out))
        assert p.returncode != -signal.SIGSEGV and "Fatal Python error" not in err, err[-3000:]
        if "finished" not in out:  # (interrupted: not too late)
            # (Python leaves by SIGINT itself after an uncaught KeyboardInterrupt: -2, 130 in a shell)
            assert p.returncode in (-signal.SIGINT, 130) and err.rstrip().endswith("KeyboardInterrupt"), err[-3000:]
    assert any(not finished for _, finished in ends)  # at least one was interrupted while working
