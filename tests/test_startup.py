"""What a command costs before it does anything: a path that is no map is refused before JAX,
h5py or MuJoCo are imported; a machine without CUDA learns so without importing MuJoCo Warp."""

from __future__ import annotations

import subprocess
import sys

HEAVY = ("jax", "h5py", "mujoco", "warp")


def _modules_after(code: str) -> set[str]:
    """The heavy modules a fresh interpreter has imported after running `code`."""
    probe = f"import sys\n{code}\nprint(sorted(m for m in {HEAVY!r} if m in sys.modules))"
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    return set(eval(r.stdout.strip().splitlines()[-1]))


def test_a_missing_map_is_refused_before_the_heavy_imports(tmp_path):
    missing = tmp_path / "missing.h5"
    text = tmp_path / "notes.txt"
    text.write_text("not a map")
    for path, message in ((missing, "does not exist"), (text, "is not an HDF5 file"), (tmp_path, "is a folder")):
        code = (
            "import contextlib, io\nfrom lmjx.cli import main\nerr = io.StringIO()\n"
            f"with contextlib.redirect_stderr(err):\n    assert main(['info', {str(path)!r}]) == 2\n"
            f"assert {message!r} in err.getvalue() and len(err.getvalue().splitlines()) == 1, err.getvalue()"
        )
        assert _modules_after(code) == set(), path


def test_no_cuda_driver_is_found_without_importing_mujoco_warp():
    code = (
        "import ctypes\nfrom lmjx.sim import gpu\n"
        "gpu._cuda_driver = lambda: False\n"  # (a machine without CUDA, whatever this one has)
        "assert gpu.warp_problem() in ('no NVIDIA CUDA driver on this machine', "
        "\"warp-lang is not installed (pip install -e '.[gpu]')\")"
    )
    assert "warp" not in _modules_after(code)
