"""ScenarioNet / MetaDrive "scenario description" pickles -> :class:`~coster_sumo.core.scene.Scene`.

**Security**: the pickle is loaded with the restricted unpickler of
:mod:`converters.scenarionet_pickle`, so no file can make the loader run code. Everything read is
then checked (:func:`description_to_scene`): a damaged file is refused with one line naming the
element.

The pickle is a plain dict of numpy arrays: ``id, version, length, tracks, dynamic_map_states,
map_features, metadata``. Mapping (the same rules as :mod:`converters.womd`; the lane builder of
:mod:`converters.womd_map` is shared: lane widths and junction flags are estimated the same way):

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

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.core.scene import LaneType, ObjectType, Ragged, RoadMap, Scene, SignalState, SignalStates, Tracks
from coster_sumo.errors import InputError

from .scenarionet_pickle import ALLOWED_GLOBALS as ALLOWED_GLOBALS  # where the tests look for them
from .scenarionet_pickle import RestrictedUnpickler as RestrictedUnpickler
from .scenarionet_pickle import load_pickle, printable
from .womd_map import FEATURE_TYPES, RawLane, build_lanes, check_raw_map, polylines

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


def _why(exc: BaseException) -> str:
    """One line for an exception raised while reading a damaged element."""
    if isinstance(exc, KeyError):
        return f"missing key {printable(repr(exc.args[0]) if exc.args else '?')}"
    return f"{type(exc).__name__}: {printable(' '.join(str(exc).split()), 160)}"


_ELEMENT_ERRORS = (KeyError, TypeError, ValueError, IndexError, AttributeError, OverflowError)


def _track_arrays(tr: Any, num_steps: int) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(type, valid (T,), position (T, 2), velocity (T, 2), heading/length/width (3, T)) of one track."""
    if not isinstance(tr, dict):
        raise ValueError(f"a {type(tr).__name__}, not a dict")
    ot = tr.get("type")
    otype = int(ObjectType[ot]) if isinstance(ot, str) and ot in ObjectType.__members__ else int(ObjectType.OTHER)
    st = tr["state"]
    if not isinstance(st, dict):
        raise ValueError(f"state is a {type(st).__name__}, not a dict")
    valid = np.asarray(st["valid"])
    if valid.dtype.kind not in "biuf":
        raise ValueError(f"state.valid has dtype {valid.dtype}, not bool")
    arrays = {"valid": valid.astype(bool)}
    for name in ("position", "velocity", "heading", "length", "width"):
        arrays[name] = np.asarray(st[name], np.float64)
    lengths = {name: (len(a) if a.ndim else -1) for name, a in arrays.items()}
    if any(n != num_steps for n in lengths.values()):
        listed = ", ".join(f"{k} {'scalar' if v < 0 else v}" for k, v in lengths.items())
        raise InputError(f"state arrays disagree with the {num_steps} steps of the scenario ({listed})")
    for name, cols in (("valid", 0), ("heading", 0), ("length", 0), ("width", 0), ("position", 2),
                       ("velocity", 2)):
        a = arrays[name]
        if cols == 0 and a.ndim != 1:
            raise InputError(f"state.{name} has shape {a.shape}, expected ({num_steps},)")
        if cols and (a.ndim != 2 or a.shape[1] < cols):
            raise InputError(f"state.{name} has shape {a.shape}, expected ({num_steps}, 2 or 3)")
    sizes = np.stack([arrays["heading"], arrays["length"], arrays["width"]])
    return otype, arrays["valid"], arrays["position"][:, :2], arrays["velocity"][:, :2], sizes


def _tracks(raw: Any, num_steps: int) -> Tracks:
    if not isinstance(raw, dict):
        raise InputError(f"tracks is a {type(raw).__name__}, not a dict of tracks")
    ids = [str(k) for k in raw]
    n = len(ids)
    shape = (n, num_steps)
    cols = {k: np.zeros(shape) for k in ("x", "y", "heading", "vx", "vy", "length", "width")}
    valid = np.zeros(shape, bool)
    types = np.zeros(n, np.int8)
    for i, (key, tr) in enumerate(raw.items()):
        where = f"track {printable(str(key))}"
        try:
            otype, ok, pos, vel, sizes = _track_arrays(tr, num_steps)
        except InputError as exc:
            raise InputError(f"{where}: {exc}") from None
        except _ELEMENT_ERRORS as exc:
            raise InputError(f"{where}: {_why(exc)}") from None
        types[i], valid[i] = otype, ok
        cols["x"][i], cols["y"][i] = pos[:, 0], pos[:, 1]
        cols["vx"][i], cols["vy"][i] = vel[:, 0], vel[:, 1]
        cols["heading"][i], cols["length"][i], cols["width"][i] = sizes
    return Tracks(ids=np.asarray(ids, dtype=str).reshape(-1), object_type=types, valid=valid, **cols)


def _int(v: Any) -> int:
    return int(v)


MAX_STEPS = 100_000  # [steps] far beyond any WOMD scenario (91 or 199); larger is a damaged header


def _num_steps(sd: dict, md: dict) -> tuple[int, np.ndarray]:
    """The scenario's step count and timestamps; lengths that disagree are refused."""
    declared = sd.get("length") or md.get("track_length") or 0
    num_steps = int(declared)
    ts = md.get("ts")
    timestamps: np.ndarray
    if ts is not None:
        timestamps = np.asarray(ts, np.float64).reshape(-1)
        if num_steps and len(timestamps) != num_steps:
            raise InputError(f"metadata.ts has {len(timestamps)} timestamps but the scenario has {num_steps} steps")
        num_steps = len(timestamps)
    if not 0 < num_steps <= MAX_STEPS:
        raise InputError(f"the scenario length {num_steps} is not a step count (1..{MAX_STEPS})")
    if ts is None:
        timestamps = np.arange(num_steps, dtype=np.float64) * 0.1
    return num_steps, timestamps


def description_to_scene(sd: dict, source_name: str = "") -> Scene:
    """A loaded ScenarioNet scenario description (dict) -> validated :class:`Scene`.

    Raises :class:`InputError` with one line naming the damaged element (track id, map feature id,
    signal lane) for missing keys, wrong types, arrays whose lengths disagree and non-finite values.
    """
    md = sd.get("metadata") or {}
    if not isinstance(md, dict):
        raise InputError(f"metadata is a {type(md).__name__}, not a dict")
    num_steps, timestamps = _num_steps(sd, md)
    parts = _read_map_features(sd)
    signal_raw = _read_signal_states(sd, num_steps)
    lanes, lane_index = build_lanes(parts.lanes, parts.line_polys, parts.edge_polys)
    signals = _signals(signal_raw, lane_index, num_steps)
    road_map = RoadMap(
        lanes=lanes, road_lines=polylines(parts.road_lines), road_edges=polylines(parts.road_edges),
        crosswalks=polylines(parts.crosswalks),
        stop_sign_xy=np.asarray([p for p, _ in parts.stop_signs], np.float64).reshape(-1, 2),
        stop_sign_lanes=Ragged.from_list(
            [np.asarray([lane_index[f] for f in ids if f in lane_index], np.int64) for _, ids in parts.stop_signs],
            np.int64))
    tracks = _tracks(sd["tracks"], num_steps)
    sdc, current, meta = _metadata(sd, md, tracks, parts.counts, source_name)
    scene = Scene(scenario_id=str(md.get("scenario_id") or sd.get("id", "")), timestamps=timestamps,
                  tracks=tracks, road_map=road_map, signals=signals, sdc_index=sdc,
                  current_time_index=current, source="scenarionet", meta=meta)
    return scene.validate()


@dataclass(slots=True)
class _MapParts:
    """The map features of a description, read and checked, before lanes get their indices."""

    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(FEATURE_TYPES, 0))
    lanes: list[RawLane] = field(default_factory=list)
    line_polys: dict[int, np.ndarray] = field(default_factory=dict)  # road line id -> points (lane widths)
    edge_polys: dict[int, np.ndarray] = field(default_factory=dict)  # road edge id -> points (lane widths)
    road_lines: list[tuple[int, np.ndarray]] = field(default_factory=list)
    road_edges: list[tuple[int, np.ndarray]] = field(default_factory=list)
    crosswalks: list[tuple[int, np.ndarray]] = field(default_factory=list)
    stop_signs: list[tuple[np.ndarray, list[int]]] = field(default_factory=list)
    # (kind, feature id, points) for the finiteness check
    others: list[tuple[str, int, np.ndarray]] = field(default_factory=list)


def _read_map_features(sd: dict) -> _MapParts:
    """``map_features``: lanes, road lines and edges, crosswalks and stop signs, checked
    (:func:`~converters.womd_map.check_raw_map`); an error names the feature."""
    parts = _MapParts()
    features = sd["map_features"]
    if not isinstance(features, dict):
        raise InputError(f"map_features is a {type(features).__name__}, not a dict")
    for key, feat in features.items():
        where = f"map feature {printable(str(key))}"
        try:
            type_name = str(feat.get("type", ""))
            kind = _feature_kind(type_name)
            if kind is None:
                continue
            parts.counts[kind] += 1
            _read_feature(parts, kind, type_name, _int(key), feat)
        except InputError as exc:
            raise InputError(f"{where}: {exc}") from None
        except _ELEMENT_ERRORS as exc:
            raise InputError(f"{where}: {_why(exc)}") from None
    check_raw_map(parts.lanes, parts.others)
    return parts


def _neighbours(items: list) -> list[tuple[int, int, int, int, int]]:
    return [(_int(n["feature_id"]), _int(n["self_start_index"]), _int(n["self_end_index"]),
             _int(n["neighbor_start_index"]), _int(n["neighbor_end_index"])) for n in items]


def _boundaries(items: list) -> list[tuple[int, int, int]]:
    return [(_int(b["lane_start_index"]), _int(b["lane_end_index"]),
             _int(b["boundary_feature_id"])) for b in items]


def _read_feature(parts: _MapParts, kind: str, type_name: str, fid: int, feat: Any) -> None:
    """One map feature of a known ``kind`` added to ``parts``."""
    if kind == "lane":
        parts.lanes.append(RawLane(
            fid=fid, polyline=_xy(feat["polyline"]), z=_z(feat["polyline"]),
            lane_type=int(_LANE_TYPES.get(type_name, LaneType.UNDEFINED)),
            speed_limit_mph=float(feat.get("speed_limit_mph") or 0.0),
            entry=[_int(x) for x in feat.get("entry_lanes", [])],
            exit=[_int(x) for x in feat.get("exit_lanes", [])],
            left=_neighbours(feat.get("left_neighbor", [])), right=_neighbours(feat.get("right_neighbor", [])),
            left_bounds=_boundaries(feat.get("left_boundaries", [])),
            right_bounds=_boundaries(feat.get("right_boundaries", []))))
    elif kind == "road_line":
        pts = _xy(feat["polyline"])
        parts.line_polys[fid] = pts
        parts.road_lines.append((_ROAD_LINE_TYPES.get(type_name, 0), pts))
        parts.others.append(("road line", fid, pts))
    elif kind == "road_edge":
        pts = _xy(feat["polyline"])
        parts.edge_polys[fid] = pts
        parts.road_edges.append((_ROAD_EDGE_TYPES.get(type_name, 0), pts))
        parts.others.append(("road edge", fid, pts))
    elif kind == "crosswalk":
        pts = _xy(feat["polygon"])
        parts.crosswalks.append((0, pts))
        parts.others.append(("crosswalk", fid, pts))
    elif kind == "stop_sign":
        pos = _xy(feat["position"])
        if len(pos) == 0:
            raise InputError("stop sign without a position")
        parts.stop_signs.append((pos[0], [_int(x) for x in feat.get("lane", [])]))
        parts.others.append(("stop sign", fid, pos[:1]))


def _read_signal_states(sd: dict, num_steps: int) -> list[tuple[int, list, np.ndarray | None]]:
    """``dynamic_map_states``: (lane feature id, per-step state names, stop point or None) of each
    lane with a logged state, checked; an error names the state's key."""
    dms = sd.get("dynamic_map_states", {}) or {}
    if not isinstance(dms, dict):
        raise InputError(f"dynamic_map_states is a {type(dms).__name__}, not a dict")
    signal_raw = []
    for key, item in dms.items():
        where = f"dynamic map state {printable(str(key))}"
        try:
            states = list((item.get("state") or {}).get("object_state") or [])
            if any(st is not None for st in states):
                if len(states) != num_steps:
                    raise InputError(f"{len(states)} signal states for {num_steps} steps")
                sp = item.get("stop_point")
                stop = _xy(sp)[0] if sp is not None and len(_xy(sp)) else None
                if stop is not None and not np.all(np.isfinite(stop)):
                    raise InputError(f"stop point ({stop[0]}, {stop[1]}) is not finite")
                signal_raw.append((_int(item.get("lane", key)), states, stop))
        except InputError as exc:
            raise InputError(f"{where}: {exc}") from None
        except _ELEMENT_ERRORS as exc:
            raise InputError(f"{where}: {_why(exc)}") from None
    return signal_raw


def _signals(signal_raw: list[tuple[int, list, np.ndarray | None]], lane_index: dict[int, int],
             num_steps: int) -> SignalStates:
    """:class:`SignalStates` of the logged states whose lane is in the map."""
    signal_raw = [s for s in signal_raw if s[0] in lane_index]
    state = np.zeros((num_steps, len(signal_raw)), np.int8)
    stop_points = np.zeros((len(signal_raw), 2))
    for c, (_, states, sp) in enumerate(signal_raw):
        for t, name in enumerate(states[:num_steps]):
            state[t, c] = _signal_state(name)
        if sp is not None:
            stop_points[c] = sp
    return SignalStates(lane_index=np.asarray([lane_index[lid] for lid, _, _ in signal_raw], np.int64),
                        state=state, stop_point=stop_points)


def _metadata(sd: dict, md: dict, tracks: Tracks, counts: dict[str, int], source_name: str
              ) -> tuple[int, int, dict]:
    """The SDC's track index, the current time index and ``scene.meta``."""
    try:
        sdc_id = md.get("sdc_id")
        sdc = tracks.index_of(str(sdc_id)) if sdc_id is not None and str(sdc_id) in set(tracks.ids) else -1
        ttp = md.get("tracks_to_predict") or {}
        meta = {"map_feature_counts": counts,
                "tracks_to_predict": sorted(int(v["track_index"]) for v in ttp.values()
                                            if isinstance(v, dict) and "track_index" in v),
                "objects_of_interest": [str(x) for x in md.get("objects_of_interest", []) or []],
                "version": str(sd.get("version", "")), "source_file": source_name}
        current = int(md.get("current_time_index", 0) or 0)
    except _ELEMENT_ERRORS as exc:
        raise InputError(f"metadata: {_why(exc)}") from None
    return sdc, current, meta


def load_pickle_scene(path: str | Path) -> Scene:
    """Read one ScenarioNet pickle as a :class:`Scene` (restricted unpickling, then checked)."""
    path = Path(path)
    sd = load_pickle(path)
    if not isinstance(sd, dict) or "tracks" not in sd or "map_features" not in sd:
        raise InputError(f"{path}: not a ScenarioNet scenario description (no tracks/map_features)")
    try:
        return description_to_scene(sd, path.name)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    except (*_ELEMENT_ERRORS, RecursionError, MemoryError) as exc:
        raise InputError(f"{path}: malformed ScenarioNet scenario ({_why(exc)})") from None


def iter_pickle_scenes(path: str | Path) -> Iterator[Scene]:
    """The one scene of a ScenarioNet pickle, as an iterator (same shape as the TFRecord reader)."""
    yield load_pickle_scene(path)
