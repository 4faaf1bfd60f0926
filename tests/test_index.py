"""The whole-arm spatial index on the device (`lmjx.edges.index`, `kernels.index`) against
the numpy reference (`reference_index`), pair for pair: on the states of the shared maps of
two failures, on edges split over several maps of marks, on blocks that need more than one pass,
and on items built to sit exactly on a decision's threshold (settled on the host).

The crafted items use the shared case-2 map's grid size (20 x 24 cells of 5 cm), whose
programs its build compiles: only the grid's corner, which is an input, is moved.  On a GPU
(JAX_PLATFORMS=cuda) the same tests run there, and one more builds a larger map."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from conftest import TINY_ARM, cli
from reference_index import reference_pairs, reference_pairs_of_ends

from lmjx.edges.index import Grid, arm_index, arm_index_pairs, index_totals
from lmjx.mapfile.read import load_map
from lmjx.model.robot import load_robot
from lmjx.runtime.devices import index_devices

SMALL_GRID = (0.05, 20, 24)  # the shared case-2 map's cell and size (conftest.SMALL_MAP)
HEIGHT = 0.05  # the maps' index height (BundleConfig.index_height)


def _map(path, robot):
    m = load_map(path, robot)
    return m.reach, np.asarray(m.edges.q), np.asarray(m.edges.length), m.edges


def _assert_same(got, want) -> None:
    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1]), (len(got[0]), len(want[0]))
    assert got[0].dtype == want[0].dtype == np.int32 and got[1].dtype == want[1].dtype == np.int32


@pytest.mark.parametrize("which", ["small_map", "tiny_map"], ids=["panda case2", "tiny arm J4=0.5"])
def test_pairs_equal_the_reference_on_a_maps_states(robot, request, which):
    """Every pair, in order, on all the states of a built map; and the map's own index (built
    through the packing path) is the same."""
    path = request.getfixturevalue(which)
    if which == "tiny_map":
        robot = load_robot(str(TINY_ARM))
    reach, q, length, edges = _map(path, robot)
    before = index_totals()
    got = arm_index_pairs(reach, robot, q, length, HEIGHT)
    want = reference_pairs(reach, robot, q, length, HEIGHT)
    _assert_same(got, want)
    assert len(want[0]) > 1000
    done = index_totals(before)
    assert done["batches"] == 1 and done["states"] == len(q) and done["pairs"] == len(want[0])
    cells = np.repeat(np.arange(len(edges.index_offset) - 1), np.diff(edges.index_offset))
    assert np.array_equal(cells, want[0]) and np.array_equal(edges.index_edges, want[1])


def test_edges_over_several_maps_of_marks(robot, small_map):
    """More edges than one map of marks holds: the groups' pairs merged in (cell, edge) order."""
    reach, q, length, _ = _map(small_map, robot)
    index = arm_index(robot, *reversed(reach.labels.shape), reach.config.cell)
    n = index.shape.edges + 300
    # three states of each map edge in turn (the map's edges, tiled)
    first = np.concatenate([[0], np.cumsum(length)[:-1]])
    rows = (first[np.arange(n) % len(length)][:, None] + np.arange(3)[None]).ravel()
    q3, length3 = q[rows], np.full(n, 3, np.int32)
    got = arm_index_pairs(reach, robot, q3, length3, HEIGHT)
    want = reference_pairs(reach, robot, q3, length3, HEIGHT)
    _assert_same(got, want)
    assert want[1].max() >= index.shape.edges  # pairs in the second map of marks


def _far(n: int, nc: int) -> tuple[np.ndarray, np.ndarray]:
    """Capsule ends of n states with every capsule far above the table, off the grid."""
    a = np.full((n, nc, 3), 10.0, np.float32)
    a[..., 2] = 1.0
    return a, a.copy()


def _index_of_ends(robot, grid: Grid, a, b, length, height=HEIGHT):
    index = arm_index(robot, grid.nx, grid.ny, grid.cell)
    before = index_totals()
    got = index.pairs_of_ends(grid, a, b, length, height)
    want = reference_pairs_of_ends((grid.x0, grid.y0, grid.cell, grid.nx, grid.ny), robot, a, b, length, height)
    _assert_same(got, want)
    return got, index_totals(before), index


def test_items_on_a_threshold_are_settled_on_the_host(robot):
    """Items whose decisions sit exactly on their thresholds (a sample on a cell's boundary,
    a stretch of a whole number of half cells ending where the capsule crosses the height, a
    sample exactly the radius from a square) go to the host, and the pairs are the
    reference's."""
    cell, nx, ny = SMALL_GRID
    caps = np.asarray(robot.arm.table_caps)
    r = np.asarray(robot.arm.cap_r, np.float64)
    big, small = int(caps[np.argmax(r[caps])]), int(caps[np.argmin(r[caps])])
    a, b = _far(3, len(r))
    # (coordinates of float32 exactly; the grid's corner, an input, placed against them)
    # 1. a vertical capsule on the table: its one sample on a row boundary, and exactly its
    #    radius from the square of the cell two columns to its left
    a[0, big] = b[0, big] = (0.5, 0.25, 0.0)
    b[0, big, 2] = 0.25
    x0 = 0.5 - r[big] - 3 * cell  # that square's right edge: x0 + 3 cells
    y0 = 0.25 - 5 * cell
    # 2. a slanted capsule crossing the height where its low stretch is 4 half cells long
    a[1, small] = (0.625, 0.375, 0.0)
    b[1, small] = (0.875, 0.5, 0.375)
    z = a[1, small, 2] - robot.arm.table_z - r[small], b[1, small, 2] - robot.arm.table_z - r[small]
    along = np.hypot(*(b[1, small, :2].astype(np.float64) - a[1, small, :2]))
    height = float(z[0] + (z[1] - z[0]) * (4 * (cell / 2)) / along)
    # 3. a capsule lying on the table along the row boundary
    a[2, small] = (0.75, 0.25, 0.0)
    b[2, small] = (0.875, 0.25, 0.0)
    grid = Grid(x0, y0, cell, nx, ny)
    got, done, _ = _index_of_ends(robot, grid, a, b, np.array([1, 1, 1]), height)
    assert done["borderline"] >= 3 and done["host_blocks"] == 0
    assert len(got[0]) > 10


@pytest.mark.parametrize("wider", [False, True], ids=["alone", "beside a wider capsule"])
def test_the_neighbourhood_of_a_settled_item_is_its_blocks(robot, wider):
    """The cells around a sample that the reference looks at: as many as the widest capsule
    low among the 65,536 states around needs, found also where that capsule's state lies in
    no pass of the batch's (here: the batch indexes the first edge only)."""
    from kernels.index import params_words
    from lmjx.edges.index import NEIGHBOURHOOD_STATES, _params, _Run, neighbourhood

    cell, nx, ny = SMALL_GRID
    index = arm_index(robot, nx, ny, cell)
    index.compile()
    r = np.asarray(robot.arm.cap_r, np.float64)
    caps = list(index.shape.caps)
    small, big = int(np.argmin(r[caps])), int(np.argmax(r[caps]))
    n = min(3 * index.shape.states, NEIGHBOURHOOD_STATES)  # the wide capsule's state: the last, in another pass
    a, b = _far(n, len(r))
    a[0, caps[small]] = b[0, caps[small]] = (0.5, 0.25, 0.0)
    if wider:
        a[n - 1, caps[big]] = b[n - 1, caps[big]] = (1.0, 0.5, 0.0)
    grid = Grid(0.1, -0.6, cell, nx, ny)
    words = index._put(params_words(_params(grid, HEIGHT, robot.arm.table_z)))
    starts = np.array([0, 10, n])
    run = _Run(index, grid, HEIGHT, n, starts, words, lambda rows: (index._put(a[rows]), index._put(b[rows])))
    run.group(0, 1)
    assert set(run.low_caps) == {0}
    want = neighbourhood(r[caps[big if wider else small]], cell)
    assert run._block_reach(5, small) == want
    assert want == (2 if wider else 1)


def test_a_block_of_many_borderline_items_is_settled_whole(robot):
    """More borderline items in a block than a pass reports: the block is settled on the host."""
    cell, nx, ny = SMALL_GRID
    caps = np.asarray(robot.arm.table_caps)
    a, b = _far(200, len(robot.arm.cap_r))
    a[:, caps[0]] = b[:, caps[0]] = (0.5, 0.25, 0.0)
    b[:, caps[0], 2] = 0.25
    a[:, caps[0], 0] += np.linspace(0, 0.3, 200).astype(np.float32)  # other places, all on a row boundary
    b[:, caps[0], 0] = a[:, caps[0], 0]
    grid = Grid(0.1, 0.25 - 5 * cell, cell, nx, ny)
    _, done, index = _index_of_ends(robot, grid, a, b, np.full(10, 20))
    assert done["host_blocks"] == 1 and done["borderline"] == 200 > index.shape.flags


def test_blocks_of_more_items_than_a_pass_holds(robot):
    """Every table capsule of every state low and spread over the grid: more candidates and
    samples than one pass's slots, taken in several passes."""
    cell, nx, ny = SMALL_GRID
    index = arm_index(robot, nx, ny, cell)
    caps = np.asarray(robot.arm.table_caps)
    n = 2 * -(-index.shape.items // len(caps))
    rng = np.random.default_rng(5)
    a, b = _far(n, len(robot.arm.cap_r))
    start = rng.uniform((0.1, -0.6, 0.0), (1.1, 0.6, 0.03), (n, len(caps), 3))
    a[:, caps] = start
    b[:, caps] = start + rng.uniform((-0.1, -0.1, 0.0), (0.1, 0.1, 0.2), (n, len(caps), 3))
    length = np.full(n // 8, 8)
    length[-1] += n - length.sum()
    _, done, _ = _index_of_ends(robot, Grid(0.1, -0.6, cell, nx, ny), a, b, length)
    assert done["extra_passes"] >= 1


@pytest.mark.skipif(jax.default_backend() == "cpu", reason="the device's own arithmetic: on a GPU")
def test_a_larger_map_on_the_gpu(robot, tmp_path):
    """On the GPU: a 20,000-edge case-2 map's index, as built and recomputed on each of the
    devices the index runs on, is the reference's, pair for pair."""
    path = tmp_path / "case2.h5"
    cli("build-map", "--failure", "case2", "--edges", "20000", "--seed", "0", "--out", path).ok()
    reach, q, length, edges = _map(path, robot)
    want = reference_pairs(reach, robot, q, length, HEIGHT)
    grid = Grid.of(reach)
    for device in index_devices():
        _assert_same(arm_index(robot, grid.nx, grid.ny, grid.cell, device).pairs(grid, q, length, HEIGHT), want)
    cells = np.repeat(np.arange(len(edges.index_offset) - 1), np.diff(edges.index_offset))
    assert np.array_equal(cells, want[0]) and np.array_equal(edges.index_edges, want[1])
