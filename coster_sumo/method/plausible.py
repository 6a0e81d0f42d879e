"""Plausible adversary states at the collision snapshot: a real vehicle's size, a speed that fits the
traffic around it.

The prior's heads are independent: a sampled length and width can make a vehicle nobody drives
(2.1 m x 2.05 m), and its speed head can say "stopped" in the middle of free-flowing traffic.

**Size.** The sampled (length, width) is moved to the nearest vehicle class of the nominal corpus
(docs/corpus/card.md: the lengths and widths SUMO reported for each class), nearest in log-ratio
of length plus log-ratio of width, and clamped into that class's ranges: a 2.1 x 2.05 m sample
becomes a 3.7 x 1.95 m small car, a 2.2 x 0.9 m sample stays a motorcycle.

**Speed.** A stopped adversary (the prior's stopped class, < 0.5 m/s) is kept only where stopping
is what traffic does: the vehicles within :data:`LOCAL_RADIUS_M` of the target move at a median
speed below :data:`CONGESTED_SPEED_MPS` (the corpus calls such traffic congested), or the
adversary's lane ends or meets a signal's stop line within :data:`QUEUE_DISTANCE_M`, or, off the
freeway, its lane enters a junction within that distance or lies inside one (vehicles yield at
priority junctions and roundabout entries, and wait inside a junction to turn across the others:
a fifth of the nominal vehicles of the held-out roundabout network stand still, with no signal in it). Elsewhere the
speed is drawn again from the same head, from its classes between standstill and
:data:`FASTEST_FACTOR` x the fastest vehicle around the target (a moving vehicle that keeps up
with the traffic it is in, not one from another road class).
"""

from __future__ import annotations

import math

import numpy as np

from coster_sumo.core.scene import LaneType, ObjectType, Scene

# class: ((shortest, longest) length [m], (narrowest, widest) width [m]) as the corpus saw them
VEHICLE_CLASSES: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {
    "bicycle": ((1.6, 1.7), (0.65, 0.65)),
    "motorcycle": ((2.2, 2.2), (0.8, 0.9)),
    "passenger": ((3.7, 5.0), (1.65, 1.95)),
    "delivery": ((5.6, 6.5), (2.0, 2.16)),
    "truck": ((7.1, 9.0), (2.4, 2.45)),
    "bus": ((12.0, 16.5), (2.55, 2.55)),  # city buses, coaches, semi-trailers
}
LOCAL_RADIUS_M = 50.0  # [m] the traffic around the target that the adversary's speed must fit
CONGESTED_SPEED_MPS = 5.0  # [m/s] median speed below which traffic counts as congested
QUEUE_DISTANCE_M = 30.0  # [m] a lane end or stop line this close makes stopping plausible
FASTEST_FACTOR = 1.1  # a redrawn speed is at most this times the fastest vehicle around the target


def vehicle_size(length: float, width: float) -> tuple[float, float, str]:
    """The nearest corpus vehicle class to ``length`` x ``width`` [m], and the size clamped into it."""
    best = ("", math.inf, length, width)
    for name, ((l0, l1), (w0, w1)) in VEHICLE_CLASSES.items():
        cl, cw = min(max(length, l0), l1), min(max(width, w0), w1)
        d = abs(math.log(max(length, 0.1) / cl)) + abs(math.log(max(width, 0.1) / cw))
        if d < best[1]:
            best = (name, d, cl, cw)
    return best[2], best[3], best[0]


def local_speeds(scene: Scene, step: int, target: int, radius_m: float = LOCAL_RADIUS_M) -> np.ndarray:
    """Speeds [m/s] of the vehicles (not pedestrians or cyclists) within ``radius_m`` of the target
    at ``step``, the target's own included (so there is always one)."""
    tr = scene.tracks
    d = np.hypot(tr.x[:, step] - tr.x[target, step], tr.y[:, step] - tr.y[target, step])
    near = tr.valid[:, step] & (d <= radius_m) & (tr.object_type == ObjectType.VEHICLE)
    near[target] = True
    return np.hypot(tr.vx[near, step], tr.vy[near, step])


def local_speed(scene: Scene, step: int, target: int, radius_m: float = LOCAL_RADIUS_M) -> float:
    """Median of :func:`local_speeds` [m/s]."""
    return float(np.median(local_speeds(scene, step, target, radius_m)))


def stop_plausible(scene: Scene, step: int, target: int, lane: int, point: np.ndarray) -> bool:
    """Whether a stopped vehicle on map lane ``lane`` at ``point`` (2,) [m] fits the scene at ``step``."""
    if local_speed(scene, step, target) < CONGESTED_SPEED_MPS:
        return True
    lanes = scene.road_map.lanes
    if 0 <= lane < len(lanes):
        nexts = lanes.successors[lane]
        yields = lanes.lane_type[lane] != LaneType.FREEWAY and (
            bool(lanes.is_junction[lane]) or bool(np.any(lanes.is_junction[np.asarray(nexts, np.int64)])))
        if yields and lanes.is_junction[lane]:
            return True  # inside a street junction: vehicles wait there to turn across the others
        shape = lanes.centerline[lane]
        if (len(nexts) == 0 or yields) and len(shape) and float(np.hypot(*(shape[-1] - point))) <= QUEUE_DISTANCE_M:
            return True  # the lane ends here, or enters a street junction: vehicles wait (or yield) at its end
    stops = scene.signals.stop_point
    return bool(len(stops)) and float(np.min(np.hypot(*(stops - point).T))) <= QUEUE_DISTANCE_M


def moving_speed_class(probs: np.ndarray, centres: np.ndarray, stopped_class: int, rng: np.random.Generator,
                       fastest: float) -> int:
    """A speed class drawn from a speed head's class probabilities (C,) (bin ``centres`` (C,) [m/s])
    among its moving classes whose centre is at most ``FASTEST_FACTOR * fastest``; the moving class
    nearest to ``fastest`` when the head puts no mass there."""
    centres = np.asarray(centres, np.float64)
    allowed = np.ones(len(centres), bool)
    allowed[stopped_class] = False
    allowed &= centres <= FASTEST_FACTOR * fastest
    p = np.where(allowed, np.asarray(probs, np.float64), 0.0)
    total = float(p.sum())
    if not total > 0.0:
        moving = np.flatnonzero(np.arange(len(centres)) != stopped_class)
        return int(moving[np.argmin(np.abs(centres[moving] - fastest))])
    return int(rng.choice(len(p), p=p / total))
