"""The target as an agent drives it: its route, Frenet state, kinematics and observation.

One definition for the two drivers that must see and move alike: the Gymnasium environment
``coster_sumo/Scenario-v0`` (:class:`coster_sumo.gym.env.ScenarioEnv`, whose module docstring lists
the observation and the action) and a trained policy driving the target of an injection pass
(:class:`coster_sumo.sim.policy.PolicyPlanner`). It lives with the simulation because the policy
planner is one of the simulation's planners; the environment builds on it from above.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from coster_sumo.geometry.boxes import polyline_arc_length, resample_polyline

STEP_S = 0.1  # [s] SUMO's step (the replay scenes' rate)
MAX_ACCEL = 3.0  # [m/s^2]
MAX_DECEL = 8.0  # [m/s^2]
MAX_SPEED = 40.0  # [m/s]
MAX_OFFSET_M = 3.5  # [m] lateral offset at |a[1]| = 1 (one lane)
MAX_LATERAL_SPEED = 2.0  # [m/s]
LATERAL_TIME_S = 1.0  # [s] time constant of the approach to the commanded offset
MAX_LATERAL_RATIO = 0.3  # lateral speed at most this share of the speed
NUM_NEIGHBOURS = 8
NEIGHBOUR_RADIUS_M = 50.0  # [m]
NEIGHBOUR_FEATURES = 9
LOOKAHEAD_M = (5.0, 10.0, 20.0, 40.0)  # [m]
EGO_FEATURES = 8 + 2 * len(LOOKAHEAD_M) + 2
OBS_SIZE = EGO_FEATURES + NUM_NEIGHBOURS * NEIGHBOUR_FEATURES
ROUTE_SPACING_M = 0.5  # [m] the route polyline is resampled to this spacing
ROUTE_EXTENSION_M = 60.0  # [m] straight run-on beyond the route's end (lookahead only)


class Route:
    """The target's path as an evenly resampled polyline with tangents, for Frenet coordinates.

    Args:
        points: (P, 2) [m] the recorded path (repeated points allowed).
        heading: [rad] heading to use when the path has no length (a target that never moved).
    """

    def __init__(self, points: np.ndarray, heading: float) -> None:
        pts = np.asarray(points, np.float64).reshape(-1, 2)
        keep = np.concatenate([[True], np.hypot(*np.diff(pts, axis=0).T) > 1e-3]) if len(pts) else np.zeros(0, bool)
        pts = pts[keep]
        if len(pts) >= 2 and polyline_arc_length(pts)[-1] > ROUTE_SPACING_M:
            pts = resample_polyline(pts, ROUTE_SPACING_M)
        else:
            pts = pts[:1] if len(pts) else np.zeros((1, 2))
        self.length_m = float(polyline_arc_length(pts)[-1]) if len(pts) >= 2 else 0.0
        if len(pts) >= 2:
            end_dir = pts[-1] - pts[-2]
            end_heading = math.atan2(end_dir[1], end_dir[0])
        else:
            end_heading = heading
        ext = pts[-1] + np.outer(np.arange(1, int(ROUTE_EXTENSION_M / ROUTE_SPACING_M) + 1) * ROUTE_SPACING_M,
                                 [math.cos(end_heading), math.sin(end_heading)])
        self.points = np.concatenate([pts, ext])  # (Q, 2)
        self.cum = polyline_arc_length(self.points)  # (Q,)
        seg = np.diff(self.points, axis=0)
        self.seg_heading = np.arctan2(seg[:, 1], seg[:, 0])  # (Q-1,)

    def pose(self, s: float) -> tuple[float, float, float]:
        """Point (x, y) [m] and tangent heading [rad] at arc length ``s`` [m]."""
        s = min(max(s, 0.0), float(self.cum[-1]))
        k = min(int(np.searchsorted(self.cum, s, side="right")) - 1, len(self.seg_heading) - 1)
        k = max(k, 0)
        f = (s - self.cum[k]) / max(self.cum[k + 1] - self.cum[k], 1e-9)
        p = self.points[k] + f * (self.points[k + 1] - self.points[k])
        return float(p[0]), float(p[1]), float(self.seg_heading[k])


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


class Driver:
    """The target an agent drives: its route, Frenet state and kinematics, and what it observes.

    Shared by the environment and by a trained policy driving the target of an injection pass
    (:class:`coster_sumo.sim.policy.PolicyPlanner`), so both see and move alike.
    """

    route: Route
    s: float = 0.0  # [m] arc length along the route
    d: float = 0.0  # [m] lateral offset (> 0 left)
    d_dot: float = 0.0  # [m/s]
    v: float = 0.0  # [m/s]
    accel: float = 0.0  # [m/s^2] last commanded
    length: float = 4.5  # [m]
    width: float = 1.9  # [m]
    target_id: str = "ego"
    states: Any = None  # VehicleStates of the last step
    api: Any = None  # the SUMO API of the session

    def _ego_pose(self) -> tuple[float, float, float]:
        x, y, h = self.route.pose(self.s)
        return (x - self.d * math.sin(h), y + self.d * math.cos(h),
                _wrap(h + math.atan2(self.d_dot, max(self.v, 0.1))))

    def _command(self, action: np.ndarray) -> float:
        """Set the acceleration from ``action``; returns the commanded lateral offset [m]."""
        a = np.clip(np.asarray(action, np.float64).reshape(2), -1.0, 1.0)
        self.accel = float(a[0] * (MAX_ACCEL if a[0] >= 0 else MAX_DECEL))
        return float(a[1]) * MAX_OFFSET_M

    def _kinematic_step(self, d_target: float) -> None:
        """Advance speed, offset and arc length by one SUMO step."""
        self.v = min(max(self.v + self.accel * STEP_S, 0.0), MAX_SPEED)
        lat_max = min(MAX_LATERAL_SPEED, MAX_LATERAL_RATIO * self.v)
        self.d_dot = min(max((d_target - self.d) / LATERAL_TIME_S, -lat_max), lat_max)
        self.d += self.d_dot * STEP_S
        self.s += math.sqrt(max(self.v * self.v - self.d_dot * self.d_dot, 0.0)) * STEP_S

    def _observe(self) -> np.ndarray:
        obs = np.zeros(OBS_SIZE, np.float64)
        x, y, yaw = self._ego_pose()
        rx, ry, rh = self.route.pose(self.s)
        c, s_ = math.cos(yaw), math.sin(yaw)
        length = self.route.length_m
        obs[0] = self.v / 30.0
        obs[1] = self.accel / MAX_DECEL
        obs[2] = self.d / MAX_OFFSET_M
        obs[3] = _wrap(yaw - rh) / math.pi
        obs[4] = min(self.s / length, 1.0) if length > 0 else 1.0
        obs[5] = max(length - self.s, 0.0) / 100.0
        target = self.target_id
        api = self.api
        try:
            obs[6] = float(api.vehicle.getAllowedSpeed(target)) / 30.0
        except Exception:
            obs[6] = 0.0
        obs[7] = self.length / 10.0
        for i, ahead in enumerate(LOOKAHEAD_M):
            px, py, _ = self.route.pose(self.s + ahead)
            dx, dy = px - x, py - y
            obs[8 + 2 * i] = (c * dx + s_ * dy) / 50.0
            obs[9 + 2 * i] = (-s_ * dx + c * dy) / 50.0
        obs[16], obs[17] = 1.0, 0.0
        try:
            lights = api.vehicle.getNextTLS(target)
            if lights:
                _, _, dist, state = lights[0]
                obs[16] = min(float(dist) / 100.0, 1.0)
                obs[17] = 1.0 if str(state) in "rRyYu" else 0.0
        except Exception:
            pass
        st = self.states
        others = np.flatnonzero(st.ids != target) if len(st) else np.zeros(0, np.int64)
        if len(others):
            dx, dy = st.x[others] - x, st.y[others] - y
            dist = np.hypot(dx, dy)
            near = others[dist <= NEIGHBOUR_RADIUS_M]
            order = np.argsort(dist[dist <= NEIGHBOUR_RADIUS_M])[:NUM_NEIGHBOURS]
            rows = near[order]
            if len(rows):
                dx, dy = st.x[rows] - x, st.y[rows] - y
                vx = st.speed[rows] * np.cos(st.yaw[rows]) - self.v * c
                vy = st.speed[rows] * np.sin(st.yaw[rows]) - self.v * s_
                rel = st.yaw[rows] - yaw
                feats = np.stack([np.ones(len(rows)), (c * dx + s_ * dy) / 50.0, (-s_ * dx + c * dy) / 50.0,
                                  (c * vx + s_ * vy) / 30.0, (-s_ * vx + c * vy) / 30.0, np.cos(rel), np.sin(rel),
                                  st.length[rows] / 10.0, st.width[rows] / 5.0], -1)  # (k, 9)
                obs[EGO_FEATURES:EGO_FEATURES + feats.size] = feats.reshape(-1)
        return np.clip(obs, -1.0, 1.0).astype(np.float32)
