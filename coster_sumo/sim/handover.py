"""SUMO's driver takes over an adversary that missed, once the labels' horizon has passed.

Up to :data:`~coster_sumo.core.plan.HORIZON_AFTER_TCOL_S` after t_col an adversary whose contact did not
happen drives its plan's road continuation (:mod:`coster_sumo.geometry.road_follow`), exactly what the
avoidability search assumed. After that nothing is promised about it, and a vehicle that drives a
fixed path through traffic for the rest of a pass is no driver: SUMO's car-following and
lane-change models take it over, with a route towards the end of its road path.
"""

from __future__ import annotations

import numpy as np

from coster_sumo.core.plan import HORIZON_AFTER_TCOL_S, AdversaryPlan
from coster_sumo.sim.session import SumoSession

TIME_EPS = 1e-6  # [s]


def due(plan: AdversaryPlan, t_next: float) -> bool:
    """Whether SUMO's driver should have the adversary of ``plan`` at step time ``t_next`` [s]."""
    return plan.road is not None and t_next > plan.t_col + HORIZON_AFTER_TCOL_S + TIME_EPS


def hand_over(session: SumoSession, vehicle_id: str, plan: AdversaryPlan) -> bool:
    """Release the adversary to SUMO's driver with a route towards the far end of its road path;
    False (nothing done) while it is on no lane (SUMO's driver could not take it there)."""
    road = plan.road
    if road is None or vehicle_id not in session.vehicle_ids():
        return False
    if not session.api.vehicle.getLaneID(vehicle_id):  # off every lane: a safe getter (docs/sumo.md §3)
        return False
    ends = []
    for k in (len(road) - 1, (3 * len(road)) // 4, len(road) // 2):  # the farthest point first
        d = road[min(k + 1, len(road) - 1)] - road[max(k - 1, 0)]
        ends.append((float(road[k, 0]), float(road[k, 1]), float(np.arctan2(d[1], d[0])), plan.length))
    session.release_vehicle(vehicle_id, ends)
    return True
