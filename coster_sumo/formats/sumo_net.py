"""Any SUMO ``.net.xml`` -> :class:`coster_sumo.core.scene.RoadMap`, plus the traffic-light links.

``sumolib.net.readNet(withInternal=True)`` is used at the boundary only; everything it returns is
converted to our arrays here. Coordinates are the network's own (``netOffset`` already applied by
netconvert), which are also the coordinates SUMO reports for vehicles.

What becomes what:

- **Lanes**: every lane, normal or internal (inside a junction), that admits at least one *road*
  vehicle class. Lanes only for pedestrians (sidewalks, crossings, walking areas), rail, ships or
  aircraft are left out (``include_non_road=True`` keeps them, typed ``UNDEFINED``). Lane ids are
  the SUMO lane ids.
- **lane_type**: ``BIKE_LANE`` when bicycles are the only road class allowed (pedestrians may share
  it); ``FREEWAY`` when the edge type names a motorway / freeway / expressway, or the lane's speed
  limit is >= 80 km/h; else ``SURFACE_STREET``. Internal lanes take the type of the lane that
  feeds them (a motorway ramp's junction lane stays FREEWAY).
- **speed_limit**: the lane's ``speed`` [m/s]; **width**: the lane's width [m].
- **is_junction**: True for internal lanes (ids starting with ``:``).
- **successors / predecessors**: from the connections; a connection with a ``via`` internal lane
  links from-lane -> via lane -> ... -> to-lane, so topology runs through junctions. A net built
  with ``--no-internal-links`` links from-lane -> to-lane directly.
- **left / right neighbours**: lanes of the same edge; in SUMO lane index + 1 is the lane to the
  left.
- **junctions**: the junction polygons (``<junction shape=...>``, internal junctions left out).
- **crosswalks**: pedestrian crossings (``function="crossing"`` lanes) as rectangles.
- **road_edges**: the right border of every normal edge, and its left border when no edge runs
  the opposite way between the same nodes (kind 1 = WOMD ``TYPE_ROAD_EDGE_BOUNDARY``).
- **road_lines**: borders between adjacent lanes of an edge (kind 1 = ``TYPE_BROKEN_SINGLE_WHITE``)
  and the centre line of a two-way road, once per edge pair (kind 7 = ``TYPE_SOLID_DOUBLE_YELLOW``).

Traffic lights: :func:`signal_links` lists, per traffic light, its links
``(link_index, from_lane, to_lane, via_lane)``; index ``i`` of a red-yellow-green state string is
the state of every link with ``link_index == i``.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.core.scene import Lanes, LaneType, Polylines, Ragged, RoadMap
from coster_sumo.errors import InputError, not_found
from coster_sumo.formats.sumocfg import check_xml
from coster_sumo.infra.sumo_install import import_sumolib

FREEWAY_MIN_SPEED_MPS = 80.0 / 3.6  # [m/s] lanes at least this fast count as freeway
_FREEWAY_TYPE = re.compile(r"motorway|freeway|expressway|autobahn", re.IGNORECASE)

# Classes that do not drive on roads: a lane that admits only these is not a lane for us.
NON_ROAD_CLASSES = frozenset({
    "pedestrian", "wheelchair", "tram", "rail_urban", "rail", "rail_electric", "rail_fast", "subway",
    "cable_car", "ship", "aircraft", "drone", "container",
})
_BIKE_ONLY = frozenset({"bicycle"})

ROAD_EDGE_BOUNDARY = 1  # WOMD RoadEdge TYPE_ROAD_EDGE_BOUNDARY
ROAD_LINE_BROKEN_SINGLE_WHITE = 1  # WOMD RoadLine types
ROAD_LINE_SOLID_DOUBLE_YELLOW = 7


@dataclass(frozen=True, slots=True)
class SignalLink:
    """One traffic-light-controlled connection.

    Attributes:
        tls_id: the traffic light.
        link_index: index into the traffic light's red-yellow-green state string.
        from_lane: the incoming lane (ends at the stop line).
        to_lane: the lane after the junction.
        via_lane: the first internal lane of the connection ("" in nets without internal lanes).
    """

    tls_id: str
    link_index: int
    from_lane: str
    to_lane: str
    via_lane: str


@dataclass(frozen=True, slots=True)
class SumoNet:
    """A converted network: the map, the signal links, and where it came from.

    Attributes:
        path: the ``.net.xml``.
        road_map: the map in our types.
        signal_links: ``{tls_id: [SignalLink, ...]}`` sorted by link index.
        location_offset: (2,) float64 [m] SUMO's ``netOffset`` (net = original + offset).
    """

    path: Path
    road_map: RoadMap
    signal_links: dict[str, list[SignalLink]]
    location_offset: np.ndarray


def read_sumolib_net(path: str | Path) -> Any:
    """``sumolib.net.readNet(path, withInternal=True)`` with a one-line error naming the file."""
    path = Path(path)
    if not path.is_file():
        raise not_found(path)
    # well-formed, and no entity declarations (XML bombs) before sumolib's own SAX parser sees it
    check_xml(path, "SUMO net")
    sumolib = import_sumolib()
    try:
        return sumolib.net.readNet(str(path), withInternal=True)
    except Exception as exc:  # xml.sax.SAXParseException and friends
        msg = " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(f"{path}: not a readable SUMO net ({msg})") from None


def _is_road_lane(permissions: Iterable[str]) -> bool:
    return any(c not in NON_ROAD_CLASSES for c in permissions)


def _own_lane_type(edge: Any, lane: Any) -> LaneType:
    road = {c for c in lane.getPermissions() if c not in NON_ROAD_CLASSES}
    if not road:
        return LaneType.UNDEFINED
    if road == _BIKE_ONLY:
        return LaneType.BIKE_LANE
    if _FREEWAY_TYPE.search(edge.getType() or "") or lane.getSpeed() >= FREEWAY_MIN_SPEED_MPS - 1e-9:
        return LaneType.FREEWAY
    return LaneType.SURFACE_STREET


def offset_polyline(points: np.ndarray, distance: float) -> np.ndarray:
    """Shift a polyline sideways by ``distance`` [m] (positive = to the left of its direction).

    Args:
        points: (n, 2) float64 [m], n >= 2.
    Returns:
        (m, 2) float64 [m], m <= n (repeated points dropped); interior vertices move along the
        bisector so that the segments stay parallel to the input's.
    """
    pts = np.asarray(points, dtype=np.float64)
    keep = np.concatenate([[True], np.any(np.abs(np.diff(pts, axis=0)) > 1e-9, axis=1)])
    if keep.sum() < 2:
        return pts.copy()
    pts = pts[keep]  # repeated points have no direction
    seg = np.diff(pts, axis=0)  # (n-1, 2)
    norm = np.linalg.norm(seg, axis=1, keepdims=True)
    seg = np.divide(seg, norm, out=np.zeros_like(seg), where=norm > 1e-12)
    left = np.stack([-seg[:, 1], seg[:, 0]], axis=1)  # (n-1, 2) unit left normals
    vn = np.empty_like(pts)
    vn[0], vn[-1] = left[0], left[-1]
    if len(pts) > 2:
        bis = left[:-1] + left[1:]  # (n-2, 2)
        cos_half = np.einsum("ij,ij->i", bis, left[1:]) / np.maximum(np.linalg.norm(bis, axis=1), 1e-12)
        bis_len = np.linalg.norm(bis, axis=1, keepdims=True)
        unit = np.divide(bis, bis_len, out=left[1:].copy(), where=bis_len > 1e-12)
        # miter length 1/cos(half angle), capped so hairpins do not shoot off
        vn[1:-1] = unit / np.clip(cos_half, 0.25, None)[:, None]
    return pts + distance * vn


def _crossing_polygon(shape: np.ndarray, width: float) -> np.ndarray:
    if len(shape) < 2:
        return shape
    left = offset_polyline(shape, 0.5 * width)
    right = offset_polyline(shape, -0.5 * width)
    return np.concatenate([right, left[::-1]])


def _map_lanes(net: Any, include_non_road: bool) -> tuple[list[Any], list[np.ndarray]]:
    """The sumolib lanes the map holds, in map order, and the crosswalk polygons."""
    lanes: list[Any] = []
    crosswalks: list[np.ndarray] = []
    for edge in net.getEdges(withInternal=True):
        func = edge.getFunction()
        if func == "crossing":
            for lane in edge.getLanes():
                crosswalks.append(_crossing_polygon(np.asarray(lane.getShape(), np.float64), lane.getWidth()))
            if not include_non_road:
                continue
        if func == "walkingarea" and not include_non_road:
            continue
        for lane in edge.getLanes():
            if include_non_road or _is_road_lane(lane.getPermissions()):
                lanes.append(lane)
    return lanes, crosswalks


def _links(lanes: list[Any], index: dict[str, int]) -> tuple[list[list[int]], list[list[int]]]:
    """Successors and predecessors of every lane (through the internal lane of a connection)."""
    succ: list[list[int]] = [[] for _ in lanes]
    pred: list[list[int]] = [[] for _ in lanes]
    for i, lane in enumerate(lanes):
        for conn in lane.getOutgoing():
            target = conn.getViaLaneID() or conn.getToLane().getID()
            j = index.get(target)
            if j is not None and j not in succ[i]:
                succ[i].append(j)
                pred[j].append(i)
    return succ, pred


def _lane_types(lanes: list[Any], pred: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    """The type of every lane (int8) and whether it is a junction's internal lane (bool)."""
    lane_type = np.zeros(len(lanes), np.int8)
    is_junction = np.zeros(len(lanes), bool)
    for i, lane in enumerate(lanes):
        edge = lane.getEdge()
        is_junction[i] = edge.getFunction() == "internal"
        lane_type[i] = _own_lane_type(edge, lane)
    # internal lanes inherit the type of what feeds them (chains of internal lanes: repeat)
    types = lane_type.tolist()
    undefined, bike = int(LaneType.UNDEFINED), int(LaneType.BIKE_LANE)
    inner = [int(i) for i in np.flatnonzero(is_junction) if types[i] != bike]
    for _ in range(4):
        changed = False
        for i in inner:
            feeders = [types[p] for p in pred[i] if types[p] != undefined]
            if feeders:
                new = max(feeders, key=feeders.count)
                changed |= new != types[i]
                types[i] = new
        if not changed:
            break
    return np.array(types, np.int8), is_junction


def _neighbours(lanes: list[Any], index: dict[str, int]) -> tuple[list[list[int]], list[list[int]]]:
    """The lane left and the lane right of every lane on its edge (where the map holds them)."""
    left: list[list[int]] = [[] for _ in lanes]
    right: list[list[int]] = [[] for _ in lanes]
    for i, lane in enumerate(lanes):
        edge_lanes = lane.getEdge().getLanes()
        k = lane.getIndex()
        if k + 1 < len(edge_lanes) and edge_lanes[k + 1].getID() in index:
            left[i].append(index[edge_lanes[k + 1].getID()])
        if k >= 1 and edge_lanes[k - 1].getID() in index:
            right[i].append(index[edge_lanes[k - 1].getID()])
    return left, right


def sumo_net_to_road_map(net: Any, *, include_non_road: bool = False) -> tuple[RoadMap, list[Any]]:
    """Convert a sumolib net (read with internal lanes) to a :class:`RoadMap`.

    Returns the map and the sumolib lane objects in map order (lane ``i`` <-> ``lanes[i]``).
    """
    lanes, crosswalks = _map_lanes(net, include_non_road)
    index = {lane.getID(): i for i, lane in enumerate(lanes)}
    succ, pred = _links(lanes, index)
    lane_type, is_junction = _lane_types(lanes, pred)
    left, right = _neighbours(lanes, index)
    shapes = [np.asarray(lane.getShape(), np.float64).reshape(-1, 2) for lane in lanes]
    lanes_out = Lanes(
        ids=np.array([lane.getID() for lane in lanes], dtype=str),
        centerline=Ragged.from_list(shapes, np.float64, (2,)),
        width=np.array([lane.getWidth() for lane in lanes], np.float64),
        lane_type=lane_type,
        speed_limit=np.array([lane.getSpeed() for lane in lanes], np.float64),
        is_junction=is_junction,
        predecessors=Ragged.from_list([np.array(p, np.int64) for p in pred], np.int64),
        successors=Ragged.from_list([np.array(s, np.int64) for s in succ], np.int64),
        left_neighbors=Ragged.from_list([np.array(v, np.int64) for v in left], np.int64),
        right_neighbors=Ragged.from_list([np.array(v, np.int64) for v in right], np.int64),
    )

    junctions = [np.asarray(node.getShape(), np.float64).reshape(-1, 2) for node in net.getNodes()
                 if node.getType() != "internal" and len(node.getShape()) >= 3]
    road_edges, road_lines, line_kinds = _borders(net, include_non_road)
    road_map = RoadMap(
        lanes=lanes_out,
        road_lines=Polylines(points=Ragged.from_list(road_lines, np.float64, (2,)),
                             kind=np.array(line_kinds, np.int8)),
        road_edges=Polylines(points=Ragged.from_list(road_edges, np.float64, (2,)),
                             kind=np.full(len(road_edges), ROAD_EDGE_BOUNDARY, np.int8)),
        crosswalks=Polylines(points=Ragged.from_list(crosswalks, np.float64, (2,)),
                             kind=np.zeros(len(crosswalks), np.int8)),
        junctions=Polylines(points=Ragged.from_list(junctions, np.float64, (2,)),
                            kind=np.zeros(len(junctions), np.int8)),
    )
    return road_map, lanes


def _borders(net: Any, include_non_road: bool) -> tuple[list[np.ndarray], list[np.ndarray], list[int]]:
    """Road edges and lane lines of the normal edges (see the module docstring)."""
    edges: list[np.ndarray] = []
    lines: list[np.ndarray] = []
    kinds: list[int] = []
    pairs = {(e.getFromNode().getID(), e.getToNode().getID()) for e in net.getEdges(withInternal=False)}
    centre_done: set[frozenset[str]] = set()
    for edge in net.getEdges(withInternal=False):
        road = [ln for ln in edge.getLanes() if include_non_road or _is_road_lane(ln.getPermissions())]
        if not road:
            continue
        shapes = [np.asarray(ln.getShape(), np.float64) for ln in road]
        if any(len(s) < 2 for s in shapes):
            continue
        edges.append(offset_polyline(shapes[0], -0.5 * road[0].getWidth()))
        for lane, shape in zip(road[:-1], shapes[:-1], strict=True):  # left border of all but the last
            lines.append(offset_polyline(shape, 0.5 * lane.getWidth()))
            kinds.append(ROAD_LINE_BROKEN_SINGLE_WHITE)
        left_border = offset_polyline(shapes[-1], 0.5 * road[-1].getWidth())
        fr, to = edge.getFromNode().getID(), edge.getToNode().getID()
        if (to, fr) in pairs:
            key = frozenset((fr, to))
            if key not in centre_done:
                centre_done.add(key)
                lines.append(left_border)
                kinds.append(ROAD_LINE_SOLID_DOUBLE_YELLOW)
        else:
            edges.append(left_border)
    return edges, lines, kinds


def signal_links(net: Any) -> dict[str, list[SignalLink]]:
    """``{tls_id: [SignalLink, ...]}`` for every traffic light, sorted by link index.

    Includes links of lanes that are not in the map (e.g. pedestrian crossings), so that the
    list covers the whole state string.
    """
    out: dict[str, list[SignalLink]] = {}
    for edge in net.getEdges(withInternal=True):
        for lane in edge.getLanes():
            for conn in lane.getOutgoing():
                tls = conn.getTLSID()
                if tls and conn.getTLLinkIndex() >= 0:
                    out.setdefault(tls, []).append(SignalLink(
                        tls_id=tls, link_index=int(conn.getTLLinkIndex()), from_lane=lane.getID(),
                        to_lane=conn.getToLane().getID(), via_lane=conn.getViaLaneID() or ""))
    for links in out.values():
        links.sort(key=lambda s: (s.link_index, s.from_lane, s.to_lane))
    return out


def read_sumo_net(path: str | Path, *, include_non_road: bool = False) -> SumoNet:
    """Read and convert a ``.net.xml`` (no caching; see :func:`load_sumo_net`)."""
    path = Path(path)
    net = read_sumolib_net(path)
    road_map, _ = sumo_net_to_road_map(net, include_non_road=include_non_road)
    return SumoNet(path=path, road_map=road_map, signal_links=signal_links(net),
                   location_offset=np.asarray(net.getLocationOffset(), np.float64))


@functools.lru_cache(maxsize=16)
def _cached(path: str, mtime_ns: int, size: int, include_non_road: bool) -> SumoNet:
    return read_sumo_net(path, include_non_road=include_non_road)


def load_sumo_net(path: str | Path, *, include_non_road: bool = False) -> SumoNet:
    """Like :func:`read_sumo_net`, cached per file (a changed file is read again).

    The result is shared between callers: its arrays must be treated as read-only.
    """
    path = Path(path).resolve()
    if not path.is_file():
        raise not_found(path)
    st = path.stat()
    return _cached(str(path), st.st_mtime_ns, st.st_size, include_non_road)

