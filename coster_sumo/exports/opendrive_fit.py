"""Make netconvert's OpenDRIVE lanes follow the SUMO lane shapes they came from.

netconvert's OpenDRIVE writer (SUMO 1.28, measured in ``docs/sumo.md §12``) writes a road per SUMO
edge whose reference line is the leftmost lane's shape moved to that lane's left border, and every
lane with its constant SUMO width; a connecting road per junction connection whose reference line is
one cubic curve from the incoming lane's end to the outgoing lane's start. Both ignore shapes that
do not follow that pattern: the lanes of a converted WOMD map each keep their logged centre line
(they fan out and overlap where the log's lanes do), and its junction lanes follow the logged
interior lanes. There the OpenDRIVE lanes were metres off the SUMO lanes.

:func:`fit_lanes` rewrites such a file in place, road by road (netconvert writes every road with one
lane section; a road that does not match the net is left as it is and counted):

- a **connecting road** gets the SUMO shape of its leftmost lane (the connection's internal lane(s),
  through internal junctions) as its reference line, one ``<line>`` per polyline segment;
- on **every road** each lane's centre is measured against the reference line every
  :data:`STATION_M` (the SUMO lane's lateral offset where its shape crosses the normal there), and
  the borders are solved station by station: lane centre = middle of its two borders, borders in
  order (widths >= 0), widths as close to SUMO's as that leaves room for (a small least-squares
  weight); ``laneOffset`` carries the left border. The border and width curves are written as
  piecewise-linear ``<laneOffset>`` and ``<width>`` records, simplified to :data:`RECORD_TOLERANCE_M`;
  a lane that has no SUMO shape somewhere (before its start, after its end) is left out of the
  lane section there (a section per stretch with the same lanes, :func:`_write_sections`);
- a **normal road** first spans only the stretch where every lane a connection enters or leaves
  exists, its lanes cut at its ends and the pieces handed to the connecting roads
  (:mod:`~coster_sumo.exports.opendrive_ends`), so that no link meets a lane of width 0; those
  are fitted first; a road whose lanes end together (netconvert's) moves its ends in where a
  connection there is too short for its lane to turn without folding
  (:meth:`NetLanes.tight_cutbacks`; game/grid6's corners);
- a U-turn between two lanes side by side is left out (:meth:`NetLanes.uturn_is_pinched`).

The centres are then exact wherever the SUMO lanes of one edge lie side by side in order. Where two
lanes of one edge overlap (a WOMD lane splitting from or merging into its neighbour), adjacent
OpenDRIVE lanes cannot both keep their centres with widths >= 0; the solve then spreads the
smallest error over the lanes involved.
"""

from __future__ import annotations

import copy
import functools
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
from defusedxml import ElementTree as SafeET

from coster_sumo.exports.opendrive_bend import fold_ratio
from coster_sumo.exports.opendrive_ends import CUT_EPS_M, cut_both, road_span, shortfall
from coster_sumo.exports.opendrive_ends import length as piece_length
from coster_sumo.exports.opendrive_join import join_connecting_roads
from coster_sumo.exports.opendrive_net import DEFAULT_LANE_WIDTH_M, NetLanes
from coster_sumo.exports.opendrive_readers import link_lane
from coster_sumo.exports.opendrive_roads import (
    NOT_DRIVABLE,
    Sampler,
    drop_outer_walkways,
    extend_reference,
    fmt,
    one_lane_road,
    overhang,
    renumber,
    set_smooth_plan_view,
    split_connecting,
)
from coster_sumo.exports.opendrive_solve import (
    STATION_M,
    centre_error,
    extent,
    lateral,
    merge_short_runs,
    records,
    reference_axis,
    runs_of,
    solve_borders,
)

STUB_M = 0.01  # [m] length of the connecting road written for a zero-length internal lane
FIT_TOLERANCE_M = 0.005  # [m] lanes whose centres touching lanes miss by more than this get fillers
WIDTH_SLACK_M = 0.5  # [m] ... or that differ from SUMO's widths by more than this get fillers too
FILLER_CODE = "costerFiller"  # userData code marking a filler lane
SECTION_LINK_M = 0.005  # [m] a lane continues into the next section (linked) where its borders meet so
SPAN_TRIES = 4  # placements of a road's ends until its linked lanes reach both (opendrive_ends)
SHORT_M = 0.05  # [m] an internal lane this short pointing backwards is rounding: written along its incoming lane


def _fit_road(road: ET.Element, targets: list[np.ndarray], widths: np.ndarray, sample: Sampler
              ) -> tuple[dict[str, dict[int, int]] | None, float]:
    """Rewrite one road's laneOffset and its right lanes' widths (lane -1 first in ``targets``),
    lengthening its reference line where SUMO lanes start before or end after it, with filler
    lanes between its lanes where they run apart and a lane section per stretch with the same
    lanes (:func:`_write_sections`). Returns, per road end, the new id of each lane where fillers
    or sections renumbered them (empty: ids kept; None: not fitted)."""
    lanes_el = road.find("lanes")
    plan = road.find("planView")
    if lanes_el is None or plan is None or len(list(lanes_el.iter("laneSection"))) != 1:
        return None, 0.0
    right = lanes_el.find("laneSection/right")
    if right is None:
        return None, 0.0
    lane_els = sorted(right.findall("lane"), key=lambda e: -int(e.get("id", "0")))
    if len(lane_els) != len(targets) or any(int(e.get("id", "0")) != -(k + 1) for k, e in enumerate(lane_els)):
        return None, 0.0
    length = float(road.get("length", "0"))
    if length <= 0:
        return None, 0.0
    x, y, h = sample(plan, np.array([0.0, length]))
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        return None, 0.0
    before, after = overhang(x, y, h, targets)
    if before or after:
        extend_reference(road, plan, before, after, x, y, h)
        length = float(road.get("length", "0"))
    s = np.unique(np.append(np.arange(0.0, length, STATION_M), length))
    x, y, h = sample(plan, s)
    # where each lane starts and ends along the reference line: stations there and just outside,
    # so that a lane starts and ends where its SUMO shape does, not on the station grid
    extents = [extent(x, y, h, s, shape) for shape in targets]
    ends = [e for ext in extents if ext is not None for e in (ext[0] - 1e-3, ext[0], ext[1], ext[1] + 1e-3)]
    s2 = np.unique(np.concatenate([s, [e for e in ends if 0.0 < e < length]]))
    if len(s2) != len(s):
        s = s2
        x, y, h = sample(plan, s)
    n = len(targets)
    centres = np.zeros((len(s), n))
    present = np.zeros((len(s), n), bool)
    for k, shape in enumerate(targets):
        if len(shape) < 2:
            continue
        got = lateral(x, y, h, s, shape, extents[k])
        if got is not None:
            centres[:, k], present[:, k] = got
    if not present.any():
        return None, 0.0
    present = merge_short_runs(s, present)
    offset, width, filler = solve_borders(centres, present, widths)
    error = centre_error(centres, present, offset, width, filler)
    odd = float(np.abs(width - widths)[present].max())  # touching lanes keep centres by odd widths
    with_fillers = (error > FIT_TOLERANCE_M or odd > WIDTH_SLACK_M) and n > 1
    if with_fillers:  # neighbours apart by more than their widths: room between them for fillers
        offset, width, filler = solve_borders(centres, present, widths, fillers=True)
        error = centre_error(centres, present, offset, width, filler)
    runs = runs_of(present)
    for el in lanes_el.findall("laneOffset"):
        lanes_el.remove(el)
    for j, (s0, a, b) in enumerate(records(s, offset, runs)):
        lanes_el.insert(j, ET.Element("laneOffset", {"s": fmt(s0), "a": fmt(a), "b": fmt(b), "c": "0", "d": "0"}))
    if len(runs) == 1 and not with_fillers and present[0].all():  # (else absent lanes are left out)
        for k, el in enumerate(lane_els):
            _set_widths(el, records(s, width[:, k], runs))
        return {}, error
    return _write_sections(lanes_el, lane_els, s, width, filler if with_fillers else None, present, runs), error


def _write_sections(lanes_el: ET.Element, lane_els: list[ET.Element], s: np.ndarray, width: np.ndarray,
                    filler: np.ndarray | None, present: np.ndarray, runs: list[tuple[int, int]]
                    ) -> dict[str, dict[int, int]]:
    """One lane section per run of stations where the same lanes are present (a lane that has not
    begun or has ended is left out of the section, rather than written with width 0, which readers
    take for a lane there), each holding its present lanes (``lane_els``, lane -1 first) and, with
    ``filler`` (S, n - 1) [m], the fillers between them, numbered -1, -2, ... from the centre.
    A lane that goes on into the next section is linked to itself there where both its borders
    meet within :data:`SECTION_LINK_M`. Returns, per road end (``start``, ``end``), the new id of
    each old lane id there (a lane absent at that end has none)."""
    template = lanes_el.find("laneSection")
    assert template is not None
    at = list(lanes_el).index(template)
    lanes_el.remove(template)
    n = len(lane_els)
    sections = []  # per run: [(("lane"|"filler", k), element, records)]
    for i, j in runs:
        here = []
        for k in range(n):
            if present[i, k]:
                here.append((("lane", k), records(s[i:j + 1] - s[i], width[i:j + 1, k], [(0, j - i)])))
            if filler is not None and k < n - 1 and float(filler[i:j + 1, k].max()) > 0.0:
                here.append((("filler", k), records(s[i:j + 1] - s[i], filler[i:j + 1, k], [(0, j - i)])))
        if not here:  # no lane at all here (one ends before the next begins): the schema wants one
            here.append((("filler", -1), _gap_records(s, width * present, i, j)))
        sec = copy.deepcopy(template)
        sec.set("s", fmt(float(s[i])))
        right = sec.find("right")
        assert right is not None
        for el in list(right):
            right.remove(el)
        els = {}
        for m, (key, recs) in enumerate(here):
            if key[0] == "lane":
                el = copy.deepcopy(lane_els[key[1]])
                el.set("id", str(-(m + 1)))
                link = el.find("link")
                if link is not None:  # a road's own lanes link to other roads at its ends only
                    for end in list(link):
                        if (end.tag == "predecessor" and i != runs[0][0]) or \
                                (end.tag == "successor" and j != runs[-1][1]):
                            link.remove(end)
                _set_widths(el, recs)
            else:
                el = _filler(-(m + 1), recs)
            right.append(el)
            els[key] = el
        sections.append((float(s[i]), here, els, right))
        lanes_el.insert(at + len(sections) - 1, sec)
    for (s_a, here_a, els_a, _), (s_b, here_b, els_b, _) in zip(sections[:-1], sections[1:], strict=True):
        inner_a, inner_b = _inner_borders(here_a, s_b - s_a), _inner_borders(here_b, 0.0)
        for key in els_a.keys() & els_b.keys():
            if max(abs(inner_a[key][0] - inner_b[key][0]), abs(inner_a[key][1] - inner_b[key][1])) > SECTION_LINK_M:
                continue
            link_lane(els_a[key], "successor", els_b[key].get("id", "0"))
            link_lane(els_b[key], "predecessor", els_a[key].get("id", "0"))
    ends = {}
    for name, (_, here, els, _) in (("start", sections[0]), ("end", sections[-1])):
        ends[name] = {-(key[1] + 1): int(els[key].get("id", "0")) for key, _ in here if key[0] == "lane"}
    return ends


def _gap_records(s: np.ndarray, width: np.ndarray, i: int, j: int) -> list[tuple[float, float, float]]:
    """The width record of a filler over stations ``i..j`` where no lane is present: from the
    lanes' total width before to their total after (``width`` (S, n) [m], 0 where absent)."""
    a = float(width[i - 1].sum()) if i > 0 else float(width[min(j + 1, len(s) - 1)].sum())
    b = float(width[j + 1].sum()) if j + 1 < len(s) else a
    span = float(s[min(j + 1, len(s) - 1)] - s[i])
    return [(0.0, a, (b - a) / span if span > 0 else 0.0)]


def _inner_borders(here: list[tuple[tuple[str, int], list[tuple[float, float, float]]]], at: float
                   ) -> dict[tuple[str, int], tuple[float, float]]:
    """Inner and outer border [m] (from the section's left border, positive to the right) of each
    lane of a section at ``at`` [m] from the section's start, as a reader evaluates the width records."""
    out, border = {}, 0.0
    for key, recs in here:
        w = 0.0
        for s0, a, b in recs:
            if s0 <= at + 1e-9:
                w = a + b * (at - s0)
        out[key] = (border, border + w)
        border += w
    return out


def _set_widths(lane: ET.Element, recs: list[tuple[float, float, float]]) -> None:
    """Replace a lane's ``<width>`` records (linear pieces (s, value, slope)) where they were."""
    old = lane.findall("width")
    at = list(lane).index(old[0]) if old else min(1, len(lane))
    for w in old:
        lane.remove(w)
    for j, (s0, a, b) in enumerate(recs):
        lane.insert(at + j, ET.Element("width", {"sOffset": fmt(s0), "a": fmt(a), "b": fmt(b), "c": "0",
                                                 "d": "0"}))


def _filler(lane_id: int, recs: list[tuple[float, float, float]]) -> ET.Element:
    """A filler lane: the room between two lanes of one SUMO edge that run apart (a median)."""
    el = ET.Element("lane", {"id": str(lane_id), "type": "median", "level": "true"})
    ET.SubElement(el, "link")
    _set_widths(el, recs)
    ET.SubElement(el, "roadMark", {"sOffset": "0", "type": "none", "weight": "standard", "color": "standard",
                                   "width": "0.13"})
    ET.SubElement(el, "userData", {"code": FILLER_CODE, "value": "true"})
    return el


def fit_lanes(xodr: Path, net_file: Path, sample: Sampler) -> dict[str, int]:
    """Rewrite ``xodr`` (netconvert's, written with ``--output.original-names``) so that its lanes
    follow the SUMO lanes of ``net_file`` (see the module docstring).

    ``sample(planView, s)`` gives x, y, heading of a reference line at ``s``. Returns the number of
    roads fitted and left as they were, normal and connecting.
    """
    net = NetLanes.read(net_file)
    cutbacks = net.tight_cutbacks()
    root = (tree := SafeET.parse(str(xodr), forbid_dtd=True)).getroot()
    counts = {"roads_fitted": 0, "roads_kept": 0, "connecting_fitted": 0, "connecting_kept": 0, "connecting_split": 0,
              "renumbered": 0}
    if net.lefthand:
        counts["roads_kept"] = len(root.findall("road"))
        return counts
    edge_of: dict[str, str] = {}
    for road in root.findall("road"):
        user = road.find("userData[@code='sumoId']")
        if user is not None:
            edge_of[road.get("id", "")] = user.get("value", "")
    renumbered: dict[str, dict[str, dict[int, int]]] = {}
    next_id = [max((int(r.get("id", "0")) for r in root.findall("road") if r.get("id", "").isdigit()), default=0) + 1]
    # normal roads first: where one starts and ends decides what its connecting roads drive on
    roads = sorted(root.findall("road"), key=lambda r: r.get("junction", "-1") != "-1")
    for road in roads:
        connecting = road.get("junction", "-1") != "-1"
        if connecting:  # sidewalks of a connecting road: SUMO has no internal lane for them
            drop_outer_walkways(root, road, functools.partial(_served, road, net=net, edge_of=edge_of))
        targets, widths = _targets(road, net, edge_of, connecting)
        if targets is None:
            counts["connecting_kept" if connecting else "roads_kept"] += 1
        elif connecting and _keys(road, net, edge_of) <= net.pinched_uturns:
            _remove_connecting(root, road)  # (NetLanes.uturn_is_pinched: no lane outline holds it)
            counts["pinched_uturns_left_out"] = counts.get("pinched_uturns_left_out", 0) + 1
        elif connecting:  # one road per lane, each on its lane's SUMO shape (module docstring)
            if len(targets) == 1:
                one_lane_road(road, targets[0], float(widths[0]))
            else:
                split_connecting(root, road, targets, widths, next_id)
                counts["connecting_split"] += 1
            counts["connecting_fitted"] += 1
        else:  # netconvert's curve through a jittery WOMD lane wiggles; lanes far from it fold
            axis = reference_axis(targets, widths)
            lane_ids = _road_lane_ids(road, net, edge_of)
            enters, leaves = [lane in net.enters for lane in lane_ids], [lane in net.leaves for lane in lane_ids]
            inset = (0.0, 0.0)
            for _ in range(SPAN_TRIES):
                span, moved = road_span(axis, targets, enters, leaves, inset)
                if inset == (0.0, 0.0):  # room for tight turns (NetLanes.tight_cutbacks)
                    inset = (max((cutbacks.get(lane, (0.0, 0.0))[0] for lane in lane_ids), default=0.0),
                             max((cutbacks.get(lane, (0.0, 0.0))[1] for lane in lane_ids), default=0.0))
                    if max(inset) > CUT_EPS_M:
                        span, moved = road_span(axis, targets, enters, leaves, inset)
                        counts["roads_cut_back"] = counts.get("roads_cut_back", 0) + moved
                set_smooth_plan_view(road, span if moved else axis, sample)
                if not moved:
                    break
                x, y, h = sample(road.find("planView"), np.array([0.0, float(road.get("length", "0"))]))
                short = shortfall(targets, enters, leaves, np.array([x[0], y[0]]), float(h[0]),
                                  np.array([x[-1], y[-1]]), float(h[-1]))
                if max(short) <= CUT_EPS_M:
                    break
                inset = (inset[0] + short[0] + CUT_EPS_M, inset[1] + short[1] + CUT_EPS_M)
            if moved:  # the lanes cut at the road's ends (opendrive_ends)
                targets, lost = _cut_lanes(road, lane_ids, net, sample)
                counts["roads_moved"] = counts.get("roads_moved", 0) + 1
                counts["lost_cm"] = counts.get("lost_cm", 0) + int(round(100 * lost))
            ids, _ = _fit_road(road, targets, widths, sample)
            if ids:
                renumbered[road.get("id", "")] = ids
            counts["roads_fitted" if ids is not None else "roads_kept"] += 1
    counts["renumbered"] = len(renumbered)
    counts["sections"] = sum(len(r.findall("lanes/laneSection")) > 1 for r in root.findall("road"))
    counts["links_to_no_lane_removed"] = renumber(root, renumbered)
    counts["connecting_joined"], counts["connecting_folded"] = join_connecting_roads(root, sample)
    counts["folded_walkways_left_out"] = _drop_folded_walkways(root)
    ET.indent(tree)
    tree.write(xodr, encoding="UTF-8", xml_declaration=True)
    return counts


def _road_lane_ids(road: ET.Element, net: NetLanes, edge_of: dict[str, str]) -> list[str]:
    """The SUMO lane ids of a normal road's right lanes, lane -1 (the leftmost) first."""
    lanes = net.edge_lanes.get(edge_of.get(road.get("id", ""), ""), [])
    return lanes[::-1]


def _cut_lanes(road: ET.Element, lane_ids: list[str], net: NetLanes, sample: Sampler
               ) -> tuple[list[np.ndarray], float]:
    """Cut every lane of a road on the normals of its reference line's two ends
    (:func:`~coster_sumo.exports.opendrive_ends.cut_both`): the pieces before and past go to
    ``net.head`` and ``net.tail``, what lies between becomes the lane's shape. Returns the new
    shapes (lane -1 first) and the length [m] cut off where no connection takes it up."""
    plan = road.find("planView")
    assert plan is not None  # (set_smooth_plan_view wrote it)
    x, y, h = sample(plan, np.array([0.0, float(road.get("length", "0"))]))
    shapes, lost = [], 0.0
    for lane in lane_ids:
        head, mid, tail = cut_both(net.shape[lane], np.array([x[0], y[0]]), float(h[0]),
                                   np.array([x[-1], y[-1]]), float(h[-1]))
        if head is not None:
            net.head[lane] = head
            lost += 0.0 if lane in net.enters else piece_length(head)
        if tail is not None:
            net.tail[lane] = tail
            lost += 0.0 if lane in net.leaves else piece_length(tail)
        net.shape[lane] = mid
        shapes.append(mid)
    return shapes, lost


def _keys(road: ET.Element, net: NetLanes, edge_of: dict[str, str]) -> set[tuple[str, int, str, int]]:
    """The SUMO connections (keys as ``NetLanes.via``) a connecting road's lanes came from."""
    pred, succ = road.find("link/predecessor"), road.find("link/successor")
    if pred is None or succ is None:
        return set()
    frm, to = edge_of.get(pred.get("elementId", ""), ""), edge_of.get(succ.get("elementId", ""), "")
    n_from, n_to = len(net.edge_lanes.get(frm, [])), len(net.edge_lanes.get(to, []))
    keys = set()
    for lane in road.findall("lanes/laneSection/right/lane"):
        p, q = lane.find("link/predecessor"), lane.find("link/successor")
        if p is None or q is None:
            return set()
        keys.add((frm, n_from + int(p.get("id", "0")), to, n_to + int(q.get("id", "0"))))
    return keys


def _drop_folded_walkways(root: ET.Element) -> int:
    """Take out every connecting road that is a walkway folding on its curve (:func:`_folded_walkway`;
    SUMO has no drivable lane there); returns how many."""
    gone = [r for r in root.findall("road") if r.get("junction", "-1") != "-1" and _folded_walkway(r)]
    for road in gone:
        _remove_connecting(root, road)
    return len(gone)


def _folded_walkway(road: ET.Element) -> bool:
    """Whether a connecting road of netconvert's is one lane that is not drivable (a sidewalk
    the fit left on netconvert's curve) and that folds on that curve (cubics on OSM cuts whose u
    runs back: their outline crosses itself, commonroad's invalid lanelets)."""
    lanes = road.findall("lanes/laneSection/right/lane") + road.findall("lanes/laneSection/left/lane")
    geos = road.findall("planView/geometry")
    if len(lanes) != 1 or lanes[0].get("type") not in NOT_DRIVABLE or not geos \
            or any(g.find("paramPoly3[@pRange='normalized']") is None for g in geos):
        return False
    width = max((float(w.get("a", "0")) for w in lanes[0].findall("width")), default=0.0)
    pieces = [{**{k: float(pp.get(k, "0")) for k in ("bU", "cU", "dU", "cV", "dV")},
               "length": float(g.get("length", "0"))} for g in geos if (pp := g.find("paramPoly3")) is not None]
    return width > 0.0 and fold_ratio(pieces, width, width) >= 1.0


def _remove_connecting(root: ET.Element, road: ET.Element) -> None:
    """Take a connecting road out of the file with its junction's connections to it (and the
    junction, where none is left; make_readable drops the roads' links to it)."""
    junction = root.find(f"junction[@id='{road.get('junction', '')}']")
    if junction is not None:
        for conn in junction.findall("connection"):
            if conn.get("connectingRoad") == road.get("id"):
                junction.remove(conn)
        if junction.find("connection") is None:
            root.remove(junction)
    root.remove(road)


def _served(road: ET.Element, lane: ET.Element, *, net: NetLanes, edge_of: dict[str, str]) -> bool:
    """Whether a SUMO connection runs where a connecting road's lane does (or it is unknown)."""
    pred, succ = road.find("link/predecessor"), road.find("link/successor")
    p, q = lane.find("link/predecessor"), lane.find("link/successor")
    if pred is None or succ is None or p is None or q is None:
        return True
    frm, to = edge_of.get(pred.get("elementId", ""), ""), edge_of.get(succ.get("elementId", ""), "")
    key = (frm, len(net.edge_lanes.get(frm, [])) + int(p.get("id", "0")), to,
           len(net.edge_lanes.get(to, [])) + int(q.get("id", "0")))
    return net.connection_shape(*key) is not None


def _targets(road: ET.Element, net: NetLanes, edge_of: dict[str, str], connecting: bool
             ) -> tuple[list[np.ndarray] | None, np.ndarray]:
    """The SUMO shapes (lane -1 first) and widths a road's right lanes came from (None: unknown)."""
    right = road.find("lanes/laneSection/right")
    if right is None:
        return None, np.zeros(0)
    ids = sorted((int(e.get("id", "0")) for e in right.findall("lane")), reverse=True)
    if not connecting:
        lanes = net.edge_lanes.get(edge_of.get(road.get("id", ""), ""), [])
        if len(lanes) != len(ids):
            return None, np.zeros(0)
        chosen = [lanes[len(lanes) + i] for i in ids]  # id -1 = the leftmost (highest index)
        return [net.shape[c] for c in chosen], np.array([net.width[c] for c in chosen])
    pred, succ = road.find("link/predecessor"), road.find("link/successor")
    if pred is None or succ is None:
        return None, np.zeros(0)
    frm, to = edge_of.get(pred.get("elementId", ""), ""), edge_of.get(succ.get("elementId", ""), "")
    n_from, n_to = len(net.edge_lanes.get(frm, [])), len(net.edge_lanes.get(to, []))
    shapes, widths = [], []
    for i in ids:
        lane = right.find(f"lane[@id='{i}']")
        p = lane.find("link/predecessor") if lane is not None else None
        q = lane.find("link/successor") if lane is not None else None
        if p is None or q is None:
            return None, np.zeros(0)
        key = (frm, n_from + int(p.get("id", "0")), to, n_to + int(q.get("id", "0")))
        shape = net.connection_shape(*key)
        if shape is None:
            return None, np.zeros(0)
        length = float(np.hypot(*np.diff(shape, axis=0).T).sum()) if len(shape) > 1 else 0.0
        src = net.shape.get(net.edge_lanes[frm][key[1]]) if 0 <= key[1] < n_from else None
        d = src[-1] - src[-2] if src is not None and len(src) >= 2 else shape[-1] - shape[0]
        d = d / max(float(np.hypot(*d)), 1e-9) if np.hypot(*d) > 0 else np.array([1.0, 0.0])
        if length < SHORT_M and float(np.dot(shape[-1] - shape[0], d)) <= 0:
            # a few centimetres pointing backwards: rounding; a stub along the incoming lane
            shape = np.vstack([shape[0], shape[0] + max(length, STUB_M) * d])
        via = net.via[key]
        shapes.append(shape)
        widths.append(net.width.get(via, DEFAULT_LANE_WIDTH_M))
    return shapes, np.array(widths)
