"""The FCD file of a SUMO export: every replayed vehicle's recorded states as SUMO's FCD replay
device reads them (``traj.fcd.xml``), and the vTypes it names (``fcd_vtypes.add.xml``).

The export folder around it is :mod:`coster_sumo.exports.sumo`.

Source: the injection pass's recording (:attr:`InjectionResult.scene`: one state per simulation
step; box centre, heading, speed, size). It is what the pass did: the adversary on its plan up to
its first contact and frozen as a wreck at the contact pose after it
(:class:`~coster_sumo.sim.inject.AdversaryController`), the replayed target, and only what the pass
showed (agents parked on a converted net's staging lane are never recorded). Frames are converted
with :mod:`coster_sumo.geometry.frames`.

Device behaviour that shapes the file (measured on SUMO 1.28, see ``docs/sumo.md §11``):

- time: the entry labelled ``L`` is the pose the vehicle has in SUMO's FCD output labelled ``L``,
  i.e. after the step that starts at ``L``; libsumo's time after that step is ``L + dt``. A state
  recorded at simulation time ``T`` is therefore written with the label ``T - dt``.
- insertion: a vehicle's first entry only inserts it (on its lane, at the lane centre, along the
  lane); exact placement starts with its second entry. Each vehicle gets one **staging entry** one
  step before its first recorded state, at its first pose on the nearest lane it may use, so it
  enters where it appears (not on a converted net's staging lane, from which every replayed vehicle
  would jump onto the map one step later: 273 of 379 in a WOMD sample did).
- a blocked insertion delays the vehicle and its whole trajectory (entries are played in order):
  the export sets ``insertion-checks`` to ``none`` for the device's vehicles and keeps the pass's
  checks on every element of the copied demand (:mod:`coster_sumo.exports.demand`).
- after its last entry a vehicle is SUMO's again and drives on at its last speed. In a converted
  scene a vehicle whose recording ends early (the log lost it) gets one more entry that parks it on
  the staging lane at speed 0; ``fcd-output.filter-edges.input-file`` keeps the staging lane out
  of any FCD output, so parking does not show up there.
- placement: an entry with a ``lane`` attribute is placed exactly (moveToXY keepRoute 7: x, y and
  lateral offset as given, also off the road); without one the device snaps the vehicle to the lane
  centre unless the sublane model is on, and aborts the run at a position more than 100 m from every
  lane. Every entry therefore names its nearest lane outside junctions (any class), and SUMO's
  models stay those of the pass (no sublane model). The device routes the vehicle along the edges
  its entries name (junction-internal ones skipped) and SUMO puts it on the route lane nearest to
  its position, junction lanes between consecutive route edges included; a vehicle whose route
  holds no lane of the map would count as off the network and drop out of filtered FCD output.
- ``type=`` must name a vType loaded before the device reads the file: the per-vehicle vTypes
  (recorded size, class, shape) are the first additional file of the configuration.
"""

from __future__ import annotations

import functools
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely

from coster_sumo.core.scene import Scene
from coster_sumo.errors import InputError
from coster_sumo.formats.scene_folder import MIN_SIZE_M, vtype_for
from coster_sumo.formats.sumo_net import read_sumolib_net
from coster_sumo.geometry import frames
from coster_sumo.sim.replay import STAGING_SPACING_M

FCD_FILE = "traj.fcd.xml"
VTYPES_FILE = "fcd_vtypes.add.xml"
VTYPE_SUFFIX = "@fcd"  # vType id of an FCD vehicle: "<vehicle id>@fcd"
MAX_SPEED_MPS = 100.0  # [m/s] vType maxSpeed: no recorded speed is capped
TIME_EPS_S = 1e-6  # [s]


@dataclass(frozen=True)
class LaneIndex:
    """The lanes of a SUMO net for nearest-lane queries.

    Attributes:
        ids: (L,) SUMO lane ids, internal (junction) lanes included.
        edges: (L,) the edge of each lane.
        lines: (L,) shapely LineStrings of the lane shapes [m].
        length: (L,) float64 [m] SUMO lane length (positions along a lane are in this unit).
        internal: (L,) bool, a lane inside a junction.
        permissions: the vehicle classes each lane allows.
    """

    ids: tuple[str, ...]
    edges: tuple[str, ...]
    lines: np.ndarray
    length: np.ndarray
    internal: np.ndarray
    permissions: tuple[frozenset[str], ...]
    seg_lane: np.ndarray = field(repr=False)  # (S,) int64 lane of each tree item (a 2-point segment)
    tree: shapely.STRtree = field(repr=False)  # segments of the lanes outside junctions

    @classmethod
    def read(cls, net_file: Path) -> LaneIndex:
        """Index every lane of ``net_file`` (cached per file version)."""
        path = Path(net_file).resolve()
        st = path.stat()
        return _lane_index(str(path), st.st_mtime_ns, st.st_size)

    def nearest(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(N,) int64 index of the lane outside junctions nearest to each point (x, y) (N,) [m].

        Outside junctions: the device routes a vehicle along the edges its entries name and skips
        junction-internal ones; SUMO then finds the junction lane between two route edges itself.
        """
        pts = shapely.points(np.asarray(x, np.float64), np.asarray(y, np.float64))
        hit = self.tree.query_nearest(pts, all_matches=False)  # (2, N): point index, tree index
        out = np.empty(len(pts), np.int64)
        out[hit[0]] = self.seg_lane[hit[1]]
        return out

    def nearest_for(self, x: float, y: float, vclass: str) -> int:
        """Nearest lane outside junctions that ``vclass`` may use (any lane outside junctions if none)."""
        ok = np.array([not internal and vclass in perm
                       for internal, perm in zip(self.internal, self.permissions, strict=True)])
        if not ok.any():
            ok = ~self.internal
        if not ok.any():
            ok[:] = True
        cand = np.flatnonzero(ok)
        d = shapely.distance(self.lines[cand], shapely.Point(x, y))
        return int(cand[int(np.argmin(d))])

    def lane_pos(self, i: int, x: float, y: float) -> float:
        """[m] position along lane ``i`` of the point nearest to (x, y), in SUMO's lane length."""
        line = self.lines[i]
        geo = float(line.length)
        s = float(line.project(shapely.Point(x, y)))
        return s * float(self.length[i]) / geo if geo > 0 else 0.0

    def slots(self, i: int, spacing: float = STAGING_SPACING_M) -> np.ndarray:
        """(K, 4) x, y [m], lane position [m], SUMO angle [deg] every ``spacing`` m along lane ``i``."""
        line = self.lines[i]
        geo = float(line.length)
        s = np.arange(spacing, geo - spacing + 1e-9, spacing)
        if len(s) == 0:
            return np.zeros((0, 4))
        p = shapely.get_coordinates(shapely.line_interpolate_point(line, s))
        q = shapely.get_coordinates(shapely.line_interpolate_point(line, np.minimum(s + 1.0, geo)))
        yaw = np.arctan2(q[:, 1] - p[:, 1], q[:, 0] - p[:, 0])
        return np.column_stack([p, s * float(self.length[i]) / geo, frames.yaw_to_sumo_angle(yaw)])


@functools.lru_cache(maxsize=8)
def _lane_index(path: str, mtime_ns: int, size: int) -> LaneIndex:
    net = read_sumolib_net(path)
    ids: list[str] = []
    edges: list[str] = []
    lines = []
    length: list[float] = []
    internal: list[bool] = []
    perms: list[frozenset[str]] = []
    for edge in net.getEdges(withInternal=True):
        for lane in edge.getLanes():
            shape = np.asarray(lane.getShape(), np.float64)[:, :2]
            if len(shape) < 2:
                continue
            ids.append(lane.getID())
            edges.append(edge.getID())
            lines.append(shapely.LineString(shape))
            length.append(float(lane.getLength()))
            internal.append(edge.getID().startswith(":"))
            perms.append(frozenset(lane.getPermissions()))
    if not ids:
        raise InputError(f"{path}: the net has no lanes")
    arr = np.empty(len(lines), object)
    arr[:] = lines
    inside = np.array(internal, bool)
    outside = np.flatnonzero(~inside) if (~inside).any() else np.arange(len(ids))
    # one tree item per segment: tight boxes make nearest queries several times faster than whole lanes
    coords = [shapely.get_coordinates(arr[j]) for j in outside]
    segs = np.concatenate([np.stack([c[:-1], c[1:]], axis=1) for c in coords])  # (S, 2, 2)
    seg_lane = np.repeat(outside, [len(c) - 1 for c in coords])
    return LaneIndex(ids=tuple(ids), edges=tuple(edges), lines=arr, length=np.array(length), internal=inside,
                     permissions=tuple(perms), seg_lane=seg_lane, tree=shapely.STRtree(shapely.linestrings(segs)))


@dataclass
class FcdVehicle:
    """One vehicle of the FCD replay file, with its vType.

    Attributes:
        vehicle_id: SUMO id (the recorded one; ``<id>@<k>`` for the k-th later stretch of a recording
            with gaps).
        vclass, gui_shape: SUMO vehicle class and shape of its vType.
        length, width: [m] recorded size.
        color: RGBA 0-255, or None for SUMO's default.
        labels: (N,) float64 [s] FCD time labels: the pose after the step starting at the label,
            i.e. the recorded state at simulation time ``label + dt``.
        x, y: (N,) float64 [m] front-bumper centre.
        angle: (N,) float64 [deg] SUMO angle (0 = north, clockwise).
        speed: (N,) float64 [m/s].
        lane: (N,) lane index (into the :class:`LaneIndex`) each entry names.
        pos: (N,) float64 [m] position along that lane (SUMO reads it for the first entry only).
        staged: the first entry is a staging entry, not a recorded state.
        parked: the last entry parks the vehicle on the staging lane.
    """

    vehicle_id: str
    vclass: str
    gui_shape: str
    length: float
    width: float
    color: tuple[int, int, int, int] | None
    labels: np.ndarray
    x: np.ndarray
    y: np.ndarray
    angle: np.ndarray
    speed: np.ndarray
    lane: np.ndarray
    pos: np.ndarray
    staged: bool = False
    parked: bool = False

    def add_entry(self, at_end: bool, label: float, x: float, y: float, angle: float, speed: float, lane: int,
                  pos: float) -> None:
        """Prepend (``at_end=False``) or append one entry."""

        def cat(arr: np.ndarray, v: float | int) -> np.ndarray:
            return np.append(arr, v) if at_end else np.insert(arr, 0, v)

        self.labels, self.x, self.y = cat(self.labels, label), cat(self.x, x), cat(self.y, y)
        self.angle, self.speed = cat(self.angle, angle), cat(self.speed, speed)
        self.lane, self.pos = cat(self.lane, lane), cat(self.pos, pos)


def _runs(valid: np.ndarray) -> list[tuple[int, int]]:
    """[(first, last)] step indices of every stretch of True in ``valid`` (T,)."""
    d = np.diff(np.concatenate([[0], valid.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), (np.flatnonzero(d == -1) - 1).tolist(), strict=True))


def recorded_vehicles(scene: Scene, ids: list[str], lanes: LaneIndex, step_length: float,
                      colors: dict[str, tuple[int, int, int, int]] | None = None) -> list[FcdVehicle]:
    """The recorded states of ``ids`` as FCD vehicles (no staging or parking entries yet).

    Args:
        scene: a recorded pass (timestamps = simulation time after each step [s]; box centres).
        ids: vehicles to take; ids not in the scene are skipped.
        lanes: the net's lanes (each entry names its nearest lane).
        step_length: [s] the pass's simulation step; labels are ``timestamps - step_length``.
        colors: vType colour per vehicle id.
    """
    tr = scene.tracks
    known = set(tr.ids.tolist())
    speed = tr.speed  # (A, T), computed once
    out: list[FcdVehicle] = []
    for vid in ids:
        if vid not in known:
            continue
        a = tr.index_of(vid)
        v = tr.valid[a]
        if not v.any():
            continue
        length = float(np.median(tr.length[a, v]))
        width = float(np.median(tr.width[a, v]))
        length = length if np.isfinite(length) and length >= MIN_SIZE_M else MIN_SIZE_M
        width = width if np.isfinite(width) and width >= MIN_SIZE_M else MIN_SIZE_M
        _, vclass, shape, _, _ = vtype_for(int(tr.object_type[a]))
        for k, (s0, s1) in enumerate(_runs(v)):
            sl = slice(s0, s1 + 1)
            fx, fy, ang = frames.to_sumo(tr.x[a, sl], tr.y[a, sl], tr.heading[a, sl], length)
            out.append(FcdVehicle(
                vehicle_id=vid if k == 0 else f"{vid}@{k}", vclass=vclass, gui_shape=shape, length=length,
                width=width, color=(colors or {}).get(vid),
                labels=np.round(scene.timestamps[sl] - step_length, 6), x=fx, y=fy, angle=ang,
                speed=np.asarray(speed[a, sl], np.float64), lane=np.zeros(len(fx), np.int64),
                pos=np.full(len(fx), np.nan)))
    if out:  # every entry names its nearest lane (one query for all)
        lanes_all = lanes.nearest(np.concatenate([veh.x for veh in out]), np.concatenate([veh.y for veh in out]))
        splits = np.cumsum([len(veh.x) for veh in out])[:-1]
        for veh, lane in zip(out, np.split(lanes_all, splits), strict=True):
            veh.lane = lane
    return out


def stage_and_park(vehicles: list[FcdVehicle], lanes: LaneIndex, staging_lane: str | None, step_length: float,
                   last_label: float) -> int:
    """Add every vehicle's staging entry and, with a staging lane, park those that end early.

    Staging: one entry at ``labels[0] - step_length``, speed 0, at the vehicle's first pose on the
    nearest lane outside junctions that its class may use: the vehicle enters where it appears.
    Parking: vehicles whose last label is before ``last_label`` get one entry one step later on a
    slot of their own on ``staging_lane`` (slots :data:`~coster_sumo.sim.replay.STAGING_SPACING_M`
    apart), speed 0: after its last entry SUMO would drive a vehicle on (measured on a converted
    WOMD scene: 54 of 379 vehicles, up to 7.1 s beyond their log), and the staging lane, filtered
    out of the FCD output, takes it off the map when the log does. Returns the number of parked
    vehicles.
    """
    park_slots = np.zeros((0, 4))
    lane_i = -1
    if staging_lane is not None and staging_lane in lanes.ids:
        lane_i = lanes.ids.index(staging_lane)
        park_slots = lanes.slots(lane_i)
    for veh in sorted(vehicles, key=lambda v: float(v.labels[0])):
        label = round(float(veh.labels[0]) - step_length, 6)
        x, y = float(veh.x[0]), float(veh.y[0])
        i = lanes.nearest_for(x, y, veh.vclass)
        veh.add_entry(False, label, x, y, float(veh.angle[0]), 0.0, i, lanes.lane_pos(i, x, y))
        veh.staged = True
    parked = 0
    if len(park_slots):
        for veh in sorted(vehicles, key=lambda v: float(v.labels[-1])):
            if float(veh.labels[-1]) < last_label - TIME_EPS_S:
                x, y, pos, ang = park_slots[parked % len(park_slots)]
                veh.add_entry(True, round(float(veh.labels[-1]) + step_length, 6), x, y, ang, 0.0, lane_i, pos)
                veh.parked = True
                parked += 1
    return parked


def _vtype_id(vehicle_id: str) -> str:
    return f"{vehicle_id}{VTYPE_SUFFIX}"


def write_fcd(path: Path, vehicles: list[FcdVehicle], lanes: LaneIndex) -> int:
    """Write the FCD replay file (timesteps in label order); returns the number of entries."""
    rows: list[tuple[float, int, int]] = []  # label, vehicle, entry
    for j, veh in enumerate(vehicles):
        rows.extend((float(t), j, e) for e, t in enumerate(veh.labels))
    rows.sort()
    lines = ['<?xml version="1.0" encoding="UTF-8"?>',
             "<!-- coster-sumo export: read by SUMO's FCD replay device (device.fcd-replay.files); "
             "x, y = front-bumper centre [m], angle [deg clockwise from north], speed [m/s]; "
             "the entry labelled L is the pose after the step starting at L -->",
             "<fcd-export>"]
    current: float | None = None
    for t, j, e in rows:
        if current is None or abs(t - current) > TIME_EPS_S:
            if current is not None:
                lines.append("    </timestep>")
            lines.append(f'    <timestep time="{t:.3f}">')
            current = t
        veh = vehicles[j]
        pos = float(veh.pos[e])
        pos_attr = f' pos="{pos:.3f}"' if np.isfinite(pos) else ""
        lines.append(f'        <vehicle id="{_xml(veh.vehicle_id)}" x="{veh.x[e]:.4f}" y="{veh.y[e]:.4f}" '
                     f'angle="{veh.angle[e]:.4f}" type="{_xml(_vtype_id(veh.vehicle_id))}" '
                     f'speed="{veh.speed[e]:.4f}" lane="{_xml(lanes.ids[int(veh.lane[e])])}"{pos_attr}/>')
    if current is not None:
        lines.append("    </timestep>")
    lines.append("</fcd-export>")
    path.write_text("\n".join(lines) + "\n")
    return len(rows)


def write_vtypes(path: Path, vehicles: list[FcdVehicle]) -> None:
    """One vType per FCD vehicle: its recorded size, class and shape, speeds never capped."""
    root = ET.Element("additional")
    root.append(ET.Comment(" coster-sumo export: the vTypes the FCD file names (loaded before the FCD "
                           "replay device reads it) "))
    for veh in vehicles:
        attrs = {"id": _vtype_id(veh.vehicle_id), "vClass": veh.vclass, "guiShape": veh.gui_shape,
                 "length": f"{veh.length:.4f}", "width": f"{veh.width:.4f}", "maxSpeed": f"{MAX_SPEED_MPS:g}",
                 "speedFactor": "1", "speedDev": "0"}
        if veh.color is not None:
            attrs["color"] = ",".join(str(int(c)) for c in veh.color)
        ET.SubElement(root, "vType", attrs)
    ET.indent(root)
    ET.ElementTree(root).write(path, encoding="unicode", xml_declaration=True)


def _xml(s: str) -> str:
    return s.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;").replace(">", "&gt;")
