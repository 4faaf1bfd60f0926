"""Shared fixtures and helpers.  Tests run on the CPU (C MuJoCo is the reference everywhere).

What is expensive is made once per test run and shared: every kernel is compiled at one
shape (the shapes the commands use: the Reach-Ability map's IK program per failure, which
the edges' start IK shares, and one rollout program per failure), the maps are fixtures of
the whole run (`scope="session"`: `coarse`, `table1`, `table1_ur5e`, `small_map`, `tiny_map`, ...), and
commands run in this process (`cli`) unless what is tested needs a process of its own
(`cli_process`: signals, several host devices or processes).  Compiled programs are kept in
one cache folder for the whole run, subprocesses included (`LMJX_CACHE_DIR`: JAX's persistent compilation cache and the
traced kernels), a folder of its own under the temp dir unless the variable is set.  From the
start of the run a thread compiles the programs the tests will need (`_compile_ahead`), so
that compiling uses the second core while a test's own work leaves it idle.
"""

from __future__ import annotations

import codecs
import contextlib
import io
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")
CACHE = Path(os.environ.setdefault("LMJX_CACHE_DIR", os.path.join(tempfile.gettempdir(), f"lmjx-test-{os.getuid()}")))
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(CACHE / "jax"))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")
# On a GPU machine JAX and MuJoCo Warp share the GPU: JAX must not take most of it up front.
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

# The small case-2 map every planning and map-file test shares (tests/golden.py's arguments),
# built in chunks of 1000 edges.
SMALL_MAP = ("--failure", "case2", "--edges", "3000", "--cell", "0.05", "--seed", "1", "--chunk", "1000")
# The planner's tests: a map dense enough that edges over a target pass the transit and
# contact tests (2 cm cells as make run's; the launch size of the shared small map).
PLAN_MAP = ("--failure", "case2", "--edges", "6000", "--seed", "0", "--chunk", "1000")
# A four-joint arm whose kernels compile several times faster than the Panda's and whose maps
# take a fraction of the work: the tests that build maps again and again (other chunkings,
# kills and resumes, several host devices or processes) and the atlas tests build its.
TINY_ARM = Path(__file__).parent / "data" / "tiny_arm.xml"
TINY_MAP = ("--robot", TINY_ARM, "--failure", "J4=0.5", "--edges", "1200", "--cell", "0.05", "--seed", "3",
            "--chunk", "400")  # fmt: skip
# A small atlas of the four-joint test arm: 6 pairs x 2 x 2 angles, 4 x 5 cells, 4 attempts of 2
# restarts (the atlas tests and the docs' example read it).
TINY_ATLAS = ("--robot", TINY_ARM, "--joints", "2", "--angles", "2", "--cell", "0.2", "--attempts", "4", "--restarts",
              "2", "--iterations", "16", "--group", "3", "--chunk", "128")  # fmt: skip


def benchmark_module(name: str):
    """A script of benchmarks/ imported as a module (the folder is not a package)."""
    import importlib

    sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.pop(0)


def random_configs(robot, n: int, seed: int) -> np.ndarray:
    return robot.lower + np.random.default_rng(seed).random((n, robot.nq)) * (robot.upper - robot.lower)


# ------------------------------------------------------------------------------ commands


@dataclass
class Run:
    """What a command did: its exit status and what it printed."""

    returncode: int
    stdout: str
    stderr: str

    def ok(self) -> Run:
        assert self.returncode == 0, self.stderr[-3000:]
        return self

    def one_line_error(self, message: str) -> None:
        """Exit status 2, one line on stderr that holds `message`, nothing on stdout."""
        lines = self.stderr.strip().splitlines()
        assert self.returncode == 2 and len(lines) == 1 and message in lines[0], (self.returncode, self.stderr)
        assert "Traceback" not in self.stderr and self.stdout == ""


@contextlib.contextmanager
def _environment(env: dict[str, str] | None) -> Iterator[None]:
    old = {k: os.environ.get(k) for k in env or {}}
    os.environ.update(env or {})
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def cli(*args: object, env: dict[str, str] | None = None) -> Run:
    """`lmjx ARGS` in this process: the kernels it compiles are the tests' own (and theirs
    its).  An exception a command lets through fails the test with its traceback."""
    from lmjx.cli import main

    out, err = io.StringIO(), io.StringIO()
    handler = signal.getsignal(signal.SIGINT)
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), _environment(env):
        try:
            code = main([str(a) for a in args])
        except SystemExit as e:  # argparse: --help, usage errors
            code = e.code if isinstance(e.code, int) else int(e.code is not None)
        finally:
            signal.signal(signal.SIGINT, handler)
    return Run(code, out.getvalue(), err.getvalue())


def cli_process(*args: object, env: dict[str, str] | None = None) -> subprocess.Popen:
    """`lmjx ARGS` in a process of its own (started, not waited for)."""
    return subprocess.Popen(
        [sys.executable, "-m", "lmjx.cli", *(str(a) for a in args)],
        env={**os.environ, "JAX_PLATFORMS": "cpu", **(env or {})},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


class Collected:
    """What a process writes to one of its pipes, collected by a thread as it comes (so a
    test can wait for a line while the process runs); `text` so far."""

    def __init__(self, pipe) -> None:
        self.parts: list[str] = []
        self.thread = threading.Thread(target=self._read, args=(pipe,), daemon=True)
        self.thread.start()

    def _read(self, pipe) -> None:
        decode = codecs.getincrementaldecoder("utf-8")(errors="replace")
        for piece in iter(lambda: os.read(pipe.fileno(), 4096), b""):
            self.parts.append(decode.decode(piece))

    @property
    def text(self) -> str:
        return "".join(self.parts)

    def finish(self) -> str:
        self.thread.join(timeout=60)
        return self.text


def finish(p: subprocess.Popen, timeout: float = 600) -> Run:
    out, err = p.communicate(timeout=timeout)
    return Run(p.returncode, out, err)


def wait_for(condition: Callable[[], bool], p: subprocess.Popen, what: str, timeout: float = 300) -> None:
    """Poll until `condition` holds; fail if the process `p` ends first or time runs out."""
    t0 = time.monotonic()
    while not condition():
        assert p.poll() is None, f"the process ended before {what}: {p.communicate()[1][-2000:]}"
        assert time.monotonic() - t0 < timeout, f"no {what} after {timeout} s"
        time.sleep(0.02)


# ------------------------------------------------------------------------------ robots and maps


@pytest.fixture(scope="session")
def robot():
    from lmjx.model.robot import load_robot  # imported here: tests/test_plain_reader.py imports no lmjx

    return load_robot()


@pytest.fixture(scope="session")
def ur5e():
    from lmjx.model.robot import load_robot

    return load_robot("ur5e")


@pytest.fixture(scope="session", params=["panda", "ur5e"])
def arm(request):
    """Each shipped robot in turn, for the kernel tests that must hold for any arm."""
    from lmjx.model.robot import load_robot

    return load_robot(request.param)


class Maps:
    """Reach-Ability maps of one robot and config, made on first use and kept for the run."""

    def __init__(self, robot, config) -> None:
        self.robot, self.config, self.maps = robot, config, {}

    def __getitem__(self, spec: str):
        from lmjx.reach.reachability import reach_map

        if spec not in self.maps:
            self.maps[spec] = reach_map(spec, self.config, robot=self.robot)
        return self.maps[spec]


@pytest.fixture(scope="session")
def coarse(robot) -> Maps:
    """The Panda's maps of 5 cm cells (none, case1, case2, ...): the default map's IK
    program per failure (the same launch size), less work."""
    from lmjx.reach.reachability import ReachConfig

    return Maps(robot, ReachConfig(cell=0.05))


@pytest.fixture(scope="session")
def table1(robot) -> Maps:
    """The Panda's default maps (Table I)."""
    from lmjx.reach.reachability import ReachConfig

    return Maps(robot, ReachConfig())


@pytest.fixture(scope="session")
def table1_ur5e(ur5e) -> Maps:
    """The UR5e's default maps (its Table I)."""
    from lmjx.reach.reachability import reach_config

    return Maps(ur5e, reach_config(ur5e))


def ik_batch(robot, failure, settings=None, chunk: int | None = None):
    """An IKBatch on the Reach-Ability map's program for `failure` (its sites: the TCP, then
    the default interaction points; its settings and launch size): compiled once per run."""
    from lmjx.reach.ik_batch import IKBatch, default_chunk
    from lmjx.reach.reachability import attempt_plan, reach_config

    config = reach_config(robot)
    sites = attempt_plan(robot, config)[0]
    return IKBatch(robot, failure, sites, settings or config.ik_settings(), chunk or default_chunk())


def built_once(tmp_path_factory: pytest.TempPathFactory, name: str, file: str, build: Callable[[Path], None]) -> Path:
    """The file `file` that `build(path)` makes, made once for the whole run: under pytest-xdist
    the first worker to ask builds it in a folder the run's workers share (the run's base
    temp folder, removed with it) while the others wait, then every worker reads the same
    file (the fixtures' maps are read, never written); alone, in a folder of its own."""
    if "PYTEST_XDIST_WORKER" not in os.environ:
        path = tmp_path_factory.mktemp(name) / file
        build(path)
        return path
    folder = tmp_path_factory.getbasetemp().parent / "shared" / name
    folder.mkdir(parents=True, exist_ok=True)
    from lmjx.runtime.compilelock import held

    with held(folder.parent / f"{name}.lock"):
        if not (folder / ".built").exists():
            build(folder / file)
            (folder / ".built").touch()
    return folder / file


@pytest.fixture(scope="session")
def tiny_map(tmp_path_factory) -> Path:
    """The four-joint test arm's map (TINY_MAP), built by `lmjx build-map` once for the run."""
    return built_once(tmp_path_factory, "tiny_map", "tiny.h5", lambda p: cli("build-map", *TINY_MAP, "--out", p).ok())


@pytest.fixture(scope="session")
def small_map(tmp_path_factory) -> Path:
    """The shared case-2 map (SMALL_MAP), built by `lmjx build-map` once for the run with its
    threads sampled (LMJX_THREAD_PROFILE: threads.json beside it)."""

    def build(path: Path) -> None:
        profile = {"LMJX_THREAD_PROFILE": str(path.with_name("threads.json"))}
        cli("build-map", *SMALL_MAP, "--out", path, env=profile).ok()

    return built_once(tmp_path_factory, "small_map", "case2.h5", build)


@pytest.fixture(scope="session")
def tiny_atlas(tmp_path_factory) -> Path:
    """The four-joint test arm's small atlas (TINY_ATLAS), by `lmjx atlas` on one device in
    this process."""
    path = tmp_path_factory.mktemp("atlas") / "single.h5"
    cli("atlas", *TINY_ATLAS, "--no-shard", "--out", path, "--json").ok()
    return path


@contextlib.contextmanager
def _shared_reach(maps: Maps, spec: str) -> Iterator[list[bool]]:
    """Within: a build's reach map of failure `spec` with `maps`' robot and config is the run's
    own `maps[spec]` (computed once for the run: the map is deterministic) instead of a second
    computation of the same map; any other reach map is computed as usual.  Yields a list that
    holds True once the shared map was used."""
    import lmjx.edges.stream

    real, used = lmjx.edges.stream.reach_map, []

    def reach_map(failure, config=None, robot=None, progress=False):
        shared = maps[spec]
        if config == maps.config and getattr(robot, "key", None) == maps.robot.key and failure == shared.failure:
            used.append(True)
            return shared
        return real(failure, config, robot=robot, progress=progress)

    lmjx.edges.stream.reach_map = reach_map
    try:
        yield used
    finally:
        lmjx.edges.stream.reach_map = real


@pytest.fixture(scope="session")
def plan_map(tmp_path_factory, table1: Maps) -> Path:
    """The planner tests' case-2 map (PLAN_MAP), built by `lmjx build-map` once for the run on
    the Panda's default case-2 reach map of `table1` (the same map: computed once)."""

    def build(path: Path) -> None:
        with _shared_reach(table1, "case2") as used:
            cli("build-map", *PLAN_MAP, "--out", path).ok()
        assert used, "PLAN_MAP's reach map is no longer table1's case2 map"

    return built_once(tmp_path_factory, "plan_map", "case2.h5", build)


def _programs_ahead() -> list[Callable[[], None]]:
    """What `_compile_ahead` compiles, in about the order the tests first need it: the
    programs (ChunkedKernel keys) the tests and the commands they run build themselves."""
    from lmjx.edges.sampling import rollout_kernel
    from lmjx.mapfile.bundle import BundleConfig
    from lmjx.mapfile.pushsamples import compile_program
    from lmjx.model.failure import parse_failure
    from lmjx.model.robot import load_robot
    from lmjx.reach.reachability import attempt_plan, reach_config
    from lmjx.sim.sceneboxes import clearance_kernel

    panda, ur, tiny = load_robot("panda"), load_robot("ur5e"), load_robot(str(TINY_ARM))
    config = BundleConfig()

    def ik(robot, spec):
        return lambda: ik_batch(robot, parse_failure(spec, robot)).compile()

    def rollout(robot, spec, with_tcp):
        sites = attempt_plan(robot, reach_config(robot))[0]
        return lambda: rollout_kernel(robot, parse_failure(spec, robot), config, config.kernel_chunk(),
                                      valid_only=False, sites=sites if with_tcp else sites[1:]).compile()  # fmt: skip

    return [
        ik(tiny, "J4=0.5"),
        rollout(tiny, "J4=0.5", False),
        lambda: compile_program(tiny),  # (every map built stores its push counts)
        ik(panda, "case1"),
        rollout(panda, "case1", True),
        ik(panda, "case2"),
        rollout(panda, "case2", False),
        lambda: compile_program(panda),
        ik(panda, "none"),
        rollout(panda, "none", True),
        lambda: clearance_kernel(panda).compile(),
        ik(ur, "case1"),
        ik(ur, "none"),
        ik(ur, "case2"),
    ]


@pytest.fixture(scope="session", autouse=True)
def _compile_ahead(request: pytest.FixtureRequest):
    """Compile, in a thread of its own from the start of the run, the programs the tests
    will need: a test then finds its program compiled, or waits for the compilation under
    way (a program is compiled once, whoever asks first).  Only for a run of several test
    files (a run of one test compiles only what it needs); LMJX_TEST_AHEAD=1 forces it,
    LMJX_TEST_AHEAD=0 turns it off."""
    modules = {item.module.__name__ for item in request.session.items if hasattr(item, "module")}
    ahead = os.environ.get("LMJX_TEST_AHEAD", "")
    if ahead == "0" or (ahead != "1" and len(modules) < 4):
        yield
        return

    # under pytest-xdist each worker compiles its share of the list first (worker k of n: every
    # n-th program from the k-th), then the rest, which the other workers have compiled into the
    # run's compile cache meanwhile or are compiling (lmjx.runtime.compilelock: then it waits
    # for theirs and loads it): each program is compiled once for the run
    k = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw") or 0)
    n = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))

    def run() -> None:
        programs = _programs_ahead()
        for compile_one in programs[k % n :: n] + [p for i, p in enumerate(programs) if i % n != k % n]:
            with contextlib.suppress(Exception):  # the test that needs the program meets the error itself
                compile_one()

    thread = threading.Thread(target=run, name="lmjx-compile-ahead", daemon=True)
    thread.start()
    yield
    thread.join()


# ------------------------------------------------------------------------------ the longest files first

# the files that take longest (a cold compile cache, two workers: `make test`, which keeps this
# order: --no-loadscope-reorder), first, so that pytest-xdist's workers (a file each, `--dist
# loadfile`; each starts with two files, then takes the next as it runs short) do not end with one
# of them alone; the planner's files apart, the second starting once the first has built the maps
# both read (`built_once`), the files without those maps between
LONGEST_FIRST = ("test_planning.py", "test_robot_import.py", "test_reach.py", "test_edgestream.py",
                 "test_planning_quality.py", "test_cli.py", "test_scenes.py", "test_bench_ik.py",
                 "test_docs.py")  # fmt: skip


def pytest_collection_modifyitems(config, items):
    """The test files in LONGEST_FIRST order, then the others as collected."""
    rank = {name: k for k, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


# ------------------------------------------------------------------------------ what was skipped

# how to run what a machine skips, by a word of the skip's reason
HOW_TO_RUN = {
    "chromium": "install Debian's Chromium (apt install chromium) and run make test again",
    "CUDA": "run the suite on a machine with an NVIDIA GPU, JAX's CUDA plugin and MuJoCo Warp "
    "(pip install --no-deps -r requirements.lock -r requirements-gpu.lock)",
    "GPU": "run the suite on a machine with an NVIDIA GPU (see README.md's GPU set-up)",
    "OSMesa": "(this machine has OSMesa: the test of a machine without it cannot run here)",
    "git": "run the suite in a git checkout",
}


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """After the run: each skipped test, why, and how to get it to run."""
    skipped = terminalreporter.stats.get("skipped", [])
    if not skipped:
        return
    terminalreporter.write_sep("-", f"{len(skipped)} skipped, and how to run them")
    for report in skipped:
        reason = str(report.longrepr[2]) if isinstance(report.longrepr, tuple) else str(report.longrepr)
        reason = reason.removeprefix("Skipped: ")
        how = next((v for k, v in HOW_TO_RUN.items() if k.lower() in reason.lower()), "")
        terminalreporter.write_line(f"{report.nodeid}: {reason}" + (f"; to run it: {how}" if how else ""))
