"""Scene model: frozen dataclasses of numpy arrays shared by every stage.

Conventions (internal, everywhere in the library):
- positions are the **box centre** in metres, in the source's own coordinates (WOMD scenes keep
  their absolute WOMD coordinates; SUMO scenes keep the network's coordinates);
- headings are radians, counter-clockwise from +x; see :mod:`coster_sumo.geometry.frames` for SUMO's
  front-bumper / degrees / clockwise-from-north convention;
- invalid states are arbitrary (WOMD zero-fills them): always mask with ``Tracks.valid``.

Ragged data (lane polylines, neighbour lists) is stored flat with offsets so that a whole map is a
handful of arrays and saves to one ``.npz``.

Change a scene through :func:`dataclasses.replace`; every type has ``validate()``.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from coster_sumo.errors import InputError


class ObjectType(enum.IntEnum):
    """WOMD ``Track.ObjectType`` values."""

    UNSET = 0
    VEHICLE = 1
    PEDESTRIAN = 2
    CYCLIST = 3
    OTHER = 4


class LaneType(enum.IntEnum):
    """WOMD ``LaneCenter.LaneType`` values (SUMO lanes are mapped onto these)."""

    UNDEFINED = 0
    FREEWAY = 1
    SURFACE_STREET = 2
    BIKE_LANE = 3


class SignalState(enum.IntEnum):
    """WOMD ``TrafficSignalLaneState.State`` values (SUMO link states are mapped onto these)."""

    UNKNOWN = 0
    ARROW_STOP = 1
    ARROW_CAUTION = 2
    ARROW_GO = 3
    STOP = 4
    CAUTION = 5
    GO = 6
    FLASHING_STOP = 7
    FLASHING_CAUTION = 8


def _check(cond: bool, what: str) -> None:
    if not cond:
        raise InputError(f"invalid scene: {what}")


def _shown(value: object, limit: int = 60) -> str:
    """An id as one printable line (ids come from input files)."""
    text = str(value)
    out = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text[:limit])
    return out + ("..." if len(text) > limit else "")


def _check_ids(ids: np.ndarray, what: str) -> None:
    """Ids must be non-empty and unique; the message names the first offender."""
    values = [str(v) for v in ids.tolist()]
    for i, v in enumerate(values):
        _check(v != "", f"{what} at index {i} has an empty id")
    if len(set(values)) != len(values):
        seen: set[str] = set()
        for v in values:
            _check(v not in seen, f"{what} {_shown(v)} appears twice (ids must be unique)")
            seen.add(v)


def _check_points(points: np.ndarray, offsets: np.ndarray, what: str, names: Sequence[str] | None = None) -> None:
    """Every point finite; the message names the item (by id where given) and the point."""
    if len(points) == 0:
        return
    bad = ~np.isfinite(np.asarray(points, np.float64).reshape(len(points), -1)).all(axis=1)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        item = int(np.searchsorted(offsets, row, side="right") - 1)
        name = _shown(names[item]) if names is not None else str(item)
        _check(False, f"{what} {name}: point {row - int(offsets[item])} "
                      f"{tuple(float(v) for v in np.ravel(points[row]))} is not finite")


@dataclass(frozen=True, slots=True)
class Ragged:
    """A list of variable-length arrays stored flat.

    Attributes:
        values: (total, ...) the concatenated rows.
        offsets: (num_items + 1,) int64; item ``i`` is ``values[offsets[i]:offsets[i+1]]``.
    """

    values: np.ndarray
    offsets: np.ndarray

    @classmethod
    def from_list(cls, items: Sequence[np.ndarray], dtype: type | np.dtype = np.float64,
                  inner_shape: tuple[int, ...] = ()) -> Ragged:
        """Pack ``items`` (each ``(n_i, *inner_shape)``) into one flat array."""
        lengths = np.array([len(it) for it in items], dtype=np.int64)
        offsets = np.zeros(len(items) + 1, dtype=np.int64)
        np.cumsum(lengths, out=offsets[1:])
        if len(items) and offsets[-1] > 0:
            values = np.concatenate([np.asarray(it, dtype=dtype).reshape(-1, *inner_shape)
                                     for it in items])
        else:
            values = np.zeros((0, *inner_shape), dtype=dtype)
        return cls(values=values, offsets=offsets)

    @classmethod
    def empty(cls, num_items: int = 0, dtype: type | np.dtype = np.int64,
              inner_shape: tuple[int, ...] = ()) -> Ragged:
        return cls(values=np.zeros((0, *inner_shape), dtype=dtype),
                   offsets=np.zeros(num_items + 1, dtype=np.int64))

    def __len__(self) -> int:
        return len(self.offsets) - 1

    def __getitem__(self, i: int) -> np.ndarray:
        return self.values[self.offsets[i]:self.offsets[i + 1]]

    def __iter__(self) -> Iterator[np.ndarray]:
        for i in range(len(self)):
            yield self[i]

    def lengths(self) -> np.ndarray:
        """(num_items,) int64 number of rows per item."""
        return np.diff(self.offsets)

    def item_index(self) -> np.ndarray:
        """(total,) int64: the item each flat row belongs to."""
        return np.repeat(np.arange(len(self)), self.lengths())

    def validate(self, name: str) -> None:
        _check(self.offsets.ndim == 1 and len(self.offsets) >= 1, f"{name}.offsets must be 1-D")
        _check(self.offsets[0] == 0 and self.offsets[-1] == len(self.values),
               f"{name}.offsets must start at 0 and end at len(values)")
        _check(bool(np.all(np.diff(self.offsets) >= 0)), f"{name}.offsets must be non-decreasing")


@dataclass(frozen=True, slots=True)
class Tracks:
    """Logged or simulated agents.

    Attributes:
        ids: (num_agents,) str, unique.
        object_type: (num_agents,) int8 :class:`ObjectType`.
        x: (num_agents, num_steps) float64 [m] box centre.
        y: (num_agents, num_steps) float64 [m] box centre.
        heading: (num_agents, num_steps) float64 [rad] counter-clockwise from +x.
        vx: (num_agents, num_steps) float64 [m/s].
        vy: (num_agents, num_steps) float64 [m/s].
        length: (num_agents, num_steps) float64 [m] along the heading.
        width: (num_agents, num_steps) float64 [m] across the heading.
        valid: (num_agents, num_steps) bool; other fields are meaningless where False.
    """

    ids: np.ndarray
    object_type: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    length: np.ndarray
    width: np.ndarray
    valid: np.ndarray

    @property
    def num_agents(self) -> int:
        return int(self.x.shape[0])

    @property
    def num_steps(self) -> int:
        return int(self.x.shape[1])

    @property
    def xy(self) -> np.ndarray:
        """(num_agents, num_steps, 2) float64 [m], a new array (see :meth:`xy_of` for a few agents)."""
        return np.stack([self.x, self.y], axis=-1)

    def xy_of(self, agents: Any, steps: Any = slice(None)) -> np.ndarray:
        """``xy[agents, steps]`` without building ``xy`` for every agent first (a city recording's
        is 0.8 GB: 3,614 agents x 14,000 steps on the wheel's A10KW motorway)."""
        return np.stack([self.x[agents, steps], self.y[agents, steps]], axis=-1)

    @property
    def speed(self) -> np.ndarray:
        """(num_agents, num_steps) float64 [m/s]."""
        return np.hypot(self.vx, self.vy)

    def index_of(self, agent_id: str) -> int:
        hits = np.flatnonzero(self.ids == agent_id)
        if len(hits) == 0:
            raise KeyError(agent_id)
        return int(hits[0])

    def select(self, agents: np.ndarray | slice | None = None, steps: np.ndarray | slice | None = None
               ) -> Tracks:
        """Sub-select agents (first axis) and/or steps (second axis)."""
        a = slice(None) if agents is None else agents
        s = slice(None) if steps is None else steps
        per_agent = {"ids": self.ids[a], "object_type": self.object_type[a]}
        # one copy per field: x[a][:, s] would first copy every step of the agents (a city
        # recording has 14,000 of them), and two index arrays together need np.ix_
        both = np.ix_(a, s) if not isinstance(a, slice) and not isinstance(s, slice) else (a, s)
        per_step = {f.name: getattr(self, f.name)[both] for f in dataclasses.fields(self)
                    if f.name not in per_agent}
        return Tracks(**per_agent, **per_step)

    def validate(self) -> None:
        n = len(self.ids)
        _check(self.ids.ndim == 1, "tracks.ids must be 1-D")
        _check_ids(self.ids, "track")
        _check(self.object_type.shape == (n,), "tracks.object_type must be (num_agents,)")
        shape = self.x.shape
        _check(len(shape) == 2 and shape[0] == n, "tracks.x must be (num_agents, num_steps)")
        for f in ("y", "heading", "vx", "vy", "length", "width", "valid"):
            _check(getattr(self, f).shape == shape, f"tracks.{f} must have shape {shape}")
        _check(self.valid.dtype == np.bool_, "tracks.valid must be bool")
        for f in ("x", "y", "heading", "vx", "vy", "length", "width"):
            arr = getattr(self, f)
            bad = self.valid & ~np.isfinite(arr)
            if bad.any():  # invalid states may hold anything; valid ones must be numbers
                a, t = (int(v) for v in np.argwhere(bad)[0])
                _check(False, f"track {_shown(self.ids[a])} step {t}: {f} is {arr[a, t]} in a valid state")


@dataclass(frozen=True, slots=True)
class Lanes:
    """Lane centrelines with their topology.

    Attributes:
        ids: (num_lanes,) str (WOMD feature ids as decimal strings; SUMO lane ids).
        centerline: Ragged of (n_i, 2) float64 [m] points in driving direction.
        width: (num_lanes,) float64 [m] full lane width.
        lane_type: (num_lanes,) int8 :class:`LaneType`.
        speed_limit: (num_lanes,) float64 [m/s]; 0 where unknown.
        is_junction: (num_lanes,) bool, lane lies inside a junction (WOMD interior lane or SUMO
            internal lane).
        predecessors, successors, left_neighbors, right_neighbors: Ragged of int64 lane indices.
    """

    ids: np.ndarray
    centerline: Ragged
    width: np.ndarray
    lane_type: np.ndarray
    speed_limit: np.ndarray
    is_junction: np.ndarray
    predecessors: Ragged
    successors: Ragged
    left_neighbors: Ragged
    right_neighbors: Ragged

    @classmethod
    def empty(cls) -> Lanes:  # no lanes (a recording that left the map out)
        e = Ragged.empty
        return cls(np.zeros(0, str), e(0, np.float64, (2,)), np.zeros(0), np.zeros(0, np.int8), np.zeros(0),
                   np.zeros(0, bool), e(), e(), e(), e())

    def __len__(self) -> int:
        return len(self.ids)

    def index_of(self, lane_id: str) -> int:
        hits = np.flatnonzero(self.ids == lane_id)
        if len(hits) == 0:
            raise KeyError(lane_id)
        return int(hits[0])

    def validate(self) -> None:
        n = len(self.ids)
        _check_ids(self.ids, "lane")
        self.centerline.validate("lanes.centerline")
        _check(len(self.centerline) == n, "lanes.centerline must have one polyline per lane")
        lengths = self.centerline.lengths()
        if np.any(lengths == 0):
            _check(False, f"lane {_shown(self.ids[int(np.flatnonzero(lengths == 0)[0])])}: no centreline points")
        _check_points(self.centerline.values, self.centerline.offsets, "lane", [str(v) for v in self.ids])
        for f in ("width", "lane_type", "speed_limit", "is_junction"):
            _check(getattr(self, f).shape == (n,), f"lanes.{f} must be (num_lanes,)")
        for f in ("predecessors", "successors", "left_neighbors", "right_neighbors"):
            r: Ragged = getattr(self, f)
            r.validate(f"lanes.{f}")
            _check(len(r) == n, f"lanes.{f} must have one list per lane")
            _check(bool(np.all((r.values >= 0) & (r.values < n))), f"lanes.{f} index out of range")


@dataclass(frozen=True, slots=True)
class Polylines:
    """Typed polylines or polygons (road lines, road edges, crosswalks, junction shapes).

    Attributes:
        points: Ragged of (n_i, 2) float64 [m].
        kind: (num_items,) int8 source type code (WOMD RoadLine / RoadEdge type; 0 where none).
    """

    points: Ragged
    kind: np.ndarray

    @classmethod
    def empty(cls) -> Polylines:
        return cls(points=Ragged.empty(0, np.float64, (2,)), kind=np.zeros(0, np.int8))

    def __len__(self) -> int:
        return len(self.kind)

    def validate(self, name: str) -> None:
        self.points.validate(name)
        _check(len(self.points) == len(self.kind), f"{name}: one kind per item")
        _check_points(self.points.values, self.points.offsets, f"{name} item")


@dataclass(frozen=True, slots=True)
class RoadMap:
    """The static map.

    Attributes:
        lanes: lane centrelines and topology.
        road_lines: painted lines (kind = WOMD RoadLine type).
        road_edges: road boundaries (kind = WOMD RoadEdge type).
        crosswalks: polygons.
        junctions: polygons of junction areas (SUMO nets; empty for WOMD scenes).
        stop_sign_xy: (num_stop_signs, 2) float64 [m].
        stop_sign_lanes: Ragged of int64 lane indices controlled by each stop sign.
    """

    lanes: Lanes
    road_lines: Polylines = field(default_factory=Polylines.empty)
    road_edges: Polylines = field(default_factory=Polylines.empty)
    crosswalks: Polylines = field(default_factory=Polylines.empty)
    junctions: Polylines = field(default_factory=Polylines.empty)
    stop_sign_xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    stop_sign_lanes: Ragged = field(default_factory=lambda: Ragged.empty(0))

    def validate(self) -> None:
        self.lanes.validate()
        self.road_lines.validate("road_lines")
        self.road_edges.validate("road_edges")
        self.crosswalks.validate("crosswalks")
        self.junctions.validate("junctions")
        _check(self.stop_sign_xy.ndim == 2 and self.stop_sign_xy.shape[1] == 2,
               "stop_sign_xy must be (num_stop_signs, 2)")
        _check(len(self.stop_sign_lanes) == len(self.stop_sign_xy), "one lane list per stop sign")
        _check_points(self.stop_sign_xy, np.arange(len(self.stop_sign_xy) + 1), "stop sign")

    def lane_type_at(self, xy: np.ndarray) -> np.ndarray:
        """(N,) int8 :class:`LaneType` of the lane whose centreline is nearest to each point of
        ``xy`` (N, 2) [m]; UNDEFINED for every point when the map has no lane."""
        import shapely

        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        lanes = self.lanes
        counts = np.diff(lanes.centerline.offsets)
        usable = np.flatnonzero(counts >= 2)
        out = np.full(len(xy), int(LaneType.UNDEFINED), np.int8)
        if not len(usable) or not len(xy):
            return out
        owner = np.repeat(np.arange(len(counts)), counts)  # lane of each centreline point
        keep = np.isin(owner, usable)
        lines = shapely.linestrings(lanes.centerline.values[keep],  # one per usable lane, in order
                                    indices=np.searchsorted(usable, owner[keep]))
        hit = shapely.STRtree(lines).query_nearest(shapely.points(xy), all_matches=False)  # (2, N): point, line
        out[hit[0]] = lanes.lane_type[usable[hit[1]]]
        return out

    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of all lane points [m]."""
        pts = self.lanes.centerline.values
        if len(pts) == 0:
            return (0.0, 0.0, 0.0, 0.0)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))


@dataclass(frozen=True, slots=True)
class SignalStates:
    """Per-step traffic-signal state of controlled lanes.

    Attributes:
        lane_index: (num_controlled,) int64 index into ``RoadMap.lanes``.
        state: (num_steps, num_controlled) int8 :class:`SignalState` (UNKNOWN where not logged).
        stop_point: (num_controlled, 2) float64 [m].
    """

    lane_index: np.ndarray
    state: np.ndarray
    stop_point: np.ndarray

    @classmethod
    def empty(cls, num_steps: int) -> SignalStates:
        return cls(lane_index=np.zeros(0, np.int64), state=np.zeros((num_steps, 0), np.int8),
                   stop_point=np.zeros((0, 2)))

    def validate(self, num_steps: int, num_lanes: int) -> None:
        k = len(self.lane_index)
        _check(self.state.shape == (num_steps, k), f"signals.state must be ({num_steps}, {k})")
        _check(self.stop_point.shape == (k, 2), "signals.stop_point must be (num_controlled, 2)")
        _check(bool(np.all((self.lane_index >= 0) & (self.lane_index < num_lanes))),
               "signals.lane_index out of range")
        _check_points(self.stop_point, np.arange(k + 1), "signal stop point of controlled lane")

    def per_lane(self, num_lanes: int) -> np.ndarray:
        """(num_steps, num_lanes) int8 state of every lane (UNKNOWN where uncontrolled)."""
        out = np.zeros((self.state.shape[0], num_lanes), np.int8)
        out[:, self.lane_index] = self.state
        return out


@dataclass(frozen=True, slots=True)
class Scene:
    """One traffic scene: agents over time, the map, signals.

    Attributes:
        scenario_id: str.
        timestamps: (num_steps,) float64 [s].
        tracks: the agents.
        road_map: the static map.
        signals: per-step signal states.
        sdc_index: index of the self-driving car / default target in ``tracks`` (-1 if none).
        current_time_index: WOMD's current step (history/future boundary); 0 for SUMO scenes.
        source: where the scene came from ("womd", "scenarionet", "sumo", "synthetic").
        meta: free-form JSON-able metadata (e.g. SUMO config path, coordinate offset).
    """

    scenario_id: str
    timestamps: np.ndarray
    tracks: Tracks
    road_map: RoadMap
    signals: SignalStates
    sdc_index: int = -1
    current_time_index: int = 0
    source: str = "synthetic"
    meta: dict = field(default_factory=dict)

    @property
    def num_steps(self) -> int:
        return len(self.timestamps)

    @property
    def dt(self) -> float:
        """Step length [s] (median of timestamp differences)."""
        if len(self.timestamps) < 2:
            return 0.1
        return float(np.median(np.diff(self.timestamps)))

    def validate(self) -> Scene:
        """Raise :class:`InputError` on the first inconsistency; return self for chaining."""
        self.tracks.validate()
        self.road_map.validate()
        _check(self.timestamps.ndim == 1, "timestamps must be 1-D")
        if not np.all(np.isfinite(self.timestamps)):
            k = int(np.flatnonzero(~np.isfinite(self.timestamps))[0])
            _check(False, f"timestamp of step {k} is {self.timestamps[k]}")
        _check(self.tracks.num_steps == len(self.timestamps),
               f"tracks have {self.tracks.num_steps} steps but there are {len(self.timestamps)} timestamps")
        steps = np.flatnonzero(np.diff(self.timestamps) <= 0)
        _check(len(steps) == 0, "timestamps must increase"
               + (f" (step {int(steps[0]) + 1} is not after step {int(steps[0])})" if len(steps) else ""))
        self.signals.validate(len(self.timestamps), len(self.road_map.lanes))
        _check(-1 <= self.sdc_index < self.tracks.num_agents,
               f"sdc_index {self.sdc_index} is not a track index (-1 or 0..{self.tracks.num_agents - 1})")
        _check(0 <= self.current_time_index < max(1, self.num_steps), "current_time_index out of range")
        return self


def resample(scene: Scene, hz: float = 2.0) -> Scene:
    """Downsample a scene to ``hz`` by keeping every k-th step, k = round(1 / (hz * dt)).

    WOMD's 91 steps at 10 Hz become 19 steps at 2 Hz (steps 0, 5, ..., 90). The step that holds
    ``current_time_index`` is kept when it falls on the grid (WOMD's 10 does).
    """
    k = max(1, int(round(1.0 / (hz * scene.dt))))
    if k == 1:
        return scene
    phase = scene.current_time_index % k
    steps = np.arange(phase, scene.num_steps, k)
    sig = scene.signals
    return dataclasses.replace(
        scene,
        timestamps=scene.timestamps[steps],
        tracks=scene.tracks.select(steps=steps),
        signals=SignalStates(lane_index=sig.lane_index, state=sig.state[steps], stop_point=sig.stop_point),
        current_time_index=int(np.searchsorted(steps, scene.current_time_index)),
    )
