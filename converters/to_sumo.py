"""A WOMD scene -> a converted SUMO scene folder (network, vTypes, config, replay data, mapping).

``convert_scene(scene, outdir)`` writes ``outdir/<scenario_id>/``:

- ``<id>.net.xml``: the network, WOMD coordinates kept exactly (plain XML from
  :mod:`converters.to_sumo_net`, then netconvert with
  ``--offset.disable-normalization true --precision 4 --junctions.endpoint-shape true`` and
  ``spreadType="center"``, docs/sumo.md §2); lanes netconvert cut back to its junction polygons get
  their WOMD polyline back and internal lanes the logged interior lanes, joined end to end
  (:func:`set_womd_geometry`); a staging lane 1 km below the map is
  added for the replay;
- ``<id>.rou.xml``: vTypes for the logged agents (``womd_vehicle`` passenger, ``womd_pedestrian``
  and ``womd_cyclist`` as vehicles of class pedestrian / bicycle, ``womd_other``);
- ``<id>.tll.xml``: the logged signal states as a fixed-time program (only with traffic lights);
- ``<id>.sumocfg``: relative paths, step length 0.1 s, begin 0, end = the scene's end on SUMO's
  clock (the log is shifted by ``sumo_time_offset_s`` = 0.2 s for a WOMD log starting at 0, to
  leave a staging step before it; see :func:`on_sumo_clock` and :mod:`coster_sumo.sim.replay`);
- ``scene.npz``: the scene (:func:`coster_sumo.formats.scene_file.save_scene`), WOMD coordinates, timestamps on
  SUMO's clock;
- ``lane_map.json``: WOMD lane id -> SUMO lane ids, WOMD link -> SUMO connection, and per traffic
  light the WOMD lane whose logged signal drives each link index;
- ``summary.json``: counts, fidelity figures, warnings, conversion time.

The folder is written under a temporary name and renamed at the end, so a failed scene leaves
nothing behind. A folder with a ``.sumocfg``, ``scene.npz`` and ``lane_map.json`` is "a converted
scene" for every later stage.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np
from defusedxml import ElementTree as SafeET

from coster_sumo import sumo_env
from coster_sumo.errors import CosterError, InputError
from coster_sumo.formats.net_joints import measure_joints
from coster_sumo.formats.scene_file import save_scene
from coster_sumo.formats.scene_folder import (
    STAGING_EDGE,
    folder_name,
    is_converted_scene,
    tls_state_strings,
    vtype_for,
)
from coster_sumo.geometry import polyline_arc_length, project_points
from coster_sumo.outdir import check_output, new_staging, publish, raise_if_disk_full
from coster_sumo.scene import ObjectType, Scene

from .to_sumo_net import (
    Connection,
    PlainNet,
    build_plain_net,
    clean_polyline,
    cut_polyline,
    is_bike_lane,
    lane_speed,
    lane_width,
)

__all__ = ["ConversionError", "ConvertResult", "convert_scene", "is_converted_scene", "read_net"]

NETCONVERT_OPTIONS = [
    "--offset.disable-normalization", "true",  # keep WOMD coordinates (no shift to the origin)
    "--precision", "4",                        # 0.1 mm output instead of 1 cm
    # Junction polygons from the lane end points, and no pushing lane ends apart where they overlap:
    # the least cutting of WOMD lanes (on the real samples: 94-100 % of lanes within 0.5 m before
    # set_womd_geometry). --junctions.minimal-shape (docs/sumo.md §2, right for lane-per-edge
    # chains) builds a tiny polygon around the node's centroid and *extends* every lane of an
    # intersection up to it (measured: 86 % / 72 % of lanes matched on the two TFRecord samples).
    "--junctions.endpoint-shape", "true",
    "--geometry.avoid-overlap", "false",
    "--no-turnarounds", "true",                # only the connections WOMD has
    "--no-warnings", "true",
]
# An isolated lane far below the map where the replay puts each agent for one step before it first
# appears: a vehicle whose very first placement is off every lane crashes SUMO in its outputs
# (FCD) and in some getters (docs/sumo.md §3).
STAGING_OFFSET_M = 1000.0  # [m] below the map
STAGING_LENGTH_M = 15000.0  # [m] room for 600 agents appearing in one step
MATCH_DISTANCE_M = 0.5  # [m] a WOMD lane is matched when its mean distance to its SUMO lane is below

class ConversionError(CosterError):
    """A scene that cannot be converted (bad map, netconvert failure): one line naming the scene."""

    exit_code = 1


@dataclass(frozen=True, slots=True)
class ConvertResult:
    """What :func:`convert_scene` wrote and measured."""

    folder: Path
    summary: dict


# ----------------------------------------------------------------------------- plain XML

def _xy(points: np.ndarray) -> str:
    return " ".join(f"{x:.6f},{y:.6f}" for x, y in points)


def write_plain_xml(plain: PlainNet, scene: Scene, folder: Path, stem: str) -> tuple[Path, Path, Path]:
    """Write ``stem.nod.xml``, ``stem.edg.xml``, ``stem.con.xml``; returns their paths."""
    rm = scene.road_map
    nod, edg, con = (folder / f"{stem}.{k}.xml" for k in ("nod", "edg", "con"))
    rows = ["<nodes>"]
    for nid, xy in plain.nodes.items():
        kind = ' type="traffic_light" tlType="static"' if nid in plain.tls_nodes else ""
        rows.append(f'  <node id="{nid}" x="{xy[0]:.6f}" y="{xy[1]:.6f}"{kind}/>')
    xmin, ymin, _, _ = rm.bounds()
    sx, sy = xmin, ymin - STAGING_OFFSET_M
    rows.append(f'  <node id="{STAGING_EDGE}.a" x="{sx:.3f}" y="{sy:.3f}"/>')
    rows.append(f'  <node id="{STAGING_EDGE}.b" x="{sx + STAGING_LENGTH_M:.3f}" y="{sy:.3f}"/>')
    rows.append("</nodes>")
    nod.write_text("\n".join(rows) + "\n")
    rows = ["<edges>"]
    for eid, grp in plain.edges.items():
        frm, to = plain.edge_nodes[eid]
        pcs = [plain.pieces[m] for m in grp]
        speed = max(lane_speed(rm, p.lane) for p in pcs)
        if len(pcs) == 1:
            shape = pcs[0].points
        else:  # edge line halfway between the outer lanes; each lane carries its own WOMD shape
            shape = 0.5 * (_resample_n(pcs[0].points, 50) + _resample_n(pcs[-1].points, 50))
        rows.append(f'  <edge id={quoteattr(eid)} from="{frm}" to="{to}" numLanes="{len(pcs)}" '
                    f'speed="{speed:.3f}" spreadType="center" shape="{_xy(shape)}">')
        for p in pcs:
            attrs = f'index="{p.index}" width="{lane_width(rm, p.lane):.3f}" speed="{lane_speed(rm, p.lane):.3f}"'
            if is_bike_lane(rm, p.lane):
                attrs += ' allow="bicycle"'
            if len(pcs) > 1:
                attrs += f' shape="{_xy(p.points)}"'
            rows.append(f"    <lane {attrs}/>")
        rows.append("  </edge>")
    rows.append(f'  <edge id="{STAGING_EDGE}" from="{STAGING_EDGE}.a" to="{STAGING_EDGE}.b" numLanes="1" '
                f'speed="30" width="4"/>')
    rows.append("</edges>")
    edg.write_text("\n".join(rows) + "\n")
    rows = ["<connections>"]
    for c in plain.connections:
        a, b = plain.pieces[c.src], plain.pieces[c.dst]
        shape_attr = f' shape="{_xy(c.shape)}"' if c.shape is not None and len(c.shape) >= 2 else ""
        rows.append(f'  <connection from={quoteattr(a.edge)} to={quoteattr(b.edge)} fromLane="{a.index}" '
                    f'toLane="{b.index}"{shape_attr}/>')
    rows.append("</connections>")
    con.write_text("\n".join(rows) + "\n")
    return nod, edg, con


def _resample_n(points: np.ndarray, n: int) -> np.ndarray:
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    s = np.linspace(0.0, cum[-1], n)
    return np.stack([np.interp(s, cum, points[:, 0]), np.interp(s, cum, points[:, 1])], -1)


def run_netconvert(nod: Path, edg: Path, con: Path, net: Path) -> None:
    """Run netconvert on the plain files; raise :class:`ConversionError` with SUMO's message."""
    cmd = [sumo_env.binary("netconvert"), "-n", str(nod), "-e", str(edg), "-x", str(con), "-o", str(net),
           *NETCONVERT_OPTIONS]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=sumo_env.subprocess_env())
    if proc.returncode != 0 or not net.exists():
        err = [ln for ln in (proc.stderr + proc.stdout).splitlines() if ln.startswith("Error")]
        msg = " ".join(err[:2]) or (proc.stderr.strip().splitlines() or ["no message"])[-1]
        raise ConversionError(f"netconvert failed: {msg}")


# ----------------------------------------------------------------------------- reading the net back

def _parse_xml(path: Path) -> Any:
    """``path`` parsed with defusedxml; a file that is not plain XML raises :class:`ConversionError`."""
    try:
        return SafeET.parse(path, forbid_dtd=True)
    except Exception as exc:  # noqa: BLE001 - ParseError, DTDForbidden, EntitiesForbidden, OSError
        raise_if_disk_full(path)  # a net truncated by a full disk is the disk's fault, not the net's
        raise ConversionError(f"{path.name}: not a readable SUMO net ({type(exc).__name__}: {exc})") from None


@dataclass(slots=True)
class NetInfo:
    """What the written network contains, read back from ``.net.xml``.

    Attributes:
        lane_shapes: SUMO lane id -> (n, 2) shape.
        connections: (from_lane, to_lane) -> (via lane chain, tl id or "", link index or -1).
        tls: tls id -> number of link indices.
    """

    lane_shapes: dict[str, np.ndarray]
    connections: dict[tuple[str, str], tuple[list[str], str, int]]
    tls: dict[str, int]


def read_net(net: Path) -> NetInfo:
    """Parse lanes, connections (with their internal-lane chain) and traffic lights of a net.

    Read with ``defusedxml`` (no DTD, no entities), like every XML file coster-sumo parses itself.
    """
    root = _parse_xml(net).getroot()
    shapes: dict[str, np.ndarray] = {}
    for e in root.iter("edge"):
        for ln in e.iter("lane"):
            pts = [tuple(map(float, p.split(",")[:2])) for p in ln.get("shape", "").split()]
            shapes[ln.get("id", "")] = np.asarray(pts, np.float64).reshape(-1, 2)
    raw: dict[tuple[str, int], list[ET.Element]] = {}
    for c in root.iter("connection"):
        raw.setdefault((c.get("from", ""), int(c.get("fromLane", "0"))), []).append(c)
    conns: dict[tuple[str, str], tuple[list[str], str, int]] = {}
    for (frm, fl), items in raw.items():
        if frm.startswith(":"):
            continue
        for c in items:
            to_lane = f"{c.get('to')}_{c.get('toLane')}"
            chain: list[str] = []
            via = c.get("via")
            while via and len(chain) < 10:  # internal lanes split at conflict points chain by via
                chain.append(via)
                edge, _, idx = via.rpartition("_")
                nxt = [x for x in raw.get((edge, int(idx)), [])]
                via = nxt[0].get("via") if nxt else None
            conns[(f"{frm}_{fl}", to_lane)] = (chain, c.get("tl", ""), int(c.get("linkIndex", "-1")))
    tls: dict[str, int] = {}
    for t in root.iter("tlLogic"):
        phases = list(t.iter("phase"))
        tls[t.get("id", "")] = len(phases[0].get("state", "")) if phases else 0
    return NetInfo(shapes, conns, tls)


def _mean_max_distance(points: np.ndarray, shape: np.ndarray) -> tuple[float, float]:
    if len(shape) == 0:
        return float("inf"), float("inf")
    _, lat, _ = project_points(points, shape)
    d = np.abs(lat)
    return float(d.mean()), float(d.max())


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


# ----------------------------------------------------------------------------- fidelity

def measure_fidelity(plain: PlainNet, scene: Scene, info: NetInfo) -> tuple[dict, dict]:
    """Fidelity figures and the WOMD -> SUMO lane / link / signal mapping.

    Every WOMD lane (junction-interior lanes included) is compared with the SUMO lane(s) built
    from it: road lanes with their piece lane(s), interior lanes realised as connection shapes with
    the internal lanes of those connections. Distances are from each WOMD centreline point to the
    SUMO lane polyline.
    """
    lanes = scene.road_map.lanes
    from_to_conn: dict[tuple[int, int], str] = {}
    link_to_sumo: dict[tuple[int, int], tuple[str, str]] = {}
    interior_shapes: dict[int, list[np.ndarray]] = {}
    interior_sumo: dict[int, list[str]] = {}
    realised_links: set[tuple[int, int]] = set()
    join_shape: dict[tuple[int, str], np.ndarray] = {}  # (piece, "in"/"out") -> a straight join's path
    tls_links: dict[str, list[str | None]] = {t: [None] * k for t, k in info.tls.items()}
    for c in plain.connections:
        a, b = plain.pieces[c.src], plain.pieces[c.dst]
        got = info.connections.get((a.sumo_lane, b.sumo_lane))
        if got is None:
            continue
        chain, tl, idx = got
        for lk in c.links:
            realised_links.add(lk)
            link_to_sumo.setdefault(lk, (a.sumo_lane, b.sumo_lane))
        if c.via_lanes:
            shape = np.concatenate([info.lane_shapes[v] for v in chain if v in info.lane_shapes]) \
                if chain else np.zeros((0, 2))
            for v in c.via_lanes:
                interior_shapes.setdefault(v, []).append(shape)
                interior_sumo.setdefault(v, []).extend(x for x in chain if x not in interior_sumo.get(v, []))
        if tl and 0 <= idx < len(tls_links.get(tl, [])) and c.signal_lane >= 0:
            tls_links[tl][idx] = str(lanes.ids[c.signal_lane])
        from_to_conn[(c.src, c.dst)] = tl
        if not c.via_lanes and chain:  # a straight join: its internal lanes carry both lane ends
            joined = np.concatenate([info.lane_shapes[v] for v in chain if v in info.lane_shapes])
            join_shape.setdefault((c.src, "out"), joined)
            join_shape.setdefault((c.dst, "in"), joined)
    def realised(i: int) -> tuple[list[np.ndarray], list[str]]:
        """The SUMO shapes that may realise WOMD lane ``i`` (any one of them) and its SUMO lanes."""
        if i in plain.connectors:  # several connections may share an interior lane
            return interior_shapes.get(i, []), interior_sumo.get(i, [])
        # the lane's pieces in order, with the straight joins that carry their ends between and
        # around them (set_womd_geometry lends a lane's ends to those joins' internal lanes)
        parts = []
        for k, p in enumerate(plain.lane_pieces[i]):
            if k == 0 and (p, "in") in join_shape:
                parts.append(join_shape[(p, "in")])
            parts.append(info.lane_shapes.get(plain.pieces[p].sumo_lane, np.zeros((0, 2))))
            if (p, "out") in join_shape:
                parts.append(join_shape[(p, "out")])
        return [np.concatenate(parts)], [plain.pieces[p].sumo_lane for p in plain.lane_pieces[i]]

    per_lane: list[dict] = []
    lane_map: dict[str, list[str]] = {}
    skipped = set(plain.skipped)
    point_at: dict[int, set[int]] = {}  # stub of one point -> the lanes whose SUMO lane it lies on
    for i in range(len(lanes)):
        lid = str(lanes.ids[i])
        pts = np.asarray(lanes.centerline[i], np.float64)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        dists: list[tuple[float, float]] = []
        if i in skipped:
            # a lane with no length (WOMD's map crop leaves lanes of one point) is not a SUMO lane;
            # it is realised where it sits: at the end of a lane it follows or the start of one it
            # leads to, so its point must lie on the SUMO lane(s) of those
            before, after = plain.point_ends.get(i, ([], []))
            lane_map[lid] = []
            for j in ([*before, *after] if len(pts) else []):
                shapes, ids = realised(j)
                best = (float("inf"), float("inf"))
                for sh in shapes:
                    best = min(best, _mean_max_distance(pts, sh))
                if best[0] < MATCH_DISTANCE_M:
                    dists.append(best)
                    if j not in plain.connectors:  # the SUMO lane of that end only
                        ids = ids[-1:] if j in before else ids[:1]
                    lane_map[lid].extend(x for x in ids if x not in lane_map[lid])
                    if not before or not after:  # a stub: no link across it to realise
                        point_at.setdefault(i, set()).add(j)
        else:
            shapes, lane_map[lid] = realised(i)
            dists = [_mean_max_distance(pts, s) for s in shapes]
        mean, mx = min(dists) if dists else (float("inf"), float("inf"))
        per_lane.append({"lane": lid, "matched": bool(mean < MATCH_DISTANCE_M),
                         "mean_m": mean if np.isfinite(mean) else None,
                         "max_m": mx if np.isfinite(mx) else None})
    n = len(lanes)
    matched = sum(p["matched"] for p in per_lane)
    means = np.array([p["mean_m"] for p in per_lane if p["mean_m"] is not None])
    maxes = np.array([p["max_m"] for p in per_lane if p["max_m"] is not None])
    all_links = {(int(a), int(b)) for a in range(n) for b in lanes.successors[a] if int(b) != a}
    all_links |= {(int(p), int(b)) for b in range(n) for p in lanes.predecessors[b] if int(p) != b}
    # a link to or from a stub of one point is realised where the stub sits on the lane it links
    realised_links |= {(a, b) for a, b in all_links if b in point_at.get(a, ()) or a in point_at.get(b, ())}
    fidelity = {
        "lanes": n,
        "lanes_matched": int(matched),
        "lanes_matched_share": matched / n if n else 1.0,
        "links": len(all_links),
        "links_realised": len(realised_links & all_links),
        "links_realised_share": len(realised_links & all_links) / len(all_links) if all_links else 1.0,
        "centreline_mean_m": float(means.mean()) if len(means) else None,
        "centreline_max_m": float(maxes.max()) if len(maxes) else None,
        "unmatched_lanes": [p["lane"] for p in per_lane if not p["matched"]],
    }
    mapping = {
        "lanes": lane_map,
        "links": {f"{lanes.ids[a]}->{lanes.ids[b]}": list(v) for (a, b), v in sorted(link_to_sumo.items())},
        "tls": {t: {"links": v} for t, v in sorted(tls_links.items())},
    }
    return fidelity, mapping


# ----------------------------------------------------------------------------- signals

def on_sumo_clock(scene: Scene) -> Scene:
    """The scene with its timestamps moved onto the converted network's SUMO clock.

    SUMO starts at 0; the replay needs one staging step before the first log step (see
    :mod:`coster_sumo.sim.replay`), and ``SumoSession.time`` after the step that shows log step 0
    is then ``2 * dt``. ``meta["sumo_time_offset_s"]`` = SUMO time - log time.
    """
    t0 = float(scene.timestamps[0]) if scene.num_steps else 0.0
    offset = round(2 * scene.dt - t0, 9)
    meta = {**scene.meta, "sumo_time_offset_s": offset, "log_t0_s": t0}
    return dataclasses.replace(scene, timestamps=np.round(scene.timestamps + offset, 9), meta=meta)


def _write_tll(path: Path, states: dict[str, list[str]], dt: float, lead_in: float) -> None:
    """The logged signal states as fixed-time programs (``lead_in`` [s] of the first state first)."""
    rows = ["<additional>"]
    for tid, seq in states.items():
        rows.append(f'  <tlLogic id={quoteattr(tid)} type="static" programID="womd_log" offset="0">')
        k = 0
        while k < len(seq):
            j = k
            while j < len(seq) and seq[j] == seq[k]:
                j += 1
            duration = (j - k) * dt + (lead_in if k == 0 else 0.0)
            rows.append(f'    <phase duration="{duration:.3f}" state="{seq[k]}"/>')
            k = j
        rows.append("  </tlLogic>")
    rows.append("</additional>")
    path.write_text("\n".join(rows) + "\n")


# ----------------------------------------------------------------------------- routes and config

def _write_routes(path: Path, scene: Scene) -> None:
    tr = scene.tracks
    rows = ["<routes>"]
    seen: set[str] = set()
    for ot in sorted({int(t) for t in tr.object_type} | {int(ObjectType.VEHICLE)}):
        vid, vclass, shape, length, width = vtype_for(ot)
        if vid in seen:
            continue
        seen.add(vid)
        rows.append(f'  <vType id="{vid}" vClass="{vclass}" guiShape="{shape}" length="{length}" '
                    f'width="{width}" minGap="0.5" speedFactor="10" speedDev="0" maxSpeed="100"/>')
    rows.append("</routes>")
    path.write_text("\n".join(rows) + "\n")


def _write_sumocfg(path: Path, stem: str, scene: Scene, with_tll: bool) -> None:
    dt = scene.dt
    begin = 0.0
    end = float(scene.timestamps[-1]) if scene.num_steps else 0.0  # already on SUMO's clock
    add = f'\n    <additional-files value="{stem}.tll.xml"/>' if with_tll else ""
    path.write_text(f"""<configuration>
  <input>
    <net-file value="{stem}.net.xml"/>
    <route-files value="{stem}.rou.xml"/>{add}
  </input>
  <time>
    <begin value="{begin:.3f}"/>
    <end value="{end:.3f}"/>
    <step-length value="{dt:.3f}"/>
  </time>
</configuration>
""")


# ----------------------------------------------------------------------------- one scene

def check_convertible(scene: Scene) -> None:
    """Raise :class:`InputError` for scenes that cannot become a SUMO scene."""
    if len(scene.road_map.lanes) == 0:
        raise InputError(f"scene {scene.scenario_id}: the map has no lanes")
    veh = scene.tracks.object_type == int(ObjectType.VEHICLE)
    if not np.any(scene.tracks.valid[veh]):
        raise InputError(f"scene {scene.scenario_id}: no vehicle has a valid state")


def _type_name(object_type: int) -> str:
    try:
        return ObjectType(int(object_type)).name.lower()
    except ValueError:
        return f"type_{int(object_type)}"


SCENE_KIND = "scene"  # the marker kind of a converted scene folder (coster_sumo.outdir)


def convert_scene(scene: Scene, outdir: str | Path, *, overwrite: bool = True, name: str | None = None
                  ) -> ConvertResult:
    """Convert one scene into ``outdir/<name>/`` (atomically); see the module docstring.

    An existing ``outdir/<name>/`` is replaced only with ``overwrite`` and only when it is a scene
    folder coster-sumo wrote (:mod:`coster_sumo.outdir`); otherwise :class:`InputError`.

    ``name`` (folder and file stem) defaults to :func:`~coster_sumo.formats.scene_folder.folder_name`
    of the scenario id: never a path, never empty, whatever the input file says.
    """
    t0 = time.perf_counter()
    check_convertible(scene)
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    sid = scene.scenario_id
    stem = folder_name(sid) if name is None else name
    if stem != folder_name(stem):
        raise InputError(f"{stem!r} is not a safe folder name")
    final = outdir / stem
    tmp = new_staging(final)
    try:
        plain = build_plain_net(scene.road_map, scene.signals)
        t_plain = time.perf_counter()
        if not plain.edges:
            raise ConversionError(f"scene {sid}: no lane could be converted")
        work = tmp / "plain"
        work.mkdir()
        nod, edg, con = write_plain_xml(plain, scene, work, stem)
        net = tmp / f"{stem}.net.xml"
        run_netconvert(nod, edg, con, net)
        t_net = time.perf_counter() - t0
        t_plain = t_plain - t0
        info = read_net(net)
        restored = set_womd_geometry(net, plain, info)
        t_restore = time.perf_counter() - t0
        fidelity, mapping = measure_fidelity(plain, scene, info)
        fidelity["lanes_restored"] = restored
        fidelity["continuity"] = measure_joints(net).summary()
        t_measure = time.perf_counter() - t0
        tls_states = tls_state_strings(scene, mapping["tls"])
        sumo_scene = on_sumo_clock(scene)
        if tls_states:
            _write_tll(tmp / f"{stem}.tll.xml", tls_states, scene.dt,
                       float(sumo_scene.timestamps[0]) - scene.dt)
        _write_routes(tmp / f"{stem}.rou.xml", scene)
        _write_sumocfg(tmp / f"{stem}.sumocfg", stem, sumo_scene, bool(tls_states))
        save_scene(sumo_scene, tmp / "scene.npz")
        mapping["scenario_id"] = sid
        mapping["staging_lane"] = f"{STAGING_EDGE}_0"
        mapping["sumo_time_offset_s"] = sumo_scene.meta["sumo_time_offset_s"]
        (tmp / "lane_map.json").write_text(json.dumps(mapping, indent=1))
        shutil.rmtree(work)
        tr = scene.tracks
        counts = {
            "agents": tr.num_agents,
            "agents_by_type": {_type_name(t): int(np.sum(tr.object_type == t))
                               for t in sorted(set(tr.object_type.tolist()))},
            "steps": scene.num_steps,
            "womd_lanes": len(scene.road_map.lanes),
            "sumo_edges": len(plain.edges),
            "sumo_lanes": sum(len(g) for g in plain.edges.values()),
            "multi_lane_edges": sum(len(g) > 1 for g in plain.edges.values()),
            "junction_connections": sum(bool(c.via_lanes) for c in plain.connections),
            "connections": len(plain.connections),
            "traffic_lights": len(info.tls),
            "skipped_lanes": len(plain.skipped),
        }
        summary = {
            "scenario_id": sid, "source": scene.source,
            "files": {"net": f"{stem}.net.xml", "routes": f"{stem}.rou.xml", "config": f"{stem}.sumocfg",
                      "scene": "scene.npz", "lane_map": "lane_map.json",
                      **({"tls": f"{stem}.tll.xml"} if tls_states else {})},
            "counts": counts, "fidelity": fidelity, "warnings": plain.warnings,
            "timing_s": {"lane_graph": round(t_plain, 4), "netconvert": round(t_net - t_plain, 4),
                         "restore": round(t_restore - t_net, 4), "measure": round(t_measure - t_restore, 4)},
            "conversion_s": round(time.perf_counter() - t0, 4),
        }
        (tmp / "summary.json").write_text(json.dumps(summary, indent=1))
        check_output(final, kind=SCENE_KIND, overwrite=overwrite)  # never replaces a folder we did not write
        publish(tmp, final, kind=SCENE_KIND)
        return ConvertResult(folder=final, summary=summary)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
