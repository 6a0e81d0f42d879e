"""Road geometry and links of an OpenDRIVE file being fitted (:mod:`coster_sumo.exports.opendrive_fit`).

- reference lines: a smooth curve through a polyline (:func:`set_smooth_plan_view`, normal roads),
  the polyline itself (:func:`set_polyline_plan_view`, connecting roads), straight pieces added
  at the ends (:func:`extend_reference`), everything placed by ``s`` on the road moved along;
- links: lane ids renumbered by fillers rewritten where other roads and the junctions use them
  (:func:`renumber`); a connecting road whose lanes cannot share it (they cross, or one runs
  backwards) split into one connecting road per lane (:func:`split_connecting`).
"""

from __future__ import annotations

import copy
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from coster_sumo.exports.opendrive_bend import (
    NARROW,
    TIGHT,
    Narrowing,
    bend,
    deviation,
    fold_ratio,
    smooth_path,
    untangle,
)
from coster_sumo.exports.opendrive_solve import (
    END_TOLERANCE_M,
    STATION_M,
    cubic_pieces,
    hermite_pieces,
    hermite_through,
    records,
    station_of,
)

Sampler = Callable[[ET.Element, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]
# [m] a connecting road joins a lane at least this wide at the contact: every lane the fit gave a
# SUMO shape there (at least opendrive_solve.MIN_WIDTH_M), not one that has not begun (width 0)
MIN_JOIN_WIDTH_M = 0.005
# [m] a connecting road's curve may leave its SUMO shape by this much to keep its lane from folding
# (the converted WOMD maps' connecting roads lie within 0.1 m of their logged lanes) ...
BEND_DEVIATION_M = 0.09
# [-] ... or by this many times as far as the curve through the shape's points does (netconvert's
# internal lanes that leave their lanes at an angle: that curve runs up to 0.25 m beside them)
BEND_KINK_FACTOR = 1.5
# [-] ... and where every curve within those bounds folds, by up to this share of the narrower
# linked lane's width: the SUMO shape then stays within the middle half of the exported lane (the
# converted corpus cuts' junction lanes: kinked shapes that a lane 3.2 m wide cannot follow)
FOLD_ESCAPE_WIDTH_SHARE = 0.25


def fmt(v: float) -> str:
    return f"{v:.8g}" if abs(v) >= 1e-9 else "0"


def set_smooth_plan_view(road: ET.Element, points: np.ndarray, sample: Sampler) -> None:
    """Replace a road's planView by a smooth curve through ``points`` (:func:`hermite_pieces`);
    signals and objects keep their world positions, elevation records scale with the length."""
    plan = road.find("planView")
    if plan is None:
        return
    old_len = float(road.get("length", "0"))
    placed = [el for tag in ("signals/signal", "objects/object") for el in road.findall(tag)
              if el.get("s") is not None and el.get("t") is not None]
    world = np.zeros((len(placed), 2))
    if placed:
        st = np.array([float(el.get("s", "0")) for el in placed])
        x, y, h = sample(plan, st)
        t = np.array([float(el.get("t", "0")) for el in placed])
        world = np.column_stack([x - t * np.sin(h), y + t * np.cos(h)])
    for g in list(plan):
        plan.remove(g)
    s0 = 0.0
    for piece in hermite_pieces(points):
        g = ET.SubElement(plan, "geometry", {"s": fmt(s0), "x": fmt(piece["x"]), "y": fmt(piece["y"]),
                                              "hdg": fmt(piece["hdg"]), "length": fmt(piece["length"])})
        ET.SubElement(g, "paramPoly3", {**{k: fmt(piece[k]) for k in ("aU", "bU", "cU", "dU", "aV", "bV", "cV",
                                                                      "dV")}, "pRange": "normalized"})
        s0 += piece["length"]
    road.set("length", f"{s0:.8f}")
    for tag in ("elevationProfile/elevation", "lateralProfile/superelevation", "signals/signalReference"):
        for el in road.findall(tag):
            if el.get("s") is not None and old_len > 0:
                el.set("s", fmt(float(el.get("s", "0")) * s0 / old_len))
    if placed:
        s = np.unique(np.append(np.arange(0.0, s0, STATION_M), s0))
        x, y, h = sample(plan, s)
        sp, t, _ = station_of(x, y, h, s, world)
        for el, a, b in zip(placed, sp, t, strict=True):
            el.set("s", fmt(float(a)))
            el.set("t", fmt(float(b)))


def set_polyline_plan_view(road: ET.Element, shape: np.ndarray) -> float:
    """Replace a road's planView by one ``<line>`` per segment of ``shape``; returns its length."""
    plan = road.find("planView")
    if plan is None:
        plan = ET.SubElement(road, "planView")
    for g in list(plan):
        plan.remove(g)
    s = 0.0
    for (x0, y0), (x1, y1) in zip(shape[:-1], shape[1:], strict=True):
        length = float(np.hypot(x1 - x0, y1 - y0))
        g = ET.SubElement(plan, "geometry", {"s": f"{s:.8f}", "x": f"{x0:.8f}", "y": f"{y0:.8f}",
                                              "hdg": f"{np.arctan2(y1 - y0, x1 - x0):.8f}", "length": f"{length:.8f}"})
        ET.SubElement(g, "line")
        s += length
    road.set("length", f"{s:.8f}")
    return s


def extend_reference(road: ET.Element, plan: ET.Element, before: float, after: float, x: np.ndarray, y: np.ndarray,
            h: np.ndarray) -> None:
    """Lengthen a road's reference line by straight pieces, ``before`` [m] ahead of its start and
    ``after`` [m] past its end (x, y, h: its start and end poses at [0] and [-1]); everything the
    road places by ``s`` moves with it."""
    geos = plan.findall("geometry")
    if before > 0:
        for g in geos:
            g.set("s", fmt(float(g.get("s", "0")) + before))
        for tag in ("elevationProfile/elevation", "lateralProfile/superelevation", "lateralProfile/shape",
                    "objects/object", "signals/signal", "signals/signalReference"):
            for el in road.findall(tag):
                if el.get("s") is not None and (float(el.get("s", "0")) > 0 or tag.startswith("objects")
                                                 or tag.startswith("signals")):
                    el.set("s", fmt(float(el.get("s", "0")) + before))
        first = ET.Element("geometry", {"s": "0", "x": fmt(x[0] - before * np.cos(h[0])),
                                        "y": fmt(y[0] - before * np.sin(h[0])), "hdg": fmt(h[0]),
                                        "length": fmt(before)})
        ET.SubElement(first, "line")
        plan.insert(0, first)
    length = float(road.get("length", "0")) + before
    if after > 0:
        last = ET.SubElement(plan, "geometry", {"s": fmt(length), "x": fmt(x[-1]), "y": fmt(y[-1]),
                                                "hdg": fmt(h[-1]), "length": fmt(after)})
        ET.SubElement(last, "line")
    road.set("length", f"{length + after:.8f}")


def overhang(x: np.ndarray, y: np.ndarray, h: np.ndarray, targets: list[np.ndarray]) -> tuple[float, float]:
    """How far [m] the SUMO shapes start ahead of the reference line's start and end past its end
    (along the line's direction there; 0 within :data:`END_TOLERANCE_M`)."""
    before = after = 0.0
    for shape in targets:
        if len(shape) < 2:
            continue
        a = (shape[:, 0] - x[0]) * np.cos(h[0]) + (shape[:, 1] - y[0]) * np.sin(h[0])
        b = (shape[:, 0] - x[-1]) * np.cos(h[-1]) + (shape[:, 1] - y[-1]) * np.sin(h[-1])
        before, after = max(before, -float(a.min())), max(after, float(b.max()))
    return (before if before > END_TOLERANCE_M else 0.0), (after if after > END_TOLERANCE_M else 0.0)


def renumber(root: ET.Element, ids: dict[str, dict[str, dict[int, int]]]) -> int:
    """Rewrite the lane ids that connecting roads and junctions use for roads whose lanes were
    renumbered (fillers, lane sections): ``ids[road]["start"|"end"]`` maps an old lane id to its id
    at that end of the road. A link to a lane that is not there at that end is removed (it has not
    begun or has ended; readers take a link into no lane for an error). Returns how many."""
    removed = 0
    junction_of = {r.get("id", ""): r for r in root.findall("road")}
    for road in root.findall("road"):
        if road.get("junction", "-1") == "-1":
            continue
        pred, succ = road.find("link/predecessor"), road.find("link/successor")
        for lane in road.findall("lanes/laneSection/right/lane"):
            for end, ref in (("predecessor", pred), ("successor", succ)):
                link = lane.find("link")
                el = link.find(end) if link is not None else None
                mapping = ids.get(ref.get("elementId", ""), {}).get(ref.get("contactPoint", "")) \
                    if ref is not None else None
                if link is None or el is None or mapping is None:
                    continue
                new = mapping.get(int(el.get("id", "0")))
                if new is None:
                    link.remove(el)
                    removed += 1
                else:
                    el.set("id", str(new))
    for junction in root.findall("junction"):
        for conn in junction.findall("connection"):
            incoming = junction_of.get(conn.get("incomingRoad", ""))
            if incoming is None or conn.get("incomingRoad", "") not in ids:
                continue
            succ = incoming.find("link/successor")
            at_end = succ is not None and succ.get("elementType") == "junction" \
                and succ.get("elementId") == junction.get("id")
            mapping = ids[conn.get("incomingRoad", "")]["end" if at_end else "start"]
            for ll in conn.findall("laneLink"):
                new = mapping.get(int(ll.get("from", "0")))
                if new is None:
                    conn.remove(ll)
                    removed += 1
                else:
                    ll.set("from", str(new))
    return removed


def split_connecting(root: ET.Element, road: ET.Element, shapes: list[np.ndarray], widths: np.ndarray,
                     next_id: list[int]) -> list[ET.Element]:
    """Replace a connecting road by one per lane (lane -1 first in ``shapes``, ``widths``): each on
    its lane's SUMO shape, laneOffset half its width, the junction's connection split alike.
    ``next_id``: a one-element list holding the next free road id (advanced). Returns the new roads
    (none when the road is not as netconvert writes it)."""
    parent = next((el for el in root.iter() if road in list(el)), None)
    junction = root.find(f"junction[@id='{road.get('junction', '')}']")
    right = road.find("lanes/laneSection/right")
    if parent is None or junction is None or right is None:
        return []
    lanes = sorted(right.findall("lane"), key=lambda e: -int(e.get("id", "0")))
    conns = [c for c in junction.findall("connection") if c.get("connectingRoad") == road.get("id")]
    next_conn = max((int(c.get("id", "0")) for c in junction.findall("connection")), default=0) + 1
    at = list(parent).index(road)
    new_roads = []
    for k, (lane, shape, width) in enumerate(zip(lanes, shapes, widths, strict=True)):
        rid = str(next_id[0])
        next_id[0] += 1
        new = copy.deepcopy(road)
        new.set("id", rid)
        new.set("name", f"{road.get('name', '')}#{k}")
        one_lane_road(new, shape, float(width), lane)
        parent.insert(at + 1 + k, new)
        new_roads.append(new)
        for c in conns:
            for ll in c.findall("laneLink"):
                if ll.get("to") == lane.get("id"):
                    nc = ET.SubElement(junction, "connection", {
                        "id": str(next_conn), "incomingRoad": c.get("incomingRoad", ""), "connectingRoad": rid,
                        "contactPoint": c.get("contactPoint", "start")})
                    ET.SubElement(nc, "laneLink", {"from": ll.get("from", "0"), "to": "-1"})
                    next_conn += 1
    for c in conns:
        junction.remove(c)
    parent.remove(road)
    return new_roads


def one_lane_road(road: ET.Element, shape: np.ndarray, width: float, lane: ET.Element | None = None) -> None:
    """Make ``road`` a one-lane road on ``shape`` (the lane's SUMO centre line; laneOffset half its
    constant ``width``); the lane kept is ``lane`` (a copy, id -1) or the road's own lane -1."""
    lanes_el = road.find("lanes")
    right = road.find("lanes/laneSection/right")
    if lanes_el is None or right is None:
        return
    src = lane if lane is not None else right.find("lane[@id='-1']")
    one = copy.deepcopy(src) if src is not None else ET.Element("lane", {"type": "driving", "level": "true"})
    for el in list(right):
        right.remove(el)
    one.set("id", "-1")
    for w in one.findall("width"):
        one.remove(w)
    one.insert(1 if one.find("link") is not None else 0, _poly_record("width", "sOffset", width))
    right.append(one)
    for el in lanes_el.findall("laneOffset"):
        lanes_el.remove(el)
    lanes_el.insert(0, _poly_record("laneOffset", "s", width / 2))
    set_polyline_plan_view(road, shape)


def _poly_record(tag: str, start: str, a: float) -> ET.Element:
    """A constant OpenDRIVE polynomial record (``<width>``, ``<laneOffset>``) from 0 on."""
    return ET.Element(tag, {start: "0", "a": fmt(a), "b": "0", "c": "0", "d": "0"})


def _records_at(records: list[ET.Element], start_key: str, s: float, base: float = 0.0) -> float:
    """Value at ``s`` of the piecewise cubic given by OpenDRIVE records (each from base + its start)."""
    value = 0.0
    for rec in sorted(records, key=lambda r: float(r.get(start_key, "0"))):
        s0 = base + float(rec.get(start_key, "0"))
        if s0 <= s + 1e-9:
            ds = s - s0
            value = sum(float(rec.get(k, "0")) * ds ** n for n, k in enumerate(("a", "b", "c", "d")))
    return value


def lane_at(road: ET.Element, s: float, lane_id: int, sample: Sampler) -> tuple[np.ndarray, float, float] | None:
    """Centre point (2,) [m], width [m] and heading [rad] of right lane ``lane_id`` at station ``s``
    of a road, in the lane section there (the last one that starts at or before ``s``; None where
    the road does not hold that lane)."""
    lanes_el, plan = road.find("lanes"), road.find("planView")
    if lanes_el is None or plan is None or lane_id >= 0:
        return None
    sections = [sec for sec in lanes_el.findall("laneSection") if float(sec.get("s", "0")) <= s + 1e-9]
    right = sections[-1].find("right") if sections else None
    if right is None:
        return None
    base = float(sections[-1].get("s", "0"))
    offset = _records_at(lanes_el.findall("laneOffset"), "s", s)
    border = offset
    for lane in sorted(right.findall("lane"), key=lambda e: -int(e.get("id", "0"))):
        width = _records_at(lane.findall("width"), "sOffset", s, base)
        if int(lane.get("id", "0")) == lane_id:
            t = border - width / 2
            x, y, h = sample(plan, np.array([s], np.float64))
            return np.array([x[0] - t * np.sin(h[0]), y[0] + t * np.cos(h[0])]), width, float(h[0])
        border -= width
    return None


@dataclass(frozen=True)
class _Connecting:
    """A one-lane connecting road to join: its plan view and lane, its polyline (N, 2) [m] with the
    contacts as first and last point, and each contact as (point (2,) [m], width [m], heading [rad])."""

    road: ET.Element
    plan: ET.Element
    lane: ET.Element
    path: np.ndarray
    start: tuple[np.ndarray, float, float]
    end: tuple[np.ndarray, float, float]


def _connecting(road: ET.Element, roads: dict[str, ET.Element], sample: Sampler) -> _Connecting | None:
    """``road`` with its contacts where it is a one-lane connecting road linked at both ends (None:
    not one to join)."""
    if road.get("junction", "-1") == "-1":
        return None
    lanes = road.findall("lanes/laneSection/right/lane")
    pred, succ = road.find("link/predecessor"), road.find("link/successor")
    if len(lanes) != 1 or pred is None or succ is None or pred.get("contactPoint") != "end" \
            or succ.get("contactPoint") != "start":
        return None
    lp, ls = lanes[0].find("link/predecessor"), lanes[0].find("link/successor")
    a, b = roads.get(pred.get("elementId", "")), roads.get(succ.get("elementId", ""))
    # a lane link is gone where the linked lane is not there at that road end (opendrive_fit's
    # renumbering): that end stays on the SUMO lane, the other still joins its lane
    if (lp is None or a is None) and (ls is None or b is None):
        return None
    plan = road.find("planView")
    if plan is None:
        return None
    length = float(road.get("length", "0"))
    s = np.unique(np.concatenate([[float(g.get("s", "0")) for g in plan.findall("geometry")], [length]]))
    x, y, h = sample(plan, s)
    path = np.column_stack([x, y])
    own = _records_at(lanes[0].findall("width"), "sOffset", 0.0)
    start = None if lp is None or a is None else lane_at(a, float(a.get("length", "0")), int(lp.get("id", "0")),
                                                         sample)
    end = None if ls is None or b is None else lane_at(b, 0.0, int(ls.get("id", "0")), sample)
    # a lane that has not begun yet at the contact (width 0: a logged lane that starts later
    # than its edge's others where the road's end could not move), or no linked lane, is no
    # place to join: that end stays on the SUMO lane
    if start is None or start[1] < MIN_JOIN_WIDTH_M:
        start = (path[0].copy(), own, float(h[0]))
    if end is None or end[1] < MIN_JOIN_WIDTH_M:
        end = (path[-1].copy(), own, float(h[-1]))
    path[0], path[-1] = start[0], end[0]
    return _Connecting(road, plan, lanes[0], path, start, end)


def _joining_curve(c: _Connecting) -> tuple[list[dict[str, float]], np.ndarray | None, bool]:
    """The cubic pieces of the joined road, half its lane's width at their ends (None: the width
    changes linearly) and whether its lane folds all the same."""
    path, start, end = c.path, c.start, c.end
    # In order: the smooth curve where its lane keeps whole within BEND_DEVIATION_M of the SUMO
    # shape (or BEND_KINK_FACTOR times the curve through the points' distance: netconvert's kinked
    # internal lanes); else that lane narrowed where it turns; else the curve through the points
    # where its lane keeps whole; else the closest of those or of the lane narrowed further (TIGHT)
    # within FOLD_ESCAPE_WIDTH_SHARE of the lane's width; else the curve through the points, folded.
    through = hermite_through(path, start[2], end[2])
    bound = max(BEND_KINK_FACTOR * deviation(through, path), BEND_DEVIATION_M)
    smooth = cubic_pieces(*smooth_path(path, start[2], end[2], start[1], end[1]), samples=64)
    # (deviation from the SUMO shape [m], pieces, half widths) of the curves whose lane keeps whole
    whole: list[tuple[float, list[dict[str, float]], np.ndarray | None]] = []
    if fold_ratio(smooth, start[1], end[1]) < 1.0:
        whole.append((deviation(smooth, path), smooth, None))
    if not any(w[0] <= bound for w in whole) and (bent := _narrowed(c, NARROW)) is not None:
        whole.append(bent)
    if not any(w[0] <= bound for w in whole):
        if fold_ratio(through, start[1], end[1]) < 1.0:
            return through, None, False
        if (bent := _narrowed(c, TIGHT)) is not None:
            whole.append(bent)
    within = [w for w in whole if w[0] <= bound]
    if within:
        return within[0][1], within[0][2], False
    escape = FOLD_ESCAPE_WIDTH_SHARE * min(start[1], end[1])
    near = sorted((w for w in whole if w[0] <= escape), key=lambda w: w[0])
    if near:
        return near[0][1], near[0][2], False
    return through, None, True


def _narrowed(c: _Connecting, narrowing: Narrowing
              ) -> tuple[float, list[dict[str, float]], np.ndarray] | None:
    """The joined road's curve with its lane narrowed where it turns (its deviation from the SUMO
    shape [m], its pieces, half its width at their ends), or None where its lane folds all the same."""
    p, hd, half = bend(c.path, c.start[2], c.end[2], c.start[1], c.end[1], narrow=narrowing)
    bent = cubic_pieces(p, hd, samples=64)
    if fold_ratio(bent, c.start[1], c.end[1], half=half) >= 1.0:
        return None
    kept = untangle(bent, half, c.start[1], c.end[1], narrowing)
    if kept is None or fold_ratio(bent, c.start[1], c.end[1], half=kept) >= 1.0:
        return None
    return deviation(bent, c.path), bent, kept


def _write_joined(c: _Connecting, pieces: list[dict[str, float]], half: np.ndarray | None) -> bool:
    """Write the pieces as the road's plan view and its lane's width (centred on the reference
    line) from the one contact's to the other's; False where the road has no lanes element."""
    for g in list(c.plan):
        c.plan.remove(g)
    s0 = 0.0
    for piece in pieces:
        g = ET.SubElement(c.plan, "geometry", {"s": fmt(s0), "x": fmt(piece["x"]), "y": fmt(piece["y"]),
                                                "hdg": fmt(piece["hdg"]), "length": fmt(piece["length"])})
        ET.SubElement(g, "paramPoly3", {**{k: fmt(piece[k]) for k in ("aU", "bU", "cU", "dU", "aV", "bV",
                                                                      "cV", "dV")}, "pRange": "normalized"})
        s0 += piece["length"]
    c.road.set("length", f"{s0:.8f}")
    if half is None:
        widths = [(0.0, c.start[1], (c.end[1] - c.start[1]) / s0 if s0 > 0 else 0.0)]
    else:  # linear piece by piece: the width at each piece's ends
        at = np.concatenate([[0.0], np.cumsum([pc["length"] for pc in pieces])])
        widths = records(at, 2.0 * half, [(0, len(at) - 1)])
    lanes_el = c.road.find("lanes")
    if lanes_el is None:
        return False
    for el in lanes_el.findall("laneOffset"):
        lanes_el.remove(el)
    for w in c.lane.findall("width"):
        c.lane.remove(w)
    first = 1 if c.lane.find("link") is not None else 0
    for k, (sw, a_w, b_w) in enumerate(widths):  # the lane stays centred on the reference line
        lanes_el.insert(k, ET.Element("laneOffset", {"s": fmt(sw), "a": fmt(a_w / 2), "b": fmt(b_w / 2),
                                                     "c": "0", "d": "0"}))
        c.lane.insert(first + k, ET.Element("width", {"sOffset": fmt(sw), "a": fmt(a_w), "b": fmt(b_w),
                                                      "c": "0", "d": "0"}))
    return True


def _smooth_unlinked(road: ET.Element, sample: Sampler) -> None:
    """A one-lane connecting road linked at neither end, left on its SUMO polyline (converted OSM
    cuts' bicycle turns), gets the curve through the polyline's points where its lane keeps whole
    and within :data:`FOLD_ESCAPE_WIDTH_SHARE` of its width: the kinks fold its inner border."""
    plan, lanes = road.find("planView"), road.findall("lanes/laneSection/right/lane")
    if road.get("junction", "-1") == "-1" or plan is None or len(lanes) != 1 or len(plan) < 2 \
            or any(g.find("line") is None for g in plan) or len(lanes[0].findall("width")) != 1:
        return
    s = np.array([float(g.get("s", "0")) for g in plan.findall("geometry")] + [float(road.get("length", "0"))])
    (x, y, h), width = sample(plan, s), _records_at(lanes[0].findall("width"), "sOffset", 0.0)
    path, through = np.column_stack([x, y]), hermite_through(np.column_stack([x, y]), float(h[0]), float(h[-1]))
    if width > 0.0 and fold_ratio(through, width, width) < 1.0 \
            and deviation(through, path) <= FOLD_ESCAPE_WIDTH_SHARE * width:
        _write_joined(_Connecting(road, plan, lanes[0], path, (path[0], width, float(h[0])),
                                  (path[-1], width, float(h[-1]))), through, None)


def join_connecting_roads(root: ET.Element, sample: Sampler) -> tuple[int, int]:
    """Make every one-lane connecting road start exactly where its incoming lane ends and end where
    its outgoing lane starts: same centre point, heading and width, so both borders of the two lanes
    meet (readers check each border, within 1 cm). Its reference line becomes a smooth curve along
    its own polyline from the one end to the other that its lane's inner border can follow without
    folding back (:func:`~coster_sumo.exports.opendrive_bend.smooth_path`), or where none can,
    the curve through its polyline's points; its width changes linearly between the two lanes'
    widths, or where only a narrower lane can follow the curve, narrows where it turns
    (:func:`~coster_sumo.exports.opendrive_bend.bend`, ``untangle``). Returns how many roads were
    joined and how many of them fold all the same."""
    roads = {r.get("id", ""): r for r in root.findall("road")}
    joined = folded = 0
    for road in roads.values():
        c = _connecting(road, roads, sample)
        if c is None:
            _smooth_unlinked(road, sample)
            continue
        pieces, half, folds = _joining_curve(c)
        folded += folds
        joined += _write_joined(c, pieces, half)
    return joined, folded


# lane types ASAM's checker does not take for drivable (its gap rule skips them)
NOT_DRIVABLE = {"sidewalk", "median", "shoulder", "curb", "none", "walking", "bidirectional", "tram", "rail"}


def drop_outer_walkways(root: ET.Element, road: ET.Element, served: Callable[[ET.Element], bool]) -> int:
    """Remove a connecting road's outermost right lanes that are not drivable and that no SUMO
    internal lane serves (``served(lane)`` False: a sidewalk, which SUMO crosses by walking areas
    instead), with the junction's lane links into them, so that the road's drivable lanes can be
    fitted; returns how many lanes went."""
    right = road.find("lanes/laneSection/right")
    if right is None or len(road.findall("lanes/laneSection")) != 1:
        return 0
    lanes = sorted(right.findall("lane"), key=lambda e: int(e.get("id", "0")))  # outermost first
    gone: set[str] = set()
    for lane in lanes[:-1]:  # at least one lane stays
        if lane.get("type") not in NOT_DRIVABLE or served(lane):
            break
        right.remove(lane)
        gone.add(lane.get("id", ""))
    if gone:
        rid = road.get("id", "")
        for conn in root.iter("connection"):
            if conn.get("connectingRoad") == rid:
                for link in conn.findall("laneLink"):
                    if link.get("to") in gone:
                        conn.remove(link)
    return len(gone)
