"""Where an added adversary starts in SUMO: the edge under it and the vType of its class."""

from __future__ import annotations

import contextlib

from coster_sumo.geometry.frames import centre_to_front
from coster_sumo.sim.session import SumoSession

# SUMO's default vType of each adversary vehicle class (sumo-gui draws a person / a bicycle for them)
BASE_TYPES = {"passenger": "DEFAULT_VEHTYPE", "pedestrian": "DEFAULT_PEDTYPE", "bicycle": "DEFAULT_BIKETYPE"}


def edge_under(session: SumoSession, x: float, y: float, yaw: float, length: float,
               vclass: str = "passenger") -> list[str] | None:
    """The route of a vehicle added at box centre ``x, y`` [m]: the (non-internal) edge under its front
    that admits ``vclass`` (a pedestrian or bicycle adversary: the nearest edge its class may use)."""
    fx, fy = centre_to_front(x, y, yaw, length)
    with contextlib.suppress(Exception):
        edge, _, _ = session.api.simulation.convertRoad(float(fx), float(fy), False, vclass)
        if edge and not str(edge).startswith(":"):
            return [str(edge)]
    return None
