"""Choosing targets automatically (``coster-sumo run CFG --targets N``): the longest-lived vehicles.

A target is worth generating for when it stays on the map long enough for the collision-time search
to have a choice. Before the nominal pass nothing has been simulated, so the choice reads the demand
instead: every vehicle, trip and flow of the configuration's route and additional files, its
departure, and the time its route takes at the edges' speed limits (the *free-flow time*). A
vehicle's score is the part of that time inside the window [begin, end]; the N best are chosen.

What the demand says, and how it is read:

* ``<vehicle>`` with a nested ``<route edges=...>`` or ``route="id"`` (a ``<route>`` or the first
  route of a ``<routeDistribution>`` defined elsewhere): the route's free-flow time;
* ``<trip>`` / ``<flow>`` with ``from``/``to`` (and ``via``): SUMO routes them at insertion; here
  the shortest path in the net (sumolib's Dijkstra) gives the time. Routing every trip of a city
  would take minutes, so trips are first ranked by the straight line between their edges and only
  the best few per target asked are routed;
* a ``<flow>`` is a series of vehicles ``<flow id>.<k>`` that share a route; its departures follow
  from ``begin`` and ``period`` / ``vehsPerHour`` / ``number``; where they are random
  (``probability``, ``period="exp(rate)"``) the mean gap stands in for the period, and the k-th
  vehicle is expected k + 1 mean gaps after ``begin`` (the mean time of a random process's k-th
  arrival), not at ``begin``: a rare flow's first vehicle (``probability="0.0117"`` on the shipped
  arterial: one in 85 s on average) is not expected at once. One vehicle per flow at most, the
  first expected to depart in the window: several targets from one flow would be the same drive;
* departures that are not times (``triggered``, ``containerTriggered``) are left out;
* so are vehicles whose ``vType`` has a class that uses no road (``vClass="rail"``, ships, ...,
  :data:`OFF_ROAD_CLASSES`): the prior places road vehicles around a target on road lanes (the
  wheel's ``rail_demo`` runs only trains).

The free-flow time is a lower bound of the real one (queues, signals and insertion backlogs only add
to it), so a chosen vehicle may still never run in the window; the run then lists it with that
reason and the others go on (``OUT/summary.json``). :func:`missing_target` is that reason's line,
with the vehicles that did run as candidates.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

from defusedxml import ElementTree as SafeET

from coster_sumo.errors import InputError
from coster_sumo.formats.sumocfg import check_xml, open_maybe_gzip, parse_time, read_sumocfg

if TYPE_CHECKING:
    from coster_sumo.core.scene import Scene

# vehicle classes that use no road lanes: the prior places road vehicles, so none is a target
# (trams stay: their tracks often run in the street)
OFF_ROAD_CLASSES = frozenset({"rail", "rail_urban", "rail_electric", "rail_fast", "subway", "cable_car", "ship",
                              "aircraft", "drone", "pedestrian", "wheelchair", "container"})
MIN_IN_WINDOW_S = 10.0  # [s] shorter lives leave the collision-time search no choice (5 s horizon + margins)
DETOUR = 1.3  # straight line -> road distance, for ranking trips before they are routed
ROUTED_PER_TARGET = 4  # trips routed per target asked (the best by the straight-line estimate)
TIE_S = 5.0  # [s] expected lives this close rank by departure


@dataclass(frozen=True)
class Candidate:
    """A vehicle of the demand and how long it is expected to run inside the window."""

    vehicle_id: str
    depart_s: float  # [s] absolute simulation time
    free_flow_s: float  # [s] its route at the speed limits
    in_window_s: float  # [s] the part of [depart, depart + free_flow] inside [begin, end]
    route_m: float  # [m]

    def to_dict(self) -> dict[str, Any]:
        return {"target": self.vehicle_id, "depart_s": round(self.depart_s, 3),
                "free_flow_s": round(self.free_flow_s, 1), "in_window_s": round(self.in_window_s, 1),
                "route_m": round(self.route_m, 1)}


@dataclass
class _Demand:
    """One vehicle-like element, before its route is known (``edges``) or after."""

    vehicle_id: str
    depart_s: float
    edges: list[str] | None = None
    src: str | None = None  # trip / flow endpoints (edge ids), ``via`` in between
    dst: str | None = None
    via: tuple[str, ...] = ()
    flow: tuple[float, float, int, bool] | None = None  # begin, period, count of a flow's vehicles; random
    vtype: str = ""  # its type="..." ("": SUMO's default type)
    vclass: str = "passenger"  # its vType's class, resolved once every file is read


def _depart(text: str | None, where: str) -> float | None:
    if text is None:
        return None
    try:
        return parse_time(text, where)
    except InputError:  # "triggered", "containerTriggered", "now"...: no time known beforehand
        return None


def _flow_series(el: Any, where: str, default_end: float) -> tuple[float, float, int, bool] | None:
    """(begin, period, count, random) of a flow's departures (random ones: the mean gap), None when
    unknown."""
    begin = _depart(el.get("begin", "0"), where)
    end = _depart(el.get("end"), where) if el.get("end") else default_end
    if begin is None or end is None:
        return None
    number = int(float(el.get("number"))) if el.get("number") else None
    period_text = (el.get("period") or "").strip()
    is_random = bool(el.get("probability")) or (period_text.startswith("exp(") and period_text.endswith(")"))
    if el.get("probability"):  # random, on average one vehicle per 1 / probability seconds
        period = 1.0 / max(float(el.get("probability")), 1e-9)
    elif is_random:  # exp(rate): random gaps, mean 1 / rate
        period = 1.0 / max(float(period_text[4:-1]), 1e-9)
    elif period_text:
        period = parse_time(period_text, where)
    elif el.get("vehsPerHour"):
        period = 3600.0 / max(float(el.get("vehsPerHour")), 1e-9)
    elif number:
        period = max(end - begin, 0.0) / number
    else:
        return None
    if period <= 0:
        return None
    count = int(math.floor((end - begin) / period + 1e-9)) + 1 if end > begin else 0
    if number is not None:
        count = min(count, number) if el.get("end") else number
    return (begin, period, max(count, 0), is_random)


def _read_demand(files: list[Path], default_end: float) -> list[_Demand]:
    """Vehicle-like elements of the files, their ``route="id"`` references resolved."""
    out: list[_Demand] = []
    routes: dict[str, list[str]] = {}
    vclass: dict[str, str] = {}
    for path in files:
        check_xml(path, "route file")
        with open_maybe_gzip(path) as fh:
            try:
                root = SafeET.parse(fh, forbid_dtd=True).getroot()
            except Exception as exc:  # noqa: BLE001 - defusedxml raises several types; all mean "bad file"
                raise InputError(f"{path}: not a readable route file ({type(exc).__name__})") from None
        for vt in root.iter("vType"):
            if vt.get("id"):
                vclass[vt.get("id")] = vt.get("vClass") or "passenger"
        for rd in root.iter("routeDistribution"):
            first = next(iter(rd.iter("route")), None)
            if rd.get("id") and first is not None and first.get("edges"):
                routes.setdefault(rd.get("id"), first.get("edges").split())
        for r in root.iter("route"):
            if r.get("id") and r.get("edges"):
                routes.setdefault(r.get("id"), r.get("edges").split())
        for el in root:
            tag = str(el.tag).split("}")[-1]
            vid = el.get("id")
            if tag not in ("vehicle", "trip", "flow") or not vid:
                continue
            where = f"{path}: {tag} {vid!r}"
            nested = el.find("route")
            edges = (nested.get("edges").split() if nested is not None and nested.get("edges")
                     else routes.get(el.get("route", "")) if el.get("route") else None)
            d = _Demand(vid, 0.0, edges=edges, src=el.get("from"), dst=el.get("to"),
                        via=tuple((el.get("via") or "").split()), vtype=el.get("type") or "")
            if tag == "flow":
                d.flow = _flow_series(el, where, default_end)
                if d.flow is None or d.flow[2] == 0:
                    continue
                d.depart_s = d.flow[0]
            else:
                dep = _depart(el.get("depart"), where)
                if dep is None:
                    continue
                d.depart_s = dep
            if d.edges is None and el.get("route"):  # a route defined after it, or in a later file
                d.edges = [f"@{el.get('route')}"]
            out.append(d)
    for d in out:  # late references (routes, and types, may be defined after their users)
        if d.edges and len(d.edges) == 1 and d.edges[0].startswith("@"):
            d.edges = routes.get(d.edges[0][1:])
        d.vclass = vclass.get(d.vtype, "passenger")
    return out


# elements that insert vehicles under ids the files do not spell out (a calibrator's own flows)
_OPAQUE_SOURCES = ("calibrator",)


@dataclass(frozen=True)
class DemandIds:
    """The vehicle ids a configuration's demand can insert, read without simulating.

    Attributes:
        vehicles: ids of its ``<vehicle>`` and ``<trip>`` elements, in file order.
        flows: ids of its ``<flow>`` elements (their vehicles are ``<flow id>.<k>``), in file order.
    """

    vehicles: tuple[str, ...]
    flows: tuple[str, ...]
    classes: dict[str, str] = field(default_factory=dict)  # vehicle or flow id -> its vType's vClass
    departs: dict[str, float] = field(default_factory=dict)  # vehicle id -> its planned departure [s]

    def depart_s(self, vehicle_id: str) -> float | None:
        """When ``vehicle_id`` is planned to depart [s] (SUMO inserts it then or later); None for a
        flow's vehicle, a departure that is no time (``triggered``), or an id not in the demand."""
        return self.departs.get(vehicle_id)

    def vclass(self, vehicle_id: str) -> str | None:
        """The vehicle class of ``vehicle_id`` (a flow member's is its flow's); None if not in the demand."""
        src = self._source(vehicle_id)
        return None if src is None else self.classes.get(src, "passenger")

    @cached_property
    def _sets(self) -> tuple[frozenset[str], frozenset[str]]:
        return frozenset(self.vehicles), frozenset(self.flows)

    def _source(self, vehicle_id: str) -> str | None:
        """The vehicle or flow id that inserts ``vehicle_id``, None if none."""
        vehicles, flows = self._sets
        head, _, k = vehicle_id.rpartition(".")
        if vehicle_id in vehicles:
            return vehicle_id
        return head if k.isdigit() and head in flows else None

    def examples(self, like: list[str], n: int = 8) -> list[str]:
        """Up to ``n`` ids for an error: those containing one of ``like`` (case-insensitive), else
        the first ones (a flow's first vehicle stands for it)."""
        every = [*self.vehicles, *(f"{f}.0" for f in self.flows)]
        near = [v for v in every if any(x.lower() in v.lower() for x in like)]
        return (near or every)[:n]


def config_demand(config: str | Path) -> DemandIds | None:
    """What ``config``'s route and additional files can insert (:class:`DemandIds`); None where the
    files cannot tell: the configuration loads a saved state, a calibrator inserts vehicles too, or
    a file is missing or unreadable (the simulation will then say what is wrong with it).

    A city's nominal pass takes minutes; this tells in seconds that a target is not in the demand.
    """
    try:
        cfg = read_sumocfg(config)
    except InputError:
        return None
    if cfg.load_state:  # a saved state brings vehicles that no route file names
        return None
    vehicles: list[str] = []
    flows: list[str] = []
    types: dict[str, str] = {}  # vehicle or flow id -> its type id
    departs: dict[str, float] = {}
    vtypes: dict[str, str] = {}  # type id -> vClass
    for path in [*cfg.route_files, *cfg.additional_files]:
        try:
            check_xml(path, "route file")
            with open_maybe_gzip(path) as fh:
                for _, el in SafeET.iterparse(fh, forbid_dtd=True):
                    tag, vid = str(el.tag).split("}")[-1], el.get("id")
                    if tag in _OPAQUE_SOURCES:
                        return None
                    if vid and tag in ("vehicle", "trip", "flow"):
                        (flows if tag == "flow" else vehicles).append(vid)
                        if el.get("type"):
                            types[vid] = str(el.get("type"))
                        if tag != "flow":
                            with contextlib.suppress(InputError):  # "triggered", "now": no time
                                departs[vid] = parse_time(str(el.get("depart", "")), str(path))
                    elif vid and tag == "vType":
                        vtypes[vid] = el.get("vClass") or "passenger"
                    el.clear()  # a city's demand is large: keep no element's content
        except Exception:  # noqa: BLE001 - any reading problem: leave the answer to the simulation
            return None
    classes = {v: vtypes.get(t, "passenger") for v, t in types.items()}
    return DemandIds(tuple(vehicles), tuple(flows), classes, departs)


def _in_window(depart: float, duration: float, begin: float, end: float) -> float:
    return max(0.0, min(depart + duration, end) - max(depart, begin))


def _first_member(d: _Demand, begin: float) -> tuple[str, float] | None:
    """A flow's first vehicle (expected to be) departing at or after ``begin``, and when: of all its
    vehicles in the window it has the most time in it (a later one's route fits at best as well).
    A random flow's k-th vehicle is expected k + 1 mean gaps after the flow's begin. None: none
    departs by then."""
    assert d.flow is not None
    fb, period, count, is_random = d.flow
    first = fb + period if is_random else fb  # when vehicle 0 is expected
    k = max(0, math.ceil((begin - first) / period - 1e-9))
    return None if k >= count else (f"{d.vehicle_id}.{k}", first + k * period)


def long_lived(config: str | Path, n: int, begin: float | None = None, end: float | None = None,
               net: Any = None) -> list[Candidate]:
    """The ``n`` vehicles of ``config``'s demand with the most free-flow time in [begin, end].

    ``begin``/``end`` [s] default to the configuration's (end: begin + 3600 s when it has none);
    ``net`` is a sumolib net of the configuration (read when not given). Fewer than ``n`` come back
    when the demand has fewer that run at least :data:`MIN_IN_WINDOW_S` inside the window; none is
    an :class:`InputError` naming the configuration.
    """
    if n < 1:
        raise InputError(f"--targets must be >= 1, not {n}")
    cfg = read_sumocfg(config)
    begin = (cfg.begin or 0.0) if begin is None else begin
    end = (cfg.end if cfg.end is not None else begin + 3600.0) if end is None else end
    if net is None:
        from coster_sumo.formats.sumo_net import read_sumolib_net

        net = read_sumolib_net(cfg.net_file)
    every = _read_demand([*cfg.route_files, *cfg.additional_files], end)
    demand = [d for d in every if d.vclass not in OFF_ROAD_CLASSES]
    if every and not demand:
        classes = sorted({d.vclass for d in every})
        raise InputError(f"{config}: no road vehicle in its demand (only {', '.join(classes)}): the adversaries "
                         "COSTER places are road vehicles")

    def edge(eid: str) -> Any:
        return net.getEdge(eid) if net.hasEdge(eid) else None

    def route_time(edges: list[str]) -> tuple[float, float] | None:
        objs = [edge(e) for e in edges]
        if not objs or any(o is None for o in objs):
            return None
        return (sum(o.getLength() / max(o.getSpeed(), 0.1) for o in objs), sum(o.getLength() for o in objs))

    scored: list[Candidate] = []
    trips: list[tuple[float, _Demand]] = []
    for d in demand:
        if d.edges is not None:
            rt = route_time(d.edges)
            c = _candidate(d, rt[0], rt[1], begin, end) if rt is not None else None
            if c is not None:
                scored.append(c)
        elif d.src and d.dst and edge(d.src) is not None and edge(d.dst) is not None:
            a, b = edge(d.src), edge(d.dst)
            (x0, y0), (x1, y1) = a.getFromNode().getCoord(), b.getToNode().getCoord()
            speed = max(0.5 * (a.getSpeed() + b.getSpeed()), 0.1)
            guess = DETOUR * math.hypot(x1 - x0, y1 - y0) / speed
            c = _candidate(d, guess, 0.0, begin, end)
            if c is not None:
                trips.append((c.in_window_s, d))
    trips.sort(key=lambda x: -x[0])
    for _, d in trips[:ROUTED_PER_TARGET * n]:
        path: list[Any] = []
        stops = [str(d.src), *d.via, str(d.dst)]
        for u, v in zip(stops[:-1], stops[1:], strict=True):
            leg, _cost = net.getShortestPath(edge(u), edge(v)) if edge(u) and edge(v) else (None, None)
            if not leg:
                path = []
                break
            path += leg if not path else leg[1:]
        if path:
            rt = route_time([e.getID() for e in path])
            c = _candidate(d, rt[0], rt[1], begin, end) if rt is not None else None
            if c is not None:
                scored.append(c)
    scored = [c for c in scored if c.in_window_s >= MIN_IN_WINDOW_S and begin <= c.depart_s < end]
    # lives within TIE_S of each other count as equal and the earlier departure wins: the shared
    # nominal pass ends when the last target has arrived
    scored.sort(key=lambda c: (-round(c.in_window_s / TIE_S), c.depart_s, c.vehicle_id))
    if not scored:
        raise InputError(f"{config}: no vehicle of its demand is expected to run {MIN_IN_WINDOW_S:g} s or more in "
                         f"[{begin:g}, {end:g}] s; name targets with --target")
    return scored[:n]


def _candidate(d: _Demand, duration: float, length: float, begin: float, end: float) -> Candidate | None:
    member = (d.vehicle_id, d.depart_s) if d.flow is None else _first_member(d, begin)
    if member is None:
        return None
    return Candidate(member[0], member[1], duration, _in_window(member[1], duration, begin, end), length)


def iter_lines(chosen: list[Candidate]) -> Iterator[str]:
    """One line per chosen target, as ``coster-sumo run --targets`` prints them."""
    for c in chosen:
        yield (f"chose target {c.vehicle_id}: departs {c.depart_s:.1f} s, expected about {c.in_window_s:.0f} s "
               "in the window")


def choose_targets(config: str | Path, n: int, begin: float | None = None,
                   end: float | None = None) -> list[Candidate]:
    """``coster-sumo run --targets N``: :func:`long_lived` for a SUMO configuration; for a converted
    WOMD scene, the ``n`` vehicles of its log with the most valid steps (their time in the log)."""
    from coster_sumo.formats.scene_folder import converted_scene_file

    log = converted_scene_file(config)
    if log is None:
        return long_lived(config, n, begin, end)
    if n < 1:
        raise InputError(f"--targets must be >= 1, not {n}")
    import numpy as np

    from coster_sumo.core.scene import ObjectType
    from coster_sumo.formats.scene_file import load_scene

    scene = load_scene(log)
    tr, ts = scene.tracks, scene.timestamps
    steps = np.where(tr.object_type == int(ObjectType.VEHICLE), tr.valid.sum(axis=1), 0)
    dt = float(np.median(np.diff(ts))) if len(ts) > 1 else 0.1
    out = []
    for i in np.argsort(-steps, kind="stable")[:n]:
        if steps[i] < 2:
            break
        first = int(np.argmax(tr.valid[i]))
        speed = np.hypot(tr.vx[i], tr.vy[i])[tr.valid[i]]
        out.append(Candidate(str(tr.ids[i]), float(ts[first]), float(steps[i] * dt), float(steps[i] * dt),
                             float(speed.mean() * steps[i] * dt)))
    if not out:
        raise InputError(f"{config}: its log has no vehicle to target")
    return out


def missing_target(config: Any, requested: Sequence[str | None], window: str, ran: dict[str, float]) -> InputError:
    """The one-line error for targets that never run: ``requested`` (None: the default 'ego'), the
    window, and candidates from ``ran`` (every vehicle that ran, in order of appearance, with how
    long it ran): ids containing a requested name, else the longest-running ones."""
    if not ran:
        return InputError(f"{config}: no vehicle runs in the window ({window}) at all")
    if requested == [None]:
        longest = sorted(ran, key=lambda v: -ran[v])[:8]
        return InputError(f"{config}: no vehicle 'ego' runs in the window ({window}); pick a target with "
                          "--target, e.g. " + ", ".join(longest))
    names = [r or "ego" for r in requested]
    near = [v for v in ran if any(n.lower() in v.lower() for n in names)][:8] or list(ran)[:8]
    which = (f"target {names[0]!r} never runs" if len(names) == 1 else
             "none of the targets " + ", ".join(map(repr, names)) + " runs")
    return InputError(f"{config}: {which} in the window ({window}); candidates: {', '.join(near)}")


def choose_target(scene: Scene, requested: str | None, config: Any) -> int:
    """Index of the target: ``requested``, else the SDC of a converted scene, else ``ego``.

    Raises :class:`InputError` (naming ``config`` and candidate ids) when there is none, or when
    the target runs for fewer than two steps of the window.
    """
    ids = scene.tracks.ids.tolist()
    ts = scene.timestamps
    window = f"{float(ts[0]):.1f}-{float(ts[-1]):.1f} s" if len(ts) else "empty"
    if requested is None and scene.sdc_index >= 0:
        index = scene.sdc_index
    elif (requested or "ego") in ids:
        index = ids.index(requested or "ego")
    else:
        steps = scene.tracks.valid.sum(axis=1).tolist()
        raise missing_target(config, [requested], window, dict(zip(ids, steps, strict=True)))
    if scene.tracks.valid[index].sum() < 2:
        raise InputError(f"{config}: target {ids[index]!r} never departs in the window")
    return index
