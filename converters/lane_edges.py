"""Step 3 of the plain net (:mod:`converters.to_sumo_net`): road lanes split into pieces, and
pieces grouped into SUMO edges.

Road lanes that WOMD lists as left/right neighbours are cut where their neighbour ranges start and
end (the cut propagates to the neighbour at the projected point), and pieces that run alongside
each other over (nearly) their whole length become one multi-lane edge, rightmost lane first.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from coster_sumo.core.scene import Lanes
from coster_sumo.geometry.boxes import polyline_arc_length, project_points

from .lane_graph import UnionFind
from .polyline import cut_polyline

MIN_PIECE_M = 2.0  # [m] no cut closer than this to a lane end or another cut
NEIGHBOUR_MAX_OFFSET_M = 8.0  # [m] a neighbour farther than this laterally is not alongside
NEIGHBOUR_MIN_OFFSET_M = 1.0  # [m] lanes closer than this laterally are not side by side
GROUP_OVERLAP = 0.8  # [-] pieces alongside over this share of both lengths form one edge
MAX_LANES_PER_EDGE = 8


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


Neighbours = dict[int, dict[int, tuple[float, float, float]]]  # lane -> neighbour -> :func:`_alongside`


def alongside_neighbours(lanes: Lanes, road: list[int], lines: dict[int, np.ndarray], cache: dict
                         ) -> Neighbours:
    """For each road lane, the road lanes WOMD lists as its neighbours that run alongside
    it (both ways round), with the interval where they do and their lateral offset."""
    neigh: Neighbours = defaultdict(dict)
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
    return neigh


def _cut_points(road: list[int], lines: dict[int, np.ndarray], neigh: Neighbours
                ) -> tuple[dict[int, list[float]], dict[int, float]]:
    """[m] where each road lane is cut (where a neighbour's range begins or ends, then
    propagated to the neighbours at the projected point) and each lane's length."""
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
    return cuts, length


def cut_into_pieces(road: list[int], lines: dict[int, np.ndarray], neigh: Neighbours
                     ) -> tuple[list[Piece], dict[int, list[int]]]:
    """The road lanes cut into pieces; returns the pieces and each lane's pieces in order."""
    cuts, length = _cut_points(road, lines, neigh)
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
    return pieces, lane_pieces


def _alongside_groups(pieces: list[Piece], lane_pieces: dict[int, list[int]], lines: dict[int, np.ndarray],
                      neigh: Neighbours) -> dict[object, list[int]]:
    """Pieces of neighbour lanes that run alongside over most of both lengths, grouped."""
    uf = UnionFind()
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
    return groups


def group_into_edges(lanes: Lanes, pieces: list[Piece], lane_pieces: dict[int, list[int]],
                      lines: dict[int, np.ndarray], neigh: Neighbours) -> dict[str, list[int]]:
    """The SUMO edges (edge id -> pieces, rightmost lane first); sets each piece's
    ``edge`` and ``index``. A group whose pieces cannot share an edge becomes one edge per piece."""
    edges: dict[str, list[int]] = {}
    for members in _alongside_groups(pieces, lane_pieces, lines, neigh).values():
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
    return edges


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
