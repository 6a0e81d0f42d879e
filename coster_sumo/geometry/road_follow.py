"""Where an adversary that missed its contact drives after t_col: on along the road.

The adversary's plan ends at t_col. Whether the target was hit or not, the injection pass and the
avoidability search must know where the adversary goes next, and both must see the same thing
(docs/method.md, step 8, "The others"). Driving on at constant velocity along its final heading
took an adversary that missed across a freeway; here it keeps to the lane it is on:

- the lane: among the vehicle lanes whose centreline passes within :data:`SNAP_M` of the
  adversary's centre at t_col and runs within :data:`MAX_HEADING_RAD` of its heading, the nearest;
  where none does (in the middle of a junction, across lanes), the first such lane found at points
  :data:`AHEAD_M` along its heading (the nearest lane along its heading);
- the path: that lane's centreline from the adversary's position on, then the successor that keeps
  its direction best, and so on for :func:`road_path`'s ``length_m``; the adversary's sideways
  offset from the centreline and its heading relative to it fade out over :data:`BLEND_S` of
  driving (at least :data:`BLEND_MIN_M`) along a cubic, so that the path starts exactly at its
  pose and heading and runs on the centreline after that;
- it drives that path at its speed at t_col (:meth:`coster_sumo.core.plan.AdversaryPlan.sample`).

After the labelling horizon SUMO's own driver takes it over (:mod:`coster_sumo.sim.inject`).
Where no lane qualifies (an adversary off the map), :func:`road_path` gives None and the plan keeps
the constant-velocity run-on.
"""

from __future__ import annotations

import numpy as np

from coster_sumo.core.plan import HORIZON_AFTER_TCOL_S, AdversaryPlan
from coster_sumo.core.scene import LaneType, RoadMap
from coster_sumo.geometry.boxes import point_at_arc_length, polyline_arc_length, project_points

SNAP_M = 3.0  # [m] a lane's centreline this close to the adversary's centre is the lane it is on
MAX_HEADING_RAD = np.radians(45.0)  # a lane running further from its heading is not its lane
AHEAD_M = (5.0, 10.0, 20.0)  # [m] where along its heading a lane is looked for when none is under it
BLEND_S = 2.0  # [s] of driving over which its own line joins the centreline
BLEND_MIN_M = 10.0  # [m] ... and at least this far
STEP_M = 1.0  # [m] spacing of the path's points


def road_path(road_map: RoadMap, x: float, y: float, yaw: float, speed: float, length_m: float
              ) -> np.ndarray | None:
    """(n, 2) [m] the path an adversary at centre (x, y), heading ``yaw`` [rad] and ``speed``
    [m/s] follows after t_col, starting at (x, y) and ``length_m`` long at least where the road
    goes that far (module docstring); None where no lane qualifies."""
    found = _lane_at(road_map, np.array([x, y]), yaw)
    if found is None:
        return None
    lane, s0 = found
    centre = _lane_walk(road_map, lane, s0, length_m + BLEND_MIN_M)
    # the centreline straight back from where it was found, so that the adversary stands beside it
    back = centre[1] - centre[0]
    back = back / max(float(np.hypot(*back)), 1e-9)
    centre = np.concatenate([(centre[0] - (max(AHEAD_M) + 5.0) * back)[None], centre])
    s_at, d0, _ = project_points(np.array([x, y]), centre)
    cum = polyline_arc_length(centre)
    blend = max(BLEND_MIN_M, BLEND_S * speed)
    u = np.arange(0.0, max(length_m, blend) + STEP_M, STEP_M)
    s = float(s_at) + u
    xy, hd = point_at_arc_length(centre, np.minimum(s, cum[-1]))
    past = s > cum[-1]  # the road ends: straight on along its last direction
    xy[past] += (s[past] - cum[-1])[:, None] * np.stack([np.cos(hd[past]), np.sin(hd[past])], -1)
    # its sideways offset from the centreline fades out (cubic Hermite: its own offset and heading
    # at the start, on the centreline and along it after the blend)
    lane_yaw = float(point_at_arc_length(centre, float(s_at))[1])
    slope = float(np.tan(np.clip((yaw - lane_yaw + np.pi) % (2 * np.pi) - np.pi, -MAX_HEADING_RAD, MAX_HEADING_RAD)))
    w = np.clip(u / blend, 0.0, 1.0)
    d = float(d0) * (2 * w**3 - 3 * w**2 + 1) + blend * slope * (w**3 - 2 * w**2 + w)
    out = xy + d[:, None] * np.stack([-np.sin(hd), np.cos(hd)], -1)
    out[0] = (x, y)
    return out


def _lane_at(road_map: RoadMap, xy: np.ndarray, yaw: float) -> tuple[int, float] | None:
    """(lane, arc length [m] of the point on its centreline) of the lane under ``xy`` along ``yaw``,
    else of the first one found ahead (:data:`AHEAD_M`); None where there is none."""
    lanes = road_map.lanes
    pts = lanes.centerline.values
    if len(pts) < 2:
        return None
    item = lanes.centerline.item_index()
    same = item[:-1] == item[1:]
    vehicle = lanes.lane_type[item[:-1]] != LaneType.BIKE_LANE
    seg = np.flatnonzero(same & vehicle)
    a, e = pts[seg], pts[seg + 1] - pts[seg]
    seg_len = np.hypot(e[:, 0], e[:, 1])
    ok = seg_len > 1e-6
    seg, a, e, seg_len = seg[ok], a[ok], e[ok], seg_len[ok]
    diff = np.abs((np.arctan2(e[:, 1], e[:, 0]) - yaw + np.pi) % (2 * np.pi) - np.pi)
    aligned = diff <= MAX_HEADING_RAD
    direction = np.array([np.cos(yaw), np.sin(yaw)])
    for ahead in (0.0, *AHEAD_M):
        p = xy + ahead * direction
        t = np.clip(np.sum((p - a) * e, 1) / seg_len**2, 0.0, 1.0)
        dist = np.hypot(*(a + t[:, None] * e - p).T)
        cand = np.flatnonzero(aligned & (dist <= SNAP_M))
        if not len(cand):
            continue
        best = cand[np.argmin(dist[cand])]
        lane = int(item[seg[best]])
        first = int(lanes.centerline.offsets[lane])
        cum = polyline_arc_length(lanes.centerline[lane])
        k = int(seg[best]) - first
        return lane, float(cum[k] + t[best] * seg_len[best])
    return None


def _lane_walk(road_map: RoadMap, lane: int, s0: float, length_m: float) -> np.ndarray:
    """(n, 2) the centreline of ``lane`` from arc length ``s0`` on, then of the successor that turns
    least at each lane's end, until ``length_m`` or the road ends (or a lane comes again)."""
    lanes = road_map.lanes
    line = lanes.centerline[lane]
    cum = polyline_arc_length(line)
    start = np.array([np.interp(s0, cum, line[:, 0]), np.interp(s0, cum, line[:, 1])])
    parts = [start[None], line[cum > s0 + 1e-6]]
    total = float(cum[-1] - s0)
    seen = {lane}
    while total < length_m:
        end = lanes.centerline[lane]
        end_dir = np.arctan2(*(end[-1] - end[-2])[::-1])
        best, best_turn = -1, np.inf
        for nxt in lanes.successors[lane].tolist():
            nl = lanes.centerline[int(nxt)]
            if int(nxt) in seen or len(nl) < 2 or lanes.lane_type[int(nxt)] == LaneType.BIKE_LANE:
                continue
            turn = abs((np.arctan2(*(nl[1] - nl[0])[::-1]) - end_dir + np.pi) % (2 * np.pi) - np.pi)
            if turn < best_turn:
                best, best_turn = int(nxt), turn
        if best < 0:
            break
        lane = best
        seen.add(lane)
        nl = lanes.centerline[lane]
        tail = next(p[-1] for p in reversed(parts) if len(p))  # the adversary may stand at its lane's very end
        parts.append(nl[1:] if np.hypot(*(nl[0] - tail)) < 0.5 else nl)
        total += float(polyline_arc_length(nl)[-1])
    path = np.concatenate([p for p in parts if len(p)])
    if len(path) < 2:  # a lane that ends where the adversary is: straight on along it
        d = line[-1] - line[-2]
        path = np.stack([start, start + d / max(float(np.hypot(*d)), 1e-9)])
    return path


RUN_ON_AFTER_HORIZON_S = 10.0  # [s] of path beyond the horizon, should SUMO's driver not take over at once
RUN_ON_EXTRA_M = 50.0  # [m] more, for the destination SUMO's driver is given


def follow_road(plan: AdversaryPlan, road_map: RoadMap) -> AdversaryPlan:
    """``plan`` with its continuation after t_col on the road (:func:`road_path`); unchanged where
    no lane qualifies. The search (:func:`coster_sumo.avoidability.search.assess`) and every SUMO pass sample the
    plan (:meth:`AdversaryPlan.sample`), so both see this continuation."""
    ax, ay, ayaw, _ = (float(v[0]) for v in plan.sample(np.array([plan.t_col])))
    v = max(plan.final_speed, 0.0)
    path = road_path(road_map, ax, ay, ayaw, v, v * (HORIZON_AFTER_TCOL_S + RUN_ON_AFTER_HORIZON_S) + RUN_ON_EXTRA_M)
    return plan if path is None else plan.replaced(road=path)
