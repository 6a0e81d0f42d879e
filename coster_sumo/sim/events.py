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

import math
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


def _sat_gap(ax: float, ay: float, ayaw: float, alen: float, awid: float,
             bx: float, by: float, byaw: float, blen: float, bwid: float) -> float:
    """Largest separation [m] of two oriented boxes along their four axes (< 0: overlapping)."""
    ac, as_, bc, bs = math.cos(ayaw), math.sin(ayaw), math.cos(byaw), math.sin(byaw)
    dx, dy = bx - ax, by - ay
    ahl, ahw, bhl, bhw = 0.5 * alen, 0.5 * awid, 0.5 * blen, 0.5 * bwid
    cc, cs = ac * bc + as_ * bs, as_ * bc - ac * bs  # cos and sin of the heading difference
    ec, es = abs(cc), abs(cs)
    return max(abs(dx * ac + dy * as_) - ahl - bhl * ec - bhw * es,   # a's longitudinal axis
               abs(-dx * as_ + dy * ac) - ahw - bhl * es - bhw * ec,  # a's lateral axis
               abs(dx * bc + dy * bs) - bhl - ahl * ec - ahw * es,    # b's longitudinal axis
               abs(-dx * bs + dy * bc) - bhw - ahl * es - ahw * ec)   # b's lateral axis


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
    """Stateful per-step detector for one injection pass.

    The adversary's collisions are decided at the step they happen (its controller reacts to
    contact). Everything nothing reacts to during a pass (the target's collisions with other
    vehicles, off-road for both) is queued and evaluated ``batch`` steps at a time, vectorised over
    the batch: a few numpy calls and one shapely call instead of that many per step. Queued events
    carry the time of the step they started and are returned by the :meth:`check` call that closes
    the batch, or by :meth:`flush` (call it at the end). ``batch=1`` reports every event at once.
    """

    def __init__(self, target_id: str, adversary_id: str, drivable: DrivableArea | None,
                 batch: int = 1) -> None:
        self.target_id = target_id
        self.adversary_id = adversary_id
        self.drivable = drivable
        self.batch = max(1, int(batch))
        self._active: set[tuple[str, ...]] = set()  # live pairs (adversary, SUMO's list) in contact
        self._tgt_active: set[tuple[str, ...]] = set()  # queued target pairs in contact
        self._off_active: set[str] = set()
        self._off_last: dict[str, int] = {}  # step index of each reference's last off-road check
        self._queue: list[tuple[int, float, VehicleStates, list[str]]] = []
        self._step = 0
        self.last_ids: list[str] = []  # the ids of the last checked step, in state order
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

    @staticmethod
    def _in_contact(s: VehicleStates, i: int, j: int) -> bool:
        """Boxes ``i`` and ``j`` within ``CONTACT_TOLERANCE_M``: scalar SAT first, exact distance if unsure.

        The largest gap along the four box axes is a lower bound of the Euclidean gap, and <= 0
        exactly when the boxes overlap; only a gap in (0, tolerance] needs the exact distance.
        """
        gap = _sat_gap(float(s.x[i]), float(s.y[i]), float(s.yaw[i]), float(s.length[i]), float(s.width[i]),
                       float(s.x[j]), float(s.y[j]), float(s.yaw[j]), float(s.length[j]), float(s.width[j]))
        if gap > CONTACT_TOLERANCE_M:
            return False
        if gap <= 0.0:
            return True
        a = make_boxes(s.x[i], s.y[i], s.yaw[i], s.length[i], s.width[i])
        b = make_boxes(s.x[j], s.y[j], s.yaw[j], s.length[j], s.width[j])
        return bool(box_signed_distance(a, b) <= CONTACT_TOLERANCE_M)

    def _pairs_in_contact(self, time: float, s: VehicleStates, ids: list[str], r: int,
                          skip: str | None, active: set[tuple[str, ...]], now: set[tuple[str, ...]],
                          cand: list[int]) -> list[Event]:
        """Contact of reference ``r`` with the candidate rows; new events for pairs not in ``active``."""
        out: list[Event] = []
        for j in cand:
            if j == r or ids[j] == skip or not self._in_contact(s, r, j):
                continue
            key = ("collision", *sorted((ids[r], ids[j])))
            if key not in active and key not in now:
                out.append(self._collision_event(time, s, r, j, "collision"))
            now.add(key)
        return out

    def check(self, time: float, states: VehicleStates, sumo_collisions: list[dict] | None = None
              ) -> list[Event]:
        """Check one step; return (and keep) the events found now.

        Those are the adversary's collisions and SUMO's list at this step and, when this step
        closes a batch, the queued target collisions and off-road events of the batch.
        """
        new: list[Event] = []
        now: set[tuple[str, ...]] = set()
        ids = states.ids.tolist()
        self.last_ids = ids
        if self.adversary_id in ids:
            r = ids.index(self.adversary_id)
            xr, yr = float(states.x[r]), float(states.y[r])
            # bounding circles can meet (self too): one radius for all others, the largest now
            reach = 0.5 * (math.hypot(states.length.max(), states.width.max())
                           + math.hypot(states.length[r], states.width[r])) + CONTACT_TOLERANCE_M
            cand = np.flatnonzero(np.hypot(states.x - xr, states.y - yr) < reach)
            if len(cand) > 1:
                new.extend(self._pairs_in_contact(time, states, ids, r, None, self._active, now, cand.tolist()))
        for c in sumo_collisions or ():
            a, b = str(c.get("collider", "")), str(c.get("victim", ""))
            key = ("sumo_collision", *sorted((a, b)))
            now.add(key)
            if key in self._active:
                continue
            i = ids.index(a) if a in ids else -1
            j = ids.index(b) if b in ids else -1
            if i >= 0 and j >= 0:
                ev = self._collision_event(time, states, i, j, "sumo_collision",
                                           {"type": c.get("type", ""), "lane": c.get("lane", "")})
            else:
                ev = Event(time=float(time), kind="sumo_collision", vehicles=[a, b], positions=[],
                           detail={"type": c.get("type", ""), "lane": c.get("lane", "")})
            new.append(ev)
        self._active = now
        self._queue.append((self._step, float(time), states, ids))
        self._step += 1
        if len(self._queue) >= self.batch:
            new.extend(self._flush_queue())
        self.events.extend(new)
        return new

    def _flush_queue(self) -> list[Event]:
        """Evaluate the queued steps: target collisions (not with the adversary), then off-road."""
        queue, self._queue = self._queue, []
        rows = [(k, ids.index(self.target_id)) for k, (_, _, _, ids) in enumerate(queue) if self.target_id in ids]
        out: list[Event] = []
        if rows:
            # one vectorised bounding-circle prefilter over every vehicle of every queued step
            st = [queue[k][2] for k, _ in rows]
            sizes = [len(s.ids) for s in st]
            x = np.concatenate([s.x for s in st])
            y = np.concatenate([s.y for s in st])
            diam = np.hypot(np.concatenate([s.length for s in st]), np.concatenate([s.width for s in st]))
            start = np.concatenate([[0], np.cumsum(sizes)[:-1]])
            ref = start + np.array([r for _, r in rows])
            rep = np.repeat(np.arange(len(rows)), sizes)
            dx, dy = x - x[ref][rep], y - y[ref][rep]
            reach = 0.5 * (diam + diam[ref][rep]) + CONTACT_TOLERANCE_M
            near = dx * dx + dy * dy < reach * reach
            counts = np.add.reduceat(near, start)
            busy = counts > 1  # the target itself is always counted
            row_of = {k: m for m, (k, _) in enumerate(rows)}
            for k, (_step, t, s, ids) in enumerate(queue):  # in step order: episodes span steps
                m = row_of.get(k, -1)
                if m < 0 or not busy[m]:
                    self._tgt_active = set()
                    continue
                cand = np.flatnonzero(near[start[m]:start[m] + sizes[m]]).tolist()
                now: set[tuple[str, ...]] = set()
                out.extend(self._pairs_in_contact(t, s, ids, rows[m][1], self.adversary_id, self._tgt_active,
                                                  now, cand))
                self._tgt_active = now
        else:
            self._tgt_active = set()
        if self.drivable is not None:
            out.extend(self._off_road(queue))
        return out

    def _off_road(self, queue: list[tuple[int, float, VehicleStates, list[str]]]) -> list[Event]:
        """Off-road of the adversary and the target over the queued steps (one shapely call)."""
        assert self.drivable is not None
        pending: list[tuple[int, float, str, int, VehicleStates]] = []
        for step, t, s, ids in queue:
            for vid in (self.adversary_id, self.target_id):
                if vid in ids:
                    pending.append((step, t, vid, ids.index(vid), s))
        if not pending:
            return []
        cx = np.array([s.x[r] for *_, r, s in pending])
        cy = np.array([s.y[r] for *_, r, s in pending])
        yaw = np.array([s.yaw[r] for *_, r, s in pending])
        length = np.array([s.length[r] for *_, r, s in pending])
        width = np.array([s.width[r] for *_, r, s in pending])
        area = self.drivable.outside_area(cx, cy, yaw, length, width).tolist()
        out: list[Event] = []
        for k, (step, t, vid, _r, _s) in enumerate(pending):
            if self._off_last.get(vid, -2) != step - 1:  # absent for a step: a new episode
                self._off_active.discard(vid)
            self._off_last[vid] = step
            if area[k] > self.drivable.tolerance_m2:
                if vid not in self._off_active:
                    out.append(Event(time=t, kind="off_road", vehicles=[vid],
                                     positions=[[float(cx[k]), float(cy[k])]],
                                     detail={"area_outside_m2": float(area[k])}))
                self._off_active.add(vid)
            else:
                self._off_active.discard(vid)
        return out

    def flush(self) -> list[Event]:
        """Evaluate the queued steps now; return (and keep) their events. Call at the end of a pass."""
        new = self._flush_queue()
        self.events.extend(new)
        self.events.sort(key=lambda e: e.time)  # stable: same-step order kept
        return new

    def first(self, kind: str, a: str, b: str | None = None) -> Event | None:
        """The first event of ``kind`` involving ``a`` (and ``b`` when given)."""
        for e in self.events:
            if e.kind == kind and a in e.vehicles and (b is None or b in e.vehicles):
                return e
        return None
