"""OpenDRIVE (``.xodr``) of a scene's SUMO net, and how far its lanes are from the SUMO lanes.

:func:`write_xodr`: ``netconvert --opendrive-output`` with ``--offset.disable-normalization true``,
so the OpenDRIVE inertial frame is the SUMO net's own frame (netconvert would otherwise shift the
net to start at the origin), and ``--output.original-names true``, so every road names its SUMO
edge (``<userData code="sumoId">``); a converted scene's staging edge is left out (it is no road);
then :func:`coster_sumo.exports.opendrive_fit.fit_lanes` moves
the lanes onto the SUMO lane shapes (netconvert writes an edge's leftmost lane border plus constant
widths, and one cubic curve per junction connection). netconvert writes one road per edge (and one
connecting road per junction connection), lanes as right lanes (negative ids).

:func:`xodr_lane_centres` samples the lane centre lines back (line, arc and paramPoly3 geometries,
laneOffset, width polynomials; stretches where a lane's width is 0 are no lane and are left out)
and :func:`compare_with_net` measures them against the SUMO lane shapes (which are lane centre
lines), both ways.
"""

from __future__ import annotations

import math
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from defusedxml import ElementTree as SafeET

from coster_sumo.errors import InputError, SumoError
from coster_sumo.exports.opendrive_fit import FILLER_CODE, fit_lanes
from coster_sumo.exports.opendrive_net import NetLanes
from coster_sumo.exports.opendrive_readers import MIN_ROAD_M, make_readable
from coster_sumo.formats.scene_folder import STAGING_EDGE
from coster_sumo.infra import sumo_install

SAMPLE_STEP_M = 0.5  # [m] spacing of the xodr samples in compare_with_net
MIN_WIDTH_M = 1e-3  # [m] a lane narrower than this is no lane there (it starts or ends)


def write_xodr(net_file: Path, out: Path, fit: bool = True) -> Path:
    """OpenDRIVE of a SUMO net by netconvert, in the net's own coordinates, its lanes fitted onto
    the SUMO lane shapes and what readers need rewritten
    (:func:`~coster_sumo.exports.opendrive_readers.make_readable`; ``fit=False``: netconvert's file
    as it is)."""
    cmd = [sumo_install.binary("netconvert"), "--sumo-net-file", str(net_file), "--opendrive-output", str(out),
           "--offset.disable-normalization", "true", "--output.original-names", "true", "--no-warnings", "true",
           # a converted scene's staging edge is no road (netconvert ignores the name in other nets)
           "--remove-edges.explicit", STAGING_EDGE]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=sumo_install.subprocess_env(), timeout=600)
    if proc.returncode != 0 or not out.is_file():
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
        raise SumoError(f"netconvert --opendrive-output failed on {net_file}: {tail[0]}")
    if fit:
        fit_lanes(out, net_file, _reference_line)
        tree = SafeET.parse(str(out), forbid_dtd=True)
        make_readable(tree.getroot())
        tree.write(out, encoding="UTF-8", xml_declaration=True)
    return out


# --- OpenDRIVE sampling ---------------------------------------------------------------------------


@dataclass
class XodrLane:
    """Centre line samples of one OpenDRIVE lane.

    Attributes:
        road: road id; junction: the road's junction id (-1: none); lane: lane id; kind: lane type.
        xy: (N, 2) float64 [m] centre line points in the OpenDRIVE inertial frame.
        filler: a filler lane (the room between two lanes that run apart; no SUMO lane).
    """

    road: str
    junction: str
    lane: int
    kind: str
    xy: np.ndarray
    filler: bool = False


def _f(el: Any, key: str, default: float = 0.0) -> float:
    v = el.get(key)
    return float(v) if v is not None else default


def _poly(recs: list[tuple[float, float, float, float, float]], s: np.ndarray) -> np.ndarray:
    """Piecewise cubic (s0, a, b, c, d) records evaluated at ``s`` (each record from its s0 on)."""
    out = np.zeros_like(s)
    if not recs:
        return out
    starts = np.array([r[0] for r in recs])
    idx = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(recs) - 1)
    for k, (s0, a, b, c, d) in enumerate(recs):
        m = idx == k
        ds = s[m] - s0
        out[m] = a + b * ds + c * ds ** 2 + d * ds ** 3
    return out


def _reference_line(plan_view: Any, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x, y [m], heading [rad] of a road's reference line at ``s`` (line, arc, paramPoly3)."""
    x, y, h = np.full_like(s, np.nan), np.full_like(s, np.nan), np.full_like(s, np.nan)
    geos = list(plan_view.iter("geometry"))
    starts = np.array([_f(g, "s") for g in geos])
    which = np.clip(np.searchsorted(starts, s + 1e-9, side="right") - 1, 0, len(geos) - 1)  # last s0 <= s
    for k, g in enumerate(geos):
        s0, length = _f(g, "s"), _f(g, "length")
        m = which == k
        ds = s[m] - s0  # (past the last geometry's end by rounding only: extrapolated)
        x0, y0, h0 = _f(g, "x"), _f(g, "y"), _f(g, "hdg")
        shape = next(iter(g))
        if shape.tag == "line":
            x[m], y[m], h[m] = x0 + ds * math.cos(h0), y0 + ds * math.sin(h0), h0
        elif shape.tag == "arc":
            kc = _f(shape, "curvature")
            if abs(kc) < 1e-12:
                x[m], y[m], h[m] = x0 + ds * math.cos(h0), y0 + ds * math.sin(h0), h0
            else:
                x[m] = x0 + (np.sin(h0 + kc * ds) - math.sin(h0)) / kc
                y[m] = y0 - (np.cos(h0 + kc * ds) - math.cos(h0)) / kc
                h[m] = h0 + kc * ds
        elif shape.tag == "paramPoly3":
            p = ds / length if shape.get("pRange", "normalized") == "normalized" and length > 0 else ds
            cu = [_f(shape, k_) for k_ in ("aU", "bU", "cU", "dU")]
            cv = [_f(shape, k_) for k_ in ("aV", "bV", "cV", "dV")]
            u = cu[0] + cu[1] * p + cu[2] * p ** 2 + cu[3] * p ** 3
            v = cv[0] + cv[1] * p + cv[2] * p ** 2 + cv[3] * p ** 3
            du = cu[1] + 2 * cu[2] * p + 3 * cu[3] * p ** 2
            dv = cv[1] + 2 * cv[2] * p + 3 * cv[3] * p ** 2
            c, sn = math.cos(h0), math.sin(h0)
            x[m], y[m], h[m] = x0 + c * u - sn * v, y0 + sn * u + c * v, h0 + np.arctan2(dv, du)
        else:
            raise InputError(f"OpenDRIVE geometry <{shape.tag}> is not supported by this sampler")
    return x, y, h


def xodr_lane_centres(path: Path, step: float = SAMPLE_STEP_M) -> list[XodrLane]:
    """Every lane's centre line of an OpenDRIVE file, sampled every ``step`` m along its road, at
    each geometry's start and on both sides of each laneOffset and width record's start.

    Lateral position of lane ``-k`` (right): laneOffset - sum of the widths of lanes -1..-(k-1)
    - half its own width; left lanes mirrored. Width records start at their section's s + sOffset.
    """
    root = SafeET.parse(str(path), forbid_dtd=True).getroot()
    out: list[XodrLane] = []
    for road in root.iter("road"):
        length = _f(road, "length")
        lanes_el = road.find("lanes")
        if lanes_el is None:
            continue
        # every step, at every geometry's start (a polyline's corners), and on both sides of every
        # record's start (a lane may exist between two steps only)
        plan_view = road.find("planView")
        corners = [_f(g, "s") for g in plan_view.iter("geometry")] if plan_view is not None else []
        starts = [_f(o, "s") for o in lanes_el.iter("laneOffset")]
        for sec in lanes_el.iter("laneSection"):
            starts += [_f(sec, "s") + _f(r, "sOffset") for r in sec.iter("width")]
        edges = np.array(starts)
        s = np.unique(np.clip(np.concatenate([np.arange(0.0, length, step), [length], corners, edges, edges - 1e-6]),
                              0.0, length))
        x, y, h = _reference_line(road.find("planView"), s)
        offset = _poly([(_f(o, "s"), _f(o, "a"), _f(o, "b"), _f(o, "c"), _f(o, "d"))
                        for o in lanes_el.iter("laneOffset")], s)
        sections = list(lanes_el.iter("laneSection"))
        for j, sec in enumerate(sections):
            s_sec = _f(sec, "s")
            s_end = _f(sections[j + 1], "s") if j + 1 < len(sections) else length + 1e-9
            m = (s >= s_sec - 1e-9) & ((s < s_end) if j + 1 < len(sections) else (s <= s_end))
            if not m.any():
                continue
            for side, sign in (("right", -1.0), ("left", 1.0)):
                side_el = sec.find(side)
                if side_el is None:
                    continue
                lanes = sorted(side_el.iter("lane"), key=lambda e: abs(int(e.get("id", "0"))))
                inner = np.zeros(int(m.sum()))
                for lane in lanes:
                    w = _poly([(s_sec + _f(r, "sOffset"), _f(r, "a"), _f(r, "b"), _f(r, "c"), _f(r, "d"))
                               for r in lane.iter("width")], s[m])
                    t = offset[m] + sign * (inner + 0.5 * w)
                    inner = inner + w
                    xy = np.column_stack([x[m] - t * np.sin(h[m]), y[m] + t * np.cos(h[m])])  # t: to the left
                    wide = np.diff(np.concatenate([[0], (w >= MIN_WIDTH_M).astype(np.int8), [0]]))
                    for a, b in zip(np.flatnonzero(wide == 1), np.flatnonzero(wide == -1), strict=True):
                        out.append(XodrLane(road=road.get("id", ""), junction=road.get("junction", "-1"),
                                            lane=int(lane.get("id", "0")), kind=lane.get("type", ""), xy=xy[a:b],
                                            filler=lane.find(f"userData[@code='{FILLER_CODE}']") is not None))
    return out


def net_lane_shapes(net_file: Path) -> tuple[list[str], list[np.ndarray], np.ndarray]:
    """SUMO lane ids, shapes (K, 2) [m] and whether each lies in a junction, read with sumolib
    (the lanes :func:`write_xodr` leaves out left out: a converted scene's staging lane, U-turns
    between lanes side by side)."""
    from coster_sumo.formats.sumo_net import read_sumolib_net

    net = read_sumolib_net(str(net_file))
    lanes_of = NetLanes.read(net_file)
    left_out = {lane for key in lanes_of.pinched_uturns for lane in lanes_of.internal_lanes(key)}
    ids, shapes, internal = [], [], []
    for edge in net.getEdges(withInternal=True):
        if edge.getID() == STAGING_EDGE:  # not written (write_xodr)
            continue
        for lane in edge.getLanes():
            if lane.getID() in left_out:  # not written either (NetLanes.uturn_is_pinched)
                continue
            shape = np.asarray(lane.getShape(), np.float64)[:, :2]
            if len(shape) >= 2:
                ids.append(lane.getID())
                shapes.append(shape)
                # an internal lane of no length (two edges meeting end to end) is a point where two
                # roads meet: the .xodr links those roads directly (opendrive_readers)
                length = float(np.hypot(*np.diff(shape, axis=0).T).sum())
                internal.append(edge.getID().startswith(":") and length >= MIN_ROAD_M)
    return ids, shapes, np.array(internal, bool)


def compare_with_net(xodr: Path, net_file: Path, step: float = SAMPLE_STEP_M) -> dict[str, Any]:
    """Distances [m] between the OpenDRIVE lane centre lines and the SUMO lane shapes they came from.

    ``roads``: the samples of roads outside junctions and the SUMO lanes outside junctions;
    ``junctions``: those of connecting roads and the junction-internal lanes. ``xodr_to_net``: from
    every such xodr sample to the nearest SUMO lane shape of either kind (the xodr lies on a SUMO
    lane); ``net_to_xodr``: from every such SUMO lane shape point (vertices, and every ``step`` m
    between them) to the nearest xodr lane centre line of either kind (every SUMO lane is in the
    xodr). Either kind, because where the lanes of a SUMO edge start or end apart, the xodr road
    spans only the stretch its linked lanes share and the connecting roads drive the rest
    (:mod:`~coster_sumo.exports.opendrive_ends`): the same lanes, the border between road and
    junction elsewhere. Max and mean of each, and the sample counts.
    """
    ids, shapes, internal = net_lane_shapes(net_file)
    lanes = [ln for ln in xodr_lane_centres(xodr, step) if len(ln.xy) >= 2 and not ln.filler]
    all_sumo = [shapely.LineString(sh) for sh in shapes]
    all_xodr = [shapely.LineString(ln.xy) for ln in lanes]
    res: dict[str, Any] = {}
    for name, in_junction in (("roads", False), ("junctions", True)):
        sumo_lines = [shapely.LineString(sh) for sh, i in zip(shapes, internal, strict=True) if i == in_junction]
        mine = [ln for ln in lanes if (ln.junction != "-1") == in_junction]
        if not sumo_lines or not mine:
            res[name] = {"xodr_samples": sum(len(ln.xy) for ln in mine), "sumo_lanes": len(sumo_lines)}
            continue
        pts = np.concatenate([ln.xy for ln in mine])
        d1 = _nearest_distance(pts, all_sumo)
        # (a zero-length lane, e.g. a dead end's turnaround, is its points)
        sp = np.concatenate([shapely.get_coordinates(shapely.segmentize(ln, step) if ln.length > 0 else ln)
                             for ln in sumo_lines])
        d2 = _nearest_distance(sp, all_xodr)
        res[name] = {"xodr_samples": len(pts), "xodr_to_net_max": float(d1.max()), "xodr_to_net_mean": float(d1.mean()),
                     "xodr_to_net_p99": float(np.percentile(d1, 99)),
                     "xodr_to_net_over_0.1m": float(np.mean(d1 > 0.1)),
                     "sumo_lanes": len(sumo_lines), "sumo_samples": len(sp), "net_to_xodr_max": float(d2.max()),
                     "net_to_xodr_mean": float(d2.mean()), "net_to_xodr_p99": float(np.percentile(d2, 99))}
    return res


def _nearest_distance(points: np.ndarray, lines: list[Any]) -> np.ndarray:
    """(P,) [m] distance from each point (P, 2) to the nearest of ``lines`` (their segments in a tree)."""
    coords = [shapely.get_coordinates(ln) for ln in lines]
    segs = np.concatenate([np.stack([c[:-1], c[1:]], axis=1) if len(c) > 1 else np.stack([c, c], axis=1)
                           for c in coords])  # (S, 2, 2)
    tree = shapely.STRtree(shapely.linestrings(segs))
    _, dist = tree.query_nearest(shapely.points(points), return_distance=True, all_matches=False)
    return np.asarray(dist, np.float64)


def _borders_at(road: Any, s: float) -> dict[int, tuple[float, float]]:
    """Lane id -> (inner, outer) border offset [m] (left positive) of every lane at station ``s``."""
    lanes_el = road.find("lanes")
    at = np.array([s], np.float64)
    offset = float(_poly([(_f(o, "s"), _f(o, "a"), _f(o, "b"), _f(o, "c"), _f(o, "d"))
                          for o in lanes_el.iter("laneOffset")], at)[0])
    sections = [sec for sec in lanes_el.iter("laneSection") if _f(sec, "s") <= s + 1e-9]
    out: dict[int, tuple[float, float]] = {}
    if not sections:
        return out
    sec = sections[-1]
    for side, sign in (("right", -1.0), ("left", 1.0)):
        side_el = sec.find(side)
        if side_el is None:
            continue
        inner = 0.0
        for lane in sorted(side_el.iter("lane"), key=lambda e: abs(int(e.get("id", "0")))):
            w = float(_poly([(_f(sec, "s") + _f(r, "sOffset"), _f(r, "a"), _f(r, "b"), _f(r, "c"), _f(r, "d"))
                             for r in lane.iter("width")], at)[0])
            out[int(lane.get("id", "0"))] = (offset + sign * inner, offset + sign * (inner + w))
            inner += w
    return out


def lane_link_gaps(path: Path) -> list[tuple[str, int, str, int, float]]:
    """Every lane link between two roads of an OpenDRIVE file and how far apart the linked lanes'
    borders are at the contact: (road, lane, other road, other lane, the larger of the inner and the
    outer border's distance [m]). Both directions of a link are listed (each road names the other)."""
    root = SafeET.parse(str(path), forbid_dtd=True).getroot()
    roads = {r.get("id", ""): r for r in root.iter("road")}
    out = []
    for road in roads.values():
        link = road.find("link")
        if link is None or road.find("lanes") is None:
            continue
        for tag, s_here in (("successor", _f(road, "length")), ("predecessor", 0.0)):
            el = link.find(tag)
            other = roads.get(el.get("elementId", "")) if el is not None and el.get("elementType") == "road" else None
            if el is None or other is None or other.find("lanes") is None:
                continue
            s_other = 0.0 if el.get("contactPoint") == "start" else _f(other, "length")
            mine, theirs = _borders_at(road, s_here), _borders_at(other, s_other)
            here = _reference_line(road.find("planView"), np.array([s_here], np.float64))
            there = _reference_line(other.find("planView"), np.array([s_other], np.float64))
            for lane in road.iter("lane"):
                ll = lane.find(f"link/{tag}")
                a = int(lane.get("id", "0"))
                if ll is None or a == 0 or a not in mine or int(ll.get("id", "0")) not in theirs:
                    continue
                b = int(ll.get("id", "0"))
                gap = 0.0
                for k in (0, 1):
                    p = _offset_point(here, mine[a][k])
                    q = _offset_point(there, theirs[b][k])
                    gap = max(gap, float(np.hypot(*(p - q))))
                out.append((road.get("id", ""), a, other.get("id", ""), b, gap))
    return out


def _offset_point(pose: tuple[np.ndarray, np.ndarray, np.ndarray], t: float) -> np.ndarray:
    x, y, h = (float(v[0]) for v in pose)
    return np.array([x - t * np.sin(h), y + t * np.cos(h)])


def folded_borders(path: Path, step: float = 0.01) -> list[tuple[str, int, int, float]]:
    """Every lane of an OpenDRIVE file whose border folds back on itself: (road, lane section index,
    lane id, fold ratio), the fold ratio being the largest curvature x lateral offset [-] of either
    border over the lane's stations (every ``step`` m and each geometry's start), 1 or more where
    the border stops and runs backwards (its outline crosses itself; readers that build lane
    polygons reject it). Filler lanes (room between lanes, no lane of the net) are left out, and
    so are stations where a lane is narrower than :data:`MIN_WIDTH_M` (no lane there).

    The curvature is the reference line's heading differentiated between the stations; a lane's
    borders lie at the laneOffset minus the widths of the lanes inside it (left lanes mirrored).
    """
    root = SafeET.parse(str(path), forbid_dtd=True).getroot()
    out: list[tuple[str, int, int, float]] = []
    for road in root.iter("road"):
        lanes_el, plan_view = road.find("lanes"), road.find("planView")
        length = _f(road, "length")
        if lanes_el is None or plan_view is None or length <= 0:
            continue
        corners = [_f(g, "s") for g in plan_view.iter("geometry")]
        s = np.unique(np.clip(np.concatenate([np.arange(0.0, length, step), [length], corners]), 0.0, length))
        _, _, h = _reference_line(plan_view, s)
        curvature = np.gradient(np.unwrap(h), s) if len(s) > 1 else np.zeros_like(s)
        offset = _poly([(_f(o, "s"), _f(o, "a"), _f(o, "b"), _f(o, "c"), _f(o, "d"))
                        for o in lanes_el.iter("laneOffset")], s)
        sections = list(lanes_el.iter("laneSection"))
        for j, sec in enumerate(sections):
            s_sec = _f(sec, "s")
            s_end = _f(sections[j + 1], "s") if j + 1 < len(sections) else length
            m = (s >= s_sec - 1e-9) & (s <= s_end + 1e-9)
            for side, sign in (("right", -1.0), ("left", 1.0)):
                side_el = sec.find(side)
                if side_el is None or not m.any():
                    continue
                inner = np.zeros(int(m.sum()))
                for lane in sorted(side_el.iter("lane"), key=lambda e: abs(int(e.get("id", "0")))):
                    w = _poly([(s_sec + _f(r, "sOffset"), _f(r, "a"), _f(r, "b"), _f(r, "c"), _f(r, "d"))
                               for r in lane.iter("width")], s[m])
                    borders = np.stack([offset[m] + sign * inner, offset[m] + sign * (inner + w)])  # (2, S)
                    inner = inner + w
                    here = w >= MIN_WIDTH_M
                    if lane.find(f"userData[@code='{FILLER_CODE}']") is not None or not here.any():
                        continue
                    ratio = float((curvature[m][here] * borders[:, here]).max())
                    if ratio >= 1.0:
                        out.append((road.get("id", ""), j, int(lane.get("id", "0")), ratio))
    return out
