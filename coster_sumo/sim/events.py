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
from typing import NamedTuple

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


def _sat_gaps(ax: np.ndarray, ay: np.ndarray, ayaw: np.ndarray, alen: np.ndarray, awid: np.ndarray,
              bx: np.ndarray, by: np.ndarray, byaw: np.ndarray, blen: np.ndarray, bwid: np.ndarray
              ) -> np.ndarray:
    """:func:`_sat_gap` of many pairs at once (arrays broadcast together)."""
    ac, as_, bc, bs = np.cos(ayaw), np.sin(ayaw), np.cos(byaw), np.sin(byaw)
    dx, dy = bx - ax, by - ay
    ahl, ahw, bhl, bhw = 0.5 * alen, 0.5 * awid, 0.5 * blen, 0.5 * bwid
    ec, es = np.abs(ac * bc + as_ * bs), np.abs(as_ * bc - ac * bs)
    gap = np.abs(dx * ac + dy * as_) - ahl - bhl * ec - bhw * es
    np.maximum(gap, np.abs(dy * ac - dx * as_) - ahw - bhl * es - bhw * ec, out=gap)
    np.maximum(gap, np.abs(dx * bc + dy * bs) - bhl - ahl * ec - ahw * es, out=gap)
    np.maximum(gap, np.abs(dy * bc - dx * bs) - bhw - ahl * es - ahw * ec, out=gap)
    return gap


class _Queued(NamedTuple):
    """One step waiting for the batched checks."""

    step: int
    time: float
    states: VehicleStates
    ids: list[str]
    target_row: int  # -1: absent
    adversary_row: int  # -1: absent
    adversary_live: bool  # its collisions were checked at the step itself


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

    The adversary's collisions are decided at the step they happen while its controller still
    reacts to contact (until :meth:`settle_adversary`). Everything nothing reacts to during a pass
    (the target's collisions with other vehicles, the settled adversary's, off-road for both) is
    queued and evaluated ``batch`` steps at a time, vectorised over the batch: a few numpy calls and
    one shapely call instead of that many per step. Queued events carry the time of the step they
    started and are returned by the :meth:`check` call that closes the batch, or by :meth:`flush`
    (call it at the end). ``batch=1`` reports every event at once.
    """

    def __init__(self, target_id: str, adversary_id: str, drivable: DrivableArea | None,
                 batch: int = 1) -> None:
        self.target_id = target_id
        self.adversary_id = adversary_id
        self.drivable = drivable
        self.batch = max(1, int(batch))
        self.adversary_live = True
        self._active: set[tuple[str, ...]] = set()  # live pairs (adversary, SUMO's list) in contact
        self._batch_active: dict[str, set[tuple[str, ...]]] = {target_id: set(), adversary_id: set()}
        self._off_active: set[str] = set()
        self._off_last: dict[str, int] = {}  # step index of each reference's last off-road check
        self._queue: list[_Queued] = []
        self._step = 0
        self.last_ids: list[str] = []  # the ids of the last checked step, in state order
        self.last_rows: tuple[int, int] = (-1, -1)  # target's and adversary's row there (-1: absent)
        self.events: list[Event] = []

    def settle_adversary(self) -> None:
        """Nothing reacts to the adversary's contacts any more (its controller froze it).

        From the next step on, its collisions are checked in the batches like the target's; a
        contact going on now continues as the same event.
        """
        if self.adversary_live:
            self.adversary_live = False
            self._batch_active[self.adversary_id] = {k for k in self._active if k[0] == "collision"}

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
        x, y, yaw, length, width = s.x, s.y, s.yaw, s.length, s.width
        gap = _sat_gap(x.item(i), y.item(i), yaw.item(i), length.item(i), width.item(i),
                       x.item(j), y.item(j), yaw.item(j), length.item(j), width.item(j))
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

        Those are the live adversary's collisions and SUMO's list at this step and, when this step
        closes a batch, the queued collisions and off-road events of the batch.
        """
        new: list[Event] = []
        now: set[tuple[str, ...]] = set()
        ids = states.id_list()
        r = ids.index(self.adversary_id) if self.adversary_id in ids else -1
        tr = ids.index(self.target_id) if self.target_id in ids else -1
        self.last_ids, self.last_rows = ids, (tr, r)
        live = self.adversary_live
        if r >= 0 and live:
            x, y, length, width = states.x, states.y, states.length, states.width
            # bounding circles that can meet (self too): 2 * distance - diameter < own diameter + 2 tol
            d2 = np.hypot(x - x.item(r), y - y.item(r))
            d2 += d2
            d2 -= np.hypot(length, width)
            cand = (d2 < math.hypot(length.item(r), width.item(r)) + 2 * CONTACT_TOLERANCE_M).nonzero()[0]
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
        self._queue.append(_Queued(self._step, float(time), states, ids, tr, r, live))
        self._step += 1
        if len(self._queue) >= self.batch:
            new.extend(self._flush_queue())
        self.events.extend(new)
        return new

    def _flush_queue(self) -> list[Event]:
        """Evaluate the queued steps: collisions of the target and the settled adversary, off-road.

        Every queued step's vehicles are laid end to end in one set of arrays, so the prefilter
        and the off-road check are a few numpy calls for the whole batch.
        """
        queue, self._queue = self._queue, []
        if not queue:
            return []
        sizes = np.array([len(q.ids) for q in queue])
        start = np.concatenate(([0], np.cumsum(sizes)[:-1]))
        x = np.concatenate([q.states.x for q in queue])
        y = np.concatenate([q.states.y for q in queue])
        length = np.concatenate([q.states.length for q in queue])
        width = np.concatenate([q.states.width for q in queue])
        yaw = np.concatenate([q.states.yaw for q in queue])
        tgt = np.array([q.target_row for q in queue])
        adv = np.array([q.adversary_row for q in queue])
        live = np.array([q.adversary_live for q in queue])
        tgt_g = np.where(tgt >= 0, start + tgt, -1)  # global rows, -1: absent
        adv_g = np.where(adv >= 0, start + adv, -1)
        out: list[Event] = []
        arrays = (x, y, yaw, length, width, sizes, start)
        # the target, except its pairs with the adversary (the adversary's own check has those)
        out.extend(self._batch_collisions(queue, arrays, self.target_id, tgt_g, adv_g, np.zeros(len(queue), bool)))
        if not live.all():
            out.extend(self._batch_collisions(queue, arrays, self.adversary_id, np.where(live, -1, adv_g),
                                              np.full(len(queue), -1), live))
        if self.drivable is not None:
            out.extend(self._off_road(queue, start, x, y, yaw, length, width))
        return out

    def _batch_collisions(self, queue: list[_Queued], arrays: tuple[np.ndarray, ...], ref_id: str,
                          ref_g: np.ndarray, skip_g: np.ndarray, keep: np.ndarray) -> list[Event]:
        """New contacts of ``ref_id`` over the queued steps.

        ``ref_g`` / ``skip_g``: per step, the global row of the reference and of a vehicle left
        out (-1: none). A step without the reference ends its contacts, unless ``keep`` says the
        step was checked elsewhere (then the contacts carry over it).
        """
        x, y, yaw, length, width, sizes, start = arrays
        active = self._batch_active[ref_id]
        out: list[Event] = []
        if not (ref_g >= 0).any():
            if not keep.all():
                self._batch_active[ref_id] = set()
            return out
        # a bounding-circle prefilter, then the separating-axis gap of the pairs left, for every
        # vehicle of every queued step at once
        step_of = np.repeat(np.arange(len(queue)), sizes)
        rg, sg = ref_g[step_of], skip_g[step_of]
        own = np.arange(len(x))
        diam = np.hypot(length, width)
        dx, dy = x - x[rg], y - y[rg]
        reach = 0.5 * (diam + diam[rg]) + CONTACT_TOLERANCE_M
        pair = ((dx * dx + dy * dy < reach * reach) & (rg >= 0) & (own != rg) & (own != sg)).nonzero()[0]
        if len(pair):
            ref = rg[pair]
            gap = _sat_gaps(x[ref], y[ref], yaw[ref], length[ref], width[ref],
                            x[pair], y[pair], yaw[pair], length[pair], width[pair])
            unsure = ((gap > 0) & (gap <= CONTACT_TOLERANCE_M)).nonzero()[0]
            if len(unsure):  # the exact distance where the lower bound cannot decide
                u, v = ref[unsure], pair[unsure]
                gap[unsure] = box_signed_distance(make_boxes(x[u], y[u], yaw[u], length[u], width[u]),
                                                  make_boxes(x[v], y[v], yaw[v], length[v], width[v]))
            pair = pair[gap <= CONTACT_TOLERANCE_M]
        touching: dict[int, list[int]] = {}
        for g, k in zip(pair.tolist(), step_of[pair].tolist(), strict=True):
            touching.setdefault(k, []).append(g)
        keep_l, has = keep.tolist(), (ref_g >= 0).tolist()
        for k, q in enumerate(queue):  # in step order: an episode spans steps
            if keep_l[k]:
                continue
            now: set[tuple[str, ...]] = set()
            if has[k]:
                r = int(ref_g[k] - start[k])
                for g in touching.get(k, ()):
                    j = g - int(start[k])
                    key = ("collision", *sorted((ref_id, q.ids[j])))
                    if key not in active and key not in now:
                        out.append(self._collision_event(q.time, q.states, r, j, "collision"))
                    now.add(key)
            active = now
        self._batch_active[ref_id] = active
        return out

    def _off_road(self, queue: list[_Queued], start: np.ndarray, x: np.ndarray, y: np.ndarray,
                  yaw: np.ndarray, length: np.ndarray, width: np.ndarray) -> list[Event]:
        """Off-road of the adversary and the target over the queued steps (one shapely call).

        ``start`` and the arrays are the queued steps' vehicles laid end to end (see
        :meth:`_flush_queue`). An episode starts at a step off the road whose previous step was not
        checked off the road (on it, or the vehicle absent).
        """
        assert self.drivable is not None
        per_vid = []
        for vid, attr in ((self.adversary_id, "adversary_row"), (self.target_id, "target_row")):
            rows = np.array([getattr(q, attr) for q in queue])
            ks = (rows >= 0).nonzero()[0]
            if len(ks):
                per_vid.append((vid, ks, start[ks] + rows[ks]))
        if not per_vid:
            return []
        g = np.concatenate([gi for *_, gi in per_vid])
        off = self.drivable.outside_area(x[g], y[g], yaw[g], length[g], width[g])
        out: list[Event] = []
        at = 0
        for vid, ks, gi in per_vid:
            area = off[at:at + len(ks)]
            at += len(ks)
            steps = np.array([queue[k].step for k in ks])
            is_off = area > self.drivable.tolerance_m2
            prev_step = np.concatenate(([self._off_last.get(vid, -2)], steps[:-1]))
            prev_off = np.concatenate(([vid in self._off_active], is_off[:-1]))
            for m in (is_off & ~(prev_off & (steps - prev_step == 1))).nonzero()[0].tolist():
                out.append(Event(time=queue[ks[m]].time, kind="off_road", vehicles=[vid],
                                 positions=[[float(x[gi[m]]), float(y[gi[m]])]],
                                 detail={"area_outside_m2": float(area[m])}))
            self._off_last[vid] = int(steps[-1])
            if is_off[-1]:
                self._off_active.add(vid)
            else:
                self._off_active.discard(vid)
        out.sort(key=lambda e: e.time)  # stable: the adversary first within a step
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
