"""Transits that search: a lazy roadmap over the map's own edge starts, for the actions whose
straight transit and whose way through the park pose are both blocked.

After a push the arm often stands among objects the push moved, and in the tunnel it must
enter an opening: one or two straight lines in joint space then find no way to an edge's
start.  The roadmap's nodes are the starts of `NODES` edges of the map (seeded: the same
nodes for the same map), configurations the arm reaches low over the table, free of the
table and of itself, plus the failure's park pose; each node is linked to its `K` nearest
(in transit time: the largest joint motion over its speed), and the pieces this leaves
apart joined by their shortest links (`BRIDGES`).  A query finds, for many goals
at once (the starts of the candidate edges), the fastest way from where the arm stands:

1. nodes inside the scene's margins are dropped (one batch); the source is linked to its
   `SOURCE_K` nearest nodes, each goal to its `GOAL_K` nearest; given the way the arm came
   (its trail), its states become nodes too, chained from the source (`_trail_links`);
2. lazily, round after round (at most `ROUNDS`): the shortest paths from the source to
   every goal over the links not yet found blocked (Dijkstra, scipy's csgraph); the links
   on them not yet checked are checked all in one batch (`TransitPlanner.segments`: the
   table, the arm itself, every box of the scene at its margin, at every control step);
   a goal whose path is checked link by link is found;
3. each path found is shortened: every pair of its nodes that a straight line joins is
   tried (one batch), and the fastest chain of those kept.

The links checked are remembered for the scene they were checked in (`set_scene` starts
over).  A goal the roadmap does not reach is not offered.  Nothing here chooses actions.
"""

from __future__ import annotations

import threading
import weakref
from dataclasses import dataclass
from itertools import pairwise
from typing import Any, Protocol

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

NODES = 1500  # edge starts of the map as roadmap nodes
K = 10  # each node linked to its K nearest (transit time)
SOURCE_K = 16  # where the arm stands, linked to its nearest free nodes
BRIDGES = 5  # links joining each separate piece of the roadmap to the rest
GOAL_K = 6  # each goal (an edge's start), linked to its nearest free nodes
TRAIL_K = 4  # each node of the way back (`transits`' trail), linked to its nearest free nodes and trail nodes
TRAIL_GOAL_K = 2  # each goal, linked from its nearest nodes of the way back
ROUNDS = 32  # lazy rounds: shortest paths, then their unchecked links checked
SEED = 0  # which edge starts become nodes


def transit_time(a: np.ndarray, b: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """(..., ) the time of straight transits from a to b (broadcast, (..., nj)): the largest
    joint motion over its speed."""
    return np.max(np.abs(b - a) / speed, axis=-1)


def nearest(points: np.ndarray, nodes: np.ndarray, k: int, speed: np.ndarray, chunk: int = 256) -> tuple:
    """The k nodes nearest each point (transit time): (idx (n, k), time (n, k)), nearest first;
    a point that is also a node (time 0) keeps itself out."""
    k = min(k, len(nodes))
    idx = np.zeros((len(points), k), np.int64)
    dist = np.zeros((len(points), k))
    for s in range(0, len(points), chunk):
        t = transit_time(points[s : s + chunk, None], nodes[None], speed)
        t[t <= 1e-12] = np.inf
        part = np.argpartition(t, k - 1, axis=1)[:, :k]
        pt = np.take_along_axis(t, part, axis=1)
        order = np.argsort(pt, axis=1, kind="stable")
        idx[s : s + chunk] = np.take_along_axis(part, order, axis=1)
        dist[s : s + chunk] = np.take_along_axis(pt, order, axis=1)
    return idx, dist


def _bridged(q: np.ndarray, links: np.ndarray, time: np.ndarray, speed: np.ndarray) -> tuple:
    """The links plus bridges until the roadmap is one piece: the map's starts come in
    clusters (the arm's elbow up or down, its wrist flipped) that nearest neighbours do not
    join; each piece but the largest is linked by its `BRIDGES` shortest links to the rest."""
    while True:
        g = csr_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(len(q), len(q)))
        n, label = connected_components(g, directed=False)
        if n == 1:
            return links, time
        big = np.argmax(np.bincount(label))
        new = []
        for c in range(n):
            if c == big:
                continue
            inside, outside = np.nonzero(label == c)[0], np.nonzero(label != c)[0]
            t = transit_time(q[inside][:, None], q[outside][None], speed)  # (ni, no)
            best = np.argmin(t, axis=1)  # each node's nearest outside the piece
            order = np.argsort(t[np.arange(len(inside)), best], kind="stable")[:BRIDGES]
            for k in order:
                a, b = int(inside[k]), int(outside[best[k]])
                new.append((min(a, b), max(a, b), float(t[k, best[k]])))
        add = np.array([(a, b) for a, b, _ in new], np.int64)
        links = np.concatenate([links, add])
        time = np.concatenate([time, [t for *_, t in new]])
        links, first = np.unique(links, axis=0, return_index=True)
        time = time[first]


class TransitChecks(Protocol):
    """What the roadmap asks of the transit planner (`lmjx.planner.transit.TransitPlanner`):
    its failure's park pose and joint speeds, and its checks against the scene it holds."""

    park: np.ndarray  # (nj,)
    speed: np.ndarray  # (nj,) the transits' joint speeds [rad/s]
    scene_version: Any  # changes whenever the scene does

    def colliding_batch(self, qs: np.ndarray) -> np.ndarray: ...

    def scene_slack(self, qs: np.ndarray) -> np.ndarray: ...

    def segments(self, q0: np.ndarray, q1: np.ndarray) -> list[np.ndarray | None]: ...

    def segment_steps(self, dq: np.ndarray, slow: np.ndarray | bool = False) -> tuple[np.ndarray, np.ndarray]: ...


@dataclass(frozen=True)
class RoadmapGraph:
    """A roadmap's nodes and links (no scene): the same for every transit planner of one map
    and failure, made once (`roadmap_graph`) and shared."""

    q: np.ndarray  # (m, nj) the nodes: edge starts free of the table and the arm, the park pose
    speed: np.ndarray  # (nj,) the transits' joint speeds
    links: np.ndarray  # (L, 2) undirected links (lo, hi)
    link_time: np.ndarray  # (L,) their transit times


_GRAPHS: dict[tuple, tuple[weakref.ref, RoadmapGraph]] = {}
_GRAPHS_LOCK = threading.Lock()


def roadmap_graph(transits: TransitChecks, q_start: np.ndarray) -> RoadmapGraph:
    """The roadmap graph over the edge starts `q_start` (an array a map holds: kept while it
    lives) for the failure of `transits` (its park pose, speeds, and table and arm checks)."""
    # (the checks' kind too: C MuJoCo's and the clearance kernel's are tested to agree, not to the last bit)
    key = (id(q_start), transits.park.tobytes(), np.asarray(transits.speed).tobytes(),
           bool(getattr(transits, "batched", False)))  # fmt: skip
    with _GRAPHS_LOCK:
        held = _GRAPHS.get(key)
        if held is not None and held[0]() is q_start:
            return held[1]
        rng = np.random.default_rng(SEED)
        pick = np.sort(rng.choice(len(q_start), size=min(NODES, len(q_start)), replace=False))
        q = np.concatenate([q_start[pick].astype(np.float64), transits.park[None]])
        q = q[~transits.colliding_batch(q)]
        speed = np.asarray(transits.speed, np.float64)
        idx, dist = nearest(q, q, K, speed)
        a = np.repeat(np.arange(len(q)), idx.shape[1])
        b = idx.ravel()
        keep = np.isfinite(dist.ravel())
        lo, hi = np.minimum(a, b)[keep], np.maximum(a, b)[keep]
        pairs, first = np.unique(np.stack([lo, hi], 1), axis=0, return_index=True)
        links, link_time = _bridged(q, pairs, dist.ravel()[keep][first], speed)
        graph = RoadmapGraph(q, speed, links, link_time)
        _GRAPHS[key] = (weakref.ref(q_start, lambda _: _GRAPHS.pop(key, None)), graph)
        return graph


class Roadmap:
    """The roadmap of one map (its edge starts) for one `TransitPlanner` (its failure, its
    scene): the shared graph (`roadmap_graph`) and what this planner learned of it in its
    scene."""

    def __init__(self, transits: TransitChecks, q_start: np.ndarray) -> None:
        self.t = transits
        graph = roadmap_graph(transits, q_start)
        self.q, self.speed, self.links, self.link_time = graph.q, graph.speed, graph.links, graph.link_time
        self._scene = -1  # the scene version the caches below belong to
        self._free = np.ones(len(self.q), bool)
        self._checked: dict[tuple[int, int], bool] = {}  # undirected roadmap links in this scene

    def _in_scene(self) -> None:
        if self._scene != self.t.scene_version:
            self._scene = self.t.scene_version
            self._free = self.t.scene_slack(self.q) >= 0
            self._checked = {}

    def transits(
        self, source: np.ndarray, goals: np.ndarray, trail: np.ndarray | None = None
    ) -> list[np.ndarray | None]:
        """Joint targets from `source` (nj,) to each goal (n, nj) along the roadmap (see the
        module docstring), or None where it finds no way.

        `trail` (k, nj): the way the arm came, back from `source` (free configurations, the
        nearest first; `TransitPlanner.trail_back`), as more nodes (`_trail_links`).  After
        a push the arm may stand where no straight line to any node keeps clear (in a
        tunnel, under its roof): it can still leave the way it came."""
        out: list[np.ndarray | None] = [None] * len(goals)
        if not len(goals):
            return out
        self._in_scene()
        free = np.nonzero(self._free)[0]
        if not len(free):
            return out
        trail = np.zeros((0, len(source))) if trail is None else np.asarray(trail, np.float64)
        nodes = self.q[free]
        m = len(self.q)
        src = m  # graph ids: roadmap nodes 0..m-1, the source m, goal g at m + 1 + g,
        first_trail = m + 1 + len(goals)  # the trail's nodes after the goals
        s_idx, s_time = nearest(source[None], nodes, SOURCE_K, self.speed)
        g_idx, g_time = nearest(goals, nodes, GOAL_K, self.speed)
        link_ok = self._free[self.links[:, 0]] & self._free[self.links[:, 1]]
        # the links in this query, as (from, to, time): undirected roadmap links both ways
        la, lb, lt = self.links[link_ok, 0], self.links[link_ok, 1], self.link_time[link_ok]
        links = [(src, int(free[j]), t) for j, t in zip(s_idx[0], s_time[0], strict=True)]
        links += [(int(free[j]), m + 1 + g, g_time[g, i]) for g in range(len(goals)) for i, j in enumerate(g_idx[g])]
        if len(trail):
            links += self._trail_links(source, trail, goals, free, nodes, first_trail)
        best: dict[tuple[int, int], float] = {}  # one link per (from, to): csgraph adds duplicates up
        for a, b, t in links:
            best[(a, b)] = min(t, best.get((a, b), np.inf))
        links = [(a, b, t) for (a, b), t in best.items()]
        frm = np.concatenate([la, lb, np.array([a for a, _, _ in links], np.int64)])
        to = np.concatenate([lb, la, np.array([b for _, b, _ in links], np.int64)])
        time = np.concatenate([lt, lt, np.array([t for _, _, t in links], np.float64)])
        time = np.maximum(time, 1e-9)  # csgraph reads an explicit 0 as no link
        q_of = np.concatenate([self.q, source[None], goals, trail])  # configuration of each graph id
        segs: dict[tuple[int, int], np.ndarray | None] = {}  # checked links (directed as checked)
        n_graph = m + 1 + len(goals) + len(trail)
        key = frm * n_graph + to
        blocked = np.isin(key, self._blocked_keys(n_graph))  # roadmap links found blocked earlier
        todo = set(range(len(goals)))
        found: dict[int, list[int]] = {}
        for _ in range(ROUNDS):
            live = ~blocked
            g = csr_matrix((time[live], (frm[live], to[live])), shape=(n_graph, n_graph))
            dist, pred = dijkstra(g, directed=True, indices=src, return_predecessors=True)
            ask: dict[tuple[int, int], None] = {}
            for goal in sorted(todo):
                node = m + 1 + goal
                if not np.isfinite(dist[node]):
                    todo.discard(goal)  # no way left
                    continue
                path = [node]
                while path[-1] != src:
                    path.append(int(pred[path[-1]]))
                path.reverse()
                need = [p for p in pairwise(path) if self._known(p, segs) is None]
                if not need:
                    found[goal] = path
                    todo.discard(goal)
                for p in need:
                    ask[p] = None
            if not ask:
                break
            pairs = list(ask)
            checked = self.t.segments(q_of[[a for a, _ in pairs]], q_of[[b for _, b in pairs]])
            for p, seg in zip(pairs, checked, strict=True):
                segs[p] = seg
                if p[0] < m and p[1] < m:
                    self._checked[(min(p), max(p))] = seg is not None
            bad = [p for p, seg in zip(pairs, checked, strict=True) if seg is None]
            bad += [(b, a) for a, b in bad if m not in (a, b)]  # the same line both ways
            blocked |= np.isin(key, np.array([a * n_graph + b for a, b in bad], np.int64))
        if not found:
            return out
        paths = self._shorten(found, q_of, segs, m)
        for goal, path in paths.items():
            out[goal] = np.concatenate([self._seg(a, b, q_of, segs) for a, b in pairwise(path)])
        return out

    def _trail_links(
        self, source: np.ndarray, trail: np.ndarray, goals: np.ndarray, free: np.ndarray, nodes: np.ndarray, first: int
    ) -> list[tuple[int, int, float]]:
        """The links of the way back (graph ids `first`...): the chain from the source through
        the trail in order; the source to its SOURCE_K nearest trail nodes (a push may have
        left an object on part of the way); each trail node with its TRAIL_K nearest free
        roadmap nodes and TRAIL_K nearest trail nodes, both ways; each goal from its
        TRAIL_GOAL_K nearest trail nodes.  (from, to, transit time)"""
        src = len(self.q)
        ids = np.arange(first, first + len(trail))
        chain = np.concatenate([source[None], trail])
        step = transit_time(chain[:-1], chain[1:], self.speed)
        out = list(zip([src, *ids[:-1]], ids, step, strict=True))
        out += [(b, a, t) for a, b, t in out[1:]]
        s_idx, s_time = nearest(source[None], trail, SOURCE_K, self.speed)
        out += [(src, int(ids[j]), t) for j, t in zip(s_idx[0], s_time[0], strict=True)]
        for others, to_id in ((nodes, free), (trail, ids)):
            idx, time = nearest(trail, others, TRAIL_K, self.speed)
            for i in range(len(trail)):
                for j, t in zip(idx[i], time[i], strict=True):
                    out += [(int(ids[i]), int(to_id[j]), t), (int(to_id[j]), int(ids[i]), t)]
        g_idx, g_time = nearest(goals, trail, TRAIL_GOAL_K, self.speed)
        for g in range(len(goals)):
            out += [(int(ids[j]), src + 1 + g, t) for j, t in zip(g_idx[g], g_time[g], strict=True)]
        return out

    def _known(self, p: tuple[int, int], segs: dict) -> bool | None:
        """Whether link p is free: checked in this query (either way, unless from the source:
        every other node is a free configuration, the same line both ways), or a roadmap link
        checked in this scene."""
        if p in segs:
            return segs[p] is not None
        a, b = p
        m = len(self.q)
        if (b, a) in segs and a != b and m not in p:
            return segs[(b, a)] is not None
        return self._checked.get((min(p), max(p))) if max(p) < len(self.q) else None

    def _blocked_keys(self, n_graph: int) -> np.ndarray:
        """Graph keys (from * n_graph + to, both ways) of the roadmap links found blocked in this scene."""
        bad = np.array([k for k, ok in self._checked.items() if not ok], np.int64).reshape(-1, 2)
        return np.concatenate([bad[:, 0] * n_graph + bad[:, 1], bad[:, 1] * n_graph + bad[:, 0]])

    def _seg(self, a: int, b: int, q_of: np.ndarray, segs: dict) -> np.ndarray:
        """The joint targets of the free link a -> b: as checked, or the reverse of b -> a
        (a roadmap link: both ends free, the same line), or the straight line itself (a
        roadmap link checked in an earlier query of this scene)."""
        if segs.get((a, b)) is not None:
            return segs[(a, b)]
        if segs.get((b, a)) is not None:
            back = segs[(b, a)]
            return np.concatenate([q_of[b][None], back[:-1]])[::-1]
        n, _ = self.t.segment_steps((q_of[b] - q_of[a])[None])
        return q_of[a] + np.outer(np.arange(1, n[0] + 1) / n[0], q_of[b] - q_of[a])

    def _shorten(self, found: dict[int, list[int]], q_of: np.ndarray, segs: dict, m: int) -> dict[int, list[int]]:
        """Each path's fastest chain of straight lines between its nodes (every pair that is
        not a link of the path tried in one batch)."""
        ask: dict[tuple[int, int], None] = {}
        for path in found.values():
            for i in range(len(path)):
                for j in range(i + 2, len(path)):
                    if self._known((path[i], path[j]), segs) is None:
                        ask[(path[i], path[j])] = None
        if ask:
            pairs = list(ask)
            checked = self.t.segments(q_of[[a for a, _ in pairs]], q_of[[b for _, b in pairs]])
            for p, seg in zip(pairs, checked, strict=True):
                segs[p] = seg
        out = {}
        for goal, path in found.items():
            # fastest chain over the free pairs (i < j): a small DP, the path's links always free
            n = len(path)
            best = np.full(n, np.inf)
            came = np.zeros(n, int)
            best[0] = 0.0
            for j in range(1, n):
                for i in range(j):
                    if best[i] == np.inf or not self._known((path[i], path[j]), segs):
                        continue
                    t = best[i] + float(transit_time(q_of[path[i]], q_of[path[j]], self.speed))
                    if t < best[j]:
                        best[j], came[j] = t, i
            chain = [n - 1]
            while chain[-1] != 0:
                chain.append(int(came[chain[-1]]))
            out[goal] = [path[i] for i in reversed(chain)]
        return out
