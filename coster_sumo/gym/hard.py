"""The hand-specified adversities of a Hard scenario set (``coster-sumo scenarios build --method hard``).

No generator here makes them, so a set of them measures a policy independently of every
generator: a leader that brakes hard, a vehicle that cuts in from the next lane, a vehicle that runs
a red light across the target's path, and a pedestrian who steps out from behind a stopped vehicle
into the target's path (Euro NCAP's "car-to-pedestrian nearside child, obstructed" case in our
words: the pedestrian is hidden from the target until it steps out). Each is one more agent
(``adversity``) on the target's nominal pass, timed from the target's logged motion so that a
target that keeps it meets the adversity; docs/gym.md lists them with their numbers.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.core.scene import ObjectType, Scene, SignalState
from coster_sumo.formats.scene_file import save_scene
from coster_sumo.gym.scenario_set import ScenarioEntry
from coster_sumo.gym.scene_edit import append_agent, crop_steps

HARD_START_S = 0.0  # [s] a hand-made adversity's episode starts this long after the target departs (9.1 s clips)
ADVERSITY_ONSET_S = 3.0  # [s] the adversity (the leader's braking, the cut-in's move) starts this long into it
AVOIDANCE_TAIL_S = 5.0  # [s] an episode runs at least this long past the adversity's onset or t_col
LEADER_GAP_M = 20.0  # [m] bumper-to-bumper gap of the braking leader at the start
LEADER_DECEL = 7.0  # [m/s^2]
CUT_IN_AHEAD_M = 8.0  # [m] centre-to-centre, ahead of the target, in the next lane
CUT_IN_LATERAL_M = 3.5  # [m] the next lane
CUT_IN_AFTER_S = ADVERSITY_ONSET_S  # [s] it moves over after this long, as far ahead then as if it had after 1 s
CUT_IN_DURATION_S = 2.5  # [s] to reach the target's path
RED_RUNNER_SPEED = 12.0  # [m/s] the red-light runner's constant speed through the junction
RED_RUNNER_MIN_ANGLE = math.radians(30.0)  # a crossing movement, not one beside the target's
PED_SPEED = 1.39  # [m/s] the pedestrian's walk (5 km/h, the speed of Euro NCAP's walking pedestrian targets)
PED_START_RIGHT_M = 2.5  # [m] where it waits: right of the target's path, in front of the stopped vehicle
PED_WALK_ON_M = 3.0  # [m] it walks this far left of the path, then stands
PED_SIZE = (0.5, 0.5)  # [m] length, width (the converters' pedestrian box)
OCCLUDER_RIGHT_M = 2.85  # [m] the stopped vehicle's centre right of the path (kerb or next lane: 0.95 m clear)
OCCLUDER_GAP_M = 0.3  # [m] between its front bumper and the waiting pedestrian
OCCLUDER_SIZE = (4.5, 1.9)  # [m]
PED_MIN_TARGET_SPEED = 3.0  # [m/s] the target must be moving as it reaches the pedestrian's path
PED_MAX_TARGET_SPEED = 16.7  # [m/s] on a street where people walk (60 km/h at most)
OCCLUDER_CLEAR_M = 0.3  # [m] a logged agent's bounding circle closer than this to the stopped vehicle is left out


def hard_variants(out: Path, scene: Scene, target: int, base: str, common: dict[str, Any], t_dep: float,
                  t_last: float, horizon_s: float) -> list[ScenarioEntry]:
    """The hand-specified adversities against ``target`` (leader emergency braking, cut-in, a
    red-light runner where a crossing lane shows stop as the target passes, and a pedestrian stepping
    out from behind a stopped vehicle where the target is moving as it arrives)."""
    from coster_sumo.sim.driver import Route

    tr = scene.tracks
    ts = scene.timestamps
    v = tr.valid[target]
    t0 = t_dep + HARD_START_S
    if t0 + ADVERSITY_ONSET_S + AVOIDANCE_TAIL_S > t_last:
        return []
    k0 = int(np.argmin(np.abs(ts - t0)))
    route = Route(np.stack([tr.x[target, v & (ts >= t0 - 1e-6)], tr.y[target, v & (ts >= t0 - 1e-6)]], -1),
                  float(tr.heading[target, k0]))
    length = float(np.median(tr.length[target, v]))
    speed0 = max(float(np.hypot(tr.vx[target, k0], tr.vy[target, k0])), 5.0)
    t_stop = min(t_last, t_dep + horizon_s)
    times = ts
    after = (times >= t0 - 1e-6) & (times <= t_stop + 1e-6)
    dt = np.clip(times - t0, 0.0, None)
    entries = []
    # leader emergency braking: ahead on the target's path at its speed, then a hard stop
    t_b = ADVERSITY_ONSET_S  # the leader drives at the target's speed this long, then brakes
    braking = np.clip(dt - t_b, 0.0, speed0 / LEADER_DECEL)  # [s] spent braking (until it stands)
    s_lead = speed0 * np.minimum(dt, t_b) + speed0 * braking - 0.5 * LEADER_DECEL * braking**2
    v_lead = np.where(dt <= t_b, speed0, np.maximum(speed0 - LEADER_DECEL * (dt - t_b), 0.0))
    s_lead = s_lead + LEADER_GAP_M + length
    # cut-in: the next lane (left) a little ahead at the target's speed, moving onto its path
    f = np.clip((dt - CUT_IN_AFTER_S) / CUT_IN_DURATION_S, 0.0, 1.0)
    lateral = CUT_IN_LATERAL_M * (1.0 - (3 * f**2 - 2 * f**3))  # smooth step
    s_cut = CUT_IN_AHEAD_M + 0.1 * speed0 * (CUT_IN_AFTER_S - 1.0) + 0.9 * speed0 * dt
    for name, s_along, d_off, speed in (("leader-braking", s_lead, np.zeros_like(dt), v_lead),
                                        ("cut-in", s_cut, lateral, np.full_like(dt, 0.9 * speed0))):
        xs, ys, hs = np.zeros(len(times)), np.zeros(len(times)), np.zeros(len(times))
        for k in np.flatnonzero(after):
            x, y, h = route.pose(float(s_along[k]))
            xs[k], ys[k], hs[k] = x - d_off[k] * np.sin(h), y + d_off[k] * np.cos(h), h
        with_adv = append_agent(scene, "adversity", (xs, ys, hs), speed, after, (4.5, 1.9))
        sid = f"{base}_hard_{name}"
        save_scene(crop_steps(with_adv, t0 - 0.1, t_stop), out / "scenarios" / f"{sid}.npz")
        entries.append(ScenarioEntry(id=sid, kind="variant", method="hard", t_start=t0, t_end=t_stop,
                                     adversary="adversity", extra={"adversity": name}, **common))
    runner = red_light_runner(scene, target, t0, t_stop)
    if runner is not None:
        xs, ys, hs, speed, present, t_hit, signal = runner
        with_adv = append_agent(scene, "adversity", (xs, ys, hs), speed, present, (4.5, 1.9))
        sid = f"{base}_hard_red-light-runner"
        save_scene(crop_steps(with_adv, t0 - 0.1, t_stop), out / "scenarios" / f"{sid}.npz")
        entries.append(ScenarioEntry(id=sid, kind="variant", method="hard", t_start=t0, t_end=t_stop,
                                     adversary="adversity",
                                     extra={"adversity": "red-light-runner", "signal": signal, "t_conflict": t_hit},
                                     **common))
    stepping_out = pedestrian_behind_vehicle(scene, target, t0, t_stop)
    if stepping_out is not None:
        with_both, t_hit, left_out = stepping_out
        name = "pedestrian-behind-vehicle"
        sid = f"{base}_hard_{name}"
        save_scene(crop_steps(with_both, t0 - 0.1, t_stop), out / "scenarios" / f"{sid}.npz")
        entries.append(ScenarioEntry(id=sid, kind="variant", method="hard", t_start=t0, t_end=t_stop,
                                     adversary="adversity",
                                     extra={"adversity": name, "t_conflict": t_hit, "scripted": ["occluder"],
                                            "left_out": left_out},
                                     **common))
    return entries


def pedestrian_behind_vehicle(scene: Scene, target: int, t0: float, t_stop: float
                              ) -> tuple[Scene, float, list[str]] | None:
    """``scene`` with a stopped vehicle (``occluder``) right of the target's path and a pedestrian
    (``adversity``) waiting in front of it, hidden from the target behind it, and the time the
    pedestrian's centre reaches the path, and the logged agents left out; or None.

    The pedestrian stands until :data:`ADVERSITY_ONSET_S` into the episode, then walks left across
    the path at :data:`PED_SPEED`, timed so that its centre is on the path as the target's front
    bumper (the target as logged) reaches it: the middle of the target's front; it stands again
    :data:`PED_WALK_ON_M` left of the path. None where the target is under
    :data:`PED_MIN_TARGET_SPEED` or over :data:`PED_MAX_TARGET_SPEED` then, where that is after
    ``t_stop``, or where the stopped vehicle would stand on the target's path (a bend). Logged agents
    that pass within :data:`OCCLUDER_CLEAR_M` of the stopped vehicle (traffic in the lane it stands
    in) are left out: they could not have driven through it.
    """
    import shapely

    from coster_sumo.geometry.boxes import box_corners, project_points
    from coster_sumo.sim.driver import Route

    tr, ts = scene.tracks, scene.timestamps
    v = tr.valid[target] & (ts >= t0 - 1e-6) & (ts <= t_stop + 1e-6)
    t_walk = t0 + ADVERSITY_ONSET_S
    t_hit = t_walk + PED_START_RIGHT_M / PED_SPEED
    k_hit = int(np.argmin(np.abs(ts - t_hit)))
    if v.sum() < 2 or t_hit > t_stop or not v[k_hit] or not (
            PED_MIN_TARGET_SPEED <= math.hypot(float(tr.vx[target, k_hit]), float(tr.vy[target, k_hit]))
            <= PED_MAX_TARGET_SPEED):
        return None
    path = np.stack([tr.x[target, v], tr.y[target, v]], -1)
    route = Route(path, float(tr.heading[target, np.flatnonzero(v)[0]]))
    length, width = float(np.median(tr.length[target, v])), float(np.median(tr.width[target, v]))
    s_hit = float(project_points(path[np.searchsorted(np.flatnonzero(v), k_hit)], route.points)[0])
    s_ped = s_hit + 0.5 * length
    s_occ = s_ped - 0.5 * PED_SIZE[0] - OCCLUDER_GAP_M - 0.5 * OCCLUDER_SIZE[0]
    ox, oy, oh = route.pose(s_occ)
    ox, oy = ox + OCCLUDER_RIGHT_M * math.sin(oh), oy - OCCLUDER_RIGHT_M * math.cos(oh)
    occ = shapely.Polygon(box_corners(ox, oy, oh, *OCCLUDER_SIZE))
    if occ.distance(shapely.LineString(path)) < 0.5 * width + 0.2:
        return None
    window = (ts >= t0 - 1e-6) & (ts <= t_stop + 1e-6)
    # agents whose logs drive through the stopped vehicle's place could not have: left out of this variant
    reach = 0.5 * np.hypot(tr.length, tr.width) + OCCLUDER_CLEAR_M  # (A, T)
    near = shapely.distance(occ, shapely.points(tr.x, tr.y)) < reach
    blocked = (near & tr.valid & window[None, :]).any(axis=1)
    blocked[target] = False
    scene = dataclasses.replace(scene, tracks=tr.select(agents=np.flatnonzero(~blocked)))
    n = len(ts)
    walked = PED_SPEED * np.clip(ts - t_walk, 0.0, (PED_START_RIGHT_M + PED_WALK_ON_M) / PED_SPEED)
    lateral = walked - PED_START_RIGHT_M  # [m] > 0 left of the path
    px, py, ph = route.pose(s_ped)
    walking = (ts > t_walk) & (lateral < PED_WALK_ON_M - 1e-9)
    xs, ys = px - lateral * math.sin(ph), py + lateral * math.cos(ph)
    with_occ = append_agent(scene, "occluder", (np.full(n, ox), np.full(n, oy), np.full(n, oh)), np.zeros(n),
                            window, OCCLUDER_SIZE)
    both = append_agent(with_occ, "adversity", (xs, ys, np.full(n, ph + 0.5 * math.pi)),
                        np.where(walking, PED_SPEED, 0.0), window, PED_SIZE, ObjectType.PEDESTRIAN)
    return both, float(t_hit), [str(i) for i in tr.ids[blocked]]


def red_light_runner(scene: Scene, target: int, t0: float, t_stop: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, int] | None:
    """A vehicle that runs a red light across the target's path: its states on the scene's steps
    (x, y, heading, speed, present), the time it reaches the target's path and the column of
    ``scene.signals`` of the lane it runs, or None.

    The conflict: the first signal-controlled lane whose centreline crosses the target's logged path
    (at more than 30 degrees) at a point the target reaches at least 3 s after ``t0`` and 5 s
    before ``t_stop``, while that lane's signal shows stop (red or red arrow). The runner drives along the
    lane (extended straight before and after it) at 12 m/s, timed so that its centre is at the
    crossing point when the target's is; before ``t0`` and after ``t_stop`` it is absent.
    """
    tr, ts, lanes, sig = scene.tracks, scene.timestamps, scene.road_map.lanes, scene.signals
    v = tr.valid[target] & (ts >= t0 - 1e-6) & (ts <= t_stop + 1e-6)
    if v.sum() < 2 or not len(sig.lane_index):
        return None
    path = np.stack([tr.x[target, v], tr.y[target, v]], -1)  # (P, 2), on the scene's steps
    path_t = ts[v]
    red = {int(SignalState.STOP), int(SignalState.ARROW_STOP)}
    best: tuple[float, int, np.ndarray, int, int] | None = None  # (time, lane, point, lane segment, column)
    for c, lane in enumerate(sig.lane_index.tolist()):
        line = np.asarray(lanes.centerline[lane], np.float64)
        if len(line) < 2:
            continue
        hit = _first_crossing(path, line)
        if hit is None:
            continue
        i, j, point = hit  # path segment i, lane segment j
        t_hit = float(path_t[i])
        if not (t0 + ADVERSITY_ONSET_S <= t_hit <= t_stop - AVOIDANCE_TAIL_S):  # 3 s in, 5 s before the end
            continue
        k_hit = int(np.argmin(np.abs(ts - t_hit)))
        if int(sig.state[k_hit, c]) not in red:
            continue
        d_path, d_lane = path[i + 1] - path[i], line[j + 1] - line[j]
        cross = abs(math.atan2(d_path[0] * d_lane[1] - d_path[1] * d_lane[0], float(d_path @ d_lane)))
        if cross < RED_RUNNER_MIN_ANGLE or (best is not None and t_hit >= best[0]):
            continue
        best = (t_hit, lane, point, j, c)
    if best is None:
        return None
    t_hit, lane, point, j, column = best
    line = np.asarray(lanes.centerline[lane], np.float64)
    # the runner's route: the lane's centreline, extended straight backwards far enough to start from
    back = RED_RUNNER_SPEED * (t_hit - t0) + 10.0
    start_dir = (line[1] - line[0]) / max(float(np.hypot(*(line[1] - line[0]))), 1e-9)
    points = np.concatenate([line[:1] - back * start_dir, line])
    from coster_sumo.sim.driver import Route

    route = Route(points, math.atan2(start_dir[1], start_dir[0]))
    s_hit = back + float(np.sum(np.hypot(*np.diff(line[:j + 1], axis=0).T))) + float(np.hypot(*(point - line[j])))
    present = (ts >= t0 - 1e-6) & (ts <= t_stop + 1e-6)
    n = len(ts)
    xs, ys, hs = np.zeros(n), np.zeros(n), np.zeros(n)
    for k in np.flatnonzero(present):
        xs[k], ys[k], hs[k] = route.pose(s_hit + RED_RUNNER_SPEED * (float(ts[k]) - t_hit))
    return xs, ys, hs, np.full(n, RED_RUNNER_SPEED), present, t_hit, column


def _first_crossing(path: np.ndarray, line: np.ndarray) -> tuple[int, int, np.ndarray] | None:
    """Where polyline ``path`` (P, 2) first crosses polyline ``line`` (L, 2): (segment of path,
    segment of line, point), or None."""
    p0, p1 = path[:-1, None, :], path[1:, None, :]  # (P-1, 1, 2)
    q0, q1 = line[None, :-1, :], line[None, 1:, :]  # (1, L-1, 2)
    r, s_ = p1 - p0, q1 - q0
    denom = r[..., 0] * s_[..., 1] - r[..., 1] * s_[..., 0]  # (P-1, L-1)
    qp = q0 - p0
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (qp[..., 0] * s_[..., 1] - qp[..., 1] * s_[..., 0]) / denom
        u = (qp[..., 0] * r[..., 1] - qp[..., 1] * r[..., 0]) / denom
    ok = (np.abs(denom) > 1e-12) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    if not ok.any():
        return None
    i, j = (int(x) for x in np.argwhere(ok)[0])  # argwhere is row-major: the earliest path segment first
    return i, j, path[i] + t[i, j] * (path[i + 1] - path[i])
