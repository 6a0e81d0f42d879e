"""WOMD lane graph -> SUMO plain XML (nodes, edges, connections), keeping WOMD coordinates.

How the lane graph becomes a SUMO network (the method of the best WOMD -> SUMO converters):

1. **Clean** every centreline (drop non-finite and repeated points); a lane with fewer than two
   distinct points or shorter than :data:`MIN_LANE_LENGTH_M` is skipped with a warning.
2. **Connectors.** Junction-interior lanes (``Lanes.is_junction``) that lie on a path
   road lane -> interior lane(s) -> road lane become SUMO *connections* whose ``shape`` is the
   interior polyline(s), so SUMO's internal lanes are WOMD's own junction lanes. Interior lanes
   that reach no road lane on one side (cropped at the map border) stay ordinary lanes
   (:mod:`converters.lane_graph`, which also makes WOMD's links symmetric and links across the
   skipped lanes).
3. **Split and group.** Road lanes that WOMD lists as left/right neighbours are cut where their
   neighbour ranges start and end (the cut propagates to the neighbour at the projected point), and
   pieces that run alongside each other over (nearly) their whole length become one multi-lane
   edge; every lane keeps its exact WOMD polyline as a custom lane ``shape``
   (``spreadType="center"``, so a one-lane edge's shape *is* the centreline)
   (:mod:`converters.lane_edges`).
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

from coster_sumo.core.scene import Lanes, LaneType, RoadMap, SignalStates
from coster_sumo.geometry.boxes import polyline_arc_length

from .lane_edges import Piece, alongside_neighbours, cut_into_pieces, group_into_edges
from .lane_graph import LinkGraph, UnionFind, connector_paths, link_graph
from .polyline import clean_polyline

MIN_LANE_LENGTH_M = 0.1  # [m] shorter lanes are skipped (zero-length WOMD lanes)
DEFAULT_SPEED_MPS = 13.89  # [m/s] where WOMD gives no speed limit (50 km/h)
MIN_WIDTH_M = 1.0  # [m]
DEFAULT_WIDTH_M = 3.7  # [m]
TURN_CHORD_M = 1.0  # [m] a lane's turn is measured as its heading change over this much of it
TURN_WIDTH_RATIO = 0.9  # [-] a lane's half width stays below this share of its tightest turning radius


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


def build_plain_net(road_map: RoadMap, signals: SignalStates, interior: frozenset[int] = frozenset(),
                    _depth: int = 0, _cache: dict | None = None) -> PlainNet:
    """Turn the scene's lane graph into a :class:`PlainNet` (see the module docstring).

    ``interior``: more lanes to treat as junction-interior. A road lane whose both ends fall into
    one junction (a short lane between two interior lanes) is re-run as interior, so that it
    becomes part of a connection instead of an edge that starts and ends in the same node.
    """
    lanes = road_map.lanes
    cache: dict = {} if _cache is None else _cache  # neighbour geometry, reused by the re-run
    lines, skipped, warnings = _clean_lanes(lanes)  # 1.
    graph = link_graph(lanes, set(lines), interior)  # 2. (connectors)
    neigh = alongside_neighbours(lanes, graph.road, lines, cache)  # 3.
    pieces, lane_pieces = cut_into_pieces(graph.road, lines, neigh)
    edges = group_into_edges(lanes, pieces, lane_pieces, lines, neigh)
    ends = _join_lane_ends(pieces, edges, lane_pieces, graph)  # 4.
    # self-loops (an edge whose both ends fell into one junction) keep a private end node
    loop_edges = {eid for eid, grp in edges.items()
                  if ends.find(("p", grp[0], 0)) == ends.find(("p", grp[0], 1))}
    loop_lanes = {pieces[m].lane for eid in loop_edges for m in edges[eid]} - interior
    if loop_lanes and _depth < 4:
        return build_plain_net(road_map, signals, interior | loop_lanes, _depth + 1, cache)
    nodes, edge_nodes, detached = _place_nodes(pieces, edges, ends, loop_edges)
    for eid in sorted(loop_edges):
        warnings.append(f"edge {eid}: starts and ends in the same junction; its end was detached")
    connections = _connections(signals, lines, lane_pieces, graph, detached)  # 5.
    tls_nodes = {edge_nodes[pieces[c.src].edge][1] for c in connections if c.signal_lane >= 0}
    return PlainNet(pieces=pieces, lane_pieces=lane_pieces, edges=edges, edge_nodes=edge_nodes,
                    nodes=nodes, tls_nodes=tls_nodes, connections=connections,
                    connectors=graph.connectors,
                    skipped=skipped, links=graph.links, point_ends=graph.point_ends, warnings=warnings)


def _clean_lanes(lanes: Lanes) -> tuple[dict[int, np.ndarray], list[int], list[str]]:
    """Step 1: every lane's cleaned centreline; the lanes skipped (too short) with a warning each."""
    warnings: list[str] = []
    lines: dict[int, np.ndarray] = {}
    skipped: list[int] = []
    for i in range(len(lanes)):
        line = clean_polyline(lanes.centerline[i])
        line_len = float(polyline_arc_length(line)[-1]) if len(line) >= 2 else 0.0
        if len(line) < 2 or line_len < MIN_LANE_LENGTH_M:
            skipped.append(i)
            warnings.append(f"lane {lanes.ids[i]}: skipped ({len(lanes.centerline[i])} points, "
                            f"{line_len:.3f} m long after removing repeated points)")
            continue
        lines[i] = line
    return lines, skipped, warnings


def _join_lane_ends(pieces: list[Piece], edges: dict[str, list[int]], lane_pieces: dict[int, list[int]],
                    graph: LinkGraph) -> UnionFind:
    """Step 4: the lane ends that meet in one node, as a union-find over end slots: ``("p", piece,
    0 start / 1 end)``, and ``("j", lane)`` for both ends of a connector."""
    nodes_uf = UnionFind()
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
        if lane in graph.connectors:
            return ("j", lane)
        ids = lane_pieces[lane]
        return ("p", ids[-1], 1) if side == 1 else ("p", ids[0], 0)

    for a, b in graph.links:
        nodes_uf.union(end_slot(a, 1), end_slot(b, 0))
    return nodes_uf


def _place_nodes(pieces: list[Piece], edges: dict[str, list[int]], ends: UnionFind, loop_edges: set[str]
                 ) -> tuple[dict[str, np.ndarray], dict[str, tuple[str, str]], set[int]]:
    """Step 4: node ids and positions (the mean of the lane ends that meet there), each edge's
    (from, to) nodes, and the pieces whose end was detached (the ends of self-loop edges)."""
    detached: set[int] = set()
    node_pts: dict[object, list[np.ndarray]] = defaultdict(list)
    slot_root: dict[tuple, object] = {}
    for pi, pc in enumerate(pieces):
        for side in (0, 1):
            root = ends.find(("p", pi, side))
            if side == 1 and pc.edge in loop_edges:
                root = ("detached", pc.edge)
                detached.add(pi)
            slot_root[(pi, side)] = root
            node_pts[root].append(pc.points[0] if side == 0 else pc.points[-1])
    roots = sorted(node_pts, key=lambda r: (str(type(r)), str(r)))
    node_id = {r: f"n{k}" for k, r in enumerate(roots)}
    nodes = {node_id[r]: np.mean(np.stack(node_pts[r]), axis=0) for r in roots}
    edge_nodes = {eid: (node_id[slot_root[(grp[0], 0)]], node_id[slot_root[(grp[0], 1)]])
                  for eid, grp in edges.items()}
    return nodes, edge_nodes, detached


def _connections(signals: SignalStates, lines: dict[int, np.ndarray], lane_pieces: dict[int, list[int]],
                 graph: LinkGraph, detached: set[int]) -> list[Connection]:
    """Step 5: the connections: a lane's pieces into each other, a lane into its successor, and an
    entry lane into an exit lane through interior lanes (their polylines as the shape)."""
    sig_lanes = set()
    if signals.state.size:
        known = np.any(signals.state != 0, axis=0)
        sig_lanes = {int(li) for li, k in zip(signals.lane_index, known, strict=True) if k}
    connections: list[Connection] = []
    seen: set[tuple[int, int]] = set()
    through, connectors = graph.through, graph.connectors

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
    for a, b in graph.links:
        if a in connectors or b in connectors:
            continue
        add(lane_pieces[a][-1], lane_pieces[b][0], None, [(a, b)], [],
            a if a in sig_lanes else -1)
    for a in graph.road:
        for j in graph.succ[a]:
            if j not in connectors:
                continue
            for path in connector_paths(j, graph.succ, connectors):
                b = path[-1]
                via = path[:-1]
                shape = np.concatenate([lines[v] if k == 0 else lines[v][1:] for k, v in enumerate(via)])
                shape = clean_polyline(shape)
                lk = [(a, via[0]), *zip(via[:-1], via[1:], strict=True), (via[-1], b)]
                sig = next((v for v in via if v in sig_lanes), a if a in sig_lanes else -1)
                add(lane_pieces[a][-1], lane_pieces[b][0], shape, lk, via, sig)
    return connections


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
