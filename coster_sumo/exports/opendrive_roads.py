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

import numpy as np

from coster_sumo.exports.opendrive_solve import (
    END_TOLERANCE_M,
    STATION_M,
    hermite_pieces,
    station_of,
)

Sampler = Callable[[ET.Element, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]


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


def records_at(records: list[ET.Element], start_key: str, s: float, base: float = 0.0) -> float:
    """Value at ``s`` of the piecewise cubic given by OpenDRIVE records (each from base + its start)."""
    value = 0.0
    for rec in sorted(records, key=lambda r: float(r.get(start_key, "0"))):
        s0 = base + float(rec.get(start_key, "0"))
        if s0 <= s + 1e-9:
            ds = s - s0
            value = sum(float(rec.get(k, "0")) * ds ** n for n, k in enumerate(("a", "b", "c", "d")))
    return value


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
