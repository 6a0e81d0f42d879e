"""Observations for avoidance: the vehicles ahead and behind along the target's route, time left, lidar.

The environment's default observation (:meth:`coster_sumo.sim.driver.Driver._observe`, 90 numbers)
lists the 8 nearest vehicles in the target's frame; what avoiding needs is not in it directly: the
gap, closing speed and time to collision to the vehicle ahead and the one behind in the target's
route corridor, and the time left. ``observation="avoidance"`` appends those
(:func:`corridor_features`, :data:`CORRIDOR_FEATURES` numbers) to the default; ``observation="lidar"``
keeps the target's own 18 numbers and the corridor features, and replaces the vehicle list by
:data:`NUM_RAYS` rays to :data:`LIDAR_RANGE_M` (as MetaDrive's ScenarioEnv observes), each the
distance to the first vehicle box it meets.

Corridor features (every entry scaled to [-1, 1] and clipped):

=====  =========================================================================================
index  meaning (unit / scale)
=====  =========================================================================================
0      a vehicle ahead in the corridor within 50 m (0/1)
1      its gap, bumper to bumper along the route [m] / 50 (1: none)
2      its closing speed (the target's speed along the route minus its) [m/s] / 30
3      time to collision at that closing speed [s] / 10 (1: none, or not closing, or over 10 s)
4-7    the same for the vehicle behind (closing speed: its speed minus the target's)
8      time left in the episode [s] / 20
=====  =========================================================================================

The corridor: vehicles whose centre projects on the route within :data:`CORRIDOR_HALF_WIDTH_M` of the
target's own lateral offset, heading within 60 degrees of the route's.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from coster_sumo.geometry.boxes import project_points
from coster_sumo.sim.driver import EGO_FEATURES, NEIGHBOUR_RADIUS_M, OBS_SIZE

if TYPE_CHECKING:
    from coster_sumo.sim.driver import Driver

CORRIDOR_HALF_WIDTH_M = 1.75  # [m] half a lane
CORRIDOR_HEADING_RAD = math.radians(60.0)
CORRIDOR_FEATURES = 9
TTC_CAP_S = 10.0  # [s]
TIME_LEFT_SCALE_S = 20.0  # [s]
NUM_RAYS = 72  # every 5 degrees
LIDAR_RANGE_M = 50.0  # [m]
OBSERVATIONS = {"default": OBS_SIZE, "avoidance": OBS_SIZE + CORRIDOR_FEATURES,
                "lidar": EGO_FEATURES + CORRIDOR_FEATURES + NUM_RAYS}


def corridor_features(driver: Driver, time_left_s: float) -> np.ndarray:
    """(CORRIDOR_FEATURES,) float64: the module docstring's table, for the target ``driver`` drives."""
    out = np.array([0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, min(max(time_left_s, 0.0) / TIME_LEFT_SCALE_S, 1.0)])
    ox, oy, oyaw, ospeed, olength, _ = driver._others()
    if not len(ox):
        return out
    x, y, _ = driver._ego_pose()
    near = np.flatnonzero(np.hypot(ox - x, oy - y) <= NEIGHBOUR_RADIUS_M + 10.0)
    if not len(near):
        return out
    route = driver.route
    lo = int(np.searchsorted(route.cum, driver.s - NEIGHBOUR_RADIUS_M - 10.0))
    hi = int(np.searchsorted(route.cum, driver.s + NEIGHBOUR_RADIUS_M + 10.0)) + 1
    window = route.points[max(lo - 1, 0):hi + 1]  # (W, 2) the route around the target
    if len(window) < 2:
        return out
    s_win, d, seg = project_points(np.stack([ox[near], oy[near]], -1), window)
    s_o = s_win + route.cum[max(lo - 1, 0)]  # (N,) arc length along the whole route
    seg_h = np.arctan2(*np.diff(window, axis=0)[seg][:, ::-1].T)  # (N,) route heading there
    rel = np.abs((oyaw[near] - seg_h + np.pi) % (2 * np.pi) - np.pi)
    inside = (np.abs(d - driver.d) <= CORRIDOR_HALF_WIDTH_M) & (rel <= CORRIDOR_HEADING_RAD)
    v_along = ospeed[near] * np.cos(rel)  # (N,) their speed along the route
    gap = np.abs(s_o - driver.s) - 0.5 * (olength[near] + driver.length)
    for side, (mask, sign) in enumerate(((inside & (s_o > driver.s), 1.0), (inside & (s_o <= driver.s), -1.0))):
        if not mask.any():
            continue
        j = np.flatnonzero(mask)[np.argmin(gap[mask])]
        g = max(float(gap[j]), 0.0)
        closing = sign * (driver.v - float(v_along[j]))
        ttc = g / closing if closing > 1e-6 else math.inf
        out[4 * side: 4 * side + 4] = [1.0, min(g / NEIGHBOUR_RADIUS_M, 1.0), closing / 30.0,
                                       min(ttc, TTC_CAP_S) / TTC_CAP_S]
    return np.clip(out, -1.0, 1.0)


def lidar(driver: Driver, num_rays: int = NUM_RAYS, range_m: float = LIDAR_RANGE_M) -> np.ndarray:
    """(num_rays,) float64 in [0, 1]: per ray (counter-clockwise from the target's heading, evenly
    spaced) the distance from the target's centre to the first vehicle box it meets / ``range_m``
    (1: none within range)."""
    out = np.ones(num_rays)
    ox, oy, oyaw, _, olength, owidth = driver._others()
    if not len(ox):
        return out
    x, y, yaw = driver._ego_pose()
    reach = range_m + 0.5 * np.hypot(olength, owidth)
    near = np.flatnonzero(np.hypot(ox - x, oy - y) <= reach)
    if not len(near):
        return out
    angles = yaw + np.arange(num_rays) * (2 * np.pi / num_rays)  # (R,)
    # each ray in each box's frame: origin o, direction u; slab test against |x| <= L/2, |y| <= W/2
    c, s = np.cos(oyaw[near]), np.sin(oyaw[near])  # (B,)
    dx, dy = x - ox[near], y - oy[near]
    ox, oy = c * dx + s * dy, -s * dx + c * dy  # (B,)
    rc, rs = np.cos(angles)[:, None], np.sin(angles)[:, None]  # (R, 1)
    ux, uy = rc * c + rs * s, -rc * s + rs * c  # (R, B)
    half_l, half_w = 0.5 * olength[near], 0.5 * owidth[near]
    with np.errstate(divide="ignore", invalid="ignore"):
        t1x, t2x = (-half_l - ox) / ux, (half_l - ox) / ux
        t1y, t2y = (-half_w - oy) / uy, (half_w - oy) / uy
    t_near = np.maximum(np.fmin(t1x, t2x), np.fmin(t1y, t2y))  # (R, B)
    t_far = np.minimum(np.fmax(t1x, t2x), np.fmax(t1y, t2y))
    hit = (t_far >= np.maximum(t_near, 0.0)) & np.isfinite(t_near)
    dist = np.where(hit, np.maximum(t_near, 0.0), np.inf).min(axis=1)  # (R,)
    return np.minimum(dist / range_m, 1.0)


def observe(driver: Driver, kind: str, time_left_s: float) -> np.ndarray:
    """The observation ``kind`` (a key of :data:`OBSERVATIONS`) as float32 in [-1, 1]."""
    base = driver._observe()
    if kind == "default":
        return base
    extra = corridor_features(driver, time_left_s)
    if kind == "avoidance":
        return np.concatenate([base, extra.astype(np.float32)])
    return np.concatenate([base[:EGO_FEATURES], extra.astype(np.float32), lidar(driver).astype(np.float32)])
