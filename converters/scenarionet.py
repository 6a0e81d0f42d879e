"""ScenarioNet / MetaDrive "scenario description" pickles -> :class:`~coster_sumo.scene.Scene`.

**Security: pickles can run arbitrary code when loaded. Read only files you trust** (e.g. the ones
you converted yourself with ScenarioNet); this module calls ``pickle.load`` on them.

The pickle is a plain dict of numpy arrays: ``id, version, length, tracks, dynamic_map_states,
map_features, metadata``. Mapping (the same rules as :mod:`converters.womd`, whose lane builder is
shared: lane widths and junction flags are estimated the same way):

- tracks: ids as strings (dict order); ``type`` VEHICLE/PEDESTRIAN/CYCLIST/OTHER/UNSET ->
  :class:`ObjectType` (anything else -> OTHER); ``state.position`` (T, 3) -> x, y; heading,
  velocity (T, 2), length, width, valid.
- ``metadata.ts`` -> timestamps (0.1 s steps when absent); ``metadata.sdc_id`` -> sdc_index;
  ``metadata.current_time_index``; ``metadata.scenario_id`` (else ``id``).
- map features by ``type``: LANE_SURFACE_STREET / LANE_FREEWAY / LANE_BIKE_LANE (/ LANE_UNKNOWN) ->
  lanes; ROAD_LINE_* -> road lines (kind = WOMD RoadLine type of the same name); ROAD_EDGE_* ->
  road edges (BOUNDARY 1, MEDIAN 2); CROSSWALK -> crosswalks; STOP_SIGN -> stop signs; SPEED_BUMP and
  DRIVEWAY are only counted in ``meta["map_feature_counts"]``.
- ``dynamic_map_states[lane_id].state.object_state`` ('LANE_STATE_*' or None per step) -> signals
  of the lanes with at least one non-None state that exist in the map; None -> UNKNOWN.
"""

from __future__ import annotations

import pickle
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.errors import InputError
from coster_sumo.scene import LaneType, ObjectType, Ragged, RoadMap, Scene, SignalState, SignalStates, Tracks

from .womd import FEATURE_TYPES, RawLane, build_lanes, polylines

PICKLE_MAGIC = b"\x80"  # pickle protocol >= 2 starts with the PROTO opcode

_LANE_TYPES = {"LANE_SURFACE_STREET": LaneType.SURFACE_STREET, "LANE_FREEWAY": LaneType.FREEWAY,
               "LANE_BIKE_LANE": LaneType.BIKE_LANE, "LANE_UNKNOWN": LaneType.UNDEFINED}
_ROAD_LINE_TYPES = {f"ROAD_LINE_{name}": code for code, name in enumerate((
    "UNKNOWN", "BROKEN_SINGLE_WHITE", "SOLID_SINGLE_WHITE", "SOLID_DOUBLE_WHITE", "BROKEN_SINGLE_YELLOW",
    "BROKEN_DOUBLE_YELLOW", "SOLID_SINGLE_YELLOW", "SOLID_DOUBLE_YELLOW", "PASSING_DOUBLE_YELLOW"))}
_ROAD_EDGE_TYPES = {"ROAD_EDGE_UNKNOWN": 0, "ROAD_EDGE_BOUNDARY": 1, "ROAD_EDGE_MEDIAN": 2}


def _feature_kind(type_name: str) -> str | None:
    """ScenarioNet type string -> WOMD feature type key (None for unknown types)."""
    if type_name.startswith("LANE_"):
        return "lane"
    if type_name.startswith("ROAD_LINE_"):
        return "road_line"
    if type_name.startswith("ROAD_EDGE_"):
        return "road_edge"
    return {"CROSSWALK": "crosswalk", "STOP_SIGN": "stop_sign", "SPEED_BUMP": "speed_bump",
            "DRIVEWAY": "driveway"}.get(type_name)


def _xy(a: Any) -> np.ndarray:
    """(n, 2) x/y of an (n, 2|3) array, or (1, 2) of one (2|3,) point."""
    arr = np.asarray(a, np.float64)
    if arr.size == 0:
        return np.zeros((0, 2))
    if arr.ndim == 1:
        return arr[:2].reshape(1, 2)
    return arr.reshape(-1, arr.shape[-1])[:, :2]


def _z(a: Any) -> np.ndarray | None:
    arr = np.asarray(a, np.float64)
    return arr[:, 2] if arr.ndim == 2 and arr.shape[1] >= 3 else None


def _signal_state(name: Any) -> int:
    if name is None:
        return int(SignalState.UNKNOWN)
    key = str(name).removeprefix("LANE_STATE_")
    return int(SignalState[key]) if key in SignalState.__members__ else int(SignalState.UNKNOWN)


def _tracks(raw: dict, num_steps: int) -> Tracks:
    ids = [str(k) for k in raw]
    n = len(ids)
    shape = (n, num_steps)
    cols = {k: np.zeros(shape) for k in ("x", "y", "heading", "vx", "vy", "length", "width")}
    valid = np.zeros(shape, bool)
    types = np.zeros(n, np.int8)
    for i, tr in enumerate(raw.values()):
        types[i] = int(ObjectType[tr["type"]]) if tr.get("type") in ObjectType.__members__ \
            else int(ObjectType.OTHER)
        st = tr["state"]
        v = np.asarray(st["valid"], bool).reshape(-1)[:num_steps]
        k = len(v)
        valid[i, :k] = v
        pos = np.asarray(st["position"], np.float64).reshape(len(v), -1)
        cols["x"][i, :k], cols["y"][i, :k] = pos[:k, 0], pos[:k, 1]
        vel = np.asarray(st["velocity"], np.float64).reshape(len(v), -1)
        cols["vx"][i, :k], cols["vy"][i, :k] = vel[:k, 0], vel[:k, 1]
        for key, name in (("heading", "heading"), ("length", "length"), ("width", "width")):
            cols[key][i, :k] = np.asarray(st[name], np.float64).reshape(-1)[:k]
    return Tracks(ids=np.asarray(ids, dtype=str).reshape(-1), object_type=types, valid=valid, **cols)


def _int(v: Any) -> int:
    return int(v)


def description_to_scene(sd: dict, source_name: str = "") -> Scene:
    """A loaded ScenarioNet scenario description (dict) -> validated :class:`Scene`."""
    md = sd.get("metadata", {})
    num_steps = int(sd.get("length") or md.get("track_length") or 0)
    ts = md.get("ts")
    timestamps = (np.asarray(ts, np.float64).reshape(-1)[:num_steps] if ts is not None
                  else np.arange(num_steps) * 0.1)
    if num_steps == 0:
        num_steps = len(timestamps)
    counts = dict.fromkeys(FEATURE_TYPES, 0)
    raw_lanes: list[RawLane] = []
    line_polys: dict[int, np.ndarray] = {}
    edge_polys: dict[int, np.ndarray] = {}
    road_lines: list[tuple[int, np.ndarray]] = []
    road_edges: list[tuple[int, np.ndarray]] = []
    crosswalks: list[tuple[int, np.ndarray]] = []
    stop_signs: list[tuple[np.ndarray, list[int]]] = []
    for key, feat in sd["map_features"].items():
        type_name = str(feat.get("type", ""))
        kind = _feature_kind(type_name)
        if kind is None:
            continue
        counts[kind] += 1
        fid = _int(key)
        if kind == "lane":
            def nbs(items: list) -> list[tuple[int, int, int, int, int]]:
                return [(_int(n["feature_id"]), _int(n["self_start_index"]), _int(n["self_end_index"]),
                         _int(n["neighbor_start_index"]), _int(n["neighbor_end_index"])) for n in items]

            def bounds(items: list) -> list[tuple[int, int, int]]:
                return [(_int(b["lane_start_index"]), _int(b["lane_end_index"]),
                         _int(b["boundary_feature_id"])) for b in items]

            raw_lanes.append(RawLane(
                fid=fid, polyline=_xy(feat["polyline"]), z=_z(feat["polyline"]),
                lane_type=int(_LANE_TYPES.get(type_name, LaneType.UNDEFINED)),
                speed_limit_mph=float(feat.get("speed_limit_mph") or 0.0),
                entry=[_int(x) for x in feat.get("entry_lanes", [])],
                exit=[_int(x) for x in feat.get("exit_lanes", [])],
                left=nbs(feat.get("left_neighbor", [])), right=nbs(feat.get("right_neighbor", [])),
                left_bounds=bounds(feat.get("left_boundaries", [])),
                right_bounds=bounds(feat.get("right_boundaries", []))))
        elif kind == "road_line":
            pts = _xy(feat["polyline"])
            line_polys[fid] = pts
            road_lines.append((_ROAD_LINE_TYPES.get(type_name, 0), pts))
        elif kind == "road_edge":
            pts = _xy(feat["polyline"])
            edge_polys[fid] = pts
            road_edges.append((_ROAD_EDGE_TYPES.get(type_name, 0), pts))
        elif kind == "crosswalk":
            crosswalks.append((0, _xy(feat["polygon"])))
        elif kind == "stop_sign":
            stop_signs.append((_xy(feat["position"])[0], [_int(x) for x in feat.get("lane", [])]))

    dms = sd.get("dynamic_map_states", {}) or {}
    signal_raw = []
    for key, item in dms.items():
        states = list((item.get("state") or {}).get("object_state") or [])
        if any(s is not None for s in states):
            signal_raw.append((_int(item.get("lane", key)), states, item.get("stop_point")))
    lanes, lane_index = build_lanes(raw_lanes, line_polys, edge_polys)
    signal_raw = [s for s in signal_raw if s[0] in lane_index]
    state = np.zeros((num_steps, len(signal_raw)), np.int8)
    stop_points = np.zeros((len(signal_raw), 2))
    for c, (_, states, sp) in enumerate(signal_raw):
        for t, name in enumerate(states[:num_steps]):
            state[t, c] = _signal_state(name)
        if sp is not None:
            stop_points[c] = _xy(sp)[0]
    signals = SignalStates(lane_index=np.asarray([lane_index[lid] for lid, _, _ in signal_raw], np.int64),
                           state=state, stop_point=stop_points)

    road_map = RoadMap(
        lanes=lanes, road_lines=polylines(road_lines), road_edges=polylines(road_edges),
        crosswalks=polylines(crosswalks),
        stop_sign_xy=np.asarray([p for p, _ in stop_signs], np.float64).reshape(-1, 2),
        stop_sign_lanes=Ragged.from_list(
            [np.asarray([lane_index[f] for f in ids if f in lane_index], np.int64) for _, ids in stop_signs],
            np.int64))
    tracks = _tracks(sd["tracks"], num_steps)
    sdc_id = md.get("sdc_id")
    sdc = tracks.index_of(str(sdc_id)) if sdc_id is not None and str(sdc_id) in set(tracks.ids) else -1
    ttp = md.get("tracks_to_predict") or {}
    meta = {"map_feature_counts": counts,
            "tracks_to_predict": sorted(int(v["track_index"]) for v in ttp.values()
                                        if isinstance(v, dict) and "track_index" in v),
            "objects_of_interest": [str(x) for x in md.get("objects_of_interest", []) or []],
            "version": str(sd.get("version", "")), "source_file": source_name}
    scene = Scene(scenario_id=str(md.get("scenario_id") or sd.get("id", "")), timestamps=timestamps,
                  tracks=tracks, road_map=road_map, signals=signals, sdc_index=sdc,
                  current_time_index=int(md.get("current_time_index", 0) or 0), source="scenarionet",
                  meta=meta)
    return scene.validate()


def load_pickle_scene(path: str | Path) -> Scene:
    """Read one ScenarioNet pickle (a trusted file: pickle can run code) as a :class:`Scene`."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            sd = pickle.load(f)  # trusted files only, see the module docstring
    except OSError as exc:
        raise InputError(f"{path}: cannot open ({exc.strerror or exc})") from None
    except Exception as exc:  # UnpicklingError, EOFError, missing classes, ...
        raise InputError(f"{path}: not a ScenarioNet pickle ({type(exc).__name__}: {exc})") from None
    if not isinstance(sd, dict) or "tracks" not in sd or "map_features" not in sd:
        raise InputError(f"{path}: not a ScenarioNet scenario description (no tracks/map_features)")
    try:
        return description_to_scene(sd, path.name)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise InputError(f"{path}: malformed ScenarioNet scenario ({type(exc).__name__}: {exc})") from None


def iter_pickle_scenes(path: str | Path) -> Iterator[Scene]:
    """The one scene of a ScenarioNet pickle, as an iterator (same shape as the TFRecord reader)."""
    yield load_pickle_scene(path)
