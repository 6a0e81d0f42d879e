"""Connecting roads joined to the lanes they link (:func:`join_connecting_roads`), part of the
OpenDRIVE fit (:mod:`coster_sumo.exports.opendrive_fit`): each one-lane connecting road starts where
its incoming lane ends and ends where its outgoing lane starts (centre, heading and width), on a
curve along its SUMO shape that its lane can follow (:mod:`~coster_sumo.exports.opendrive_bend`);
a connecting road linked at neither end gets such a curve where one fits (:func:`_smooth_unlinked`).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np
import shapely

from coster_sumo.exports.opendrive_bend import (
    FINE_MAX_M,
    FINE_MIN_POINTS,
    FINE_STEP_M,
    MIN_POINTS,
    NARROW,
    PATH_STEP_M,
    TIGHT,
    Narrowing,
    bend,
    crossings,
    deviation,
    fold_ratio,
    outline,
    piece_points,
    smooth_path,
    untangle,
)
from coster_sumo.exports.opendrive_roads import Sampler, fmt, records_at
from coster_sumo.exports.opendrive_solve import cubic_pieces, hermite_through, records

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
# [m] ... or by up to this much, whatever the width: for lanes under 1.6 m (bicycle lanes and their
# turnarounds) a quarter of the width is closer than the 0.4 m the export lets any junction lane
# leave its SUMO shape on roads it can keep whole (the WOMD samples' tight turns, docs/sumo.md §12a),
# and a folded lane is one no reader can draw
FOLD_ESCAPE_MIN_M = 0.4
# vertices before the first and after the last folding piece of the curve through the points where
# a stretch bent on its own may begin and end (the rest of the road keeps that curve)
STRETCH_REACH = 2


def fold_escape(width: float) -> float:
    """How far [m] a connecting road's curve may leave its SUMO shape so that a lane ``width`` [m]
    wide does not fold: a quarter of the width, at least :data:`FOLD_ESCAPE_MIN_M`."""
    return max(FOLD_ESCAPE_WIDTH_SHARE * width, FOLD_ESCAPE_MIN_M)


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
    offset = records_at(lanes_el.findall("laneOffset"), "s", s)
    border = offset
    for lane in sorted(right.findall("lane"), key=lambda e: -int(e.get("id", "0"))):
        width = records_at(lane.findall("width"), "sOffset", s, base)
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
    own = records_at(lanes[0].findall("width"), "sOffset", 0.0)
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
    # within fold_escape of the narrower lane's width; else the curve through the points, folded.
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
    escape = fold_escape(min(start[1], end[1]))
    near = sorted((w for w in whole if w[0] <= escape), key=lambda w: w[0])
    if not near:  # the last resort before a folded lane: only the stretch where it turns bent
        near = [w for w in [_stretch_bent(c, through, escape)] if w is not None]
    if near:
        return near[0][1], near[0][2], False
    return through, None, True


def _stretch_bent(c: _Connecting, through: list[dict[str, float]], escape: float
                  ) -> tuple[float, list[dict[str, float]], np.ndarray] | None:
    """A whole curve within ``escape`` [m] of the SUMO shape (its deviation [m], pieces, half
    widths at their ends) that keeps the curve through the points except on one stretch around
    where its lane folds, which is bent on its own (:func:`_narrowed`, also on
    :data:`FINE_STEP_M`'s grid where the stretch is short); None where there is none. Where the
    SUMO shape turns round at the end of a long straight (a converted DRT junction: 58 m straight,
    then a U-turn of a 3.2 m lane within 3 m), a curve bent along the whole road spreads its
    stiffening over the straight and leaves it by 1.7 m; bent from the last vertex before the turn
    it stays within 0.7 m (its bound 0.8 m). A short road is its own stretch, bent on the fine
    grid. The shortest stretches are tried first (the least of the road changed, and the
    cheapest), and the first curve within ``escape`` is taken (docs/sumo.md §12a)."""
    # the through curve's vertices and headings (one piece per segment of the SUMO polyline, points
    # closer than a centimetre dropped) are where a stretch may begin and end
    path = np.array([[pc["x"], pc["y"]] for pc in through] + [c.path[-1]], np.float64)
    heading = [pc["hdg"] for pc in through] + [c.end[2]]
    n = len(through)
    sigma = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
    half = 0.5 * (c.start[1] + (c.end[1] - c.start[1]) * sigma / max(float(sigma[-1]), 1e-12))
    folds = [k for k in range(n) if fold_ratio([through[k]], 2 * half[k], 2 * half[k + 1]) >= 1.0]
    if not folds:
        return None
    stretches = sorted(((i, j) for i in range(max(0, folds[0] - STRETCH_REACH), folds[0] + 1)
                        for j in range(folds[-1] + 1, min(n, folds[-1] + 1 + STRETCH_REACH) + 1)),
                       key=lambda ij: (sigma[ij[1]] - sigma[ij[0]], ij))
    # how far each piece of the curve through the points strays from the SUMO shape: a stretch
    # that leaves a piece straying beyond escape unchanged cannot give a curve within it
    samples = 8  # points a piece (piece_points' default)
    off = shapely.distance(shapely.LineString(c.path), shapely.points(piece_points(through, samples)))
    stray = [float(off[k * samples:(k + 1) * samples + 1].max()) for k in range(n)]
    # the lane narrowed within NARROW on every stretch before any within TIGHT: a lane narrowed to
    # 0.6 m on a turn of 0.33 m radius keeps whole, but a reader that samples its borders every
    # half metre (commonroad) cuts across the turn (a converted fokr_bs_demo junction lane)
    for narrowing in (NARROW, TIGHT):
        for i, j in stretches:
            if max(stray[:i] + stray[j:], default=0.0) > escape:
                continue
            part = _Connecting(c.road, c.plan, c.lane, path[i:j + 1].copy(),
                               (path[i].copy(), 2 * half[i], heading[i]), (path[j].copy(), 2 * half[j], heading[j]))
            # the fine grid first where the stretch is short: its lane narrows smoothly where the
            # default grid's narrows in a saw-tooth (width following each point's curvature); the
            # whole road on the default grid is what _joining_curve tried first
            grids = ([(FINE_STEP_M, FINE_MIN_POINTS)] if sigma[j] - sigma[i] <= FINE_MAX_M else []) \
                + ([] if (i, j) == (0, n) else [(PATH_STEP_M, MIN_POINTS)])
            for step_m, min_points in grids:
                bent = _narrowed(part, narrowing, step_m, min_points)
                if bent is None:
                    continue
                pieces = through[:i] + bent[1] + through[j:]
                widths = np.concatenate([half[:i], bent[2], half[j + 1:]])
                off = deviation(pieces, c.path)
                if off <= escape and fold_ratio(pieces, 0.0, 0.0, half=widths) < 1.0 \
                        and not len(crossings(outline(pieces, widths)[0])):
                    return off, pieces, widths
    return None


def _narrowed(c: _Connecting, narrowing: Narrowing, step_m: float = PATH_STEP_M, min_points: int = MIN_POINTS
              ) -> tuple[float, list[dict[str, float]], np.ndarray] | None:
    """The joined road's curve with its lane narrowed where it turns (its deviation from the SUMO
    shape [m], its pieces, half its width at their ends), or None where its lane folds all the same
    (``step_m``, ``min_points``: :func:`~coster_sumo.exports.opendrive_bend.bend`'s grid)."""
    p, hd, half = bend(c.path, c.start[2], c.end[2], c.start[1], c.end[1], narrow=narrowing, step_m=step_m,
                       min_points=min_points)
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
    and within :func:`fold_escape` of its width: the kinks fold its inner border. Where
    that lane folds on every such curve (netconvert's cut of bs3d: a bus lane 3.2 m wide turning
    1.97 rad within 2.5 m), the lane narrowed where it turns, as a joined road's
    (:func:`_narrowed`), its SUMO width kept at both ends, within the same distance."""
    plan, lanes = road.find("planView"), road.findall("lanes/laneSection/right/lane")
    if road.get("junction", "-1") == "-1" or plan is None or len(lanes) != 1 or len(plan) < 2 \
            or any(g.find("line") is None for g in plan) or len(lanes[0].findall("width")) != 1:
        return
    s = np.array([float(g.get("s", "0")) for g in plan.findall("geometry")] + [float(road.get("length", "0"))])
    (x, y, h), width = sample(plan, s), records_at(lanes[0].findall("width"), "sOffset", 0.0)
    path, through = np.column_stack([x, y]), hermite_through(np.column_stack([x, y]), float(h[0]), float(h[-1]))
    if width <= 0.0:
        return
    c = _Connecting(road, plan, lanes[0], path, (path[0], width, float(h[0])), (path[-1], width, float(h[-1])))
    escape = fold_escape(width)
    if fold_ratio(through, width, width) < 1.0 and deviation(through, path) <= escape:
        _write_joined(c, through, None)
        return
    for narrowing in (NARROW, TIGHT):
        bent = _narrowed(c, narrowing)
        if bent is not None and bent[0] <= escape:
            _write_joined(c, bent[1], bent[2])
            return


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
