"""Per-step event detection: collisions (our box check and SUMO's list) and off-road.

Our oriented-box check is the ground truth: SUMO's own check is lane-based and misses lateral and
cross-edge overlaps (docs/sumo.md §4). SUMO's list is logged beside it as ``sumo_collision`` events.
Only pairs that involve the adversary or the target are checked (two rows of the pairwise matrix):
a bounding-circle prefilter over all other vehicles, the separating-axis gap of the pairs left (a
lower bound of their distance, exact for overlaps; :mod:`coster_sumo.geometry.boxes`, or a scalar copy
for the one pair of a live step), and the exact distance for the few within the contact tolerance.

Two boxes are in contact when their signed distance is at most ``CONTACT_TOLERANCE_M`` (5 cm, the
tolerance a collision snapshot is placed with), so touching at t_col counts. An event is reported
once when it starts; a pair that separates and overlaps again is a new
event. Off-road is checked for the adversary and the target only (footprint against the drivable
area, :class:`coster_sumo.geometry.drivable.DrivableArea`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from coster_sumo.geometry.boxes import CONTACT_TOLERANCE_M, box_signed_distance, make_boxes, sat_overlap_depth
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.metrics import impact_angle_deg
from coster_sumo.sim.session import VehicleStates


def _velocity(states: VehicleStates, i: int) -> np.ndarray:
    return states.speed[i] * np.array([np.cos(states.yaw[i]), np.sin(states.yaw[i])])


Box = tuple[float, float, float, float, float]  # x [m], y [m], yaw [rad], length [m], width [m]


def _sat_gap(a: Box, b: Box) -> float:
    """Largest separation [m] of two oriented boxes along their four axes (< 0: overlapping)."""
    ax, ay, ayaw, alen, awid = a
    bx, by, byaw, blen, bwid = b
    ac, as_, bc, bs = math.cos(ayaw), math.sin(ayaw), math.cos(byaw), math.sin(byaw)
    dx, dy = bx - ax, by - ay
    ahl, ahw, bhl, bhw = 0.5 * alen, 0.5 * awid, 0.5 * blen, 0.5 * bwid
    cc, cs = ac * bc + as_ * bs, as_ * bc - ac * bs  # cos and sin of the heading difference
    ec, es = abs(cc), abs(cs)
    return max(abs(dx * ac + dy * as_) - ahl - bhl * ec - bhw * es,   # a's longitudinal axis
               abs(-dx * as_ + dy * ac) - ahw - bhl * es - bhw * ec,  # a's lateral axis
               abs(dx * bc + dy * bs) - bhl - ahl * ec - ahw * es,    # b's longitudinal axis
               abs(-dx * bs + dy * bc) - bhw - ahl * es - ahw * ec)   # b's lateral axis


def _find(ids: list[str], vid: str, hint: int) -> int:
    """Row of ``vid`` in ``ids`` (-1: absent); ``hint`` is its row a step before.

    SUMO lists its vehicles sorted by id, so from one step to the next a vehicle keeps its row or
    moves by one when a vehicle sorted before it departs or arrives: the hint usually saves
    scanning the list.
    """
    n = len(ids)
    for k in (hint, hint + 1, hint - 1):
        if 0 <= k < n and ids[k] == vid:
            return k
    return ids.index(vid) if vid in ids else -1


_NO_POSE = np.full(5, np.nan)  # differs from every footprint


class _Batch:
    """The steps waiting for the batched checks: one list per field, so a step costs a few appends."""

    def __init__(self, first_step: int) -> None:
        self.first_step = first_step  # the steps are consecutive
        self.times: list[float] = []
        self.states: list[VehicleStates] = []
        self.ids: list[list[str]] = []
        self.sizes: list[int] = []
        self.target_rows: list[int] = []  # -1: absent
        self.adversary_rows: list[int] = []
        self.live: list[bool] = []  # the adversary's collisions were checked at the step itself
        self.x: list[np.ndarray] = []
        self.y: list[np.ndarray] = []
        self.yaw: list[np.ndarray] = []
        self.length: list[np.ndarray] = []
        self.width: list[np.ndarray] = []

    def __len__(self) -> int:
        return len(self.times)

    def add(self, time: float, states: VehicleStates, ids: list[str], target_row: int, adversary_row: int,
            live: bool) -> None:
        self.times.append(time)
        self.states.append(states)
        self.ids.append(ids)
        self.sizes.append(len(ids))
        self.target_rows.append(target_row)
        self.adversary_rows.append(adversary_row)
        self.live.append(live)
        self.x.append(states.x)
        self.y.append(states.y)
        self.yaw.append(states.yaw)
        self.length.append(states.length)
        self.width.append(states.width)


@dataclass
class Event:
    """One logged event (user-facing units: seconds, metres, degrees).

    Attributes:
        time: [s] simulation time.
        kind: "collision" (our box check), "sumo_collision" (SUMO's list) or "off_road".
        vehicles: the vehicle ids involved (reference vehicle first: the target when involved).
        positions: [[x, y], ...] centres [m] in the same order.
        relative_speed: [m/s] |v_a - v_b| (collisions); None where it does not apply (off-road, a
            SUMO collision of a vehicle no longer in the states).
        impact_angle: [deg] the other vehicle's position in the first vehicle's frame (collisions);
            None where it does not apply.
        detail: free-form extra data (SUMO's collision type, area off the road...).
    """

    time: float
    kind: str
    vehicles: list[str]
    positions: list[list[float]]
    relative_speed: float | None = None
    impact_angle: float | None = None
    detail: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """The event for events.jsonl: times to the millisecond, positions to the millimetre."""
        d = asdict(self)
        d["time"] = round(self.time, 3)
        d["positions"] = [[round(v, 3) for v in p] for p in self.positions]
        if self.relative_speed is not None:
            d["relative_speed"] = round(self.relative_speed, 3)
        if self.impact_angle is not None:
            d["impact_angle"] = round(self.impact_angle, 2)
        return d


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
        self._off_pose: dict[str, np.ndarray] = {}  # and its footprint (x, y, yaw, length, width) then
        self._off_area: dict[str, float] = {}  # and the area of it outside the drivable area
        self._queue = _Batch(0)
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
        a: Box = (s.x.item(i), s.y.item(i), s.yaw.item(i), s.length.item(i), s.width.item(i))
        b: Box = (s.x.item(j), s.y.item(j), s.yaw.item(j), s.length.item(j), s.width.item(j))
        gap = _sat_gap(a, b)
        if gap > CONTACT_TOLERANCE_M:
            return False
        return gap <= 0.0 or bool(box_signed_distance(np.array(a), np.array(b)) <= CONTACT_TOLERANCE_M)

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
        tr, r = self.last_rows
        # this runs every step: the usual case (same row as a step before) without a call
        if not (0 <= tr < len(ids) and ids[tr] == self.target_id):
            tr = _find(ids, self.target_id, tr)
        if not (0 <= r < len(ids) and ids[r] == self.adversary_id):
            r = _find(ids, self.adversary_id, r)
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
        if sumo_collisions:
            new.extend(self._sumo_collisions(time, states, ids, sumo_collisions, now))
        self._active = now
        self._queue.add(time, states, ids, tr, r, live)
        self._step += 1
        if self._step - self._queue.first_step >= self.batch:
            new.extend(self._flush_queue())
        if new:
            self.events.extend(new)
        return new

    def _sumo_collisions(self, time: float, states: VehicleStates, ids: list[str], collisions: list[dict],
                         now: set[tuple[str, ...]]) -> list[Event]:
        """Events for the pairs of SUMO's collision list not already in it a step before."""
        out: list[Event] = []
        for c in collisions:
            a, b = str(c.get("collider", "")), str(c.get("victim", ""))
            key = ("sumo_collision", *sorted((a, b)))
            now.add(key)
            if key in self._active:
                continue
            i = ids.index(a) if a in ids else -1
            j = ids.index(b) if b in ids else -1
            detail = {"type": c.get("type", ""), "lane": c.get("lane", "")}
            if i >= 0 and j >= 0:
                # SUMO's check is lane-based: say how far apart the boxes really were
                gap = box_signed_distance(*(make_boxes(states.x[k], states.y[k], states.yaw[k], states.length[k],
                                                       states.width[k]) for k in (i, j)))
                detail["box_gap_m"] = round(float(gap), 3)
                out.append(self._collision_event(time, states, i, j, "sumo_collision", detail))
            else:
                out.append(Event(time=float(time), kind="sumo_collision", vehicles=[a, b], positions=[],
                                 detail=detail))
        return out

    def _flush_queue(self) -> list[Event]:
        """Evaluate the queued steps: collisions of the target and the settled adversary, off-road.

        Every queued step's vehicles are laid end to end in one set of arrays, so the prefilter
        and the off-road check are a few numpy calls for the whole batch.
        """
        queue, self._queue = self._queue, _Batch(self._step)
        if not queue:
            return []
        sizes, tgt, adv = np.array(queue.sizes), np.array(queue.target_rows), np.array(queue.adversary_rows)
        live = np.array(queue.live, bool)
        start = np.cumsum(sizes) - sizes
        x, y, yaw = np.concatenate(queue.x), np.concatenate(queue.y), np.concatenate(queue.yaw)
        length, width = np.concatenate(queue.length), np.concatenate(queue.width)
        tgt_g = np.where(tgt >= 0, start + tgt, -1)  # global rows, -1: absent
        adv_g = np.where(adv >= 0, start + adv, -1)
        arrays = (x, y, yaw, length, width)
        # the target, except its pairs with the adversary (the adversary's own check has those);
        # the adversary once settled (its live steps are skipped, not ended)
        refs = [(self.target_id, tgt_g, adv_g, np.zeros(len(queue), bool))]
        if not live.all():
            refs.append((self.adversary_id, np.where(live, -1, adv_g), np.full(len(queue), -1), live))
        out = self._batch_collisions(queue, arrays, sizes, start, refs)
        if self.drivable is not None:
            out.extend(self._off_road(queue, arrays, ((self.adversary_id, adv_g), (self.target_id, tgt_g))))
        return out

    def _batch_collisions(self, queue: _Batch, arrays: tuple[np.ndarray, ...], sizes: np.ndarray,
                          start: np.ndarray, refs: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]
                          ) -> list[Event]:
        """New contacts of each reference over the queued steps.

        ``refs``: (id, ref_g, skip_g, keep) with, per step, the global row of the reference and
        of a vehicle left out (-1: none); a step without the reference ends its contacts, unless
        ``keep`` says the step was checked elsewhere (then they carry over it).
        """
        x, y, yaw, length, width = arrays
        step_of = np.repeat(np.arange(len(queue)), sizes)
        diam = np.hypot(length, width)
        half_diam = 0.5 * diam
        out: list[Event] = []
        for ref_id, ref_g, skip_g, keep in refs:
            pair = np.zeros(0, np.int64)
            here = ref_g >= 0
            if here.any():
                # a bounding-circle prefilter over every vehicle of every queued step at once (a step
                # without the reference puts it infinitely far away), then the separating-axis gap
                # of the few pairs left
                g = np.where(here, ref_g, 0)
                rx = np.repeat(np.where(here, x[g], np.inf), sizes)
                dx = x - rx
                dy = y - np.repeat(y[g], sizes)
                reach = np.repeat(0.5 * diam[g] + CONTACT_TOLERANCE_M, sizes)
                reach += half_diam
                dx *= dx
                dy *= dy
                dx += dy
                reach *= reach
                pair = (dx < reach).nonzero()[0]
                k = step_of[pair]
                pair = pair[(pair != ref_g[k]) & (pair != skip_g[k])]  # not itself, not the one left out
            if len(pair):
                ra = ref_g[step_of[pair]]
                a = make_boxes(x[ra], y[ra], yaw[ra], length[ra], width[ra])
                b = make_boxes(x[pair], y[pair], yaw[pair], length[pair], width[pair])
                gap = -sat_overlap_depth(a, b)  # a lower bound of the distance, <= 0 when overlapping
                unsure = (gap > 0) & (gap <= CONTACT_TOLERANCE_M)
                if unsure.any():  # the exact distance where the lower bound cannot decide
                    gap[unsure] = box_signed_distance(a[unsure], b[unsure])
                pair = pair[gap <= CONTACT_TOLERANCE_M]
            k = step_of[pair]
            out.extend(self._episodes(queue, ref_id, ref_g - start, pair - start[k], k, keep))
        return out

    def _episodes(self, queue: _Batch, ref_id: str, ref_row: np.ndarray, rows: np.ndarray,
                  steps: np.ndarray, keep: np.ndarray) -> list[Event]:
        """Events for the contacts of ``ref_id`` (vehicle ``rows`` at batch ``steps``, in step order).

        Contacts go on from step to step; a step without them ends them, unless ``keep`` (checked
        elsewhere). Only the steps with a contact are visited: ``checked`` counts the steps that
        end contacts, up to each step.
        """
        active = self._batch_active[ref_id]
        checked = np.cumsum(~keep).tolist()
        seen = -1  # the last visited step
        now: set[tuple[str, ...]] = set()
        out: list[Event] = []
        for j, k in zip(rows.tolist(), steps.tolist(), strict=True):
            if k != seen:
                active, now = (now if seen >= 0 else active), set()
                if checked[k] - (checked[seen] if seen >= 0 else 0) > 1:  # a step between had none
                    active = set()
                seen = k
            key = ("collision", *sorted((ref_id, queue.ids[k][j])))
            if key not in active and key not in now:
                out.append(self._collision_event(queue.times[k], queue.states[k], int(ref_row[k]), j, "collision"))
            now.add(key)
        if seen >= 0:
            active = now if checked[-1] == checked[seen] else set()
        elif checked[-1] > 0:
            active = set()
        self._batch_active[ref_id] = active
        return out

    def _off_road(self, queue: _Batch, arrays: tuple[np.ndarray, ...],
                  rows: tuple[tuple[str, np.ndarray], ...]) -> list[Event]:
        """Off-road of the adversary and the target over the queued steps (one shapely call).

        ``arrays`` (x, y, yaw, length, width) are the queued steps' vehicles laid end to end and
        ``rows`` each vehicle's row there per step (-1: absent; see :meth:`_flush_queue`). An
        episode starts at a step off the road whose previous step was not checked off the road (on
        it, or the vehicle absent).
        """
        assert self.drivable is not None
        x, y, yaw, length, width = arrays
        first = queue.first_step
        per_vid = []
        for vid, g in rows:
            ks = (g >= 0).nonzero()[0]
            if len(ks):
                per_vid.append((vid, ks, g[ks]))
        if not per_vid:
            return []
        g = np.concatenate([gi for *_, gi in per_vid])
        pose = np.stack([x[g], y[g], yaw[g], length[g], width[g]])  # (5, n)
        # a footprint the same as the one checked before it (a wreck, a car waiting at a light) keeps
        # that one's area: only the others go to shapely
        seg = np.cumsum([0] + [len(ks) for _, ks, _ in per_vid])[:-1]  # where each vehicle's rows start
        before = np.empty_like(pose)
        before[:, 1:] = pose[:, :-1]
        before[:, seg] = np.array([self._off_pose.get(vid, _NO_POSE) for vid, *_ in per_vid]).T
        moved = (pose != before).any(axis=0)
        off = np.zeros(len(g))
        off[seg] = [self._off_area.get(vid, 0.0) for vid, *_ in per_vid]
        todo = moved.nonzero()[0]
        if len(todo):
            off[todo] = self.drivable.outside_area(*pose[:, todo])
        moved[seg] = True
        off = off[np.maximum.accumulate(np.where(moved, np.arange(len(g)), 0))]
        out: list[Event] = []
        at = 0
        for vid, ks, gi in per_vid:
            area = off[at:at + len(ks)]
            at += len(ks)
            steps = ks + first
            is_off = area > self.drivable.tolerance_m2
            prev_step = np.concatenate(([self._off_last.get(vid, -2)], steps[:-1]))
            prev_off = np.concatenate(([vid in self._off_active], is_off[:-1]))
            for m in (is_off & ~(prev_off & (steps - prev_step == 1))).nonzero()[0].tolist():
                out.append(Event(time=float(queue.times[ks[m]]), kind="off_road", vehicles=[vid],
                                 positions=[[float(x[gi[m]]), float(y[gi[m]])]],
                                 detail={"area_outside_m2": float(area[m])}))
            self._off_last[vid] = int(steps[-1])
            self._off_pose[vid], self._off_area[vid] = pose[:, at - 1], float(area[-1])
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
