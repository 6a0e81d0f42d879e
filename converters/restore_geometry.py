"""The converted net's lanes given their WOMD geometry back, lanes and internal lanes joined.

netconvert cuts lanes back to the junction polygons it builds and draws each connection's
internal lane between the cut ends; :func:`set_womd_geometry` rewrites only lane ``shape`` and
``length`` so that every lane follows its logged polyline and every internal lane runs from the
end of its incoming lane to the start of its outgoing lane (docs/womd.md, "Converted networks:
how the lanes join at junctions").
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from coster_sumo.geometry.boxes import polyline_arc_length

from .netconvert import NetInfo, _parse_xml
from .polyline import clean_polyline, cut_polyline
from .to_sumo_net import Connection, PlainNet


def _shape_attr(points: np.ndarray) -> str:
    return " ".join(f"{x:.4f},{y:.4f}" for x, y in points)


def _length(points: np.ndarray) -> float:
    return float(np.sum(np.hypot(*np.diff(points, axis=0).T)))


JOIN_CARVE_M = 1.0  # [m] a lane end at a straight join lends this much (at most a quarter of it) to the join
BLEND_M = 3.0  # [m] a logged interior lane a little off its lanes' ends is bent onto them over this length


def _carves(plain: PlainNet) -> tuple[np.ndarray, np.ndarray]:
    """[m] how much of its start and of its end each piece lends to its junction's internal lanes.

    A connection without a logged interior lane (a lane into its successor, or a lane's pieces
    into each other) has no WOMD shape of its own: its internal lane is the last stretch of the
    incoming lane followed by the first stretch of the outgoing one, :data:`JOIN_CARVE_M` each
    (at most a quarter of the piece). Every other connection out of (into) such a lane end starts
    (ends) with the same stretch, so that every internal lane begins where the incoming lane now
    ends and ends where the outgoing lane now begins.
    """
    head = np.zeros(len(plain.pieces))
    tail = np.zeros(len(plain.pieces))
    for c in plain.connections:
        if c.shape is None or len(c.shape) < 2:
            for p, out in ((c.src, tail), (c.dst, head)):
                length = plain.pieces[p].s1 - plain.pieces[p].s0
                out[p] = min(JOIN_CARVE_M, 0.25 * length)
    return head, tail


def _stretch(points: np.ndarray, s0: float, s1: float) -> np.ndarray:
    """The part of a polyline between arc lengths s0 < s1 (clipped to the line)."""
    length = _length(points)
    s0, s1 = max(0.0, s0), min(length, s1)
    if s1 - s0 < 1e-9:
        return np.zeros((0, 2))
    return cut_polyline(points, s0, s1)


def _bend_onto(shape: np.ndarray, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """``shape`` (K, 2) moved so that it starts at ``start`` and ends at ``end``: the offsets fade
    out linearly over :data:`BLEND_M` (at most half the shape) from each end."""
    cum = polyline_arc_length(shape)
    total = float(cum[-1])
    if total < 1e-9:
        return np.stack([start, end])
    blend = min(BLEND_M, 0.5 * total)
    w0 = np.clip(1.0 - cum / blend, 0.0, 1.0)[:, None]
    w1 = np.clip(1.0 - (total - cum) / blend, 0.0, 1.0)[:, None]
    return shape + w0 * (start - shape[0]) + w1 * (end - shape[-1])


def connection_shape(plain: PlainNet, c: Connection, head: np.ndarray, tail: np.ndarray) -> np.ndarray:
    """(K, 2) the whole path of one connection: the stretch its incoming piece lends, the logged
    interior lane(s) (if any), the stretch its outgoing piece lends; it starts exactly at the
    incoming lane's new end and ends exactly at the outgoing lane's new start."""
    a, b = plain.pieces[c.src], plain.pieces[c.dst]
    la = _length(a.points)
    start = _stretch(a.points, la - tail[c.src], la)
    end = _stretch(b.points, 0.0, head[c.dst])
    a_end = cut_polyline(a.points, la - tail[c.src], la)[0] if tail[c.src] > 0 else a.points[-1]
    b_start = cut_polyline(b.points, 0.0, head[c.dst])[-1] if head[c.dst] > 0 else b.points[0]
    middle = c.shape if c.shape is not None and len(c.shape) >= 2 else np.zeros((0, 2))
    if len(middle):
        middle = _bend_onto(middle, a.points[-1], b.points[0])
    parts = [p for p in (start, middle, end) if len(p)]
    path = clean_polyline(np.concatenate(parts)) if parts else np.zeros((0, 2))
    if len(path) < 2:  # the two lanes meet in one point: a join of no length
        return np.stack([a_end, b_start])
    path[0], path[-1] = a_end, b_start
    return path


def set_womd_geometry(net: Path, plain: PlainNet, info: NetInfo) -> dict:
    """Give every lane of the net its WOMD geometry, with lanes and internal lanes joined.

    Returns ``{"lanes": how many lanes changed, "max_trim_m": the largest length change}``.

    netconvert cuts lanes back to its junction polygons and draws internal lanes between the cut
    ends. WOMD junctions are wide, so a lane that starts or ends inside one (short turn pockets,
    lanes branching inside an intersection) can lose most of its length, and netconvert's internal
    lanes do not follow the logged interior lanes. The topology, connections, right-of-way and
    signals netconvert computed stay as they are; only lane ``shape`` and ``length`` are rewritten:
    a normal lane is its WOMD piece less the stretches it lends to straight joins
    (:func:`_carves`), a connection's internal lane(s) are :func:`connection_shape`, split over an
    internal-junction chain in the same length proportions netconvert used. So every internal
    lane starts where its incoming lane ends and ends where its outgoing lane starts.
    """
    tree = _parse_xml(net)
    by_id = {ln.get("id", ""): ln for ln in tree.getroot().iter("lane")}
    head, tail = _carves(plain)
    targets: dict[str, np.ndarray] = {}
    for k, p in enumerate(plain.pieces):
        if not p.edge:
            continue
        length = _length(p.points)
        targets[p.sumo_lane] = cut_polyline(p.points, head[k], length - tail[k]) if head[k] or tail[k] else p.points
    for c in plain.connections:
        a, b = plain.pieces[c.src], plain.pieces[c.dst]
        got = info.connections.get((a.sumo_lane, b.sumo_lane))
        if not got or not got[0]:
            continue
        shape = connection_shape(plain, c, head, tail)
        chain = [v for v in got[0] if v in info.lane_shapes]
        if not chain:
            continue
        lens = np.array([max(_length(info.lane_shapes[v]), 1e-3) for v in chain])
        cum = np.concatenate([[0.0], np.cumsum(lens)]) / lens.sum() * _length(shape)
        for k, v in enumerate(chain):
            targets[v] = cut_polyline(shape, cum[k], cum[k + 1]) if len(chain) > 1 else shape
    changed = 0
    max_trim = 0.0
    for lane_id, pts in targets.items():
        el = by_id.get(lane_id)
        old = info.lane_shapes.get(lane_id)
        if el is None or old is None or len(pts) < 2:
            continue
        if len(old) == len(pts) and np.allclose(old, pts, rtol=0.0, atol=1e-4):  # (rtol: coordinates are ~1e4 m)
            continue
        max_trim = max(max_trim, abs(_length(pts) - _length(old)))
        el.set("shape", _shape_attr(pts))
        el.set("length", f"{max(_length(pts), 0.1):.4f}")
        info.lane_shapes[lane_id] = np.asarray(np.round(pts, 4))
        changed += 1
    if changed:
        tree.write(net, encoding="UTF-8", xml_declaration=True)
    return {"lanes": changed, "max_trim_m": round(max_trim, 4)}
