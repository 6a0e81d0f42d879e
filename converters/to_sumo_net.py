"""WOMD lane graph -> SUMO plain XML (nodes, edges, connections), keeping WOMD coordinates.

How the lane graph becomes a SUMO network (the method of the best WOMD -> SUMO converters):

1. **Clean** every centreline (drop non-finite and repeated points); a lane with fewer than two
   distinct points or shorter than :data:`MIN_LANE_LENGTH_M` is skipped with a warning.
2. **Connectors.** Junction-interior lanes (``Lanes.is_junction``) that lie on a path
   road lane -> interior lane(s) -> road lane become SUMO *connections* whose ``shape`` is the
   interior polyline(s), so SUMO's internal lanes are WOMD's own junction lanes. Interior lanes
   that reach no road lane on one side (cropped at the map border) stay ordinary lanes.
3. **Split and group.** Road lanes that WOMD lists as left/right neighbours are cut where their
   neighbour ranges start and end (the cut propagates to the neighbour at the projected point), and
   pieces that run alongside each other over (nearly) their whole length become one multi-lane
   edge; every lane keeps its exact WOMD polyline as a custom lane ``shape``
   (``spreadType="center"``, so a one-lane edge's shape *is* the centreline).
4. **Nodes** are the union of lane ends that WOMD links: the end of a lane and the start of its
   successor; every end of an interior lane with the lanes it links (so a whole intersection
   becomes one SUMO junction that knows which movements cross).
5. **Connections** realise every WOMD entry/exit link: lane to successor lane (or piece to piece),
   and entry lane -> exit lane through the interior lanes with their shape. Nodes whose links
   carry logged signal states become traffic lights.

Nothing here runs SUMO; :mod:`converters.to_sumo` writes the files and calls netconvert.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from coster_sumo.geometry import polyline_arc_length, project_points
from coster_sumo.scene import Lanes, LaneType, RoadMap, SignalStates

MIN_LANE_LENGTH_M = 0.1  # [m] shorter lanes are skipped (zero-length WOMD lanes)
DUPLICATE_POINT_M = 1e-3  # [m] consecutive points closer than this are one point
MIN_PIECE_M = 2.0  # [m] no cut closer than this to a lane end or another cut
NEIGHBOUR_MAX_OFFSET_M = 8.0  # [m] a neighbour farther than this laterally is not alongside
NEIGHBOUR_MIN_OFFSET_M = 1.0  # [m] lanes closer than this laterally are not side by side
GROUP_OVERLAP = 0.8  # [-] pieces alongside over this share of both lengths form one edge
MAX_LANES_PER_EDGE = 8
MAX_CONNECTOR_DEPTH = 6  # interior lanes chained in one connection
DEFAULT_SPEED_MPS = 13.89  # [m/s] where WOMD gives no speed limit (50 km/h)
MIN_WIDTH_M = 1.0  # [m]
DEFAULT_WIDTH_M = 3.7  # [m]
TURN_CHORD_M = 1.0  # [m] a lane's turn is measured as its heading change over this much of it
TURN_WIDTH_RATIO = 0.9  # [-] a lane's half width stays below this share of its tightest turning radius


@dataclass(slots=True)
class Piece:
    """A stretch of one WOMD lane that becomes one SUMO lane.

    Attributes:
        lane: WOMD lane index.
        k: piece number along the lane (0 = first).
        s0, s1: [m] arc-length interval on the cleaned lane.
        points: (n, 2) polyline of the piece.
        edge: SUMO edge id; index: SUMO lane index in that edge (0 = rightmost).
    """

    lane: int
    k: int
    s0: float
    s1: float
    points: np.ndarray
    edge: str = ""
    index: int = 0

    @property
    def sumo_lane(self) -> str:
        return f"{self.edge}_{self.index}"


@dataclass(slots=True)
class Connection:
    """One SUMO connection and the WOMD links it realises.

    Attributes:
        src, dst: pieces (indices into ``PlainNet.pieces``).
        shape: (n, 2) interior polyline or None (straight join).
        links: WOMD (predecessor, successor) lane-index pairs this connection realises.
        via_lanes: WOMD interior lane indices whose polyline is ``shape``.
        signal_lane: WOMD lane index whose logged signal controls the connection, or -1.
    """

    src: int
    dst: int
    shape: np.ndarray | None
    links: list[tuple[int, int]]
    via_lanes: list[int]
    signal_lane: int = -1


@dataclass(slots=True)
class PlainNet:
    """Everything needed to write the plain XML files and to map results back to WOMD."""

    pieces: list[Piece]
    lane_pieces: dict[int, list[int]]  # WOMD lane index -> its pieces, in driving order
    edges: dict[str, list[int]]  # edge id -> pieces by lane index
    edge_nodes: dict[str, tuple[str, str]]
    nodes: dict[str, np.ndarray]  # node id -> (2,) position
    tls_nodes: set[str]
    connections: list[Connection]
    connectors: set[int]  # WOMD interior lanes realised as connection shapes
    skipped: list[int]  # WOMD lanes not converted
    links: list[tuple[int, int]]  # every WOMD link between converted lanes
    # skipped lane -> (converted lanes it follows, converted lanes it leads to): where it sits
    point_ends: dict[int, tuple[list[int], list[int]]] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def clean_polyline(points: np.ndarray) -> np.ndarray:
    """Drop non-finite points and consecutive repeats. Returns (m, 2)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < 2:
        return p
    if np.all(np.hypot(*np.diff(p, axis=0).T) >= DUPLICATE_POINT_M):
        return p  # the usual case: nothing to drop
    keep = np.ones(len(p), bool)
    last = p[0]
    for i in range(1, len(p)):  # sequential: a run of tiny steps must still be dropped
        if np.hypot(*(p[i] - last)) < DUPLICATE_POINT_M:
            keep[i] = False
        else:
            last = p[i]
    return p[keep]


def cut_polyline(points: np.ndarray, s0: float, s1: float) -> np.ndarray:
    """The part of a polyline between arc lengths s0 < s1, end points interpolated. (m, 2)."""
    cum = polyline_arc_length(points)
    inner = (cum > s0 + DUPLICATE_POINT_M) & (cum < s1 - DUPLICATE_POINT_M)
    a = np.array([np.interp(s0, cum, points[:, 0]), np.interp(s0, cum, points[:, 1])])
    b = np.array([np.interp(s1, cum, points[:, 0]), np.interp(s1, cum, points[:, 1])])
    return np.concatenate([a[None], points[inner], b[None]])


class _UnionFind:
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


def _alongside(a: np.ndarray, b: np.ndarray) -> tuple[float, float, float] | None:
    """Arc-length interval on ``a`` where ``b`` runs alongside, and b's mean lateral offset [m]."""
    b = b[::2] if len(b) > 8 else b  # WOMD points are 0.5 m apart: 1 m is plenty for the interval
    s, lat, _ = project_points(b, a)
    cum_a = polyline_arc_length(a)
    ok = np.abs(lat) < NEIGHBOUR_MAX_OFFSET_M
    # points of b that project onto a's end caps (beyond its ends) do not count as alongside
    ok &= (s > 1e-6) & (s < cum_a[-1] - 1e-6)
    if ok.sum() < 2:
        return None
    # same driving direction
    db = np.diff(b, axis=0)
    hb = np.arctan2(db[:, 1], db[:, 0])
    _, ha = _heading_at(a, s[:-1])
    if np.mean(np.cos(hb - ha)) < 0.5:
        return None
    return float(s[ok].min()), float(s[ok].max()), float(np.mean(lat[ok]))


def _heading_at(line: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    cum = polyline_arc_length(line)
    e = np.diff(line, axis=0)
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(e) - 1)
    return k, np.arctan2(e[k, 1], e[k, 0])


def build_plain_net(road_map: RoadMap, signals: SignalStates, interior: frozenset[int] = frozenset(),
                    _depth: int = 0, _cache: dict | None = None) -> PlainNet:
    """Turn the scene's lane graph into a :class:`PlainNet` (see the module docstring).

    ``interior``: more lanes to treat as junction-interior. A road lane whose both ends fall into
    one junction (a short lane between two interior lanes) is re-run as interior, so that it
    becomes part of a connection instead of an edge that starts and ends in the same node.
    """
    lanes = road_map.lanes
    n = len(lanes)
    cache: dict = {} if _cache is None else _cache  # neighbour geometry, reused by the re-run
    warnings: list[str] = []
    lines: dict[int, np.ndarray] = {}
    skipped: list[int] = []
    for i in range(n):
        line = clean_polyline(lanes.centerline[i])
        line_len = float(polyline_arc_length(line)[-1]) if len(line) >= 2 else 0.0
        if len(line) < 2 or line_len < MIN_LANE_LENGTH_M:
            skipped.append(i)
            warnings.append(f"lane {lanes.ids[i]}: skipped ({len(lanes.centerline[i])} points, "
                            f"{line_len:.3f} m long after removing repeated points)")
            continue
        lines[i] = line
    kept = set(lines)
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

    # ---- 3. cuts where neighbour ranges begin and end, propagated to the neighbour
    neigh: dict[int, dict[int, tuple[float, float, float]]] = defaultdict(dict)
    road_set = set(road)
    for i in road:
        for jj in list(lanes.left_neighbors[i]) + list(lanes.right_neighbors[i]):
            j = int(jj)
            if j not in road_set or j == i:
                continue
            for a, b in ((i, j), (j, i)):
                if b not in neigh[a]:
                    if (a, b) not in cache:
                        cache[(a, b)] = _alongside(lines[a], lines[b])
                    iv = cache[(a, b)]
                    if iv is not None and abs(iv[2]) >= NEIGHBOUR_MIN_OFFSET_M:
                        neigh[a][b] = iv
    cum = {i: polyline_arc_length(lines[i]) for i in road}
    length = {i: float(cum[i][-1]) for i in road}
    cuts: dict[int, list[float]] = {i: [] for i in road}

    def add_cut(i: int, s: float) -> bool:
        if s < MIN_PIECE_M or s > length[i] - MIN_PIECE_M:
            return False
        if any(abs(s - c) < MIN_PIECE_M for c in cuts[i]):
            return False
        cuts[i].append(s)
        return True

    queue: list[tuple[int, float]] = []
    for i, nb in neigh.items():
        for lo, hi, _ in nb.values():
            for s_cut in (lo, hi):
                if add_cut(i, s_cut):
                    queue.append((i, s_cut))
    budget = 20 * max(1, len(road))  # bounded propagation on pathological maps
    while queue and budget > 0:
        budget -= 1
        i, s_cut = queue.pop()
        pt = np.array([[np.interp(s_cut, cum[i], lines[i][:, 0]), np.interp(s_cut, cum[i], lines[i][:, 1])]])
        for j, (lo, hi, _) in neigh[i].items():
            if lo + 0.5 < s_cut < hi - 0.5:
                sj, latj, _ = project_points(pt, lines[j])
                if abs(float(latj[0])) < NEIGHBOUR_MAX_OFFSET_M and add_cut(j, float(sj[0])):
                    queue.append((j, float(sj[0])))

    pieces: list[Piece] = []
    lane_pieces: dict[int, list[int]] = {}
    for i in road:
        bounds = [0.0, *sorted(cuts[i]), length[i]]
        ids = []
        for k in range(len(bounds) - 1):
            pts = lines[i] if len(bounds) == 2 else cut_polyline(lines[i], bounds[k], bounds[k + 1])
            ids.append(len(pieces))
            pieces.append(Piece(lane=i, k=k, s0=bounds[k], s1=bounds[k + 1], points=pts))
        lane_pieces[i] = ids

    # ---- group pieces that run alongside over most of both lengths
    uf = _UnionFind()
    for i, nb in neigh.items():
        for j in nb:
            if j not in neigh or i not in neigh[j]:
                continue
            ends = np.stack([pieces[pj].points[[0, -1]] for pj in lane_pieces[j]])  # (k, 2, 2)
            s_ends, lat_ends, _ = project_points(ends, lines[i])  # (k, 2)
            for pi in lane_pieces[i]:
                pa = pieces[pi]
                for k, pj in enumerate(lane_pieces[j]):
                    sb, lat = s_ends[k], lat_ends[k]
                    if np.any(np.abs(lat) > NEIGHBOUR_MAX_OFFSET_M):
                        continue
                    overlap = min(pa.s1, sb[1]) - max(pa.s0, sb[0])
                    if overlap >= GROUP_OVERLAP * (pa.s1 - pa.s0) and overlap >= GROUP_OVERLAP * (sb[1] - sb[0]):
                        uf.union(pi, pj)
    groups: dict[object, list[int]] = defaultdict(list)
    for pi in range(len(pieces)):
        groups[uf.find(pi)].append(pi)
    edges: dict[str, list[int]] = {}
    for members in groups.values():
        ordered = _order_right_to_left(members, pieces)
        if ordered is None:
            ordered_groups = [[m] for m in members]
        else:
            ordered_groups = [ordered]
        for grp in ordered_groups:
            first = pieces[grp[0]]
            if len(grp) == 1:
                lane_id = str(lanes.ids[first.lane])
                eid = f"e{lane_id}" if len(lane_pieces[first.lane]) == 1 else f"e{lane_id}.{first.k}"
            else:
                eid = "g" + "+".join(f"{lanes.ids[pieces[m].lane]}.{pieces[m].k}" for m in grp)
                if len(eid) > 60:
                    eid = f"g{lanes.ids[first.lane]}.{first.k}x{len(grp)}"
            for idx, m in enumerate(grp):
                pieces[m].edge, pieces[m].index = eid, idx
            edges[eid] = grp

    # ---- 4. nodes: union of linked lane ends
    nodes_uf = _UnionFind()
    for pi in range(len(pieces)):
        nodes_uf.find(("p", pi, 0))
        nodes_uf.find(("p", pi, 1))
    for grp in edges.values():
        for m in grp[1:]:
            nodes_uf.union(("p", grp[0], 0), ("p", m, 0))
            nodes_uf.union(("p", grp[0], 1), ("p", m, 1))
    for ids in lane_pieces.values():
        for a, b in zip(ids[:-1], ids[1:], strict=True):
            nodes_uf.union(("p", a, 1), ("p", b, 0))

    def end_slot(lane: int, side: int) -> tuple:
        if lane in connectors:
            return ("j", lane)
        ids = lane_pieces[lane]
        return ("p", ids[-1], 1) if side == 1 else ("p", ids[0], 0)

    for a, b in links:
        nodes_uf.union(end_slot(a, 1), end_slot(b, 0))

    # self-loops (an edge whose both ends fell into one junction) keep a private end node
    loop_edges = {eid for eid, grp in edges.items()
                  if nodes_uf.find(("p", grp[0], 0)) == nodes_uf.find(("p", grp[0], 1))}
    loop_lanes = {pieces[m].lane for eid in loop_edges for m in edges[eid]} - interior
    if loop_lanes and _depth < 4:
        return build_plain_net(road_map, signals, interior | loop_lanes, _depth + 1, cache)
    detached: set[int] = set()
    node_pts: dict[object, list[np.ndarray]] = defaultdict(list)
    slot_root: dict[tuple, object] = {}
    for pi, pc in enumerate(pieces):
        for side in (0, 1):
            root = nodes_uf.find(("p", pi, side))
            if side == 1 and pc.edge in loop_edges:
                root = ("detached", pc.edge)
                detached.add(pi)
            slot_root[(pi, side)] = root
            node_pts[root].append(pc.points[0] if side == 0 else pc.points[-1])
    for eid in sorted(loop_edges):
        warnings.append(f"edge {eid}: starts and ends in the same junction; its end was detached")
    roots = sorted(node_pts, key=lambda r: (str(type(r)), str(r)))
    node_id = {r: f"n{k}" for k, r in enumerate(roots)}
    nodes = {node_id[r]: np.mean(np.stack(node_pts[r]), axis=0) for r in roots}
    edge_nodes = {eid: (node_id[slot_root[(grp[0], 0)]], node_id[slot_root[(grp[0], 1)]])
                  for eid, grp in edges.items()}

    # ---- 5. connections
    sig_lanes = set()
    if signals.state.size:
        known = np.any(signals.state != 0, axis=0)
        sig_lanes = {int(li) for li, k in zip(signals.lane_index, known, strict=True) if k}
    connections: list[Connection] = []
    seen: set[tuple[int, int]] = set()

    def add(src: int, dst: int, shape: np.ndarray | None, lk: list[tuple[int, int]], via: list[int],
            sig: int) -> None:
        if (src, dst) in seen or src in detached:
            return
        seen.add((src, dst))
        # a link made across skipped lanes realises WOMD's links to and from them
        lk = [x for pair in lk for x in ([pair] if pair not in through else through[pair])]
        if sig < 0:
            sig = next((a for a, _ in lk if a in sig_lanes), -1)
        connections.append(Connection(src, dst, shape, lk, via, sig))

    for ids in lane_pieces.values():
        for a, b in zip(ids[:-1], ids[1:], strict=True):
            add(a, b, None, [], [], -1)
    for a, b in links:
        if a in connectors or b in connectors:
            continue
        add(lane_pieces[a][-1], lane_pieces[b][0], None, [(a, b)], [],
            a if a in sig_lanes else -1)
    for a in road:
        for j in succ[a]:
            if j not in connectors:
                continue
            for path in _paths(j, succ, connectors):
                b = path[-1]
                via = path[:-1]
                shape = np.concatenate([lines[v] if k == 0 else lines[v][1:] for k, v in enumerate(via)])
                shape = clean_polyline(shape)
                lk = [(a, via[0]), *zip(via[:-1], via[1:], strict=True), (via[-1], b)]
                sig = next((v for v in via if v in sig_lanes), a if a in sig_lanes else -1)
                add(lane_pieces[a][-1], lane_pieces[b][0], shape, lk, via, sig)
    tls_nodes = {edge_nodes[pieces[c.src].edge][1] for c in connections if c.signal_lane >= 0}
    return PlainNet(pieces=pieces, lane_pieces=lane_pieces, edges=edges, edge_nodes=edge_nodes,
                    nodes=nodes, tls_nodes=tls_nodes, connections=connections,
                    connectors=connectors,
                    skipped=skipped, links=links, point_ends=point_ends, warnings=warnings)


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


def _paths(start: int, succ: list[list[int]], connectors: set[int]) -> list[list[int]]:
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


def _order_right_to_left(members: list[int], pieces: list[Piece]) -> list[int] | None:
    """Members sorted by lateral position (rightmost first), or None if they cannot share an edge."""
    if len(members) == 1:
        return members
    lanes = [pieces[m].lane for m in members]
    if len(set(lanes)) != len(lanes) or len(members) > MAX_LANES_PER_EDGE:
        return None
    ref = pieces[members[0]].points
    mids = np.stack([_midpoint(pieces[m].points) for m in members])
    _, lat, _ = project_points(mids, ref)
    order = np.argsort(lat)
    if np.any(np.diff(lat[order]) < NEIGHBOUR_MIN_OFFSET_M):
        return None
    return [members[k] for k in order]


def _midpoint(points: np.ndarray) -> np.ndarray:
    cum = polyline_arc_length(points)
    s = cum[-1] / 2
    return np.array([np.interp(s, cum, points[:, 0]), np.interp(s, cum, points[:, 1])])


def lane_width(road_map: RoadMap, i: int) -> float:
    """[m] the SUMO width of WOMD lane ``i``: its estimate, no wider than its tightest turn allows
    (:func:`turn_width_cap`)."""
    w = float(road_map.lanes.width[i])
    w = w if np.isfinite(w) and w >= MIN_WIDTH_M else DEFAULT_WIDTH_M
    return max(min(w, turn_width_cap(clean_polyline(road_map.lanes.centerline[i]))), MIN_WIDTH_M)


def turn_width_cap(line: np.ndarray) -> float:
    """[m] the widest lane a centre line (N, 2) can carry: a lane wider than the diameter of its
    turn has an inner edge that stops and runs backwards. The turn is the largest heading change
    over :data:`TURN_CHORD_M` of the line; the cap keeps half the width at :data:`TURN_WIDTH_RATIO`
    of that radius (inf for a line shorter than the chord)."""
    cum = polyline_arc_length(line) if len(line) >= 2 else np.zeros(1)
    if cum[-1] < TURN_CHORD_M:
        return float("inf")
    s = np.arange(0.0, cum[-1] - TURN_CHORD_M + 1e-9, TURN_CHORD_M / 4)
    seg = np.diff(line, axis=0)
    heading = np.arctan2(seg[:, 1], seg[:, 0])
    k0 = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    k1 = np.clip(np.searchsorted(cum, s + TURN_CHORD_M, side="right") - 1, 0, len(seg) - 1)
    turn = float(np.abs(np.angle(np.exp(1j * (heading[k1] - heading[k0])))).max())
    return 2.0 * TURN_WIDTH_RATIO * TURN_CHORD_M / turn if turn > 0 else float("inf")


def lane_speed(road_map: RoadMap, i: int) -> float:
    v = float(road_map.lanes.speed_limit[i])
    return v if np.isfinite(v) and v > 0 else DEFAULT_SPEED_MPS


def is_bike_lane(road_map: RoadMap, i: int) -> bool:
    return int(road_map.lanes.lane_type[i]) == int(LaneType.BIKE_LANE)
