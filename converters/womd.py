"""WOMD ``Scenario`` protobufs <-> :class:`~coster_sumo.scene.Scene`.

- :func:`iter_tfrecord_scenes`: every scenario of a (plain or gzip) TFRecord file as a Scene.
- :func:`scenario_to_scene`: one parsed ``Scenario`` message -> Scene (``source="womd"``).
- :func:`scene_to_scenario`: the inverse, serialized bytes; used to write synthetic scenes as
  TFRecords for tests.

Mapping (see :mod:`coster_sumo.scene` for the target fields):

- tracks: ``id`` -> ``str(id)``; box centre, heading, velocity, length/width per step; ``valid``.
  Invalid states stay as WOMD wrote them (zero-filled): mask with ``valid``.
- lanes (``LaneCenter`` features): ids ``str(feature id)``; centreline = polyline x/y; type;
  ``speed_limit_mph`` -> m/s; predecessors = entry_lanes, successors = exit_lanes, left/right
  neighbours; ids that are not lanes of this scene are dropped (WOMD maps are cropped).
- lane width (WOMD has none), :func:`estimate_lane_widths`, first rule that applies:
  (1) the lane lists painted road-line boundaries present in the scene: the sum of the median
  distances from its centreline points (over each boundary's index range) to the left and to the
  right lines, twice the median where only one side has lines; (2) it has neighbour lanes: the
  median distance from its centreline to theirs (centre-to-centre = one lane width for equal
  widths), ignoring points closer than 2 m (WOMD lists merging and splitting lanes, which
  overlap, as neighbours); (3) it lists road-edge (kerb) boundaries: as (1) with the edges,
  which overestimates where there is a shoulder or parking; (4) 3.7 m. Clipped to [2.5, 5.5] m.
- ``is_junction`` (WOMD has no junction flag), :func:`junction_heuristic`: a lane is junction
  interior when either: (a) its centreline properly crosses the centreline of a lane that is not
  related to it (not itself, a predecessor, successor, neighbour, nor sharing a predecessor or
  successor with it) at about the same height (|dz| <= 3 m where heights are known, so overpasses
  do not count); (b) it is one of several branches at both ends: some predecessor has more than one
  successor and some successor has more than one predecessor. Plain merges, splits and approach
  lanes are not flagged. On the real samples (a) also flags 29 of the 34 signal-controlled lanes:
  WOMD attaches signal states to the lanes *inside* the intersection (stop point at their start),
  not to the approach lanes.
- road lines / road edges: polylines, ``kind`` = WOMD RoadLine / RoadEdge type; crosswalks:
  polygons; stop signs: position and controlled lanes. Speed bumps and driveways are only counted.
- signals: ``dynamic_map_states[t].lane_states`` -> controlled lanes = union over steps of the lanes
  that have a state and exist in the map, in order of first appearance; UNKNOWN where a step has
  none; stop point from the first state of each lane.
- ``scene.meta``: ``map_feature_counts`` (per WOMD feature type, all seven keys),
  ``lane_states_per_step`` (list, one count per step), ``tracks_to_predict`` (track indices),
  ``objects_of_interest`` (track ids), ``source_file``.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.errors import InputError
from coster_sumo.frames import MPH_TO_MPS
from coster_sumo.scene import (
    Lanes,
    Polylines,
    Ragged,
    RoadMap,
    Scene,
    SignalStates,
    Tracks,
)

from . import womd_schema
from .tf_example import describe_example, example_keys
from .tfrecord import iter_tfrecord

DEFAULT_LANE_WIDTH = 3.7  # [m]
LANE_WIDTH_RANGE = (2.5, 5.5)  # [m]
MIN_NEIGHBOUR_GAP = 2.0  # [m] closer neighbour points are overlapping (merging/splitting) lanes
FEATURE_TYPES = ("lane", "road_line", "road_edge", "stop_sign", "crosswalk", "speed_bump", "driveway")


# ----------------------------------------------------------------------------- shared lane building

@dataclass
class RawLane:
    """A lane as both WOMD readers see it (feature ids, not indices)."""

    fid: int
    polyline: np.ndarray  # (n, 2) [m]
    lane_type: int
    speed_limit_mph: float
    entry: list[int] = field(default_factory=list)
    exit: list[int] = field(default_factory=list)
    # (neighbour feature id, self_start, self_end, neighbour_start, neighbour_end)
    left: list[tuple[int, int, int, int, int]] = field(default_factory=list)
    right: list[tuple[int, int, int, int, int]] = field(default_factory=list)
    # (lane_start, lane_end, boundary feature id)
    left_bounds: list[tuple[int, int, int]] = field(default_factory=list)
    right_bounds: list[tuple[int, int, int]] = field(default_factory=list)
    z: np.ndarray | None = None  # (n,) [m] heights of the polyline points, where known


def point_polyline_distance(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """(n,) distance [m] from each of ``points`` (n, 2) to the polyline (m, 2), m >= 1."""
    points = np.asarray(points, np.float64).reshape(-1, 2)
    poly = np.asarray(polyline, np.float64).reshape(-1, 2)
    if len(points) == 0 or len(poly) == 0:
        return np.full(len(points), np.inf)
    origin = poly[0]
    p, q = points - origin, poly - origin  # large absolute coordinates: work relative
    if len(q) == 1:
        return np.hypot(*(p - q[0]).T)
    a, ab = q[:-1], np.diff(q, axis=0)
    denom = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12)
    rel = p[:, None, :] - a[None, :, :]
    t = np.clip(np.einsum("nmk,mk->nm", rel, ab) / denom, 0.0, 1.0)
    d = rel - t[..., None] * ab[None]
    return np.sqrt(np.min(np.einsum("nmk,nmk->nm", d, d), axis=1))


def _segment(poly: np.ndarray, start: int, end: int, max_points: int = 32) -> np.ndarray:
    """Points ``start..end`` of ``poly`` (clamped), thinned to at most ``max_points`` (for medians)."""
    n = len(poly)
    lo, hi = max(0, min(start, end)), min(n - 1, max(start, end))
    seg = poly[lo:hi + 1] if hi >= lo else poly
    if len(seg) > max_points:
        seg = seg[np.linspace(0, len(seg) - 1, max_points).round().astype(np.int64)]
    return seg


def _side_half_width(ln: RawLane, bounds: list[tuple[int, int, int]], polys: dict[int, np.ndarray]
                     ) -> float | None:
    dists = [point_polyline_distance(_segment(ln.polyline, s, e), polys[fid])
             for s, e, fid in bounds if fid in polys and len(polys[fid])]
    return float(np.median(np.concatenate(dists))) if dists else None


def estimate_lane_widths(lanes: Sequence[RawLane], road_lines: dict[int, np.ndarray],
                         road_edges: dict[int, np.ndarray]) -> np.ndarray:
    """(num_lanes,) estimated full lane width [m]; see the module docstring for the rule."""
    by_id = {ln.fid: ln for ln in lanes}
    out = np.full(len(lanes), DEFAULT_LANE_WIDTH)
    for i, ln in enumerate(lanes):
        if len(ln.polyline) == 0:
            continue
        width = _width_from_sides(ln, road_lines)  # painted lines: the best evidence
        if width is None:
            dists = [point_polyline_distance(_segment(ln.polyline, s0, s1), by_id[nid].polyline)
                     for nid, s0, s1, _, _ in (*ln.left, *ln.right)
                     if nid in by_id and len(by_id[nid].polyline)]
            all_d = np.concatenate(dists) if dists else np.zeros(0)
            apart = all_d[all_d >= MIN_NEIGHBOUR_GAP]
            if len(apart):
                width = float(np.median(apart))
        if width is None:  # kerbs may include a shoulder or parking: overestimates, clipped below
            width = _width_from_sides(ln, road_edges)
        if width is not None:
            out[i] = width
    return np.clip(out, *LANE_WIDTH_RANGE)


def _width_from_sides(ln: RawLane, polys: dict[int, np.ndarray]) -> float | None:
    sides = [h for h in (_side_half_width(ln, ln.left_bounds, polys),
                         _side_half_width(ln, ln.right_bounds, polys)) if h is not None]
    if not sides:
        return None
    return sides[0] + sides[1] if len(sides) == 2 else 2.0 * sides[0]


def _crossing_lanes(lanes: Sequence[RawLane], related: list[set[int]], max_dz: float = 3.0) -> np.ndarray:
    """(num_lanes,) bool: the centreline properly crosses an unrelated lane's at about the same height."""
    import shapely
    from shapely.strtree import STRtree

    geoms = [shapely.LineString(ln.polyline) if len(ln.polyline) >= 2 else shapely.LineString()
             for ln in lanes]
    out = np.zeros(len(lanes), bool)
    if not geoms:
        return out
    tree = STRtree(geoms)
    a_idx, b_idx = tree.query(geoms, predicate="crosses")
    for a, b in zip(a_idx.tolist(), b_idx.tolist(), strict=True):
        if a >= b or b in related[a] or (out[a] and out[b]):
            continue
        za, zb = lanes[a].z, lanes[b].z
        if za is not None and zb is not None and len(za) and len(zb):  # overpasses do not cross
            hit = shapely.get_coordinates(geoms[a].intersection(geoms[b]))[:1]
            if len(hit):
                ka = np.argmin(np.hypot(*(lanes[a].polyline - hit[0]).T))
                kb = np.argmin(np.hypot(*(lanes[b].polyline - hit[0]).T))
                if abs(float(za[ka]) - float(zb[kb])) > max_dz:
                    continue
        out[a] = out[b] = True
    return out


def junction_heuristic(lanes: Sequence[RawLane], predecessors: Ragged, successors: Ragged, left: Ragged,
                       right: Ragged) -> np.ndarray:
    """(num_lanes,) bool best-effort junction-interior flag; see the module docstring."""
    n = len(predecessors)
    n_pred, n_succ = predecessors.lengths(), successors.lengths()
    related: list[set[int]] = []
    for i in range(n):
        rel = {i, *predecessors[i].tolist(), *successors[i].tolist(), *left[i].tolist(), *right[i].tolist()}
        for p in predecessors[i]:
            rel.update(successors[p].tolist())
        for s in successors[i]:
            rel.update(predecessors[s].tolist())
        related.append(rel)
    out = _crossing_lanes(lanes, related)
    for i in range(n):
        fan_out = bool(np.any(n_succ[predecessors[i]] > 1))
        fan_in = bool(np.any(n_pred[successors[i]] > 1))
        out[i] |= fan_out and fan_in
    return out


def _first_bad_point(points: np.ndarray) -> int:
    """Index of the first point with a non-finite coordinate, or -1."""
    pts = np.asarray(points, np.float64)
    bad = ~np.isfinite(pts.reshape(len(pts), -1)).all(axis=1) if len(pts) else np.zeros(0, bool)
    return int(np.flatnonzero(bad)[0]) if bad.any() else -1


def check_raw_map(lanes: Sequence[RawLane], others: Sequence[tuple[str, int, np.ndarray]] = ()) -> None:
    """Refuse map geometry the net builder cannot use, naming the feature (both readers call it).

    Lanes: unique ids, at least one point (a single point is kept: real WOMD maps have them, and the
    net builder skips them), finite coordinates, heights and speed limit. ``others``: (kind, feature
    id, points) of road lines, edges, crosswalks, stop signs: finite coordinates.
    """
    seen: set[int] = set()
    for ln in lanes:
        where = f"lane {ln.fid}"
        if ln.fid in seen:
            raise InputError(f"{where}: duplicate lane id")
        seen.add(ln.fid)
        if len(ln.polyline) == 0:
            raise InputError(f"{where}: the polyline has no points")
        k = _first_bad_point(ln.polyline)
        if k >= 0:
            x, y = ln.polyline[k]
            raise InputError(f"{where}: polyline point {k} ({x}, {y}) is not finite")
        if ln.z is not None and len(ln.z) and not np.all(np.isfinite(ln.z)):
            k = int(np.flatnonzero(~np.isfinite(ln.z))[0])
            raise InputError(f"{where}: polyline point {k} has a non-finite height ({ln.z[k]})")
        if not np.isfinite(ln.speed_limit_mph):
            raise InputError(f"{where}: speed limit {ln.speed_limit_mph} is not finite")
    for kind, fid, pts in others:
        k = _first_bad_point(pts)
        if k >= 0:
            raise InputError(f"{kind} {fid}: point {k} ({pts[k][0]}, {pts[k][1]}) is not finite")


def build_lanes(lanes: Sequence[RawLane], road_lines: dict[int, np.ndarray], road_edges: dict[int, np.ndarray]
                ) -> tuple[Lanes, dict[int, int]]:
    """:class:`Lanes` from raw lanes, and the feature id -> lane index map.

    ``road_lines`` / ``road_edges``: boundary polylines by feature id (for the width estimate).
    """
    index = {ln.fid: i for i, ln in enumerate(lanes)}

    def rag(lists: list[list[int]]) -> Ragged:
        cleaned = []
        for ids in lists:
            seen: dict[int, None] = {}
            for fid in ids:
                if fid in index:
                    seen.setdefault(index[fid], None)
            cleaned.append(np.fromiter(seen, np.int64, len(seen)))
        return Ragged.from_list(cleaned, np.int64)

    pred = rag([ln.entry for ln in lanes])
    succ = rag([ln.exit for ln in lanes])
    left = rag([[nb[0] for nb in ln.left] for ln in lanes])
    right = rag([[nb[0] for nb in ln.right] for ln in lanes])
    result = Lanes(
        ids=np.asarray([str(ln.fid) for ln in lanes], dtype=str).reshape(-1),
        centerline=Ragged.from_list([ln.polyline for ln in lanes], np.float64, (2,)),
        width=estimate_lane_widths(lanes, road_lines, road_edges),
        lane_type=np.asarray([ln.lane_type for ln in lanes], np.int8).reshape(-1),
        speed_limit=np.asarray([ln.speed_limit_mph for ln in lanes], np.float64).reshape(-1) * MPH_TO_MPS,
        is_junction=junction_heuristic(lanes, pred, succ, left, right),
        predecessors=pred, successors=succ, left_neighbors=left, right_neighbors=right)
    return result, index


def polylines(items: Sequence[tuple[int, np.ndarray]]) -> Polylines:
    """:class:`Polylines` from (kind, (n, 2) points) pairs."""
    return Polylines(points=Ragged.from_list([p for _, p in items], np.float64, (2,)),
                     kind=np.asarray([k for k, _ in items], np.int8).reshape(-1))


def _xy(points: Any) -> np.ndarray:
    return np.asarray([(p.x, p.y) for p in points], np.float64).reshape(-1, 2)


# ----------------------------------------------------------------------------- Scenario -> Scene

def _tracks(msg: Any, num_steps: int) -> Tracks:
    n = len(msg.tracks)
    fields = ("center_x", "center_y", "heading", "velocity_x", "velocity_y", "length", "width")
    arr = np.zeros((len(fields), n, num_steps), np.float64)
    valid = np.zeros((n, num_steps), bool)
    for i, track in enumerate(msg.tracks):
        if len(track.states) != num_steps:
            raise InputError(f"track {track.id}: {len(track.states)} states for {num_steps} timestamps")
        rows = [(s.center_x, s.center_y, s.heading, s.velocity_x, s.velocity_y, s.length, s.width, s.valid)
                for s in track.states[:num_steps]]
        if rows:
            block = np.asarray(rows, np.float64)
            arr[:, i, :len(rows)] = block[:, :7].T
            valid[i, :len(rows)] = block[:, 7] > 0.5
    ids = [str(t.id) for t in msg.tracks]
    return Tracks(ids=np.asarray(ids, dtype=str).reshape(-1),
                  object_type=np.asarray([t.object_type for t in msg.tracks], np.int8).reshape(-1),
                  x=arr[0], y=arr[1], heading=arr[2], vx=arr[3], vy=arr[4], length=arr[5], width=arr[6],
                  valid=valid)


def _signals(msg: Any, num_steps: int, lane_index: dict[int, int]) -> tuple[SignalStates, list[int]]:
    order: dict[int, int] = {}  # lane index -> column
    stop_points: list[tuple[float, float]] = []
    per_step = []
    cells: list[tuple[int, int, int]] = []
    for t, dms in enumerate(msg.dynamic_map_states):
        per_step.append(len(dms.lane_states))
        if t >= num_steps:
            continue
        for ls in dms.lane_states:
            li = lane_index.get(ls.lane)
            if li is None:
                continue
            if li not in order:
                order[li] = len(order)
                stop_points.append((ls.stop_point.x, ls.stop_point.y))
            cells.append((t, order[li], ls.state))
    state = np.zeros((num_steps, len(order)), np.int8)
    for t, col, s in cells:
        state[t, col] = s
    return SignalStates(lane_index=np.fromiter(order, np.int64, len(order)), state=state,
                        stop_point=np.asarray(stop_points, np.float64).reshape(-1, 2)), per_step


def scenario_to_scene(msg: Any, source_name: str = "") -> Scene:
    """A parsed WOMD ``Scenario`` message -> validated :class:`Scene` (``source="womd"``)."""
    timestamps = np.asarray(msg.timestamps_seconds, np.float64)
    num_steps = len(timestamps)
    counts = dict.fromkeys(FEATURE_TYPES, 0)
    raw_lanes: list[RawLane] = []
    line_polys: dict[int, np.ndarray] = {}
    edge_polys: dict[int, np.ndarray] = {}
    road_lines: list[tuple[int, np.ndarray]] = []
    road_edges: list[tuple[int, np.ndarray]] = []
    crosswalks: list[tuple[int, np.ndarray]] = []
    stop_signs: list[tuple[np.ndarray, list[int]]] = []
    others: list[tuple[str, int, np.ndarray]] = []  # (kind, feature id, points) for check_raw_map
    for feat in msg.map_features:
        kind = feat.WhichOneof("feature_data")
        if kind is None:
            continue
        counts[kind] += 1
        if kind == "lane":
            ln = feat.lane
            raw_lanes.append(RawLane(
                fid=feat.id, polyline=_xy(ln.polyline), z=np.asarray([p.z for p in ln.polyline]),
                lane_type=ln.type,
                speed_limit_mph=ln.speed_limit_mph, entry=list(ln.entry_lanes), exit=list(ln.exit_lanes),
                left=[(nb.feature_id, nb.self_start_index, nb.self_end_index, nb.neighbor_start_index,
                       nb.neighbor_end_index) for nb in ln.left_neighbors],
                right=[(nb.feature_id, nb.self_start_index, nb.self_end_index, nb.neighbor_start_index,
                        nb.neighbor_end_index) for nb in ln.right_neighbors],
                left_bounds=[(b.lane_start_index, b.lane_end_index, b.boundary_feature_id)
                             for b in ln.left_boundaries],
                right_bounds=[(b.lane_start_index, b.lane_end_index, b.boundary_feature_id)
                              for b in ln.right_boundaries]))
        elif kind in ("road_line", "road_edge"):
            sub = getattr(feat, kind)
            pts = _xy(sub.polyline)
            (line_polys if kind == "road_line" else edge_polys)[feat.id] = pts
            (road_lines if kind == "road_line" else road_edges).append((sub.type, pts))
            others.append((kind.replace("_", " "), feat.id, pts))
        elif kind == "crosswalk":
            crosswalks.append((0, _xy(feat.crosswalk.polygon)))
            others.append(("crosswalk", feat.id, crosswalks[-1][1]))
        elif kind == "stop_sign":
            pos = feat.stop_sign.position
            stop_signs.append((np.array([pos.x, pos.y]), list(feat.stop_sign.lane)))
            others.append(("stop sign", feat.id, stop_signs[-1][0].reshape(1, 2)))
    check_raw_map(raw_lanes, others)
    lanes, lane_index = build_lanes(raw_lanes, line_polys, edge_polys)
    signals, per_step = _signals(msg, num_steps, lane_index)
    road_map = RoadMap(
        lanes=lanes, road_lines=polylines(road_lines), road_edges=polylines(road_edges),
        crosswalks=polylines(crosswalks),
        stop_sign_xy=np.asarray([p for p, _ in stop_signs], np.float64).reshape(-1, 2),
        stop_sign_lanes=Ragged.from_list(
            [np.asarray([lane_index[f] for f in ids if f in lane_index], np.int64) for _, ids in stop_signs],
            np.int64))
    tracks = _tracks(msg, num_steps)
    meta = {"map_feature_counts": counts, "lane_states_per_step": per_step,
            "tracks_to_predict": [int(r.track_index) for r in msg.tracks_to_predict],
            "objects_of_interest": [str(i) for i in msg.objects_of_interest],
            "source_file": source_name}
    sdc = int(msg.sdc_track_index) if msg.HasField("sdc_track_index") else -1
    scene = Scene(scenario_id=msg.scenario_id, timestamps=timestamps, tracks=tracks, road_map=road_map,
                  signals=signals, sdc_index=sdc, current_time_index=int(msg.current_time_index),
                  source="womd", meta=meta)
    return scene.validate()


def parse_scenario(data: bytes, where: str = "") -> Any:
    """Serialized bytes -> ``Scenario`` message; InputError naming ``where`` when they are not one."""
    try:
        return womd_schema.Scenario.FromString(data)
    except Exception as exc:  # google.protobuf.message.DecodeError and friends
        raise InputError(f"{where}: not a WOMD Scenario ({type(exc).__name__}: {exc})") from None


def iter_tfrecord_scenes(path: str | Path) -> Iterator[Scene]:
    """Every scenario of a WOMD TFRecord file (plain or gzip) as a :class:`Scene`.

    Raises InputError naming the file and record index (``f.tfrecord: record 3: ...``).
    """
    path = Path(path)
    for i, data in enumerate(iter_tfrecord(path)):
        where = f"{path}: record {i}"
        keys = example_keys(data)
        if keys is not None:
            raise InputError(f"{where}: {describe_example(keys)}")
        msg = parse_scenario(data, where)
        try:
            yield scenario_to_scene(msg, path.name)
        except InputError as exc:
            raise InputError(f"{where}: {exc}") from None


# ----------------------------------------------------------------------------- Scene -> Scenario

def _numeric_ids(ids: Sequence[str], start: int = 0) -> list[int]:
    """Ids as ints when all are decimal strings, else ``start, start+1, ...``."""
    try:
        return [int(s) for s in ids]
    except ValueError:
        return list(range(start, start + len(ids)))


def _set_points(field_: Any, pts: np.ndarray) -> None:
    for x, y in np.asarray(pts, np.float64).reshape(-1, 2):
        p = field_.add()
        p.x, p.y, p.z = float(x), float(y), 0.0


def scene_to_scenario(scene: Scene) -> bytes:
    """Serialize ``scene`` as a WOMD ``Scenario`` (inverse of :func:`scenario_to_scene`).

    Track and lane ids are written as ints when they are decimal strings, else as their index
    (lanes from 1). Lane widths, junction flags and junction polygons have no WOMD field and are
    dropped (the reader re-estimates the first two); lengths, widths, headings and velocities are
    float32 on the wire. Other map features get ids after the largest lane id.
    """
    msg = womd_schema.Scenario()
    msg.scenario_id = scene.scenario_id
    msg.timestamps_seconds.extend(float(t) for t in scene.timestamps)
    msg.current_time_index = scene.current_time_index
    if scene.sdc_index >= 0:
        msg.sdc_track_index = scene.sdc_index
    tr = scene.tracks
    for i, tid in enumerate(_numeric_ids(tr.ids.tolist())):
        track = msg.tracks.add(id=tid, object_type=int(tr.object_type[i]))
        for t in range(tr.num_steps):
            s = track.states.add()
            if tr.valid[i, t]:
                s.center_x, s.center_y = float(tr.x[i, t]), float(tr.y[i, t])
                s.heading, s.velocity_x, s.velocity_y = (float(tr.heading[i, t]), float(tr.vx[i, t]),
                                                         float(tr.vy[i, t]))
                s.length, s.width, s.valid = float(tr.length[i, t]), float(tr.width[i, t]), True
            else:
                s.center_x = 0.0
                s.valid = False
    msg.tracks_to_predict.extend(womd_schema.message_class("RequiredPrediction")(track_index=int(k))
                                 for k in scene.meta.get("tracks_to_predict", []))
    objects = [int(s) for s in scene.meta.get("objects_of_interest", []) if str(s).lstrip("-").isdigit()]
    msg.objects_of_interest.extend(objects)

    rm = scene.road_map
    lanes = rm.lanes
    lane_fids = _numeric_ids(lanes.ids.tolist(), start=1)
    for i, fid in enumerate(lane_fids):
        feat = msg.map_features.add(id=fid)
        ln = feat.lane
        ln.speed_limit_mph = float(lanes.speed_limit[i]) / MPH_TO_MPS
        ln.type = int(lanes.lane_type[i])
        _set_points(ln.polyline, lanes.centerline[i])
        ln.entry_lanes.extend(lane_fids[j] for j in lanes.predecessors[i])
        ln.exit_lanes.extend(lane_fids[j] for j in lanes.successors[i])
        last = len(lanes.centerline[i]) - 1
        for side, nbs in ((ln.left_neighbors, lanes.left_neighbors[i]),
                          (ln.right_neighbors, lanes.right_neighbors[i])):
            for j in nbs:
                side.add(feature_id=lane_fids[j], self_start_index=0, self_end_index=max(last, 0),
                         neighbor_start_index=0, neighbor_end_index=max(len(lanes.centerline[j]) - 1, 0))
    next_id = max(lane_fids, default=0) + 1
    for kind_name, pl in (("road_line", rm.road_lines), ("road_edge", rm.road_edges)):
        for k in range(len(pl)):
            feat = msg.map_features.add(id=next_id)
            next_id += 1
            sub = getattr(feat, kind_name)
            sub.type = int(pl.kind[k])
            _set_points(sub.polyline, pl.points[k])
    for k in range(len(rm.crosswalks)):
        feat = msg.map_features.add(id=next_id)
        next_id += 1
        _set_points(feat.crosswalk.polygon, rm.crosswalks.points[k])
    for k in range(len(rm.stop_sign_xy)):
        feat = msg.map_features.add(id=next_id)
        next_id += 1
        feat.stop_sign.lane.extend(lane_fids[j] for j in rm.stop_sign_lanes[k])
        pos = feat.stop_sign.position
        pos.x, pos.y, pos.z = float(rm.stop_sign_xy[k, 0]), float(rm.stop_sign_xy[k, 1]), 0.0

    sig = scene.signals
    for t in range(scene.num_steps):
        dms = msg.dynamic_map_states.add()
        for c, li in enumerate(sig.lane_index):
            ls = dms.lane_states.add(lane=lane_fids[int(li)], state=int(sig.state[t, c]))
            sp = ls.stop_point
            sp.x, sp.y, sp.z = float(sig.stop_point[c, 0]), float(sig.stop_point[c, 1]), 0.0
    return bytes(msg.SerializeToString())
