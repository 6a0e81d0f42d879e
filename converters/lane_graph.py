"""Step 2 of the plain net (:mod:`converters.to_sumo_net`): WOMD's link graph over the lanes kept.

:func:`link_graph` makes WOMD's links symmetric (most are listed on both lanes, some on one),
links the lanes before a skipped lane (one with no length) straight to the lanes after it, and
finds the *connectors*: junction-interior lanes on some path road lane -> interior lane(s) -> road
lane, which become the shapes of SUMO connections instead of SUMO lanes. Lanes are indices into
``Lanes``; nothing here looks at geometry.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from coster_sumo.core.scene import Lanes

MAX_CONNECTOR_DEPTH = 6  # interior lanes chained in one connection


class UnionFind:
    """Disjoint sets of hashable items (lane ends meeting in one node, pieces sharing one edge)."""

    def __init__(self) -> None:
        self.parent: dict[object, object] = {}

    def find(self, a: object) -> object:
        self.parent.setdefault(a, a)
        root = a
        while self.parent[root] != root:
            root = self.parent[root]
        while self.parent[a] != root:
            self.parent[a], a = root, self.parent[a]
        return root

    def union(self, a: object, b: object) -> None:
        ra, rb = self.find(a), self.find(b)
        if ra != rb:
            self.parent[rb] = ra




@dataclass(slots=True)
class LinkGraph:
    """WOMD's links between the lanes that are converted.

    Attributes:
        pred, succ: per lane, its predecessor / successor lanes (symmetric; across skipped lanes).
        links: every (lane, successor) pair, sorted.
        through: (lane before, lane after) a chain of skipped lanes -> the WOMD links of that chain.
        point_ends: skipped lane -> (converted lanes it follows, converted lanes it leads to).
        connectors: interior lanes realised as connection shapes.
        road: the converted lanes that are not connectors (they become SUMO lanes), sorted.
    """

    pred: list[list[int]]
    succ: list[list[int]]
    links: list[tuple[int, int]]
    through: dict[tuple[int, int], list[tuple[int, int]]]
    point_ends: dict[int, tuple[list[int], list[int]]]
    connectors: set[int]
    road: list[int]


def link_graph(lanes: Lanes, kept: set[int], interior: frozenset[int]) -> LinkGraph:
    """The link graph over the ``kept`` lanes; ``interior``: more lanes to treat as junction-interior."""
    n = len(lanes)
    pred = [[int(p) for p in lanes.predecessors[i] if int(p) in kept and int(p) != i] for i in range(n)]
    succ = [[int(s) for s in lanes.successors[i] if int(s) in kept and int(s) != i] for i in range(n)]
    # a skipped lane has no length: the lanes before it link straight to the lanes after it
    through, point_ends = _contract_skipped(lanes, kept)
    for p_, s_ in through:
        if s_ not in succ[p_]:
            succ[p_].append(s_)
    # WOMD lists most links on both sides; some only on one: make the graph symmetric
    for i in kept:
        for nxt in succ[i]:
            if i not in pred[nxt]:
                pred[nxt].append(i)
        for prv in pred[i]:
            if i not in succ[prv]:
                succ[prv].append(i)
    links = sorted({(i, nxt) for i in kept for nxt in succ[i]})
    is_junction = np.zeros(n, bool)
    is_junction[list(kept)] = np.asarray(lanes.is_junction, bool)[list(kept)]
    is_junction[[i for i in interior if i in kept]] = True
    connectors = _connectors(is_junction, pred, succ)
    road = sorted(kept - connectors)
    return LinkGraph(pred, succ, links, through, point_ends, connectors, road)


def _connectors(is_junction: np.ndarray, pred: list[list[int]], succ: list[list[int]]) -> set[int]:
    """Interior lanes on some path road lane -> interior lane(s) -> road lane (fixed point)."""
    conn = {int(i) for i in np.flatnonzero(is_junction)}
    while True:
        reach_in: set[int] = set()  # reachable from a road lane through connectors
        frontier = [j for j in conn if any(p not in conn for p in pred[j])]
        while frontier:
            j = frontier.pop()
            if j in reach_in:
                continue
            reach_in.add(j)
            frontier += [s for s in succ[j] if s in conn]
        reach_out: set[int] = set()
        frontier = [j for j in conn if any(s not in conn for s in succ[j])]
        while frontier:
            j = frontier.pop()
            if j in reach_out:
                continue
            reach_out.add(j)
            frontier += [p for p in pred[j] if p in conn]
        new = reach_in & reach_out
        if new == conn:
            return conn
        conn = new



def _contract_skipped(lanes: Lanes, kept: set[int]) -> tuple[dict[tuple[int, int], list[tuple[int, int]]],
                                                               dict[int, tuple[list[int], list[int]]]]:
    """Links across the skipped lanes (those with no length) and where each skipped lane sits.

    Returns ``through``: (kept lane before, kept lane after) -> the WOMD links of the chain of
    skipped lanes between them; ``point_ends``: skipped lane -> (kept lanes it follows, kept lanes
    it leads to), reached across other skipped lanes.
    """
    n = len(lanes)
    skipped = [i for i in range(n) if i not in kept]
    nxt: dict[int, set[int]] = defaultdict(set)
    for i in range(n):  # WOMD lists most links on both sides, some on one only
        nxt[i].update(int(s) for s in lanes.successors[i] if int(s) != i)
        for p in lanes.predecessors[i]:
            if int(p) != i:
                nxt[int(p)].add(i)
    prv: dict[int, set[int]] = defaultdict(set)
    for i, ss in nxt.items():
        for s in ss:
            prv[s].add(i)

    def reach(start: int, step: dict[int, set[int]]) -> dict[int, list[int]]:
        """Kept lanes reached from a skipped lane across skipped ones -> the skipped lanes passed."""
        out: dict[int, list[int]] = {}
        stack = [[start]]
        while stack:
            path = stack.pop()
            for j in sorted(step[path[-1]]):
                if j in kept:
                    out.setdefault(j, path)
                elif j not in path:
                    stack.append([*path, j])
        return out

    through: dict[tuple[int, int], list[tuple[int, int]]] = {}
    point_ends: dict[int, tuple[list[int], list[int]]] = {}
    for k in skipped:
        before, after = reach(k, prv), reach(k, nxt)
        point_ends[k] = (sorted(before), sorted(after))
        for a, back in before.items():
            for b, fwd in after.items():
                chain = [*back[::-1], *fwd[1:]]  # skipped lanes from a to b
                if a != b and (a, b) not in through:
                    seq = [a, *chain, b]
                    through[(a, b)] = list(zip(seq[:-1], seq[1:], strict=True))
    return through, point_ends


def connector_paths(start: int, succ: list[list[int]], connectors: set[int]) -> list[list[int]]:
    """Paths start -> connector* -> road lane; the last element is the road lane."""
    out: list[list[int]] = []
    stack: list[list[int]] = [[start]]
    while stack:
        path = stack.pop()
        for s in succ[path[-1]]:
            if s in path:
                continue
            if s not in connectors:
                out.append([*path, s])
            elif len(path) < MAX_CONNECTOR_DEPTH:
                stack.append([*path, s])
    return out
