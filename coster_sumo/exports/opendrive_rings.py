"""Closed rings of lanes written so that a reader joining lanes end to end does not close them.

A SUMO net may hold a loop of lanes that follow one another one to one all the way round: a ring
road (the classic phantom-jam experiment), or a netconvert cut that keeps a loop with no way in or
out (the corpus' DRT cut: two one-lane roads joined at both ends by turnarounds). commonroad's
OpenDRIVE conversion joins every lane with its only successor where that successor has no other
predecessor, so it joins such a loop into one lanelet that ends where it starts: its outline runs
round the loop on both borders, a polygon no single ring can be (shapely: "Self-intersection"),
whatever the roads' shapes. The reader does not join a lane to a successor on the other side of
its road's reference line (a right lane, negative id, followed by a left one, positive id).

:func:`break_lane_rings` finds each such loop and writes one road of it the other way round: its
reference line reversed (same points, the other direction), its right lanes as left lanes with
the same widths, marks and speeds, its lane offset mirrored, and every link to it rewritten (the
other roads' contact points and lane ids, the junctions' lane links). The lanes are the same
strips of road driven in the same direction; only how the file describes them changes, and the
loop is read as two lanelets. A road is written the other way round only where every element it
has can be (one lane section, right lanes only, line, arc or normalized paramPoly3 pieces, no
objects, signals or superelevation); a loop with no such road is left as it is.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections import defaultdict

from coster_sumo.exports.opendrive_roads import fmt

Lane = tuple[str, int]  # (road id, lane id)

LANE_CHILDREN = {"link", "width", "roadMark", "speed", "userData"}
CUBIC_KEYS = ("a", "b", "c", "d")


def _lane_graph(root: ET.Element) -> tuple[dict[Lane, set[Lane]], dict[Lane, set[Lane]]]:
    """Successors and predecessors of every right lane (driving along its road's s), from the
    lanes' own links and the junctions' connections."""
    roads = {r.get("id", ""): r for r in root.findall("road")}
    succ: dict[Lane, set[Lane]] = defaultdict(set)
    pred: dict[Lane, set[Lane]] = defaultdict(set)

    def add(a: Lane, b: Lane) -> None:
        if a[1] < 0 and b[1] < 0:
            succ[a].add(b)
            pred[b].add(a)

    for rid, road in roads.items():
        link = road.find("link")
        ends = {el.tag: el for el in link} if link is not None else {}
        for lane in road.findall("lanes/laneSection/right/lane"):
            i = int(lane.get("id", "0"))
            for tag in ("successor", "predecessor"):
                ll, end = lane.find(f"link/{tag}"), ends.get(tag)
                if ll is None or end is None or end.get("elementType") != "road":
                    continue
                other = end.get("elementId", "")
                # a right lane leaves a road's end into the other road's start (and back)
                if tag == "successor" and end.get("contactPoint") == "start":
                    add((rid, i), (other, int(ll.get("id", "0"))))
                elif tag == "predecessor" and end.get("contactPoint") == "end":
                    add((other, int(ll.get("id", "0"))), (rid, i))
    for junction in root.findall("junction"):
        for con in junction.findall("connection"):
            if con.get("contactPoint", "start") != "start":
                continue
            for ll in con.findall("laneLink"):
                add((con.get("incomingRoad", ""), int(ll.get("from", "0"))),
                    (con.get("connectingRoad", ""), int(ll.get("to", "0"))))
    return succ, pred


def lane_rings(root: ET.Element) -> list[list[str]]:
    """The roads of every loop of right lanes that follow one another one to one (each lane's only
    successor has it as its only predecessor) back to where they started, in driving order."""
    succ, pred = _lane_graph(root)
    seen: set[Lane] = set()
    rings = []
    for start in list(succ):
        if start in seen:
            continue
        chain, lane = [start], start
        while len(succ.get(lane, ())) == 1:
            (nxt,) = succ[lane]
            if len(pred.get(nxt, ())) != 1 or nxt in seen:
                break
            if nxt == start:
                seen.update(chain)
                rings.append([r for r, _ in chain])
                break
            if nxt in chain:
                break
            chain.append(nxt)
            lane = nxt
    return rings


def _reversible(road: ET.Element) -> bool:
    lanes = road.find("lanes")
    plan = road.find("planView")
    if lanes is None or plan is None or len(lanes.findall("laneSection")) != 1:
        return False
    if any(el.tag not in ("laneOffset", "laneSection") for el in lanes):
        return False
    sec = lanes.find("laneSection")
    assert sec is not None
    if sec.find("left/lane") is not None or sec.find("right/lane") is None:
        return False
    if any(c.tag not in LANE_CHILDREN for lane in sec.iter("lane") for c in lane):
        return False
    for tag in ("lateralProfile", "objects", "signals"):
        el = road.find(tag)
        if el is not None and len(el):
            return False
    for g in plan.findall("geometry"):
        shape = next(iter(g), None)
        if shape is None or shape.tag not in ("line", "arc", "paramPoly3"):
            return False
        if shape.tag == "paramPoly3" and shape.get("pRange", "normalized") != "normalized":
            return False
    return True


def _f(el: ET.Element, key: str) -> float:
    return float(el.get(key, "0"))


def _reverse_geometry(g: ET.Element, s_new: float) -> None:
    """One plan-view piece from its end to its start (in place), starting at station ``s_new``."""
    x0, y0, h, length = _f(g, "x"), _f(g, "y"), _f(g, "hdg"), _f(g, "length")
    shape = next(iter(g))
    if shape.tag == "line":
        x1, y1, h1 = x0 + length * math.cos(h), y0 + length * math.sin(h), h
    elif shape.tag == "arc":
        k = _f(shape, "curvature")
        h1 = h + k * length
        if abs(k) < 1e-12:
            x1, y1 = x0 + length * math.cos(h), y0 + length * math.sin(h)
        else:
            x1, y1 = x0 + (math.sin(h1) - math.sin(h)) / k, y0 - (math.cos(h1) - math.cos(h)) / k
        shape.set("curvature", fmt(-k))
    else:  # normalized paramPoly3: P(p) = start + R(h) (u(p), v(p)), p in [0, 1]
        cu = [_f(shape, f"{c}U") for c in "abcd"]
        cv = [_f(shape, f"{c}V") for c in "abcd"]
        c, s = math.cos(h), math.sin(h)
        gx = [c * u - s * v for u, v in zip(cu, cv, strict=True)]  # global offsets' coefficients
        gy = [s * u + c * v for u, v in zip(cu, cv, strict=True)]
        x1, y1 = x0 + sum(gx), y0 + sum(gy)
        h1 = math.atan2(gy[1] + 2 * gy[2] + 3 * gy[3], gx[1] + 2 * gx[2] + 3 * gx[3])
        hn = h1 + math.pi
        # P(1 - q) - P(1) in powers of q, turned into the frame of the reversed start
        qx = [0.0, -gx[1] - 2 * gx[2] - 3 * gx[3], gx[2] + 3 * gx[3], -gx[3]]
        qy = [0.0, -gy[1] - 2 * gy[2] - 3 * gy[3], gy[2] + 3 * gy[3], -gy[3]]
        cn, sn = math.cos(hn), math.sin(hn)
        for k, name in enumerate("abcd"):
            shape.set(f"{name}U", fmt(cn * qx[k] + sn * qy[k]))
            shape.set(f"{name}V", fmt(-sn * qx[k] + cn * qy[k]))
    g.set("s", fmt(s_new))
    g.set("x", fmt(x1))
    g.set("y", fmt(y1))
    g.set("hdg", fmt(math.remainder(h1 + math.pi, 2 * math.pi)))


def _reverse_cubics(records: list[ET.Element], key: str, length: float, sign: float = 1.0) -> list[ET.Element]:
    """Piecewise cubic records (each from its ``key`` station on) over [0, length] read backwards,
    times ``sign``: each piece's value and derivatives taken at its far end."""
    recs = sorted(records, key=lambda r: _f(r, key))
    starts = [_f(r, key) for r in recs] + [length]
    for k, rec in enumerate(recs):
        a, b, c, d = (_f(rec, n) for n in CUBIC_KEYS)
        h = starts[k + 1] - starts[k]
        new = (a + b * h + c * h * h + d * h ** 3, -(b + 2 * c * h + 3 * d * h * h), c + 3 * d * h, -d)
        rec.set(key, fmt(max(length - starts[k + 1], 0.0)))
        for n, v in zip(CUBIC_KEYS, new, strict=True):
            rec.set(n, fmt(sign * v))
    return recs[::-1]


def _reverse_steps(records: list[ET.Element], key: str, length: float) -> list[ET.Element]:
    """Piecewise constant records (each from its ``key`` station on) over [0, length] read backwards."""
    recs = sorted(records, key=lambda r: _f(r, key))
    starts = [_f(r, key) for r in recs] + [length]
    for k, rec in enumerate(recs):
        rec.set(key, fmt(max(length - starts[k + 1], 0.0)))
    return recs[::-1]


def _replace(parent: ET.Element, old: list[ET.Element], new: list[ET.Element]) -> None:
    """Put ``new`` where ``old`` were (the same elements in another order) among ``parent``'s children."""
    if not old:
        return
    at = list(parent).index(old[0])
    for el in old:
        parent.remove(el)
    for k, el in enumerate(new):
        parent.insert(at + k, el)


def _swap_ends(el: ET.Element | None) -> None:
    """Swap ``predecessor`` and ``successor`` children (predecessor first, as the schema orders them)."""
    if el is None:
        return
    ends = [c for c in el if c.tag in ("predecessor", "successor")]
    for c in ends:
        c.tag = "successor" if c.tag == "predecessor" else "predecessor"
    _replace(el, ends, sorted(ends, key=lambda c: c.tag != "predecessor"))


def reverse_road(root: ET.Element, road: ET.Element) -> None:
    """Write ``road`` the other way round (:func:`_reversible` must hold) and every link to it."""
    rid, length = road.get("id", ""), _f(road, "length")
    plan = road.find("planView")
    assert plan is not None
    geos = plan.findall("geometry")
    s_new = 0.0
    for g in reversed(geos):
        _reverse_geometry(g, s_new)
        s_new += _f(g, "length")
    _replace(plan, geos, geos[::-1])
    for parent_tag, tag in (("elevationProfile", "elevation"), ("lanes", "laneOffset")):
        parent = road.find(parent_tag)
        if parent is not None:
            recs = parent.findall(tag)
            # lateral offsets change sign: the reversed line's left is the old right
            _replace(parent, recs, _reverse_cubics(recs, "s", length, -1.0 if tag == "laneOffset" else 1.0))
    types = road.findall("type")
    _replace(road, types, _reverse_steps(types, "s", length))
    sec = road.find("lanes/laneSection")
    assert sec is not None
    right = sec.find("right")
    assert right is not None
    for lane in sec.iter("lane"):
        for tag, cubic in (("width", True), ("roadMark", False), ("speed", False)):
            recs = lane.findall(tag)
            _replace(lane, recs, _reverse_cubics(recs, "sOffset", length) if cubic else
                     _reverse_steps(recs, "sOffset", length))
        _swap_ends(lane.find("link"))
    lanes = right.findall("lane")
    left = ET.Element("left")
    for lane in sorted(lanes, key=lambda el: int(el.get("id", "0"))):  # outermost (-n -> n) first
        right.remove(lane)
        lane.set("id", str(-int(lane.get("id", "0"))))
        left.append(lane)
    sec.remove(right)
    sec.insert(0, left)
    _swap_ends(road.find("link"))
    flip = {"start": "end", "end": "start"}
    for other in root.findall("road"):
        link = other.find("link")
        for end in link if link is not None else []:
            if end.get("elementType") == "road" and end.get("elementId") == rid:
                end.set("contactPoint", flip.get(end.get("contactPoint", ""), end.get("contactPoint", "")))
                # the lane links to another road: the first section's predecessors, the last's successors
                sections = other.findall("lanes/laneSection")
                outer = sections[0 if end.tag == "predecessor" else -1:][:1]
                for ll in (x for sec_el in outer for x in sec_el.findall(f"*/lane/link/{end.tag}")):
                    ll.set("id", str(-int(ll.get("id", "0"))))
    for con in root.iter("connection"):
        if con.get("incomingRoad") == rid:
            for ll in con.findall("laneLink"):
                ll.set("from", str(-int(ll.get("from", "0"))))
        if con.get("connectingRoad") == rid:
            con.set("contactPoint", flip.get(con.get("contactPoint", "start"), "start"))
            for ll in con.findall("laneLink"):
                ll.set("to", str(-int(ll.get("to", "0"))))


def break_lane_rings(root: ET.Element) -> int:
    """Write one road of every closed ring of lanes (:func:`lane_rings`) the other way round,
    preferring a road outside junctions; returns how many roads were reversed."""
    roads = {r.get("id", ""): r for r in root.findall("road")}
    done: set[str] = set()
    for ring in lane_rings(root):
        if done & set(ring):
            continue  # a road of this ring is reversed already (the other lane of a two-lane ring)
        members = [roads[r] for r in dict.fromkeys(ring) if r in roads]
        candidates = [r for r in members if _reversible(r)]
        candidates.sort(key=lambda r: r.get("junction", "-1") != "-1")
        if candidates:
            reverse_road(root, candidates[0])
            done.add(candidates[0].get("id", ""))
    return len(done)
