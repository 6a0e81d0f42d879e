"""WOMD ``Scenario`` protobufs <-> :class:`~coster_sumo.core.scene.Scene`.

- :func:`iter_tfrecord_scenes`: every scenario of a (plain or gzip) TFRecord file as a Scene.
- :func:`scenario_to_scene`: one parsed ``Scenario`` message -> Scene (``source="womd"``).
- :func:`scene_to_scenario`: the inverse, serialized bytes; used to write synthetic scenes as
  TFRecords for tests.

Mapping (see :mod:`coster_sumo.core.scene` for the target fields):

- tracks: ``id`` -> ``str(id)``; box centre, heading, velocity, length/width per step; ``valid``.
  Invalid states stay as WOMD wrote them (zero-filled): mask with ``valid``.
- lanes (``LaneCenter`` features): ids ``str(feature id)``; centreline = polyline x/y; type;
  ``speed_limit_mph`` -> m/s; predecessors = entry_lanes, successors = exit_lanes, left/right
  neighbours; ids that are not lanes of this scene are dropped (WOMD maps are cropped).
- lane width and ``is_junction`` (WOMD has neither): estimated by :mod:`converters.womd_map`,
  whose docstring gives the rules.
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
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.core.scene import (
    Ragged,
    RoadMap,
    Scene,
    SignalStates,
    Tracks,
)
from coster_sumo.errors import InputError
from coster_sumo.geometry.frames import MPH_TO_MPS

from . import womd_schema
from .tf_example import describe_example, example_keys
from .tfrecord import iter_tfrecord
from .womd_map import FEATURE_TYPES, RawLane, build_lanes, check_raw_map, polylines
from .womd_map import point_polyline_distance as point_polyline_distance  # where the tests look for it

# ----------------------------------------------------------------------------- Scenario -> Scene

def _xy(points: Any) -> np.ndarray:
    return np.asarray([(p.x, p.y) for p in points], np.float64).reshape(-1, 2)


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
