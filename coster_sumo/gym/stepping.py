"""The environment's per-step checks on one box, in scalar arithmetic.

:class:`coster_sumo.gym.env.ScenarioEnv` checks the target's contacts and off-road every 0.1 s step.
With the other vehicles read from the log (``traffic="log"``), the states of every vehicle are
needed only when the observation is made (once per action, :attr:`ScenarioEnv.states` builds
them then); the checks in between need the target's box and the logged boxes of the step, which
these functions take as plain numbers and arrays. Each gives the answer of the general code it
stands for (:meth:`coster_sumo.sim.events.EventDetector._in_contact` over the rows in order,
:meth:`coster_sumo.geometry.drivable.DrivableArea.off_road`) at a fraction of numpy's per-call
overhead on one box (``tests/gym_env/test_stepping.py`` compares them).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import shapely

from coster_sumo.geometry.boxes import CONTACT_TOLERANCE_M, box_signed_distance
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.geometry.frames import from_sumo_scalar

Box = tuple[float, float, float, float, float]  # centre x, y [m], yaw [rad], length, width [m]


def first_contact(box: Box, x: np.ndarray, y: np.ndarray, yaw: np.ndarray, length: np.ndarray,
                  width: np.ndarray, half_diagonal: np.ndarray | None = None) -> int:
    """Index of the first of the boxes (arrays (N,)) within :data:`CONTACT_TOLERANCE_M` of ``box``
    (-1: none): a distance filter, then the scalar separating-axis gap, the exact distance if unsure.
    ``half_diagonal``: (N,) ``0.5 * hypot(length, width)`` where the caller has it."""
    from coster_sumo.sim.events import _sat_gap

    if not len(x):
        return -1
    bx, by, _, bl, bw = box
    if half_diagonal is None:
        half_diagonal = 0.5 * np.hypot(length, width)
    reach = half_diagonal + 0.5 * math.hypot(bl, bw)  # the sum's rounding as the event detector's
    near = np.flatnonzero(np.hypot(x - bx, y - by) <= reach + CONTACT_TOLERANCE_M)
    for j in near.tolist():
        other = (x.item(j), y.item(j), yaw.item(j), length.item(j), width.item(j))
        gap = _sat_gap(box, other)
        if gap > CONTACT_TOLERANCE_M:
            continue
        if gap <= 0.0 or bool(box_signed_distance(np.array(box), np.array(other)) <= CONTACT_TOLERANCE_M):
            return int(j)
    return -1


def box_off_road(area: DrivableArea, box: Box) -> bool:
    """``area.off_road`` of one box: its four corners inside the area (one prepared point test) is
    on the road; otherwise the exact area outside decides."""
    cx, cy, yaw, length, width = box
    c, s = math.cos(yaw), math.sin(yaw)
    hl, hw = 0.5 * length, 0.5 * width
    xs = [cx + lon * c - lat * s for lon, lat in ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))]
    ys = [cy + lon * s + lat * c for lon, lat in ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))]
    if bool(shapely.contains_xy(area.geometry, xs, ys).all()):
        return False
    b = np.array(box, np.float64)
    return bool(area.off_road(b[0], b[1], b[2], b[3], b[4]))


def sumo_box(api: Any, veh_id: str) -> Box | None:
    """The box of ``veh_id`` as SUMO has it now (getters; None: not in the network), in our frame,
    converted as :meth:`coster_sumo.sim.session.SumoSession.vehicle_states` converts it."""
    veh = api.vehicle
    if veh_id not in veh.getIDList():
        return None
    fx, fy = veh.getPosition(veh_id)
    length, width = float(veh.getLength(veh_id)), float(veh.getWidth(veh_id))
    cx, cy, yaw = from_sumo_scalar(float(fx), float(fy), float(veh.getAngle(veh_id)), length)
    return cx, cy, yaw, length, width

