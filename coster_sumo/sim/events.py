"""Per-step event detection: collisions (our box check and SUMO's list) and off-road.

Our oriented-box check (separating axes, :mod:`coster_sumo.geometry`) is the ground truth: SUMO's
own check is lane-based and misses lateral and cross-edge overlaps (SUMO_FACTS §4). SUMO's list is
logged beside it as ``sumo_collision`` events. Only pairs that involve the adversary or the target
are checked (two rows of the pairwise matrix), vectorised over all other vehicles.

Two boxes are in contact when their signed distance is at most ``CONTACT_TOLERANCE_M`` (5 cm, the
tolerance a collision snapshot is placed with), so touching at t_col counts. An event is reported
once when it starts; a pair that separates and overlaps again is a new
event. Off-road is checked for the adversary and the target only (footprint against the drivable
area, :class:`coster_sumo.drivable.DrivableArea`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from coster_sumo.drivable import DrivableArea
from coster_sumo.geometry import box_signed_distance, make_boxes
from coster_sumo.metrics import impact_angle_deg
from coster_sumo.sim.session import VehicleStates

CONTACT_TOLERANCE_M = 0.05  # [m] boxes closer than this are in contact (the snapshot's own tolerance)


def _index(states: VehicleStates, vid: str) -> int:
    hit = np.flatnonzero(states.ids == vid)
    return int(hit[0]) if len(hit) else -1


def _velocity(states: VehicleStates, i: int) -> np.ndarray:
    return states.speed[i] * np.array([np.cos(states.yaw[i]), np.sin(states.yaw[i])])


@dataclass
class Event:
    """One logged event (user-facing units: seconds, metres, degrees).

    Attributes:
        time: [s] simulation time.
        kind: "collision" (our box check), "sumo_collision" (SUMO's list) or "off_road".
        vehicles: the vehicle ids involved (reference vehicle first: the target when involved).
        positions: [[x, y], ...] centres [m] in the same order.
        relative_speed: [m/s] |v_a - v_b| (collisions), 0 for off-road.
        impact_angle: [deg] the other vehicle's position in the first vehicle's frame (collisions).
        detail: free-form extra data (SUMO's collision type, area off the road...).
    """

    time: float
    kind: str
    vehicles: list[str]
    positions: list[list[float]]
    relative_speed: float = 0.0
    impact_angle: float = 0.0
    detail: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return asdict(self)


class EventDetector:
    """Stateful per-step detector for one injection pass."""

    def __init__(self, target_id: str, adversary_id: str, drivable: DrivableArea | None) -> None:
        self.target_id = target_id
        self.adversary_id = adversary_id
        self.drivable = drivable
        self._active: set[tuple[str, ...]] = set()
        self.events: list[Event] = []

    def _order(self, s: VehicleStates, i: int, j: int) -> tuple[int, int]:
        """Reference vehicle first: the target when involved, else the adversary."""
        for ref in (self.target_id, self.adversary_id):
            if s.ids[j] == ref and s.ids[i] != ref:
                return j, i
            if s.ids[i] == ref:
                return i, j
        return i, j

    def _collision_event(self, time: float, s: VehicleStates, i: int, j: int, kind: str,
                         detail: dict | None = None) -> Event:
        i, j = self._order(s, i, j)
        vi, vj = _velocity(s, i), _velocity(s, j)
        angle = impact_angle_deg(np.array([s.x[i], s.y[i]]), s.yaw[i], np.array([s.x[j], s.y[j]]))
        return Event(time=float(time), kind=kind, vehicles=[str(s.ids[i]), str(s.ids[j])],
                     positions=[[float(s.x[i]), float(s.y[i])], [float(s.x[j]), float(s.y[j])]],
                     relative_speed=float(np.linalg.norm(vi - vj)), impact_angle=float(angle),
                     detail=detail or {})

    def check(self, time: float, states: VehicleStates, sumo_collisions: list[dict] | None = None
              ) -> list[Event]:
        """Check one step; return (and keep) the events that start at this step."""
        new: list[Event] = []
        now: set[tuple[str, ...]] = set()
        refs = [(ref, _index(states, ref)) for ref in (self.adversary_id, self.target_id)]
        refs = [(ref, r) for ref, r in refs if r >= 0]
        if refs:
            rows = np.array([r for _, r in refs])
            # bounding-circle prefilter: only vehicles whose circles meet a reference's go to SAT
            radius = 0.5 * np.hypot(states.length, states.width)  # (N,)
            dx = states.x[None, :] - states.x[rows, None]
            dy = states.y[None, :] - states.y[rows, None]
            near = dx * dx + dy * dy < (radius[None, :] + radius[rows, None]) ** 2  # (R, N)
            near[np.arange(len(rows)), rows] = False
            for (_ref, r), cand in zip(refs, near, strict=True):
                idx = np.flatnonzero(cand)
                if not len(idx):
                    continue
                a_box = make_boxes(states.x[r], states.y[r], states.yaw[r], states.length[r], states.width[r])
                b_box = make_boxes(states.x[idx], states.y[idx], states.yaw[idx], states.length[idx],
                                   states.width[idx])
                for j in idx[box_signed_distance(a_box[None, :], b_box) <= CONTACT_TOLERANCE_M].tolist():
                    key = ("collision", *sorted((str(states.ids[r]), str(states.ids[j]))))
                    if key not in self._active and key not in now:  # adversary-target is seen twice
                        new.append(self._collision_event(time, states, r, j, "collision"))
                    now.add(key)
            if self.drivable is not None:
                out = self.drivable.outside_area(states.x[rows], states.y[rows], states.yaw[rows],
                                                 states.length[rows], states.width[rows])  # one shapely call
                for (ref, r), area in zip(refs, out.tolist(), strict=True):
                    if area > self.drivable.tolerance_m2:
                        key = ("off_road", ref)
                        now.add(key)
                        if key not in self._active:
                            new.append(Event(time=float(time), kind="off_road", vehicles=[ref],
                                             positions=[[float(states.x[r]), float(states.y[r])]],
                                             detail={"area_outside_m2": float(area)}))
        for c in sumo_collisions or ():
            a, b = str(c.get("collider", "")), str(c.get("victim", ""))
            key = ("sumo_collision", *sorted((a, b)))
            now.add(key)
            if key in self._active:
                continue
            i, j = _index(states, a), _index(states, b)
            if i >= 0 and j >= 0:
                ev = self._collision_event(time, states, i, j, "sumo_collision",
                                           {"type": c.get("type", ""), "lane": c.get("lane", "")})
            else:
                ev = Event(time=float(time), kind="sumo_collision", vehicles=[a, b], positions=[],
                           detail={"type": c.get("type", ""), "lane": c.get("lane", "")})
            new.append(ev)
        self._active = now
        self.events.extend(new)
        return new

    def first(self, kind: str, a: str, b: str | None = None) -> Event | None:
        """The first event of ``kind`` involving ``a`` (and ``b`` when given)."""
        for e in self.events:
            if e.kind == kind and a in e.vehicles and (b is None or b in e.vehicles):
                return e
        return None
