"""What a :class:`~coster_sumo.sim.session.SumoSession` does to the simulation: add, place, resize,
release and remove vehicles, and force signals.

:class:`SessionControl` is a part of the session, not an object of its own: the session inherits it,
and its state (the vehicles' cached sizes, the vehicles driven with moveToXY, the types and routes
made for added vehicles) is the session's. It lives apart from the session's life cycle, stepping
and reads so that each reads on its own. Frames as in the session: box centre, heading in radians
counter-clockwise from +x; SUMO's front bumper and compass angle stay inside :mod:`coster_sumo.geometry.frames`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from coster_sumo.errors import InputError, SumoError
from coster_sumo.geometry import frames
from coster_sumo.sim.sumo_options import (
    KEEP_ROUTE_EXACT_ANYWHERE,
    LANE_CHANGE_MODE_NO_AUTONOMOUS,
    LANE_CHANGE_MODE_SUMO_DEFAULT,
    MOVE_MATCH_THRESHOLD_M,
    REMOTE_MAX_SPEED_MPS,
    REMOTE_SPEED_FACTOR,
    SPEED_MODE_ALL_CHECKS_OFF,
    SPEED_MODE_SUMO_DEFAULT,
)


@dataclass(frozen=True)
class Departure:
    """Where and how an added vehicle enters (SUMO's route and departLane / departPos / departSpeed).

    Attributes:
        edges: its route (a private route is made of them); None: ``""``, which lets SUMO put it on a
            random edge (fine for a vehicle placed with :meth:`SessionControl.move_to_xy`).
        lane, pos, speed: SUMO's departLane, departPos and departSpeed, as SUMO spells them (a vehicle
            SUMO drives from its departure waits where inserting it is unsafe).
    """

    edges: Sequence[str] | None = None
    lane: str = "first"
    pos: str = "base"
    speed: str = "0"

    def __post_init__(self) -> None:
        if self.edges is not None and not self.edges:
            raise InputError("a vehicle's route needs at least one edge")


ANYWHERE = Departure()  # SUMO's choice of edge, for a vehicle placed with move_to_xy


class SessionControl:
    """The commands of a SUMO session (see the module docstring); the session gives the state below."""

    uses_traci: bool
    hidden: set[str]
    _static: dict[str, tuple[float, float, str, str]]
    _remote: set[str]
    _pending_speed: dict[str, float]
    _types: dict[tuple[str, str, bool], str]
    _routes: dict[tuple[str, ...], str]

    @property
    def name(self) -> str:
        raise NotImplementedError

    @property
    def api(self) -> Any:
        raise NotImplementedError

    def _subscribe_vehicle(self, veh_id: str) -> None:
        raise NotImplementedError

    def add_vehicle(self, veh_id: str, length: float, width: float, vclass: str = "passenger", *,
                    departure: Departure = ANYWHERE, base_type: str = "DEFAULT_VEHTYPE",
                    color: tuple[int, int, int, int] | None = None, remote: bool = True) -> None:
        """Add a vehicle with a private vType ``"<veh_id>@coster"`` of the given size and class, now,
        entering as ``departure`` says.

        ``remote=True`` prepares it for :meth:`move_to_xy`: speed mode and lane-change mode 0, and a
        speed factor / max speed large enough that SUMO does not cap its reported speed. Place a
        remote vehicle on a lane first: a vehicle first placed far from every lane can crash
        libsumo on some getters (docs/sumo.md §3).
        """
        api = self.api
        vt = api.vehicletype
        # a vehicle added again after its removal (an environment's target, episode after episode)
        # reuses its type and any route it had: SUMO keeps every type and route it was given
        kind = (veh_id, base_type, remote)
        type_id = self._types.get(kind)
        if type_id is None:
            n = sum(1 for k in self._types if k[0] == veh_id)
            type_id = f"{veh_id}@coster" + ("" if n == 0 else f"#{n}")
            vt.copy(base_type, type_id)
            self._types[kind] = type_id
        vt.setLength(type_id, float(length))
        vt.setWidth(type_id, float(width))
        vt.setVehicleClass(type_id, vclass)
        if remote:
            vt.setSpeedFactor(type_id, REMOTE_SPEED_FACTOR)
            vt.setMaxSpeed(type_id, REMOTE_MAX_SPEED_MPS)
            vt.setSpeedDeviation(type_id, 0.0)
        route_id = None
        if departure.edges is not None:
            route_edges = tuple(departure.edges)
            route_id = self._routes.get(route_edges)
            if route_id is None:
                route_id = f"{veh_id}@route" + ("" if not self._routes else f"#{len(self._routes)}")
                api.route.add(route_id, list(route_edges))
                self._routes[route_edges] = route_id
        try:
            api.vehicle.add(veh_id, route_id or "", typeID=type_id, depart="now", departLane=departure.lane,
                            departPos=departure.pos, departSpeed=departure.speed)
        except Exception as exc:
            raise SumoError(f"{self.name}: cannot add vehicle {veh_id!r}: {sumo_message(exc)}") from None
        if color is not None:
            api.vehicle.setColor(veh_id, color)
        self._static[veh_id] = (float(length), float(width), vclass, type_id)
        if remote:
            self._make_remote(veh_id)
        if self.uses_traci:
            self._subscribe_vehicle(veh_id)

    def set_size(self, veh_id: str, length: float, width: float) -> None:
        """Change a vehicle's length and width [m] (SUMO gives it a private type)."""
        veh = self.api.vehicle
        veh.setLength(veh_id, float(length))
        veh.setWidth(veh_id, float(width))
        self._static.pop(veh_id, None)

    def remove_vehicle(self, veh_id: str) -> None:
        """Remove a vehicle now (no error if it is already gone)."""
        with contextlib.suppress(Exception):
            self.api.vehicle.remove(veh_id)
        self._static.pop(veh_id, None)
        self._remote.discard(veh_id)
        self.hidden.discard(veh_id)
        self._pending_speed.pop(veh_id, None)

    def move_to_xy(self, veh_id: str, cx: float, cy: float, yaw: float, length: float | None = None,
                   speed: float | None = None) -> None:
        """Place a vehicle so that its box centre is (cx, cy) [m] heading ``yaw`` [rad, CCW from x].

        Takes effect at the next :meth:`step`, after which SUMO reports exactly this pose. Call it
        **every** step for a vehicle you drive: one step without it hands the vehicle back to SUMO,
        which may drive it off along a rewritten route or make it arrive (docs/sumo.md §3).
        ``length`` defaults to the vehicle's known length. ``speed`` [m/s], when given, becomes the
        speed SUMO reports after the step (``setPreviousSpeed``); otherwise SUMO reports the
        displacement over the step, uncapped for vehicles added with ``remote=True`` or moved
        here before.
        """
        api = self.api
        if veh_id not in self._remote:
            self._make_remote(veh_id)
        if length is None:
            st = self._static.get(veh_id)
            length = st[0] if st is not None else float(api.vehicle.getLength(veh_id))
        fx, fy, angle = frames.to_sumo_scalar(float(cx), float(cy), float(yaw), float(length))
        api.vehicle.moveToXY(veh_id, "", -1, fx, fy, angle=angle,
                             keepRoute=KEEP_ROUTE_EXACT_ANYWHERE, matchThreshold=MOVE_MATCH_THRESHOLD_M)
        if speed is not None:
            self._pending_speed[veh_id] = float(speed)

    def release_vehicle(self, veh_id: str, destinations: Sequence[tuple[float, float, float, float]] = ()) -> None:
        """Hand a vehicle driven by :meth:`move_to_xy` back to SUMO's driver model.

        Restores SUMO's default speed mode and lane-change mode and an ordinary speed factor, so
        the driver model, safe gaps and speed limits apply again from the vehicle's current pose.
        moveToXY left it a route of the one edge it stands on; ``destinations`` (poses further on:
        centre x, y [m], yaw [rad], length [m], best first) give it a route to the first normal
        (not internal) edge under one of them that SUMO can route to.
        """
        veh = self.api.vehicle
        veh.setSpeedMode(veh_id, SPEED_MODE_SUMO_DEFAULT)
        veh.setLaneChangeMode(veh_id, LANE_CHANGE_MODE_SUMO_DEFAULT)
        veh.setSpeedFactor(veh_id, 1.0)
        vclass = veh.getVehicleClass(veh_id) if destinations else ""
        for pose in destinations:
            fx, fy, _ = frames.to_sumo(*pose)
            with contextlib.suppress(Exception):  # no edge there, or no route to it: try the next
                edge, _, _ = self.api.simulation.convertRoad(float(fx), float(fy), False, vclass)
                if edge and not str(edge).startswith(":"):
                    veh.changeTarget(veh_id, str(edge))
                    return
        self._remote.discard(veh_id)
        self._pending_speed.pop(veh_id, None)

    def _make_remote(self, veh_id: str) -> None:
        veh = self.api.vehicle
        veh.setSpeedMode(veh_id, SPEED_MODE_ALL_CHECKS_OFF)
        veh.setLaneChangeMode(veh_id, LANE_CHANGE_MODE_NO_AUTONOMOUS)
        # per-vehicle too, for vehicles not added by us (their vType is shared, leave it alone)
        veh.setSpeedFactor(veh_id, REMOTE_SPEED_FACTOR)
        veh.setMaxSpeed(veh_id, REMOTE_MAX_SPEED_MPS)
        self._remote.add(veh_id)

    def set_tls_state(self, tls_id: str, state: str) -> None:
        """Force a red-yellow-green state (kept until the program is set again)."""
        self.api.trafficlight.setRedYellowGreenState(tls_id, state)


def sumo_message(exc: BaseException) -> str:
    """What SUMO said, on one line (its exceptions span several)."""
    text = " ".join(str(exc).split())
    return text or type(exc).__name__
