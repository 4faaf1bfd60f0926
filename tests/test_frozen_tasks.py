"""The paper and hard task sets are frozen: their geometry and their layouts, exactly as the
evaluations ran them.  Every number below was read from `lmjx.sim.scenarios` and is asserted
to 1e-12 m (rad): goal regions, the target's start, the movable and fixed obstacles, the
jitters, the budgets, the paper set's distances and directions, the seeds' derivation, and
`sample_layout` for a few seeds (none an evaluation's).  A change to any of them is a new task
set, not a fix: it breaks the comparison with every run recorded."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lmjx.evaluation.evaluate import trial_seed
from lmjx.sim.scenarios import PAPER_BUDGET, PAPER_TASKS, PaperTask, resolve_task, sample_layout, scenario

TOL = 1e-12
TARGET = (0.025, 0.025, 0.025)
# (task set, scenario) -> goal centre, goal half size, the target's nominal start (x, y)
GOALS = {
    ("paper", 1): ((0.4, 0.57), (0.08, 0.08), (0.4, 0.42)),
    ("paper", 2): ((0.47, 0.35), (0.08, 0.08), (0.47, 0.18)),
    ("paper", 3): ((0.53, 0.44), (0.08, 0.08), (0.4, 0.44)),
    ("hard", 1): ((0.46, 0.14), (0.06, 0.06), (0.4, 0.42)),
    ("hard", 2): ((0.47, 0.18), (0.06, 0.06), (0.47, 0.4)),
    ("hard", 3): ((0.46, 0.14), (0.06, 0.06), (0.4, 0.44)),
}
# scenario -> movable obstacles: name, half extents, x, y, yaw, mass (both task sets)
OBSTACLES = {
    1: [
        ("obstacle1", (0.03, 0.03, 0.03), 0.475, 0.43, 0.0, 0.15),
        ("obstacle2", (0.025, 0.04, 0.03), 0.33, 0.44, 0.0, 0.15),
        ("obstacle3", (0.04, 0.025, 0.03), 0.41, 0.5, 0.0, 0.15),
    ],
    2: [],
    3: [
        ("obstacle1", (0.025, 0.025, 0.025), 0.31, 0.5, 0.0, 0.08),
        ("obstacle2", (0.03, 0.02, 0.025), 0.4, 0.535, 0.4, 0.08),
        ("obstacle3", (0.02, 0.03, 0.025), 0.5, 0.5, 0.8, 0.08),
        ("obstacle4", (0.025, 0.025, 0.025), 0.31, 0.39, 1.2, 0.08),
        ("obstacle5", (0.03, 0.02, 0.025), 0.5, 0.4, 0.0, 0.08),
        ("obstacle6", (0.02, 0.03, 0.025), 0.35, 0.31, 0.4, 0.08),
        ("obstacle7", (0.025, 0.025, 0.025), 0.46, 0.3, 0.8, 0.08),
        ("obstacle8", (0.03, 0.02, 0.025), 0.57, 0.31, 1.2, 0.08),
        ("obstacle9", (0.02, 0.03, 0.025), 0.3, 0.22, 0.0, 0.08),
        ("obstacle10", (0.025, 0.025, 0.025), 0.58, 0.21, 0.4, 0.08),
        ("obstacle11", (0.03, 0.02, 0.025), 0.38, 0.1, 0.8, 0.08),
    ],
}
# the tunnel's fixed obstacles: name, half extents, x, y, yaw, centre height (None: on the table)
TUNNEL = [
    ("wall_near", (0.085, 0.005, 0.14), 0.205, 0.26, 0.0, None),
    ("wall_far", (0.105, 0.005, 0.14), 0.755, 0.26, 0.0, None),
    ("roof", (0.18, 0.005, 0.015), 0.47, 0.26, 0.0, 0.265),
]
# (scenario, task set, seed) -> every movable object's initial (x, y, yaw), target first; the
# layouts of scenarios 1 and 3 are the same in both task sets (asserted below)
LAYOUTS = {
    (1, "paper", 0): [
        (0.40461540445925015, 0.4153471021704753, -0.18974981738834618),
        (0.4948883974315685, 0.4492334135510492, 0.11517393690092248),
        (0.3374216793792278, 0.4460183710507126, 0.01318424768737747),
        (0.41753786922283764, 0.4955568569591641, -0.09867422470934306),
    ],
    (1, "paper", 424242): [
        (0.3989838741765281, 0.4042035047800836, -0.18920890188711403),
        (0.4665285331970815, 0.41962195775164207, 0.24086002418625452),
        (0.3384827705110505, 0.4413672185783744, -0.0920696880344668),
        (0.395094207414129, 0.5167984109849058, 0.20634446786255445),
    ],
    (2, "paper", 0): [
        (0.47547846749285816, 0.1707914685505548, -0.23869376755317878),
    ],
    (2, "paper", 424242): [
        (0.46898387417652804, 0.1642035047800836, -0.11012906843794107),
    ],
    (2, "hard", 0): [
        (0.47547846749285816, 0.39079146855055485, -0.23869376755317878),
    ],
    (2, "hard", 424242): [
        (0.46898387417652804, 0.38420350478008364, -0.11012906843794107),
    ],
    (3, "paper", 0): [
        (0.4054784674928582, 0.43079146855055483, 0.06000025797025199),
        (0.2916389409574478, 0.48066110542114115, -0.06048767178382061),
        (0.4125308095680109, 0.5515102230911089, 0.6585491666103898),
        (0.5042654310306872, 0.50917986243936, 1.0500343761636397),
        (0.3117449996586169, 0.4074028969515107, 1.2964818319299614),
        (0.5126341421648613, 0.38010954000680597, 0.07823882365926449),
        (0.36429617106350276, 0.29134342301221855, 0.49799229989688887),
        (0.4691862178571978, 0.28702622482410234, 0.742239140469134),
        (0.5845271568939954, 0.3116584488099637, 1.010250182611654),
        (0.2919884756214954, 0.21690748884790634, 0.11517393690092248),
        (0.5611327868458185, 0.19497133105998254, 0.4131842476873775),
        (0.38682497658774523, 0.10588758046297, 0.701325775290657),
    ],
    (3, "paper", 424242): [
        (0.3989838741765281, 0.4242035047800836, -0.12594314549506397),
        (0.30152853319708145, 0.4896219577516421, 0.05993103957875173),
        (0.40848277051105053, 0.5363672185783744, 0.3191183116411462),
        (0.48509420741412895, 0.5167984109849058, 0.5671902625478333),
        (0.2954454690856066, 0.4085276941681734, 1.0673359323185312),
        (0.492917716305041, 0.41587265137404267, 0.08934310696250441),
        (0.35305450778495195, 0.30235279585311975, 0.39873874463944664),
        (0.46828118943084707, 0.3088935608126582, 0.5440824838802647),
        (0.5502054642197238, 0.30490728704047193, 1.118090455933126),
        (0.28213797680603186, 0.2086057788033511, 0.02500275318006684),
        (0.5625514630821878, 0.19099884715501467, 0.43062818307585105),
        (0.36237178808242715, 0.11185804477236794, 0.542282011066781),
    ],
}


def close(a, b) -> bool:
    return np.allclose(np.asarray(a, float), np.asarray(b, float), rtol=0.0, atol=TOL)


@pytest.mark.parametrize("tasks, number", sorted(GOALS))
def test_the_task_sets_geometry_is_frozen(tasks: str, number: int) -> None:
    sc = scenario(number, tasks=tasks)
    centre, half, start = GOALS[tasks, number]
    assert sc.tasks == tasks and sc.number == number and sc.budget == 30
    assert close(sc.goal_center, centre) and close(sc.goal_half, half), (sc.goal_center, sc.goal_half)
    t = sc.target
    assert close((t.x, t.y, t.yaw), (*start, 0.0)) and t.half == TARGET and t.mass == 0.1 and t.movable
    assert sc.jitter == 0.02 and sc.yaw_jitter == 0.26
    got = [(b.name, b.half, b.x, b.y, b.yaw, b.mass) for b in sc.obstacles]
    assert [g[0] for g in got] == [w[0] for w in OBSTACLES[number]] and all(b.movable for b in sc.obstacles)
    assert close([(*g[1], *g[2:]) for g in got], [(*w[1], *w[2:]) for w in OBSTACLES[number]])
    fixed = [(b.name, b.half, b.x, b.y, b.yaw, b.z) for b in sc.fixed]
    want = TUNNEL if number == 2 else []
    assert [f[0] for f in fixed] == [w[0] for w in want] and not any(b.movable for b in sc.fixed)
    for f, w in zip(fixed, want, strict=True):
        assert close((*f[1], *f[2:5]), (*w[1], *w[2:5])) and (f[5] is None) == (w[5] is None)
        assert f[5] is None or abs(f[5] - w[5]) <= TOL


def test_the_paper_sets_distances_directions_and_budget_are_frozen() -> None:
    assert PAPER_BUDGET == 30
    want = {1: PaperTask(0.15, 0.08, 90.0), 2: PaperTask(0.17, 0.08, 90.0), 3: PaperTask(0.13, 0.08, 0.0)}
    assert want == PAPER_TASKS
    for number, task in PAPER_TASKS.items():
        sc = scenario(number, tasks="paper")
        d = np.subtract(sc.goal_center, (sc.target.x, sc.target.y))
        assert abs(float(np.hypot(*d)) - task.distance) <= TOL
        assert abs(math.degrees(math.atan2(d[1], d[0])) - task.angle) <= 1e-9
    # the tunnel reversed: the paper task starts where the hard task's goal is
    assert close(GOALS["paper", 2][2], GOALS["hard", 2][0])


@pytest.mark.parametrize("key", sorted(LAYOUTS))
def test_the_layouts_are_frozen(key: tuple) -> None:
    number, tasks, seed = key
    sc = scenario(number, tasks=tasks)
    assert close(sample_layout(sc, seed).poses, LAYOUTS[key])
    assert close(resolve_task(number, _panda(), tasks).layout(seed).poses, LAYOUTS[key])
    if number != 2:  # the paper set's scenarios 1 and 3 keep the hard set's layouts
        assert close(sample_layout(scenario(number, tasks="hard"), seed).poses, LAYOUTS[key])


def test_the_trial_seeds_derive_from_the_base() -> None:
    """A trial's seed: base x 100,000 + scenario x 1,000 + trial (the registered replicate's
    seeds, docs/evaluation/REPLICATE.md, rest on it)."""
    assert trial_seed(0, 1, 0) == 1000 and trial_seed(0, 3, 14) == 3014
    assert trial_seed(31, 1, 0) == 3_101_000 and trial_seed(31, 2, 14) == 3_102_014


def _panda():
    from lmjx.model.robot import load_robot

    return load_robot("panda")
