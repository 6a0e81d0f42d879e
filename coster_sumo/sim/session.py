"""The one object that owns a SUMO connection.

Everything else in coster-sumo talks to SUMO through :class:`SumoSession`; nobody else imports
libsumo or traci. Two back ends share one API:

- **libsumo** (default): SUMO runs in this process. Fast (a getter costs about 0.5 us), but libsumo
  holds **one simulation per process** and a second ``libsumo.start`` silently throws away the
  first (docs/sumo.md §6), so a second live libsumo session raises :class:`SumoError` instead.
- **TraCI** (``traci=True``): SUMO runs as a separate process behind a socket (about 50-200 us per
  call, so bulk reads use subscriptions). Needed for ``sumo-gui`` (``gui=True``) and for attaching
  to a server somebody else started (``port=...``). Any number of TraCI sessions may be open.

Frames: every array this class returns or takes is in **our** frame (box centre, heading in radians
counter-clockwise from +x, see :mod:`coster_sumo.geometry.frames`); SUMO's front-bumper / degrees clockwise
from north convention stays inside this module.

The commands that change the simulation (add, place, release, remove vehicles; force signals)
are the session's too, written in :mod:`coster_sumo.sim.control`.

Example: ``with SumoSession("x.sumocfg", seed=1) as sim: sim.step(); sim.vehicle_states()``.
"""

from __future__ import annotations

import contextlib
import io
import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from coster_sumo.errors import CosterError, InputError, SumoError
from coster_sumo.formats.sumocfg import check_xml, read_sumocfg, runnable_config
from coster_sumo.geometry import frames
from coster_sumo.infra import sumo_install
from coster_sumo.sim import sumo_outputs as sumo_outputs_mod
from coster_sumo.sim.control import SessionControl, sumo_message
from coster_sumo.sim.states import VehicleStates, empty_states
from coster_sumo.sim.sumo_options import (
    RECOMMENDED_OPTIONS,
    SHORT_TO_LONG,
    as_list,
    fmt,
)
from coster_sumo.sim.traci_server import attach_traci, start_traci_server, subscribe_simulation, subscribe_vehicle

_LIBSUMO_OWNER: SumoSession | None = None  # the live libsumo session of this process, if any
_LABELS = itertools.count()


def _option_key(arg: str) -> str:
    key = arg.split("=", 1)[0]
    return SHORT_TO_LONG.get(key, key)


class SumoSession(SessionControl):
    """One SUMO simulation: start, step, read vehicles and signals, place vehicles.

    Args:
        config: a ``.sumocfg``; or leave it out and give ``net`` (and ``routes``/``additional``).
        net: a ``.net.xml`` (used with or instead of ``config``; on the command line it overrides
            the config's net).
        routes: route file(s) (with ``config``: instead of its own).
        additional: additional file(s); with ``config`` loaded after its own additional files, not
            instead of them (a planner's vType must not drop the demand, detectors or stops that
            a configuration keeps in additional files: the wheel's square keeps its routes there).
        seed: SUMO's ``--seed``; None keeps the configuration's own (SUMO's default is fixed, so
            runs are deterministic either way).
        step_length: [s] simulation step (default 0.1 s = 10 Hz).
        begin, end: [s] simulation begin / end (None keeps the configuration's).
        options: SUMO options that override :data:`RECOMMENDED_OPTIONS`, e.g.
            ``{"--collision.action": "remove"}`` (keys with leading dashes).
        extra_args: more raw command-line arguments appended last (they also override the
            recommended options they name).
        traci: use a TraCI socket instead of in-process libsumo.
        gui: run ``sumo-gui`` (implies ``traci``; needs a display, e.g. ``xvfb-run``).
        port: attach to a SUMO server already listening on this port (implies ``traci``; the
            files and options above are then ignored: the server was started by someone else).
        host: host of that server.
        sumo_outputs: the folder the outputs the configuration and additional files declare go to
            (None: a temporary one, :mod:`coster_sumo.sim.sumo_outputs`); never where they say.
    """

    def __init__(self, config: str | Path | None = None, *, net: str | Path | None = None,
                 routes: str | Path | Sequence[str | Path] | None = None,
                 additional: str | Path | Sequence[str | Path] | None = None,
                 seed: int | None = None, step_length: float = 0.1,
                 begin: float | None = None, end: float | None = None,
                 options: Mapping[str, object] | None = None, extra_args: Sequence[str] = (),
                 traci: bool = False, gui: bool = False, port: int | None = None,
                 host: str = "localhost", sumo_outputs: Path | None = None) -> None:
        if config is None and net is None and port is None:
            raise InputError("SumoSession needs a .sumocfg, a net file, or a port to attach to")
        self.config = Path(config) if config is not None else None
        self.net = Path(net) if net is not None else None
        self.routes = [Path(p) for p in as_list(routes)]
        self.additional = [Path(p) for p in as_list(additional)]
        self.seed = seed
        self.step_length = float(step_length)
        self.begin = begin
        self.end = end
        self.options = {str(k): fmt(v) for k, v in (options or {}).items()}
        self.extra_args = [str(a) for a in extra_args]
        self.gui = gui
        self.port = port
        self.host = host
        self.uses_traci = bool(traci or gui or port is not None)
        self.sumo_outputs = sumo_outputs
        self.own_outputs: list[Path] = []  # folders of more files only this process writes (forks detach them)
        self.redirects: tuple[sumo_outputs_mod.Redirect, ...] = ()  # set by command()
        self._api: Any = None
        self._label: str | None = None
        self._static: dict[str, tuple[float, float, str, str]] = {}  # id -> length, width, vclass, type
        self._remote: set[str] = set()  # vehicles we drive with moveToXY
        self._context: dict[str, float] = {}  # vehicle -> radius [m] of its context subscription
        self._near_values: dict[str, dict[int, Any]] = {}  # this step's context subscription values
        self._constants: Any = None  # traci.constants, once looked up
        # vehicles in the simulation that are not part of the scene yet (a log replayer's agents
        # parked on the staging lane): left out of vehicle_states() and so of recordings and events
        self.hidden: set[str] = set()
        self._pending_speed: dict[str, float] = {}  # move_to_xy speeds to report after the next step
        self._speed_set: dict[str, float] = {}  # speeds set after the last step
        self._arrived: tuple[str, ...] = ()
        self._departed: tuple[str, ...] = ()
        self._time = 0.0
        self._stderr: IO[bytes] | None = None
        self._tls_ids: tuple[str, ...] = ()
        self._types: dict[tuple[str, str, bool], str] = {}  # (vehicle id, base type, remote) -> its vType
        self._routes: dict[tuple[str, ...], str] = {}  # edges -> the route add_vehicle made of them

    # ------------------------------------------------------------------------- life cycle

    @property
    def name(self) -> str:
        """What this session runs, for messages: the config, else the net, else host:port."""
        if self.config is not None:
            return str(self.config)
        if self.net is not None:
            return str(self.net)
        return f"{self.host}:{self.port}"

    @property
    def api(self) -> Any:
        """The raw API for advanced callers: the ``libsumo`` module or a ``traci.Connection``.

        Both expose the same domains (``api.vehicle``, ``api.simulation``, ``api.trafficlight``...).
        Going around the session skips its bookkeeping: prefer the session's methods.
        """
        if self._api is None:
            raise SumoError(f"{self.name}: the SUMO session is not running (call start() first)")
        return self._api

    @property
    def is_running(self) -> bool:
        return self._api is not None

    @property
    def backend(self) -> str:
        """"libsumo" or "traci"."""
        return "traci" if self.uses_traci else "libsumo"

    def command(self) -> list[str]:
        """The SUMO command line this session starts (binary first)."""
        binary = sumo_install.binary("sumo-gui" if self.gui else "sumo")
        cmd = [binary]
        # the outputs the configuration declares: into self.sumo_outputs, or discarded (a quiet copy)
        box = sumo_outputs_mod.sandbox(self.config, self.additional, self.sumo_outputs)
        self.redirects = tuple(box.redirects)
        if self.config is not None:
            cmd += ["-c", str(box.config or runnable_config(self.config))]
        if self.net is not None:
            cmd += ["-n", str(self.net)]
        if self.routes:
            cmd += ["-r", ",".join(str(p) for p in self.routes)]
        # -a replaces the configuration's additional-files: name them too
        if self.additional or (box.staged and box.config is None):
            cmd += ["-a", ",".join(str(p) for p in box.additional)]
        opts = dict(RECOMMENDED_OPTIONS)
        opts.update(zip(box.args[::2], box.args[1::2], strict=True))  # its outputs into our folder
        opts["--step-length"] = fmt(self.step_length)
        if self.seed is not None:
            opts["--seed"] = str(int(self.seed))
        if self.begin is not None:
            opts["--begin"] = fmt(self.begin)
        if self.end is not None:
            opts["--end"] = fmt(self.end)
        if self.gui:
            opts.update({"--start": "true", "--quit-on-end": "true"})
        opts.update(self.options)
        overridden = {_option_key(a) for a in self.extra_args if a.startswith("-")}
        for key, value in opts.items():
            if _option_key(key) not in overridden:
                cmd += [key, value]
        return cmd + self.extra_args

    def check_inputs(self) -> None:
        """Raise :class:`InputError` naming the file if an input is missing or not well-formed XML.

        Done before SUMO starts: SUMO's own message is less clear, and a truncated net file
        crashes libsumo (segmentation fault) instead of raising.
        """
        files: list[tuple[Path, str, Path | None]] = []
        if self.config is not None:
            ins = read_sumocfg(self.config).inputs()
            if self.net is None:
                files += [(p, "net file", self.config) for p in ins["net-file"]]
            if not self.routes:
                files += [(p, "route file", self.config) for p in ins["route-files"]]
            files += [(p, "additional file", self.config) for p in ins["additional-files"]]
            if self.net is None and not ins["net-file"]:
                raise InputError(f"{self.config}: the configuration names no net-file")
        if self.net is not None:
            files.append((self.net, "net file", None))
        files += [(p, "route file", None) for p in self.routes]
        files += [(p, "additional file", None) for p in self.additional]
        for path, what, ref in files:
            check_xml(path, what, ref)

    def start(self) -> SumoSession:
        """Start (or attach to) SUMO. Returns self."""
        global _LIBSUMO_OWNER
        if self._api is not None:
            raise SumoError(f"{self.name}: this SUMO session is already running")
        if self.port is None:
            self.check_inputs()
        if not self.uses_traci:
            if _LIBSUMO_OWNER is not None:
                raise SumoError(
                    f"{self.name}: libsumo runs one simulation per process and {_LIBSUMO_OWNER.name} is "
                    "still running; close it first, use traci=True, or use another process")
            with contextlib.redirect_stdout(io.StringIO()):  # libsumo prints a pyarrow version notice
                api = sumo_install.import_libsumo()
            try:
                api.start(self.command())
            except Exception as exc:  # libsumo.TraCIException: SUMO refused the inputs
                raise InputError(f"{self.name}: SUMO could not load it: {sumo_message(exc)}") from None
            _LIBSUMO_OWNER = self
        else:
            traci = sumo_install.import_traci()
            self._label = f"coster{next(_LABELS)}"
            try:
                if self.port is not None:
                    api = attach_traci(traci, self.port, self.host, self._label)
                else:
                    api, self._stderr = start_traci_server(traci, self.command(), self._label, self.name)
            except CosterError:
                raise
            except Exception as exc:  # FatalTraCIError / OSError
                raise SumoError(f"{self.name}: SUMO did not start or accept the connection: "
                                f"{sumo_message(exc)}") from None
        self._api = api
        self._time = float(api.simulation.getTime())
        self._tls_ids = tuple(api.trafficlight.getIDList())
        if self.uses_traci:
            subscribe_simulation(api, self._tc())
            for tls in self._tls_ids:
                api.trafficlight.subscribe(tls, (self._tc().TL_RED_YELLOW_GREEN_STATE,))
            for vid in api.vehicle.getIDList():  # attaching mid-run
                self._subscribe_vehicle(vid)
        return self

    def close(self) -> None:
        """Close the simulation (or the connection to an external server). Safe to call twice."""
        global _LIBSUMO_OWNER
        api, self._api = self._api, None
        if api is None:
            return
        if _LIBSUMO_OWNER is self:
            _LIBSUMO_OWNER = None
        self._static.clear()
        self._remote.clear()
        self._context.clear()
        self.hidden.clear()
        self._pending_speed.clear()
        with contextlib.suppress(Exception):  # SUMO may already be gone; closing must not mask that
            api.close()
        if self._stderr is not None:
            self._stderr.close()
            self._stderr = None

    def __enter__(self) -> SumoSession:
        return self.start() if self._api is None else self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------------- stepping

    def step(self) -> float:
        """Advance one step; returns the new simulation time [s]."""
        api = self.api
        try:
            api.simulationStep()
        except Exception as exc:
            self.close()
            raise SumoError(f"{self.name}: SUMO failed during a step: {sumo_message(exc)}") from None
        sim = api.simulation
        if self.uses_traci:
            res = sim.getSubscriptionResults()
            tc = self._tc()
            self._time = float(res[tc.VAR_TIME])
            self._departed = tuple(res[tc.VAR_DEPARTED_VEHICLES_IDS])
            self._arrived = tuple(res[tc.VAR_ARRIVED_VEHICLES_IDS])
            for vid in self._departed:
                self._subscribe_vehicle(vid)
        else:
            self._time = float(sim.getTime())
            self._departed = tuple(sim.getDepartedIDList())
            self._arrived = tuple(sim.getArrivedIDList())
        self._near_values = {}
        for vid in self._arrived:
            self._static.pop(vid, None)
            self._remote.discard(vid)
            self.hidden.discard(vid)
            self._context.pop(vid, None)
        self._speed_set = {}
        if self._pending_speed:
            for vid, v in self._pending_speed.items():
                if vid not in self._arrived:
                    with contextlib.suppress(Exception):  # not inserted yet: nothing to report
                        api.vehicle.setPreviousSpeed(vid, v)
                        self._speed_set[vid] = v
            self._pending_speed.clear()
        return self._time

    @property
    def time(self) -> float:
        """Current simulation time [s]."""
        return self._time

    def min_expected_number(self) -> int:
        """Vehicles running plus those still waiting to depart (0 = the demand is exhausted)."""
        return int(self.api.simulation.getMinExpectedNumber())

    def departed_ids(self) -> tuple[str, ...]:
        """Vehicles inserted in the last step."""
        return self._departed

    def arrived_ids(self) -> tuple[str, ...]:
        """Vehicles that arrived (left the simulation) in the last step."""
        return self._arrived

    def collisions(self) -> list[dict[str, Any]]:
        """SUMO's own collision list for the last step, as plain dicts.

        Keys: collider, victim, collider_type, victim_type, collider_speed, victim_speed [m/s],
        type ("collision" or "junction"), lane, pos [m along the lane]. SUMO repeats a collision
        every step while the vehicles overlap, and misses lateral / cross-edge overlaps
        (docs/sumo.md §4): our own box check is the ground truth.
        """
        out = []
        for c in self.api.simulation.getCollisions():
            out.append({"collider": c.collider, "victim": c.victim, "collider_type": c.colliderType,
                        "victim_type": c.victimType, "collider_speed": float(c.colliderSpeed),
                        "victim_speed": float(c.victimSpeed), "type": c.type, "lane": c.lane,
                        "pos": float(c.pos)})
        return out

    # ------------------------------------------------------------------------- vehicles

    def vehicle_ids(self) -> tuple[str, ...]:
        """Ids of the vehicles in the network now (the :attr:`hidden` ones included)."""
        if self.uses_traci:
            return tuple(self.api.vehicle.getAllSubscriptionResults().keys())
        return tuple(self.api.vehicle.getIDList())

    def vehicle_states(self, ids: Iterable[str] | None = None) -> VehicleStates:
        """Bulk read of all vehicles (or of ``ids``; default: all but the :attr:`hidden` ones).

        libsumo: plain getters, or this step's values of :meth:`vehicles_near`; length, width, class
        and type cached per vehicle (refreshed by :meth:`set_size` or when it arrives). TraCI: the
        vehicle subscriptions made at departure, no extra round trip."""
        api = self.api
        veh = api.vehicle
        if self.uses_traci:
            results = veh.getAllSubscriptionResults()
            id_list = [v for v in results if v not in self.hidden] if ids is None else list(ids)
            if not id_list:
                return empty_states()
            tc = self._tc()
            rows = [results[v] for v in id_list]
            pos = np.array([r[tc.VAR_POSITION] for r in rows], np.float64).reshape(-1, 2)
            angle = np.array([r[tc.VAR_ANGLE] for r in rows], np.float64)
            speed = np.array([r[tc.VAR_SPEED] for r in rows], np.float64)
            length = np.array([r[tc.VAR_LENGTH] for r in rows], np.float64)
            width = np.array([r[tc.VAR_WIDTH] for r in rows], np.float64)
            vclass = [r[tc.VAR_VEHICLECLASS] for r in rows]
            type_id = [r[tc.VAR_TYPE] for r in rows]
        else:
            if ids is not None:
                id_list = list(ids)
            elif self.hidden:
                id_list = [v for v in veh.getIDList() if v not in self.hidden]
            else:
                id_list = list(veh.getIDList())
            if not id_list:
                return empty_states()
            # list comprehensions over bound getters (about 2x faster than filling arrays per item); the
            # vehicles found by vehicles_near this step come with their values (the getters' numbers)
            known, tc, get_xy, get_angle, get_speed = (self._near_values, self._tc(), veh.getPosition, veh.getAngle,
                                                       veh.getSpeed)
            pairs = list(zip(id_list, [known.get(v) for v in id_list] if known else [None] * len(id_list), strict=True))
            pos = np.array([get_xy(v) if r is None else r[tc.VAR_POSITION] for v, r in pairs], float).reshape(-1, 2)
            angle = np.array([get_angle(v) if r is None else r[tc.VAR_ANGLE] for v, r in pairs], np.float64)
            speed = np.array([get_speed(v) if r is None else r[tc.VAR_SPEED] for v, r in pairs], np.float64)
            static = self._static
            for vid in id_list:
                if vid not in static:
                    static[vid] = (veh.getLength(vid), veh.getWidth(vid), veh.getVehicleClass(vid),
                                   veh.getTypeID(vid))
            rows_static = [static[v] for v in id_list]
            length = np.array([r[0] for r in rows_static], np.float64)
            width = np.array([r[1] for r in rows_static], np.float64)
            vclass = [r[2] for r in rows_static]
            type_id = [r[3] for r in rows_static]
        if self._speed_set:  # TraCI subscription values predate setPreviousSpeed: same view for both
            for i, vid in enumerate(id_list):
                if vid in self._speed_set:
                    speed[i] = self._speed_set[vid]
        cx, cy, yaw = frames.from_sumo(pos[:, 0], pos[:, 1], angle, length)
        return VehicleStates(ids=np.array(id_list, dtype=str), x=cx, y=cy, yaw=yaw, speed=speed,
                             length=length, width=width, vclass=np.array(vclass, dtype=str),
                             type_id=np.array(type_id, dtype=str), names=id_list)

    def vehicles_near(self, veh_id: str, radius_m: float, *, once: bool = False, values: bool = True) -> list[str]:
        """Ids of the vehicles within ``radius_m`` of ``veh_id`` (itself included), hidden ones left out.

        SUMO finds them (a context subscription made on the first call), so the cost does not grow
        with the number of vehicles in the network. SUMO then evaluates the subscription on every
        step, 0.4-1.8 ms per step around a target in dense city traffic (bench/bench_context_query.py);
        ``once=True`` (libsumo) subscribes, reads and unsubscribes instead, for callers that ask only
        now and then; with it, ``values=False`` has SUMO send the ids only, not the values that
        :meth:`vehicle_states` takes from the query otherwise (it reads such vehicles with getters).
        """
        veh = self.api.vehicle
        tc = self._tc()
        standing = self._context.get(veh_id) == radius_m
        bare = once and not values and not self.uses_traci
        if not standing:
            veh.subscribeContext(veh_id, tc.CMD_GET_VEHICLE_VARIABLE, float(radius_m),
                                 [tc.VAR_SPEED] if bare else [tc.VAR_POSITION, tc.VAR_ANGLE, tc.VAR_SPEED])
        if standing:
            near = veh.getContextSubscriptionResults(veh_id) or {}
            if not self.uses_traci:  # this step's values of them, for vehicle_states (no getter calls)
                self._near_values.update(near)
        elif once and not self.uses_traci:
            near = dict(veh.getContextSubscriptionResults(veh_id) or {})  # libsumo: this step's, at once
            veh.unsubscribeContext(veh_id, tc.CMD_GET_VEHICLE_VARIABLE, float(radius_m))
            if not bare:
                self._near_values.update(near)
        else:
            self._context[veh_id] = radius_m
            # results arrive with the next step; this once, measure the distances ourselves
            cx, cy = veh.getPosition(veh_id)
            near = {v: None for v in veh.getIDList()
                    if math.dist(veh.getPosition(v), (cx, cy)) <= radius_m}
        ids = [v for v in near if v not in self.hidden]
        if veh_id not in near and veh_id not in self.hidden:
            ids.insert(0, veh_id)
        return ids

    # ------------------------------------------------------------------------- traffic lights

    def tls_ids(self) -> tuple[str, ...]:
        """Ids of the traffic lights (fixed for a run)."""
        _ = self.api  # raises when not running
        return self._tls_ids

    def tls_controlled_links(self, tls_id: str) -> list[list[tuple[str, str, str]]]:
        """For each link index of ``tls_id`` (usually one triple, maybe several or none): the
        (from_lane, to_lane, via_lane) it controls."""
        return [[(str(a), str(b), str(c)) for (a, b, c) in group]
                for group in self.api.trafficlight.getControlledLinks(tls_id)]

    def tls_state(self, tls_id: str) -> str:
        """Red-yellow-green state string, one char per link index (SUMO link state letters)."""
        return str(self.api.trafficlight.getRedYellowGreenState(tls_id))

    def tls_states(self) -> dict[str, str]:
        """State string of every traffic light (TraCI: from subscriptions, no extra round trip)."""
        tl = self.api.trafficlight
        if self.uses_traci:
            var = self._tc().TL_RED_YELLOW_GREEN_STATE
            res = tl.getAllSubscriptionResults()
            if len(res) == len(self._tls_ids):
                return {t: str(r[var]) for t, r in res.items()}
        return {t: str(tl.getRedYellowGreenState(t)) for t in self._tls_ids}

    # ------------------------------------------------------------------------- TraCI plumbing

    def _tc(self) -> Any:
        if self._constants is None:  # looked up a few times per step: importlib's lookup each time cost
            self._constants = sumo_install.import_traci().constants
        return self._constants

    def _subscribe_vehicle(self, veh_id: str) -> None:
        subscribe_vehicle(self._api, self._tc(), veh_id)
