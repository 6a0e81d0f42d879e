"""Backward baselines of the rollout: constant velocity and constant lane.

Both reconstruct a vehicle's past from its state at t_rev only (centre, heading, speed), at any
times ``rel_times <= 0`` [s] relative to t_rev, and return ``(T, 3)`` poses x, y [m], yaw [rad] with
the pose at ``rel_time == 0`` exactly the given state.

- :func:`constant_velocity_backward`: straight back along the heading at the current speed.
- :func:`constant_lane_backward`: back along the nearest lane centreline whose direction agrees
  with the heading (within :data:`MAX_HEADING_DIFF_RAD`, at most :data:`MAX_LANE_DISTANCE_M`
  away), continuing into the straightest predecessor lane, at the current speed and keeping the
  current lateral offset from the centreline; constant velocity when no lane qualifies.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coster_sumo.core.scene import RoadMap
from coster_sumo.core.snapshot import AgentState
from coster_sumo.geometry.boxes import polyline_arc_length

MAX_LANE_DISTANCE_M = 5.0  # [m] a lane farther than this from the vehicle is not "its" lane
MAX_HEADING_DIFF_RAD = np.pi / 4  # [rad] lane direction vs vehicle heading


def constant_velocity_backward(state: AgentState, rel_times: np.ndarray) -> np.ndarray:
    """Poses at ``rel_times`` (T,) [s] (<= 0) moving at the state's velocity: (T, 3) x, y, yaw."""
    t = np.asarray(rel_times, dtype=np.float64)
    v = state.velocity
    out = np.empty((len(t), 3))
    out[:, 0] = state.x + v[0] * t
    out[:, 1] = state.y + v[1] * t
    out[:, 2] = state.yaw
    return out


@dataclass(frozen=True)
class LaneIndex:
    """Every lane segment of a map, flat, for vectorised nearest-lane queries.

    Attributes:
        road_map: the map.
        s0, s1: (S, 2) [m] segment ends; lane: (S,) int64; arc0: (S,) [m] arc length of s0 on its lane.
    """

    road_map: RoadMap
    s0: np.ndarray
    s1: np.ndarray
    lane: np.ndarray
    arc0: np.ndarray

    @classmethod
    def build(cls, road_map: RoadMap) -> LaneIndex:
        rag = road_map.lanes.centerline
        pts = np.asarray(rag.values, np.float64).reshape(-1, 2)
        item = rag.item_index()
        same = item[1:] == item[:-1] if len(pts) else np.zeros(0, bool)
        idx = np.flatnonzero(same)
        seg = np.hypot(*(pts[idx + 1] - pts[idx]).T) if len(idx) else np.zeros(0)
        # arc length of each segment start within its lane
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        lane = item[idx]
        first_seg = np.searchsorted(lane, lane, side="left")  # lane is sorted
        arc0 = cum[:-1] - cum[first_seg] if len(idx) else np.zeros(0)
        return cls(road_map=road_map, s0=pts[idx], s1=pts[idx + 1], lane=lane.astype(np.int64), arc0=arc0)

    def nearest(self, xy: np.ndarray, yaw: float, max_distance_m: float = MAX_LANE_DISTANCE_M,
                max_heading_diff_rad: float = MAX_HEADING_DIFF_RAD) -> tuple[int, float, float] | None:
        """(lane, arc length [m], signed lateral offset [m], left positive) of the closest
        direction-compatible lane point to ``xy`` (2,), or None."""
        if len(self.s0) == 0:
            return None
        e = self.s1 - self.s0
        l2 = np.maximum(np.sum(e * e, axis=1), 1e-12)
        rel = np.asarray(xy, np.float64) - self.s0
        t = np.clip(np.sum(rel * e, axis=1) / l2, 0.0, 1.0)
        d = rel - t[:, None] * e
        dist = np.hypot(d[:, 0], d[:, 1])
        seg_yaw = np.arctan2(e[:, 1], e[:, 0])
        dh = np.abs((seg_yaw - yaw + np.pi) % (2 * np.pi) - np.pi)
        ok = (dist <= max_distance_m) & (dh <= max_heading_diff_rad)
        if not ok.any():
            return None
        j = int(np.argmin(np.where(ok, dist + 0.5 * dh, np.inf)))  # tie-break towards aligned lanes
        cross = e[j, 0] * rel[j, 1] - e[j, 1] * rel[j, 0]
        lateral = float(np.sign(cross) * dist[j]) if cross != 0 else 0.0
        return int(self.lane[j]), float(self.arc0[j] + t[j] * np.sqrt(l2[j])), lateral


def _turn(points: np.ndarray) -> float:
    """|heading change| [rad] from the first to the last segment of a polyline."""
    p = np.asarray(points, np.float64)
    if len(p) < 3:
        return 0.0
    a, b = p[1] - p[0], p[-1] - p[-2]
    return float(abs(np.angle(np.exp(1j * (np.arctan2(b[1], b[0]) - np.arctan2(a[1], a[0]))))))


def backward_path(road_map: RoadMap, lane: int, arc: float, length_m: float, heading: float = 0.0) -> np.ndarray:
    """(n, 2) points ending at arc length ``arc`` of ``lane``, reaching ``length_m`` back through
    predecessors (the straightest one where there are several: the smallest heading change along
    it), extended straight when the map ends (along the path's first segment, or ``heading``
    [rad] when the path is a single point)."""
    lanes = road_map.lanes
    pts = np.asarray(lanes.centerline[lane], np.float64)
    cum = polyline_arc_length(pts)
    keep = cum < arc
    end = np.interp(arc, cum, pts[:, 0]), np.interp(arc, cum, pts[:, 1])
    path = np.concatenate([pts[keep], np.array([end])])
    have = arc
    seen = {lane}
    cur = lane
    while have < length_m:
        preds = [int(p) for p in lanes.predecessors[cur] if int(p) not in seen]
        if not preds:
            break
        cur = min(preds, key=lambda p: (_turn(lanes.centerline[p]), p))
        seen.add(cur)
        prev = np.asarray(lanes.centerline[cur], np.float64)
        if len(prev) < 2:
            break
        have += float(polyline_arc_length(prev)[-1])
        path = np.concatenate([prev[:-1], path]) if np.allclose(prev[-1], path[0], atol=0.5) else np.concatenate(
            [prev, path])
    total = float(polyline_arc_length(path)[-1]) if len(path) > 1 else 0.0
    if total < length_m:  # straight extension behind the start
        if len(path) >= 2 and np.hypot(*(path[1] - path[0])) > 1e-9:
            d = (path[1] - path[0]) / np.hypot(*(path[1] - path[0]))
        else:
            d = np.array([np.cos(heading), np.sin(heading)])
        path = np.concatenate([path[:1] - d * (length_m - total + 1.0), path])
    return path


def constant_lane_backward(state: AgentState, rel_times: np.ndarray, road_map: RoadMap,
                           lane_index: LaneIndex | None = None) -> np.ndarray:
    """Poses at ``rel_times`` (T,) [s] (<= 0) along the vehicle's lane at its speed: (T, 3)."""
    t = np.asarray(rel_times, dtype=np.float64)
    idx = lane_index if lane_index is not None else LaneIndex.build(road_map)
    hit = idx.nearest(np.array([state.x, state.y]), state.yaw)
    if hit is None:
        return constant_velocity_backward(state, t)
    lane, arc, lateral = hit
    back = float(state.speed * max(0.0, -float(t.min()))) if len(t) else 0.0
    path = backward_path(road_map, lane, arc, back + 1.0, state.yaw)
    cum = polyline_arc_length(path)
    s = cum[-1] + state.speed * t  # arc length along the path, the state at cum[-1]
    x = np.interp(s, cum, path[:, 0])
    y = np.interp(s, cum, path[:, 1])
    e = np.diff(path, axis=0)
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(e) - 1)
    yaw = np.arctan2(e[k, 1], e[k, 0])
    out = np.stack([x - lateral * np.sin(yaw), y + lateral * np.cos(yaw), yaw], axis=-1)
    out[t == 0.0] = (state.x, state.y, state.yaw)
    # keep headings continuous with the state's
    out[:, 2] = state.yaw + np.angle(np.exp(1j * (out[:, 2] - state.yaw)))
    return out
