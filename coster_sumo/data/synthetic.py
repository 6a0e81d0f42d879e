"""Small scenes built in code, for tests, benchmarks and examples (no data files needed).

- :func:`two_lane_road`: a straight two-lane one-way road, vehicles following each other.
- :func:`four_way_junction`: a signalised four-way intersection, one lane per approach and
  direction, with junction-interior lanes (straight, left, right) like WOMD's, signal states.
- :func:`merge`: a main road with an on-ramp joining it.
- :func:`with_vulnerable_road_users`: any of them with two pedestrians and a cyclist beside the SDC's
  path (one pedestrian turns on the spot and crosses, one stops).

All use WOMD conventions: 10 Hz, 91 steps, current_time_index 10, lane ids as decimal strings,
large absolute coordinates (``origin``) so that code that silently normalises offsets is caught.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from coster_sumo.core import scene
from coster_sumo.core.scene import Ragged, Scene

DT = 0.1  # [s]
NUM_STEPS = 91
LANE_WIDTH = 3.7  # [m]
POINT_SPACING = 0.5  # [m] WOMD samples lane polylines about every 0.5 m


def _line(p0: tuple[float, float], p1: tuple[float, float], spacing: float = POINT_SPACING) -> np.ndarray:
    """(n, 2) points from p0 to p1, about ``spacing`` apart."""
    a, b = np.asarray(p0, float), np.asarray(p1, float)
    n = max(2, int(np.ceil(np.linalg.norm(b - a) / spacing)) + 1)
    t = np.linspace(0.0, 1.0, n)[:, None]
    return a + t * (b - a)


def _arc(p0: np.ndarray, h0: float, p1: np.ndarray, spacing: float = POINT_SPACING) -> np.ndarray:
    """(n, 2) quadratic Bezier from p0 (heading h0) to p1, control point on p0's heading line."""
    d0 = np.array([np.cos(h0), np.sin(h0)])
    # control point: where p0's heading line passes closest to p1's projection on it
    c = p0 + d0 * float(np.dot(p1 - p0, d0))
    approx_len = np.linalg.norm(c - p0) + np.linalg.norm(p1 - c)
    n = max(3, int(np.ceil(approx_len / spacing)) + 1)
    t = np.linspace(0.0, 1.0, n)[:, None]
    return (1 - t) ** 2 * p0 + 2 * (1 - t) * t * c + t**2 * p1


class _MapBuilder:
    def __init__(self) -> None:
        self.ids: list[str] = []
        self.lines: list[np.ndarray] = []
        self.junction: list[bool] = []
        self.types: list[int] = []
        self.speed: list[float] = []
        self.pred: list[list[int]] = []
        self.succ: list[list[int]] = []
        self.left: list[list[int]] = []
        self.right: list[list[int]] = []

    def lane(self, pts: np.ndarray, *, junction: bool = False, speed: float = 13.89,
             lane_type: scene.LaneType = scene.LaneType.SURFACE_STREET) -> int:
        i = len(self.ids)
        self.ids.append(str(100 + i))
        self.lines.append(np.asarray(pts, float))
        self.junction.append(junction)
        self.types.append(int(lane_type))
        self.speed.append(speed)
        for lst in (self.pred, self.succ, self.left, self.right):
            lst.append([])
        return i

    def link(self, a: int, b: int) -> None:
        self.succ[a].append(b)
        self.pred[b].append(a)

    def neighbours(self, left: int, right: int) -> None:
        self.left[right].append(left)
        self.right[left].append(right)

    def build(self, road_edges: list[np.ndarray] | None = None) -> scene.RoadMap:
        n = len(self.ids)

        def rag(lists: list[list[int]]) -> Ragged:
            return Ragged.from_list([np.asarray(v, np.int64) for v in lists], np.int64)

        lanes = scene.Lanes(
            ids=np.asarray(self.ids), centerline=Ragged.from_list(self.lines, np.float64, (2,)),
            width=np.full(n, LANE_WIDTH), lane_type=np.asarray(self.types, np.int8),
            speed_limit=np.asarray(self.speed), is_junction=np.asarray(self.junction, bool),
            predecessors=rag(self.pred), successors=rag(self.succ),
            left_neighbors=rag(self.left), right_neighbors=rag(self.right))
        edges = road_edges or []
        return scene.RoadMap(lanes=lanes,
                             road_edges=scene.Polylines(points=Ragged.from_list(edges, np.float64, (2,)),
                                                        kind=np.ones(len(edges), np.int8)))


def _follow(path: np.ndarray, s0: float, speed: float, steps: int = NUM_STEPS
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions and headings of an agent driving along ``path`` from arc length s0 at ``speed``."""
    seg = np.diff(path, axis=0)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    s = np.clip(s0 + speed * DT * np.arange(steps), 0.0, cum[-1])
    x = np.interp(s, cum, path[:, 0])
    y = np.interp(s, cum, path[:, 1])
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    heading = np.arctan2(seg[k, 1], seg[k, 0])
    return x, y, heading


def _tracks(agents: list[tuple[str, np.ndarray, np.ndarray, np.ndarray, float]],
            steps: int = NUM_STEPS) -> scene.Tracks:
    """agents: (id, x, y, heading, speed) with per-step arrays; all vehicles 4.5 x 1.9 m."""
    n = len(agents)
    x = np.stack([a[1] for a in agents]) if n else np.zeros((0, steps))
    y = np.stack([a[2] for a in agents]) if n else np.zeros((0, steps))
    h = np.stack([a[3] for a in agents]) if n else np.zeros((0, steps))
    # velocity from finite differences so that it agrees with positions
    vx: np.ndarray = np.gradient(x, DT, axis=1) if n else x.copy()  # type: ignore[assignment]
    vy: np.ndarray = np.gradient(y, DT, axis=1) if n else y.copy()  # type: ignore[assignment]
    return scene.Tracks(ids=np.asarray([a[0] for a in agents], dtype=str),
                        object_type=np.full(n, int(scene.ObjectType.VEHICLE), np.int8),
                        x=x, y=y, heading=h, vx=vx, vy=vy,
                        length=np.full((n, steps), 4.5), width=np.full((n, steps), 1.9),
                        valid=np.ones((n, steps), bool))


def _timestamps(steps: int = NUM_STEPS) -> np.ndarray:
    return np.round(np.arange(steps) * DT, 6)


def two_lane_road(origin: tuple[float, float] = (-7785.0, -6683.0), length_m: float = 200.0) -> Scene:
    """A straight one-way road along +x with two lanes; four vehicles, the SDC in the right lane."""
    ox, oy = origin
    b = _MapBuilder()
    right = b.lane(_line((ox, oy), (ox + length_m, oy)))
    left = b.lane(_line((ox, oy + LANE_WIDTH), (ox + length_m, oy + LANE_WIDTH)))
    b.neighbours(left, right)
    edges = [_line((ox, oy - LANE_WIDTH / 2), (ox + length_m, oy - LANE_WIDTH / 2), 5.0),
             _line((ox, oy + 1.5 * LANE_WIDTH), (ox + length_m, oy + 1.5 * LANE_WIDTH), 5.0)]
    road_map = b.build(edges)
    agents = []
    for name, lane, s0, v in (("sdc", right, 30.0, 10.0), ("lead", right, 55.0, 9.0),
                              ("left1", left, 20.0, 12.0), ("left2", left, 60.0, 11.0)):
        x, y, h = _follow(road_map.lanes.centerline[lane], s0, v)
        agents.append((name, x, y, h, v))
    return Scene(scenario_id="synthetic_two_lane", timestamps=_timestamps(), tracks=_tracks(agents),
                 road_map=road_map, signals=scene.SignalStates.empty(NUM_STEPS), sdc_index=0,
                 current_time_index=10, source="synthetic").validate()


def four_way_junction(origin: tuple[float, float] = (8123.45, -3456.78), arm_m: float = 80.0,
                      box_m: float = 10.0) -> Scene:
    """A signalised four-way junction centred at ``origin``.

    Each arm has one incoming and one outgoing lane (right-hand traffic). Inside the box, interior
    lanes connect every incoming lane to the straight, left and right outgoing lanes. North-south
    has green for the first 4.5 s, east-west for the rest.
    """
    c = np.asarray(origin, float)
    b = _MapBuilder()
    half = LANE_WIDTH / 2
    incoming: dict[str, int] = {}
    outgoing: dict[str, int] = {}
    in_end: dict[str, np.ndarray] = {}
    out_start: dict[str, np.ndarray] = {}
    # direction of travel of the incoming lane from each arm
    arms = {"S": np.array([0.0, 1.0]), "N": np.array([0.0, -1.0]),
            "W": np.array([1.0, 0.0]), "E": np.array([-1.0, 0.0])}
    for arm, d in arms.items():
        right_of_d = np.array([d[1], -d[0]])
        start = c - d * (box_m + arm_m) + right_of_d * half
        end = c - d * box_m + right_of_d * half
        incoming[arm] = b.lane(_line(tuple(start), tuple(end)))
        in_end[arm] = end
        # outgoing lane on the same arm travels away from the centre (direction -d)
        o_start = c - d * box_m - right_of_d * half
        o_end = c - d * (box_m + arm_m) - right_of_d * half
        outgoing[arm] = b.lane(_line(tuple(o_start), tuple(o_end)))
        out_start[arm] = o_start
    opposite = {"S": "N", "N": "S", "W": "E", "E": "W"}
    left_of = {"S": "W", "W": "N", "N": "E", "E": "S"}  # heading north from S, a left turn exits west
    right_of = {"S": "E", "E": "N", "N": "W", "W": "S"}
    interior: dict[tuple[str, str], int] = {}
    for arm, d in arms.items():
        h0 = float(np.arctan2(d[1], d[0]))
        for exit_arm in (opposite[arm], left_of[arm], right_of[arm]):
            p0, p1 = in_end[arm], out_start[exit_arm]
            pts = _line(tuple(p0), tuple(p1)) if exit_arm == opposite[arm] else _arc(p0, h0, p1)
            j = b.lane(pts, junction=True)
            b.link(incoming[arm], j)
            b.link(j, outgoing[exit_arm])
            interior[(arm, exit_arm)] = j
    road_map = b.build()
    lanes = road_map.lanes
    # signals on the incoming lanes, stop point at their ends
    ctrl = np.array([incoming[a] for a in ("S", "N", "W", "E")], np.int64)
    state = np.zeros((NUM_STEPS, 4), np.int8)
    ns_green = np.arange(NUM_STEPS) < 45
    state[:, 0] = state[:, 1] = np.where(ns_green, scene.SignalState.GO, scene.SignalState.STOP)
    state[:, 2] = state[:, 3] = np.where(ns_green, scene.SignalState.STOP, scene.SignalState.GO)
    state[40:45, 0:2] = scene.SignalState.CAUTION
    signals = scene.SignalStates(lane_index=ctrl, state=state,
                                 stop_point=np.stack([lanes.centerline[i][-1] for i in ctrl]))
    agents = []
    # the SDC goes straight S->N through the green; a vehicle turns left from N; one waits at W.
    path = np.concatenate([lanes.centerline[incoming["S"]], lanes.centerline[interior[("S", "N")]][1:],
                           lanes.centerline[outgoing["N"]][1:]])
    agents.append(("sdc", *_follow(path, 40.0, 9.0), 9.0))
    path = np.concatenate([lanes.centerline[incoming["N"]], lanes.centerline[interior[("N", "E")]][1:],
                           lanes.centerline[outgoing["E"]][1:]])
    agents.append(("turner", *_follow(path, 20.0, 8.0), 8.0))
    wx, wy, wh = _follow(lanes.centerline[incoming["W"]], arm_m - 3.0, 0.0)
    agents.append(("waiting", wx, wy, wh, 0.0))
    path = np.concatenate([lanes.centerline[incoming["E"]], lanes.centerline[interior[("E", "W")]][1:],
                           lanes.centerline[outgoing["W"]][1:]])
    agents.append(("late", *_follow(path, 0.0, 6.0), 6.0))
    tracks = _tracks(agents)
    # the late vehicle appears only after 2 s: exercises validity masks
    valid = tracks.valid.copy()
    valid[3, :20] = False
    x = tracks.x.copy()
    x[3, :20] = 0.0
    tracks = dataclasses.replace(tracks, valid=valid, x=x)
    return Scene(scenario_id="synthetic_four_way", timestamps=_timestamps(), tracks=tracks,
                 road_map=road_map, signals=signals, sdc_index=0, current_time_index=10,
                 source="synthetic").validate()


def merge(origin: tuple[float, float] = (1234.567, -9876.543), length_m: float = 250.0) -> Scene:
    """A one-lane main road along +x and an on-ramp joining it at 45 degrees halfway."""
    ox, oy = origin
    b = _MapBuilder()
    mid = ox + length_m / 2
    main_in = b.lane(_line((ox, oy), (mid, oy)), speed=22.0)
    main_out = b.lane(_line((mid, oy), (ox + length_m, oy)), speed=22.0)
    ramp = b.lane(_line((mid - 60.0, oy - 60.0), (mid, oy)), speed=16.0)
    b.link(main_in, main_out)
    b.link(ramp, main_out)
    road_map = b.build()
    lanes = road_map.lanes
    agents = []
    main = np.concatenate([lanes.centerline[main_in], lanes.centerline[main_out][1:]])
    agents.append(("sdc", *_follow(main, 40.0, 15.0), 15.0))
    ramp_path = np.concatenate([lanes.centerline[ramp], lanes.centerline[main_out][1:]])
    agents.append(("ramp", *_follow(ramp_path, 10.0, 12.0), 12.0))
    agents.append(("ahead", *_follow(main, 90.0, 14.0), 14.0))
    return Scene(scenario_id="synthetic_merge", timestamps=_timestamps(), tracks=_tracks(agents),
                 road_map=road_map, signals=scene.SignalStates.empty(NUM_STEPS), sdc_index=0,
                 current_time_index=10, source="synthetic").validate()


ALL = {"two_lane_road": two_lane_road, "four_way_junction": four_way_junction, "merge": merge}


# (id, object type, length, width [m]): the agents with_vulnerable_road_users adds
_VRU_AGENTS = (("walker_turns", scene.ObjectType.PEDESTRIAN, 0.5, 0.5),
               ("walker_stops", scene.ObjectType.PEDESTRIAN, 0.5, 0.5),
               ("rider", scene.ObjectType.CYCLIST, 1.8, 0.65))


def _vru_paths(x0: float, y0: float, h0: float, steps: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per added agent: x, y [m], heading [rad] (steps,) in the world, from the SDC's first pose."""
    t = np.arange(steps) * DT
    fwd, left = np.array([np.cos(h0), np.sin(h0)]), np.array([-np.sin(h0), np.cos(h0)])
    base = np.array([x0, y0])
    turn_at = steps // 2
    # walks along at 1.4 m/s 4 m right of the SDC's start, turns left on the spot and crosses
    along = 1.4 * np.minimum(t, t[turn_at])
    across = 1.4 * np.maximum(t - t[turn_at], 0.0)
    walk1 = base + (5.0 + along)[:, None] * fwd + (-4.0 + across)[:, None] * left
    head1 = np.where(t < t[turn_at], h0, h0 + np.pi / 2)
    # walks at 1.2 m/s for 3 s, then stands (facing the same way)
    walk2 = base + (2.0 + 1.2 * np.minimum(t, 3.0))[:, None] * fwd - 5.0 * left
    head2 = np.full(steps, h0)
    # rides at 5 m/s 2.5 m right of the SDC's start, bearing slowly left
    yaw = 0.04 * t
    ride = base + np.stack([np.cumsum(5.0 * DT * np.cos(yaw)), np.cumsum(5.0 * DT * np.sin(yaw))], -1) @ np.stack(
        [fwd, left]) - 2.5 * left
    return [(walk1[:, 0], walk1[:, 1], head1), (walk2[:, 0], walk2[:, 1], head2), (ride[:, 0], ride[:, 1], h0 + yaw)]


def with_vulnerable_road_users(base: Scene) -> Scene:
    """``base`` with two pedestrians and a cyclist added beside its SDC's path (see the module
    docstring); the SDC and the other agents are unchanged."""
    tr = base.tracks
    n = tr.num_steps
    x0, y0, h0 = (float(a[base.sdc_index, 0]) for a in (tr.x, tr.y, tr.heading))
    paths = _vru_paths(x0, y0, h0, n)
    x = np.stack([p[0] for p in paths])
    y = np.stack([p[1] for p in paths])
    size = np.array([[a[2], a[3]] for a in _VRU_AGENTS])  # (3, 2)
    added = scene.Tracks(ids=np.array([a[0] for a in _VRU_AGENTS], dtype=str),
                         object_type=np.array([int(a[1]) for a in _VRU_AGENTS], np.int8),
                         x=x, y=y, heading=np.stack([p[2] for p in paths]),
                         vx=np.gradient(x, DT, axis=1), vy=np.gradient(y, DT, axis=1),
                         length=np.repeat(size[:, :1], n, axis=1), width=np.repeat(size[:, 1:], n, axis=1),
                         valid=np.ones((len(paths), n), bool))
    joined = {f.name: np.concatenate([getattr(tr, f.name), getattr(added, f.name)])
              for f in dataclasses.fields(scene.Tracks)}
    return dataclasses.replace(base, scenario_id=base.scenario_id + "_vru", tracks=scene.Tracks(**joined)).validate()
