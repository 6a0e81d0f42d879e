"""An escape's verdict: what SUMO's replay of it showed, read from a pass's events and recording.

:mod:`coster_sumo.avoidability.proof` runs the passes; a verdict may join two parts of one pass (the
steps a joint pass replayed before an escape left it, and those of its own pass from then on).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from coster_sumo.avoidability.evasion import Escape
from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.core.scene import Scene
from coster_sumo.geometry.boxes import box_signed_distance, make_boxes
from coster_sumo.sim.events import Event
from coster_sumo.sim.inject import TIME_EPS, InjectionResult


@dataclass(frozen=True)
class EscapeJob:
    """One escape to prove: the variant's adversary plan and the target's escape."""

    plan: AdversaryPlan
    escape: Escape


@dataclass(frozen=True)
class Verdict:
    """What SUMO's replay of one escape showed.

    Attributes:
        ok: no contact of the target and no off-road after the adversary appeared.
        reason: one line (``no contact, on road``, ``touched X at T s``, ``left the road at T s``).
        min_gap_to_adversary_m: [m] the smallest gap of the two boxes (None: never in the pass together).
        max_deviation_m: [m] how far SUMO's target strayed from the escape; max_deviation_at_s: [s] when.
    """

    ok: bool
    reason: str
    min_gap_to_adversary_m: float | None = None
    max_deviation_m: float | None = None
    max_deviation_at_s: float | None = None
    # unrounded, for joining two parts of a pass (:func:`_joined`); not part of the verdict
    raw_deviation_m: float | None = dataclasses.field(default=None, repr=False, compare=False)
    raw_gap_m: float | None = dataclasses.field(default=None, repr=False, compare=False)

    def to_json(self) -> dict[str, Any]:
        """The verdict as an escape's ``proof`` in summary.json."""
        d = dataclasses.asdict(self)
        del d["raw_deviation_m"], d["raw_gap_m"]
        return d


def verdict(res: InjectionResult, target_id: str, job: EscapeJob) -> Verdict:
    """What the replay shows: contacts of the target, off-road, the smallest gap to the adversary
    and how far SUMO's target strayed from the escape (moveToXY places it exactly)."""
    return _verdict(res.events, res.scene, target_id, job.plan.vehicle_id, job)


def _verdict(events: list[Event], scene: Scene, target_id: str, adversary_id: str, job: EscapeJob,
             before: float | None = None) -> Verdict:
    """:func:`verdict` from a pass's events and recording, the target and adversary by their ids there;
    ``before`` [s]: only what happened before this time (the part of a pass that another one resumes)."""
    plan, esc = job.plan, job.escape
    # the escape's window, from the adversary's appearance to its last pose (t_col + the horizon): a
    # pass that steps once more, or SUMO driving the target after it, says nothing about the escape
    t0, t1 = plan.t_start - TIME_EPS, esc.times[-1] + TIME_EPS
    if before is not None:
        t1 = min(t1, before - TIME_EPS)
    contacts = [e for e in events if e.kind == "collision" and target_id in e.vehicles and t0 <= e.time <= t1]
    off = [e for e in events if e.kind == "off_road" and e.vehicles == [target_id] and t0 <= e.time <= t1]
    tr = scene.tracks
    ids = tr.ids.tolist()
    gap = deviation = dev_at = None
    if target_id in ids:
        a = tr.index_of(target_id)
        ts_all = scene.timestamps
        steps = np.flatnonzero(tr.valid[a] & (ts_all >= t0) & (ts_all <= t1))
        if len(steps):
            ts = ts_all[steps]
            k = np.clip(np.round((ts - esc.times[0]) / 0.1).astype(int), 0, len(esc.times) - 1)
            dev = np.hypot(tr.x[a, steps] - esc.x[k], tr.y[a, steps] - esc.y[k])
            deviation = float(dev.max())
            dev_at = float(ts[int(np.argmax(dev))])
            if adversary_id in ids:
                b = tr.index_of(adversary_id)
                both = steps[tr.valid[b, steps]]
                if len(both):
                    gap = float(box_signed_distance(
                        make_boxes(tr.x[a, both], tr.y[a, both], tr.heading[a, both], tr.length[a, both],
                                   tr.width[a, both]),
                        make_boxes(tr.x[b, both], tr.y[b, both], tr.heading[b, both], tr.length[b, both],
                                   tr.width[b, both])).min())
    ok = not contacts and not off
    if ok:
        reason = "no contact, on road"
    elif contacts:
        first = contacts[0]
        other = next((v for v in first.vehicles if v != target_id), "?")
        reason = f"touched {other} at {first.time:.1f} s"
    else:
        reason = f"left the road at {off[0].time:.1f} s"
    return _rounded(ok, reason, gap, deviation, dev_at)


def _rounded(ok: bool, reason: str, gap: float | None, deviation: float | None, dev_at: float | None) -> Verdict:
    return Verdict(ok, reason, min_gap_to_adversary_m=None if gap is None else round(gap, 3),
                   max_deviation_m=None if deviation is None else round(deviation, 4), max_deviation_at_s=dev_at,
                   raw_deviation_m=deviation, raw_gap_m=gap)


def _joined(head: Verdict, tail: Verdict) -> Verdict:
    """The verdict of a pass whose steps up to some time gave ``head`` and the rest ``tail``."""
    gaps = [g for g in (head.raw_gap_m, tail.raw_gap_m) if g is not None]
    dev, dev_at = head.raw_deviation_m, head.max_deviation_at_s
    if tail.raw_deviation_m is not None and (dev is None or tail.raw_deviation_m > dev):
        dev, dev_at = tail.raw_deviation_m, tail.max_deviation_at_s
    return _rounded(head.ok and tail.ok, tail.reason if head.ok else head.reason, min(gaps) if gaps else None, dev,
                    dev_at)
