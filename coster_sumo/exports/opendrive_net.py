"""What the OpenDRIVE fit (:mod:`coster_sumo.exports.opendrive_fit`) needs of a SUMO net: every
lane's shape and width, the connections and the internal lanes they run on, the U-turns whose two
lanes share a border point (:meth:`NetLanes.uturn_is_pinched`) and how far lanes' ends move in to
give tight connections room to turn (:meth:`NetLanes.tight_cutbacks`, docs/sumo.md §12a).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from defusedxml import ElementTree as SafeET

from coster_sumo.exports.opendrive_bend import FOLD_RATIO, NARROW
from coster_sumo.exports.opendrive_ends import length as piece_length
from coster_sumo.formats.sumocfg import open_maybe_gzip

DEFAULT_LANE_WIDTH_M = 3.2  # SUMO's lane width when a net does not name one
PINCH_M = 0.05  # [m] a U-turn's two lanes whose left borders are this close share them (NetLanes)
# [-] a connection gets this many times the shortest arc its lane can turn on (NetLanes.tight_cutbacks):
# 2 for a curvature rising linearly to the limit and back; the curves of opendrive_bend, held within
# 0.09 m of the SUMO points and to the contacts' headings, need more (measured on game/grid6's
# corners: with 2 none kept the lane from folding, even narrowed; with 2.5 and 3 the lane narrows to
# 1.8 m where it turns and folds nowhere; 3 leaves a margin)
TURN_ROOM = 3.0
# [rad] a connection that turns less than this but whose lanes' lines lie apart sideways needs room for
# an S-curve (shift_arc): the converted OSM cuts' 0.7-0.9 m connections between a one-lane
# road and a lane of a two-lane road, 0.55 m apart
MAX_SHIFT_TURN = np.pi / 8
MAX_PINCHED_TURN = 0.9 * np.pi  # [rad] a sharper turn is a U-turn (NetLanes.corner_is_pinched)
MAX_CUTBACK_M = 2.0  # [m] most a lane's end moves into it to give a tight connection room
STRAIGHT_TOL_M = 0.01  # [m] a lane's end runs straight while it stays this close to its end segment's line


@dataclass
class NetLanes:
    """What the fit needs of a SUMO net.

    Attributes:
        shape: lane id -> (K, 2) float64 [m] lane shape.
        width: lane id -> [m] lane width.
        edge_lanes: edge id -> its lane ids by index (0 = rightmost).
        via: (from edge, from lane index, to edge, to lane index) -> the internal lane the connection
            starts with (also from an internal lane to its continuation behind an internal junction).
        lefthand: the net drives on the left (netconvert mirrors lane ids then; not fitted).
        enters, leaves: lane ids of normal edges that a connection enters (at their start) / leaves.
        head, tail: lane id -> (K, 2) [m] the piece of a lane before its road's start / past its
            road's end (:mod:`~coster_sumo.exports.opendrive_ends`), driven on the connecting roads.
        pinched_uturns: the connections (keys as ``via``) of U-turns between two lanes whose left
            borders meet where the U-turn leaves and enters them (:meth:`uturn_is_pinched`).
    """

    shape: dict[str, np.ndarray] = field(default_factory=dict)
    width: dict[str, float] = field(default_factory=dict)
    edge_lanes: dict[str, list[str]] = field(default_factory=dict)
    via: dict[tuple[str, int, str, int], str] = field(default_factory=dict)
    lefthand: bool = False
    enters: set[str] = field(default_factory=set)
    leaves: set[str] = field(default_factory=set)
    head: dict[str, np.ndarray] = field(default_factory=dict)
    tail: dict[str, np.ndarray] = field(default_factory=dict)
    pinched_uturns: set[tuple[str, int, str, int]] = field(default_factory=set)

    @classmethod
    def read(cls, net_file: Path) -> NetLanes:
        with open_maybe_gzip(Path(net_file)) as fh:
            root = SafeET.parse(fh, forbid_dtd=True).getroot()
        out = cls(lefthand=root.get("lefthand", "false") == "true")
        for edge in root.iter("edge"):
            lanes = sorted(edge.iter("lane"), key=lambda el: int(el.get("index", "0")))
            out.edge_lanes[edge.get("id", "")] = [str(el.get("id")) for el in lanes]
            for el in lanes:
                pts = [tuple(float(v) for v in p.split(",")[:2]) for p in el.get("shape", "").split()]
                out.shape[str(el.get("id"))] = np.asarray(pts, np.float64).reshape(-1, 2)
                out.width[str(el.get("id"))] = float(el.get("width", DEFAULT_LANE_WIDTH_M))
        for c in root.iter("connection"):
            frm, to = c.get("from", ""), c.get("to", "")
            if not frm.startswith(":") and frm in out.edge_lanes and to in out.edge_lanes:
                lanes_from, lanes_to = out.edge_lanes[frm], out.edge_lanes[to]
                i, j = int(c.get("fromLane", "0")), int(c.get("toLane", "0"))
                if 0 <= i < len(lanes_from) and 0 <= j < len(lanes_to):
                    out.leaves.add(lanes_from[i])
                    out.enters.add(lanes_to[j])
            if c.get("via"):
                key = (c.get("from", ""), int(c.get("fromLane", "0")), c.get("to", ""), int(c.get("toLane", "0")))
                out.via[key] = str(c.get("via"))
                # by its lanes, not by its direction: converted maps mark some of these U-turns
                # as left turns ("l"; the corpus cuts of grid_tls3)
                if out.uturn_is_pinched(key):
                    out.pinched_uturns.add(key)
        return out

    def uturn_is_pinched(self, key: tuple[str, int, str, int]) -> bool:
        """Whether a connection leaves its lane's end and enters its next lane's start at one left
        border point (within :data:`PINCH_M`): a U-turn between two lanes side by side. Its lane's
        inner border would start and end there, and no lane outline can pass one point twice
        (commonroad-scenario-designer's lanelets of such a connecting road are invalid polygons).
        A U-turn by its heading change (more than :data:`MAX_PINCHED_TURN`), not by SUMO's ``dir``:
        the left borders of a one-way road's lanes also meet where it bends at a node or runs
        straight on, and of the leftmost lanes where two one-way roads meet at a right angle; those
        connections are turns (:meth:`corner_is_pinched`), not U-turns to leave out."""
        ends = self._connected_shapes(key)
        if ends is None:
            return False
        a, b, width_a, width_b = ends
        if abs(_turn(a, b)) <= MAX_PINCHED_TURN:
            return False
        left_a = _left_border(a[-1], a[-1] - a[-2], width_a)
        left_b = _left_border(b[0], b[1] - b[0], width_b)
        if float(np.hypot(*(left_a - left_b))) <= PINCH_M:
            return True
        # staggered: the one lane's left border end lies on the other's left border (the two lanes
        # side by side, the one ending beside the other's first metres; a converted clip of
        # grid_family03: 1 m apart), so the U-turn's inner border has to run back along a border
        # already drawn
        return (_segment_distance(left_b, _left_border(a[-2], a[-1] - a[-2], width_a), left_a) <= PINCH_M
                or _segment_distance(left_a, left_b, _left_border(b[1], b[1] - b[0], width_b)) <= PINCH_M)

    def corner_is_pinched(self, key: tuple[str, int, str, int]) -> bool:
        """Whether a turn (not a U-turn) leaves its lane's end and enters its next lane's start at
        one point of the border on its inner side (within :data:`PINCH_M`; netgenerate's spiders:
        116 degree right turns between neighbouring spokes)."""
        ends = self._connected_shapes(key)
        if ends is None:
            return False
        a, b, width_a, width_b = ends
        turn = _turn(a, b)
        if abs(turn) > MAX_PINCHED_TURN:
            return False
        side = 1.0 if turn > 0 else -1.0  # the left border on a left turn, the right on a right turn
        inner_a = _left_border(a[-1], a[-1] - a[-2], side * width_a)
        inner_b = _left_border(b[0], b[1] - b[0], side * width_b)
        return float(np.hypot(*(inner_a - inner_b))) <= PINCH_M

    def _connected_shapes(self, key: tuple[str, int, str, int]) -> tuple[np.ndarray, np.ndarray, float, float] | None:
        """A connection's from-lane and to-lane shapes and widths (None: either is missing or has no
        segment)."""
        frm, i, to, j = key
        lanes_from, lanes_to = self.edge_lanes.get(frm, []), self.edge_lanes.get(to, [])
        if not (0 <= i < len(lanes_from) and 0 <= j < len(lanes_to)):
            return None
        a, b = self.shape.get(lanes_from[i]), self.shape.get(lanes_to[j])
        if a is None or b is None or len(a) < 2 or len(b) < 2:
            return None
        return a, b, self.width[lanes_from[i]], self.width[lanes_to[j]]

    def internal_lanes(self, key: tuple[str, int, str, int]) -> list[str]:
        """The internal lane ids a connection runs on (through internal junctions)."""
        lane, out = self.via.get(key), []
        while lane is not None and lane not in out and lane in self.shape:
            out.append(lane)
            edge, _, idx = lane.rpartition("_")
            lane = self.via.get((edge, int(idx), key[2], key[3]))
        return out

    def tight_cutbacks(self) -> dict[str, tuple[float, float]]:
        """[m] per normal lane, how far its start and its end move into it so that the connections
        entering and leaving it there get room to turn (docs/sumo.md §12a). A connection that turns
        by ``a`` [rad] between its two lanes with a lane ``w`` wide turns on an arc of at least
        ``a (w / 2) / FOLD_RATIO`` where its inner border keeps from folding; it gets
        :data:`TURN_ROOM` times that: what its internal lanes lack is taken half from the end of
        the lane it leaves and half from the start of the lane it enters, only as far as that lane
        runs straight there and up to :data:`MAX_CUTBACK_M`. (game/grid6's corner connections:
        1.1 m turning 0.67 rad with a 3.2 m lane.) U-turns and turns over 90 degrees are left
        alone, unless their lanes meet at its inner corner (:meth:`corner_is_pinched`). A connection
        that hardly turns but whose two lanes' lines lie apart sideways, by no more than half the
        lane's width, needs an S-curve (:func:`shift_arc`); where its internal lanes are shorter
        than even the narrowest lane the fit may draw needs, it gets the room the same way (the
        converted OSM cuts' 0.7-0.9 m connections 0.55 m sideways)."""
        out: dict[str, tuple[float, float]] = {}
        for key in self.via:
            frm, i, to, j = key
            if frm.startswith(":") or key in self.pinched_uturns:
                continue
            lanes_from, lanes_to = self.edge_lanes.get(frm, []), self.edge_lanes.get(to, [])
            if not (0 <= i < len(lanes_from) and 0 <= j < len(lanes_to)):
                continue
            a, b = self.shape.get(lanes_from[i]), self.shape.get(lanes_to[j])
            internal = self.internal_lanes(key)
            parts = [self.shape[lane] for lane in internal]
            if a is None or b is None or len(a) < 2 or len(b) < 2 or not parts:
                continue
            length = sum(piece_length(part) for part in parts)
            turn = abs(_turn(a, b))
            half = 0.5 * self.width.get(internal[0], DEFAULT_LANE_WIDTH_M)
            need = turn * half / FOLD_RATIO
            side = side_gap(a, b)
            # (only a lane drawn aside within its own width: a connection that moves a whole lane
            # over is a lane change, left as is; and only where no curve that long can shift so far
            # even with the lane narrowed as far as the fit may narrow it, opendrive_bend.NARROW)
            if turn < MAX_SHIFT_TURN and side <= half \
                    and shift_arc(side, min(half, NARROW.min_half_m) / FOLD_RATIO) > length:
                need = max(need, shift_arc(side, half / FOLD_RATIO))
            lack = TURN_ROOM * need - length
            # (a U-turn's room is the lanes beside it; a sharper turn whose lanes meet at its
            # inner corner gets room all the same: its inner border cannot start and end there)
            if (turn > np.pi / 2 and not self.corner_is_pinched(key)) or lack <= 0.0:
                continue
            # only as far as the lane runs straight from its end: the cut piece stays on its line
            back = min(0.5 * lack, MAX_CUTBACK_M, _straight(a[::-1]), _straight(b))
            start, end = out.get(lanes_from[i], (0.0, 0.0))
            out[lanes_from[i]] = (start, max(end, back))
            start, end = out.get(lanes_to[j], (0.0, 0.0))
            out[lanes_to[j]] = (max(start, back), end)
        return out

    def connection_shape(self, frm: str, from_lane: int, to: str, to_lane: int) -> np.ndarray | None:
        """The internal lane shape(s) of one connection, joined, after the tail of the lane it leaves
        and before the head of the lane it enters (None: no such connection)."""
        lane = self.via.get((frm, from_lane, to, to_lane))
        parts = []
        lanes_from, lanes_to = self.edge_lanes.get(frm, []), self.edge_lanes.get(to, [])
        tail = self.tail.get(lanes_from[from_lane]) if 0 <= from_lane < len(lanes_from) else None
        head = self.head.get(lanes_to[to_lane]) if 0 <= to_lane < len(lanes_to) else None
        seen = set()
        while lane is not None and lane not in seen and lane in self.shape:
            seen.add(lane)
            parts.append(self.shape[lane])
            edge, _, idx = lane.rpartition("_")
            lane = self.via.get((edge, int(idx), to, to_lane))
        if not parts:
            return None
        pts = np.concatenate([p for p in (tail, *parts, head) if p is not None])
        keep = np.ones(len(pts), bool)
        keep[1:] = np.hypot(*np.diff(pts, axis=0).T) > 1e-6  # joined parts repeat their shared point
        return pts[keep]


def side_gap(a: np.ndarray, b: np.ndarray) -> float:
    """[m] how far the start of lane shape ``b`` (L, 2) [m] lies beside the circular arc from the
    end of lane shape ``a`` (K, 2) [m], in ``a``'s direction there, that turns to ``b``'s start
    direction: the sideways offset that a turn does not explain (an arc turning by ``t`` over a
    chord ``c`` ends ``c sin(t / 2)`` aside; game/grid6's 0.62 m bends of 0.38 rad: 0.12 m)."""
    d = a[-1] - a[-2]
    d = d / max(float(np.hypot(*d)), 1e-12)
    v = b[0] - a[-1]
    turn = _turn(a, b)
    return abs(float(d[0] * v[1] - d[1] * v[0]) - float(np.hypot(*v)) * float(np.sin(turn / 2.0)))


def shift_arc(side: float, radius: float) -> float:
    """[m] the shortest S-curve that moves a lane ``side`` [m] sideways onto a parallel line: two
    arcs of ``radius`` [m] (the tightest the lane can follow), each turning ``acos(1 - side / (2
    radius))`` and back; 0 for no shift."""
    if side <= 0.0 or radius <= 0.0:
        return 0.0
    return 2.0 * radius * float(np.arccos(max(1.0 - side / (2.0 * radius), -1.0)))


def _heading(v: np.ndarray) -> float:
    return float(np.arctan2(v[1], v[0]))


def _turn(a: np.ndarray, b: np.ndarray) -> float:
    """[rad] the heading change from the end of lane shape ``a`` to the start of lane shape ``b``
    (left positive, within [-pi, pi))."""
    return _wrap(_heading(b[1] - b[0]) - _heading(a[-1] - a[-2]))


def _wrap(a: float) -> float:
    return float((a + np.pi) % (2 * np.pi) - np.pi)


def _straight(shape: np.ndarray) -> float:
    """[m] how far a polyline (K, 2) runs on the line of its first segment (within
    :data:`STRAIGHT_TOL_M`) from its first point."""
    d = shape[1] - shape[0]
    d = d / max(float(np.hypot(*d)), 1e-12)
    off = np.abs((shape - shape[0]) @ np.array([-d[1], d[0]]))
    bad = np.flatnonzero(off > STRAIGHT_TOL_M)
    end = int(bad[0]) - 1 if len(bad) else len(shape) - 1
    return float((shape[end] - shape[0]) @ d)


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """[m] distance of point ``p`` from the segment ``a``-``b``."""
    ab = b - a
    t = float(np.clip(np.dot(p - a, ab) / max(float(np.dot(ab, ab)), 1e-18), 0.0, 1.0))
    return float(np.hypot(*(p - (a + t * ab))))


def _left_border(point: np.ndarray, direction: np.ndarray, width: float) -> np.ndarray:
    """(2,) [m] the left border point of a lane at ``point`` heading along ``direction``."""
    d = direction / max(float(np.hypot(*direction)), 1e-9)
    return point + 0.5 * width * np.array([-d[1], d[0]])
