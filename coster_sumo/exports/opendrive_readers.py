"""What third-party OpenDRIVE readers need of a fitted ``.xodr`` that netconvert's file does not give.

Checked with ASAM's OpenDRIVE checker (``asam-qc-opendrive``), commonroad-scenario-designer's
OpenDRIVE conversion and pyxodr (``docs/sumo.md §12a``). :func:`make_readable` rewrites the tree:

- **version**: netconvert writes OpenDRIVE 1.4, on which ASAM's checker runs 10 of its 23 checks
  (the others are defined from 1.7 on); the file is valid OpenDRIVE 1.8 as written, and is
  declared so (22 checks run; the 23rd applies up to 1.7 only).
- **integer ids for signals and controllers**: netconvert names a signal ``<tls>_<link index>``
  and a controller by its SUMO traffic light; commonroad's reader takes every signal and
  controller id for an integer and stops on the first that is not. Ids become 1, 2, ...; the
  SUMO names stay in ``name``.
- **links to junctions that exist**: netconvert links a road to the junction at its end node
  even where it writes no ``<junction>`` for that node (a dead end, a node without connecting
  roads); such links are dropped.
- **no redundant line geometries**: ASAM's checker warns about two consecutive ``<line>`` pieces of
  a reference line whose headings agree to 1e-6 rad (one line says the same); netconvert writes one
  line per collinear SUMO shape segment, and a straight end piece may continue a straight line.
  Such pieces are merged into one (:func:`merge_collinear_lines`).
- **closed rings of lanes read as more than one lanelet**: commonroad joins a lane with its only
  successor, so a loop of lanes that follow one another one to one (a ring road, a cut's closed
  loop) becomes one lanelet ending where it starts, an outline no polygon can be. One road of each
  such loop is written the other way round, its lanes as left lanes
  (:mod:`~coster_sumo.exports.opendrive_rings`): the same lanes, and the reader stops joining there.
- **no roads of (almost) no length**: a junction whose connecting roads are all shorter than
  :data:`MIN_ROAD_M` (SUMO internal lanes of length 0 where two edges meet end to end) is
  replaced by direct road-to-road links; its lane links carry over.
- **objects the schema and commonroad accept**: netconvert writes a crosswalk ``<object>`` without
  ``zOffset`` (required by the 1.8 schema; the checker skips its other checks on a file that fails
  the schema) and with the SUMO crossing's id (``:<node>_c0``), which commonroad's reader takes for
  an integer. Objects get ``zOffset="0"`` where it is missing and ids 1, 2, ... (the SUMO id stays in
  ``name``).
- **a curve as long as its length says**: ASAM's checker wants a normalized ``paramPoly3``'s arc
  length within 1 mm of its ``length``; netconvert's own curve of a connecting road the fit leaves
  as it is (a one-piece road whose u runs back and forth) may miss it by more. Such a road's
  length becomes the curve's arc length (:func:`_true_curve_lengths`).
- **road lengths in whole millimetres**: commonroad's reader evaluates a lane's border at the
  station rounded to 1 mm (its plan view takes no ``is_last_pos``, and the fallback rounds): at the
  end of a road whose length has a fraction of a millimetre of 0.5 or more it samples up to 0.5 mm
  past the road's end, and where it joins that lane to the next road's lane, the border steps back
  by as much: a self-intersecting lanelet. Every road's length becomes a whole number of
  millimetres (:func:`_whole_mm_lengths`).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np

from coster_sumo.exports.opendrive_rings import break_lane_rings

OPENDRIVE_REV_MINOR = 8  # OpenDRIVE 1.8
MIN_ROAD_M = 0.05  # [m] shorter connecting roads are bypassed (readers choke on 1 cm roads)
LINE_HEADING_TOL = 1e-6  # [rad] ASAM's checker takes two lines this close in heading for one
LINE_MERGE_M = 1e-4  # [m] two lines are merged where one line through both stays this close to them


def make_readable(root: ET.Element) -> dict[str, int]:
    """Apply every rewrite of the module docstring to an OpenDRIVE tree in place; returns counts."""
    header = root.find("header")
    if header is not None:
        header.set("revMajor", "1")
        header.set("revMinor", str(OPENDRIVE_REV_MINOR))
    counts = {"signals_renumbered": _integer_signal_ids(root), "objects_renumbered": _readable_objects(root)}
    counts["junctions_bypassed"] = _bypass_short_junctions(root)
    counts["lines_merged"] = sum(merge_collinear_lines(road) for road in root.findall("road"))
    counts["dangling_links_dropped"] = _drop_dangling_junction_links(root)
    counts["rings_broken"] = break_lane_rings(root)
    counts["lengths_corrected"] = _true_curve_lengths(root)
    counts["lengths_to_mm"] = _whole_mm_lengths(root)
    return counts


def _integer_signal_ids(root: ET.Element) -> int:
    """Signals and controllers numbered 1, 2, ... (old ids kept as names); returns how many signals."""
    signal_ids: dict[str, str] = {}
    for k, sig in enumerate(root.iter("signal"), start=1):
        old = sig.get("id", "")
        signal_ids.setdefault(old, str(k))
        sig.set("id", signal_ids[old])
        if not sig.get("name"):
            sig.set("name", old)
    for ref in root.iter("signalReference"):
        ref.set("id", signal_ids.get(ref.get("id", ""), ref.get("id", "")))
    controller_ids: dict[str, str] = {}
    for k, ctl in enumerate(root.findall("controller"), start=1):
        old = ctl.get("id", "")
        controller_ids[old] = str(k)
        ctl.set("id", str(k))
        if not ctl.get("name"):
            ctl.set("name", old)
        for control in ctl.findall("control"):
            control.set("signalId", signal_ids.get(control.get("signalId", ""), control.get("signalId", "")))
    for junction in root.findall("junction"):
        for control in junction.findall("controller"):
            control.set("id", controller_ids.get(control.get("id", ""), control.get("id", "")))
    return len(signal_ids)


def _readable_objects(root: ET.Element) -> int:
    """Road objects numbered 1, 2, ... (old ids kept as names), ``zOffset`` 0 where missing; returns
    how many objects."""
    count = 0
    for road in root.findall("road"):
        for obj in road.findall("objects/object"):
            count += 1
            old = obj.get("id", "")
            obj.set("id", str(count))
            if not obj.get("name"):
                obj.set("name", old)
            if obj.get("zOffset") is None:
                obj.set("zOffset", "0")
    return count


CURVE_LENGTH_TOL_M = 1e-4  # [m] a paramPoly3's length this far from its arc length is corrected


def _true_curve_lengths(root: ET.Element) -> int:
    """Set the length of every one-piece road whose normalized ``paramPoly3`` has another arc length
    (by more than :data:`CURVE_LENGTH_TOL_M`) to that arc length; returns how many roads."""
    p = np.linspace(0.0, 1.0, 4001)
    fixed = 0
    for road in root.findall("road"):
        geos = road.findall("planView/geometry")
        poly = geos[0].find("paramPoly3") if len(geos) == 1 else None
        if poly is None or poly.get("pRange", "normalized") != "normalized":
            continue
        c = {k: float(poly.get(k, "0")) for k in ("bU", "cU", "dU", "bV", "cV", "dV")}
        speed = np.hypot(c["bU"] + 2 * c["cU"] * p + 3 * c["dU"] * p ** 2,
                         c["bV"] + 2 * c["cV"] * p + 3 * c["dV"] * p ** 2)
        arc = float(np.sum((speed[1:] + speed[:-1]) * 0.5 * np.diff(p)))
        if abs(arc - float(geos[0].get("length", "0"))) > CURVE_LENGTH_TOL_M:
            geos[0].set("length", f"{arc:.8f}")
            road.set("length", f"{arc:.8f}")
            fixed += 1
    return fixed


def _whole_mm_lengths(root: ET.Element) -> int:
    """Make every road's length a whole number of millimetres by changing its last geometry's
    ``length``; returns how many roads changed. A normalized ``paramPoly3`` keeps its shape whatever
    its ``length`` says (p runs over [0, 1]): its length is rounded, so that it stays within 0.5 mm
    of the arc length (ASAM's checker allows 1 mm). Any other piece is parametrised by its arc
    length: its length is rounded down, so that it ends less than 1 mm short of where it did
    (ASAM's checker allows 1 cm between linked lanes) and never past the next road's start. Stations
    of signals and objects beyond the new end are moved onto it."""
    changed = 0
    for road in root.findall("road"):
        geos = road.findall("planView/geometry")
        if not geos:
            continue
        last = geos[-1]
        start = float(last.get("s", "0"))
        end = start + float(last.get("length", "0"))
        poly = last.find("paramPoly3")
        shape_free = poly is not None and poly.get("pRange", "normalized") == "normalized"
        mm = round(end * 1000.0) if shape_free else math.floor(end * 1000.0 + 1e-6)
        new_end = mm / 1000.0
        if abs(new_end - end) < 1e-9 or new_end - start <= 0.0:
            continue
        last.set("length", f"{new_end - start:.9f}")
        road.set("length", f"{new_end:.3f}")
        for el in [*road.findall("signals/signal"), *road.findall("objects/object")]:
            if float(el.get("s", "0")) > new_end:
                el.set("s", f"{new_end:.3f}")
        changed += 1
    return changed


def merge_collinear_lines(road: ET.Element) -> int:
    """Merge consecutive ``<line>`` geometries of a road's planView that continue each other (headings
    within :data:`LINE_HEADING_TOL`, or the second's ends within :data:`LINE_MERGE_M` of the first's
    line); returns how many pieces were merged away."""
    plan = road.find("planView")
    if plan is None:
        return 0
    merged = 0
    geos = plan.findall("geometry")
    keep = geos[:1]
    for g in geos[1:]:
        prev = keep[-1]
        if prev.find("line") is None or g.find("line") is None or not _continues(prev, g):
            keep.append(g)
            continue
        prev.set("length", f"{float(prev.get('length', '0')) + float(g.get('length', '0')):.8f}")
        plan.remove(g)
        merged += 1
    return merged


def _continues(a: ET.Element, b: ET.Element) -> bool:
    """Whether line ``b`` lies on line ``a`` extended (see :func:`merge_collinear_lines`)."""
    ha, hb = float(a.get("hdg", "0")), float(b.get("hdg", "0"))
    la, lb = float(a.get("length", "0")), float(b.get("length", "0"))
    ax, ay = float(a.get("x", "0")), float(a.get("y", "0"))
    ux, uy = math.cos(ha), math.sin(ha)
    bx, by = float(b.get("x", "0")), float(b.get("y", "0"))
    ex, ey = bx + lb * math.cos(hb), by + lb * math.sin(hb)
    start_gap = math.hypot(ax + la * ux - bx, ay + la * uy - by)
    off_line = abs((ex - ax) * uy - (ey - ay) * ux)  # the second's end from the first's line
    turn = abs(math.remainder(hb - ha, math.tau))
    return start_gap <= LINE_MERGE_M and (turn < LINE_HEADING_TOL or off_line <= LINE_MERGE_M)


def _drop_dangling_junction_links(root: ET.Element) -> int:
    """Remove road links to junctions the file does not hold; returns how many."""
    junctions = {j.get("id") for j in root.findall("junction")}
    dropped = 0
    for road in root.findall("road"):
        link = road.find("link")
        if link is None:
            continue
        for end in list(link):
            if end.get("elementType") == "junction" and end.get("elementId") not in junctions:
                link.remove(end)
                dropped += 1
    return dropped


def _road_length(road: ET.Element) -> float:
    return float(road.get("length", "0"))


def _bypass_short_junctions(root: ET.Element) -> int:
    """Replace junctions whose connecting roads are all shorter than :data:`MIN_ROAD_M` by direct
    links between their incoming and outgoing roads; returns how many junctions."""
    roads = {r.get("id", ""): r for r in root.findall("road")}
    bypassed = 0
    for junction in root.findall("junction"):
        jid = junction.get("id", "")
        members = [r for r in roads.values() if r.get("junction") == jid]
        if not members or any(_road_length(r) >= MIN_ROAD_M for r in members):
            continue
        pairs = []
        for conn in members:
            pred, succ = conn.find("link/predecessor"), conn.find("link/successor")
            if pred is None or succ is None or pred.get("elementType") != "road" \
                    or succ.get("elementType") != "road":
                break
            pairs.append((conn, pred, succ))
        else:
            incoming = [p.get("elementId") for _, p, _ in pairs]
            outgoing = [s.get("elementId") for _, _, s in pairs]
            # a road links to one road at each end: only junctions that pair roads one to one
            if len(set(incoming)) != len(pairs) or len(set(outgoing)) != len(pairs):
                continue
            for conn, pred, succ in pairs:
                _link_through(roads, conn, pred, succ, jid)
                root.remove(conn)
                del roads[conn.get("id", "")]
            root.remove(junction)
            bypassed += 1
    return bypassed


def _link_through(roads: dict[str, ET.Element], conn: ET.Element, pred: ET.Element, succ: ET.Element,
                  junction_id: str) -> None:
    """Link the roads before and after connecting road ``conn`` to each other, lane by lane."""
    a, b = roads.get(pred.get("elementId", "")), roads.get(succ.get("elementId", ""))
    if a is None or b is None:
        return
    a_end, b_end = pred.get("contactPoint", "end"), succ.get("contactPoint", "start")
    lane_pairs = []
    for lane in conn.iter("lane"):
        p, s = lane.find("link/predecessor"), lane.find("link/successor")
        if p is not None and s is not None:
            lane_pairs.append((p.get("id", "0"), s.get("id", "0")))
    for road, end, other, other_end, mine in ((a, a_end, b, b_end, 0), (b, b_end, a, a_end, 1)):
        tag = "successor" if end == "end" else "predecessor"
        link = road.find("link")
        if link is None:
            link = ET.SubElement(road, "link")
        for el in link.findall(tag):
            if el.get("elementType") == "junction" and el.get("elementId") == junction_id:
                link.remove(el)
        ET.SubElement(link, tag, {"elementType": "road", "elementId": other.get("id", ""),
                                  "contactPoint": other_end})
        for lane_id, other_id in ((pair[mine], pair[1 - mine]) for pair in lane_pairs):
            # the lane section at that end (a road's lanes may differ from section to section)
            sections = road.findall("lanes/laneSection")
            section = (sections[-1] if end == "end" else sections[0]) if sections else road
            found = [ln for ln in section.iter("lane") if ln.get("id") == lane_id]
            if not found:
                continue
            link_lane(found[0], tag, other_id)
        _order_link(link)


def link_lane(lane: ET.Element, tag: str, other: str) -> None:
    """Give a lane a ``predecessor``/``successor`` lane link to lane ``other`` (replacing one it had),
    predecessors first, as the schema wants."""
    link = lane.find("link")
    if link is None:
        link = ET.Element("link")
        lane.insert(0, link)
    for el in link.findall(tag):
        link.remove(el)
    el = ET.Element(tag, {"id": other})
    if tag == "predecessor":
        link.insert(0, el)
    else:
        link.append(el)


def _order_link(link: ET.Element) -> None:
    """Predecessors before successors, as the schema wants them."""
    children = list(link)
    for el in children:
        link.remove(el)
    for el in sorted(children, key=lambda e: e.tag != "predecessor"):
        link.append(el)
