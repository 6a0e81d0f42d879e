"""The target as an agent drives it: its route, Frenet state, kinematics and observation.

One definition for the two drivers that must see and move alike: the Gymnasium environment
``coster_sumo/Scenario-v0`` (:class:`coster_sumo.gym.env.ScenarioEnv`, whose module docstring lists
the observation and the action) and a trained policy driving the target of an injection pass
(:class:`coster_sumo.sim.policy.PolicyPlanner`). It lives with the simulation because the policy
planner is one of the simulation's planners; the environment builds on it from above.
"""

from __future__ import annotations

import bisect
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
Arrays6 = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
ROUTE_EXTENSION_M = 60.0  # [m] straight run-on beyond the route's end (lookahead only)
COMPLETION_MARGIN_M = 1.0  # [m] the route counts as completed this close to its end
MIN_ROUTE_M = 5.0  # [m] a shorter route (a target that hardly moved) ends by time only


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
        # the same numbers as Python lists: pose() is called several times per step, and scalar
        # arithmetic on list items costs a tenth of numpy's per-call overhead (the same IEEE results)
        self._cum = self.cum.tolist()
        self._xs, self._ys = self.points[:, 0].tolist(), self.points[:, 1].tolist()
        self._heading = self.seg_heading.tolist()

    def pose(self, s: float) -> tuple[float, float, float]:
        """Point (x, y) [m] and tangent heading [rad] at arc length ``s`` [m]."""
        cum, xs, ys = self._cum, self._xs, self._ys
        s = min(max(float(s), 0.0), cum[-1])
        k = max(min(bisect.bisect_right(cum, s) - 1, len(self._heading) - 1), 0)
        f = (s - cum[k]) / max(cum[k + 1] - cum[k], 1e-9)
        return xs[k] + f * (xs[k + 1] - xs[k]), ys[k] + f * (ys[k + 1] - ys[k]), self._heading[k]


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

    def route_completed(self) -> bool:
        """The target is at its route's end (the environment's ``completed``; a route shorter than
        :data:`MIN_ROUTE_M` is never completed)."""
        return self.route.length_m >= MIN_ROUTE_M and self.s >= self.route.length_m - COMPLETION_MARGIN_M

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
        ox, oy, oyaw, ospeed, olength, owidth = self._others()
        if len(ox):
            ex, ey = ox - x, oy - y
            ranges = np.hypot(ex, ey)
            inside = ranges <= NEIGHBOUR_RADIUS_M
            rows = np.flatnonzero(inside)[np.argsort(ranges[inside])[:NUM_NEIGHBOURS]]
            if len(rows):
                ex, ey = ex[rows], ey[rows]
                vx = ospeed[rows] * np.cos(oyaw[rows]) - self.v * c
                vy = ospeed[rows] * np.sin(oyaw[rows]) - self.v * s_
                rel = oyaw[rows] - yaw
                feats = obs[EGO_FEATURES:EGO_FEATURES + NEIGHBOUR_FEATURES * len(rows)].reshape(len(rows), -1)
                feats[:, 0] = 1.0
                feats[:, 1] = (c * ex + s_ * ey) / 50.0
                feats[:, 2] = (-s_ * ex + c * ey) / 50.0
                feats[:, 3] = (c * vx + s_ * vy) / 30.0
                feats[:, 4] = (-s_ * vx + c * vy) / 30.0
                feats[:, 5] = np.cos(rel)
                feats[:, 6] = np.sin(rel)
                feats[:, 7] = olength[rows] / 10.0
                feats[:, 8] = owidth[rows] / 5.0
        return np.clip(obs, -1.0, 1.0).astype(np.float32)

    def _others(self) -> Arrays6:
        """The vehicles but the target after the last step, in :attr:`states`' order: (N,) arrays of
        centre x, y [m], yaw [rad], speed [m/s], length and width [m]."""
        st = self.states
        if st is None or not len(st):
            e = np.zeros(0)
            return e, e, e, e, e, e
        m = st.ids != self.target_id
        return st.x[m], st.y[m], st.yaw[m], st.speed[m], st.length[m], st.width[m]
