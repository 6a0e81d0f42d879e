"""Defects, not crashes: every variant's avoidability label, proven in SUMO, and what a planner did.

Generation calls :func:`label_plans` for its kept plans: :func:`coster_sumo.avoidability.search.assess` searches
the target's escapes, :func:`coster_sumo.avoidability.proof.prove_labels` replays each one in the variant's
own pass, and an escape that SUMO refutes no longer counts (docs/method.md, step 8). The rest of
this module turns labels and a planner's pass into what users read: the summary entries, the
outcome lines ("avoided: braked to 3.1 m/s, clearance 1.2 m"; "hit, unavoidable") and the label
statistics over many variants. A regression's defect rate (contact in an avoidable variant, Wilson
interval) is :func:`coster_sumo.batch.summaries.defect_rates`, its tables are
:mod:`coster_sumo.batch.report`'s.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from coster_sumo.avoidability.candidates import SearchContext
from coster_sumo.avoidability.evasion import DEFAULT_REACTION_S, Avoidability, Escape
from coster_sumo.avoidability.proof import ProofSettings, prove_labels
from coster_sumo.avoidability.search import assess
from coster_sumo.core.plan import HORIZON_AFTER_TCOL_S, AdversaryPlan
from coster_sumo.core.results import LabelCounts, TargetResult
from coster_sumo.core.scene import Scene
from coster_sumo.core.spec import ScenarioSpec
from coster_sumo.formats.source import ScenarioSource
from coster_sumo.geometry.boxes import box_signed_distance, make_boxes
from coster_sumo.metrics import MetricSample, RunOutcome, compute, rate_with_ci

ESCAPE_FILE = "escape.csv"


def label_plans(scenario: ScenarioSpec | ScenarioSource, scene: Scene, target: int, plans: Sequence[AdversaryPlan],
                proof: ProofSettings, *, reaction_time_s: float = DEFAULT_REACTION_S,
                timings: dict[str, float] | None = None, done: Callable[[int], object] | None = None
                ) -> list[Avoidability]:
    """The avoidability of every plan, each escape proven (or refuted) in SUMO (``scenario``: the
    spec, or its source resolved already).

    ``proof``: where the escapes are replayed (the drivable area the search and the replays check,
    the held copies, ``traffic``: a converted scene's agents in the proof, ``log`` or ``reactive``).
    The other vehicles are SUMO's drivers in the proof on a SUMO configuration, and on a converted
    WOMD scene only with ``traffic="reactive"`` (with ``log`` its log moves every other agent): then
    plans blocked only by them are tried there (:func:`coster_sumo.avoidability.search.assess`).
    ``timings`` gains ``avoidability_s`` (the kinematic search) and ``proof_s`` (the replays);
    ``done(1)`` is called after each plan's search and once more after the replays.
    """
    reaction_times = tuple(sorted({0.5, 1.0, 1.5, float(reaction_time_s)}))
    source = ScenarioSource.of(scenario)
    reactive = not source.converted or proof.traffic == "reactive"
    t0 = time.perf_counter()
    labels = []
    shared: dict[tuple[float, float], SearchContext] = {}  # each time grid's candidates, built once (assess)
    for plan in plans:
        labels.append(assess(scene, target, plan, proof.drivable, reaction_times=reaction_times,
                             reaction_time_s=reaction_time_s, reactive_others=reactive, shared=shared))
        if done is not None:
            done(1)
    t1 = time.perf_counter()
    prove_labels(source, scene, target, plans, labels, proof)
    if done is not None:
        done(1)
    if timings is not None:
        timings["avoidability_s"] = timings.get("avoidability_s", 0.0) + t1 - t0
        timings["proof_s"] = timings.get("proof_s", 0.0) + time.perf_counter() - t1
    return labels


def label_line(lab: Avoidability) -> str:
    """One phrase for a variant's label (``run`` prints it after the variant's result)."""
    kind = lab.contact_kind.replace("_", " ")
    if lab.avoidable:
        e = lab.escape
        # the times as summary.json rounds them, so that the line reads as the file does
        how = (f" by '{e.manoeuvre.describe()}' from {round(lab.t_col, 3) - round(e.t_act, 3):.1f} s before t_col"
               if e else "")
        last = ("" if lab.last_moment_s is None
                else f"; last moment to act {round(lab.last_moment_s, 3):.1f} s before t_col")
        traffic = (f"; only {', '.join(e.blocked_by)} stood in its way, and SUMO's driver gave way"
                   if e is not None and e.blocked_by else "")
        return f"avoidable at {lab.reaction_time_s:g} s reaction{how} (proven in SUMO{last}{traffic}), {kind}"
    refuted = any(e and e.proven is False for e in lab.escapes.values())
    why = ("no escape from a reaction of {r:g} s after the threat" if lab.last_moment_s is None or not refuted
           else "its escape failed in SUMO").format(r=lab.reaction_time_s)
    why += blocked_words(lab)
    return f"unavoidable ({why}), {kind}"


def attach_labels(result: TargetResult, labels: Sequence[Avoidability],
                  passes: Sequence[tuple[AdversaryPlan, Any]] = ()) -> TargetResult:
    """``result`` with each variant's label (and the file its escape plan goes to, :data:`ESCAPE_FILE`
    in its folder, where it has one), and the counts of avoidable variants and of defects.

    ``passes``: (plan, injection result) per variant: each then gets its planner's ``outcome`` line.
    """
    variants = []
    for k, (rec, lab) in enumerate(zip(result.variants, labels, strict=True)):
        line, outcome = label_line(lab), None
        if k < len(passes):
            plan, res = passes[k]
            hit = any(e.kind == "collision" and result.target in e.vehicles
                      and e.time <= lab.t_col + HORIZON_AFTER_TCOL_S + 1e-6 for e in res.events)
            outcome = planner_outcome(res.scene, result.target, plan, hit, lab.avoidable)
            if not hit and not lab.avoidable:
                line = both_clause(lab, acted_after_threat(res.scene, result.target, lab))
        entry = lab.summary()
        if lab.escape is not None:
            entry["escape_file"] = f"variants/{rec.variant}/{ESCAPE_FILE}"
        variants.append(dataclasses.replace(rec, avoidability=entry, label=line, outcome=outcome))
    n = len(labels)
    avoidable = sum(lab.avoidable for lab in labels)
    counts = LabelCounts(
        avoidable_variants=avoidable,
        reaction_time_s=labels[0].reaction_time_s if labels else DEFAULT_REACTION_S,
        defects=sum(v.collision and bool(v.avoidable) for v in variants),
        unavoidable_contacts=sum(v.collision and not v.avoidable for v in variants),
        avoidable_share=avoidable / n if n else None)
    return dataclasses.replace(result, variants=tuple(variants), labels=counts)


# ----------------------------------------------------------------------------- a planner's outcome

ACTING_ACCEL = 1.0  # [m/s^2] braking or accelerating this hard is acting on the threat


def acted_after_threat(scene: Scene, target_id: str, lab: Avoidability) -> float | None:
    """[s] after the threat (negative: before) when the target in its pass first braked or
    accelerated by :data:`ACTING_ACCEL` or more from the adversary's appearance on; None: it did not."""
    tr = scene.tracks
    if target_id not in tr.ids.tolist():
        return None
    a = tr.index_of(target_id)
    steps = np.flatnonzero(tr.valid[a] & (scene.timestamps >= lab.t_appear - 1e-6)
                           & (scene.timestamps <= lab.t_col + 1e-6))
    if len(steps) < 2:
        return None
    ts = scene.timestamps[steps]
    accel = np.diff(np.hypot(tr.vx[a, steps], tr.vy[a, steps])) / np.maximum(np.diff(ts), 1e-6)
    acting = np.flatnonzero(np.abs(accel) >= ACTING_ACCEL)
    return None if not len(acting) else float(ts[acting[0]] - lab.t_threat)


def both_clause(lab: Avoidability, acted_s: float | None) -> str:
    """The label of a variant the target avoided but the reference driver could not, saying both:
    "unavoidable for a driver reacting 1 s after the threat; this target acted 0.3 s after it"."""
    kind = lab.contact_kind.replace("_", " ")
    when = ("; this target avoided it" if acted_s is None else
            f"; this target acted {acted_s:.1f} s after the threat" if acted_s >= 0.05 else
            f"; this target acted {max(-acted_s, 0.0):.1f} s before the threat" if acted_s <= -0.05 else
            "; this target acted at the threat")
    blocked = blocked_words(lab)
    return f"unavoidable for a driver reacting {lab.reaction_time_s:g} s after the threat{blocked}{when}, {kind}"


def blocked_words(lab: Avoidability) -> str:
    """'; N blocked only by traffic tried in SUMO, none cleared' for an unavoidable label ('' when
    none was tried); one cleared acts too early for the label's reaction time, and is said so."""
    tried = sum(e.proven is not None for e in lab.blocked)
    if not tried:
        return ""
    cleared = sum(bool(e.proven) for e in lab.blocked)
    return (f"; {tried} blocked only by traffic tried in SUMO, "
            + ("none cleared" if not cleared else
               f"{cleared} cleared acting less than {lab.reaction_time_s:g} s after the threat"))

def planner_outcome(scene: Scene, target_id: str, plan: AdversaryPlan, contact: bool, avoidable: bool | None
                    ) -> str:
    """How the planner's pass ended, in words: how it avoided (its lowest speed, its smallest gap to
    the adversary) or whether a hit was a defect or unavoidable. ``scene``: the pass recorded;
    ``contact``: the target touched someone up to the label's horizon; ``avoidable``: the variant's
    label (None: not labelled)."""
    if contact:
        if avoidable is None:
            return "hit"
        return "hit, a defect: the contact was avoidable" if avoidable else "hit, unavoidable"
    tr = scene.tracks
    ids = tr.ids.tolist()
    if target_id not in ids:
        return "no contact"
    a = tr.index_of(target_id)
    window = tr.valid[a] & (scene.timestamps >= plan.t_start - 1e-6) & (scene.timestamps <= plan.t_col + 3.0)
    steps = np.flatnonzero(window)
    if not len(steps):
        return "no contact"
    speed = np.hypot(tr.vx[a, steps], tr.vy[a, steps])
    parts = [f"lowest speed {speed.min():.1f} m/s"]
    v0 = float(speed[0])
    if speed.min() < v0 - 1.0:
        parts[0] = f"braked to {speed.min():.1f} m/s"
    elif speed.max() > v0 + 1.0:
        parts[0] = f"accelerated to {speed.max():.1f} m/s"
    if plan.vehicle_id in ids:
        b = tr.index_of(plan.vehicle_id)
        both = steps[tr.valid[b, steps]]
        if len(both):
            gap = box_signed_distance(
                make_boxes(tr.x[a, both], tr.y[a, both], tr.heading[a, both], tr.length[a, both], tr.width[a, both]),
                make_boxes(tr.x[b, both], tr.y[b, both], tr.heading[b, both], tr.length[b, both], tr.width[b, both]))
            parts.append(f"clearance {float(gap.min()):.1f} m")
    return "avoided: " + ", ".join(parts)


# ----------------------------------------------------------------------------- batches

def escape_dict(e: Escape | None) -> dict[str, Any] | None:
    """The escape's 10 Hz arrays for a batch's plans file (None where there is none)."""
    if e is None:
        return None
    return {"times": e.times.round(3).tolist(), "x": e.x.round(4).tolist(), "y": e.y.round(4).tolist(),
            "yaw": e.yaw.round(5).tolist(), "speed": e.speed.round(4).tolist()}


def escape_replay(d: dict[str, Any], length_m: float) -> Any:
    """The ``escape`` planner of a batch: a replay of a stored escape (:func:`escape_dict`)."""
    from coster_sumo.sim.planners import ReplayPlanner

    times = np.asarray(d["times"], float)
    return ReplayPlanner(times, np.asarray(d["x"], float), np.asarray(d["y"], float), np.asarray(d["yaw"], float),
                         np.asarray(d["speed"], float), np.ones(len(times), bool), length_m)


# ----------------------------------------------------------------------------- label statistics

def label_record(lab: Avoidability) -> dict[str, Any]:
    """The flat per-variant fields of a label that statistics over many variants read."""
    kinematic = {f"{r:g}": e is not None for r, e in lab.escapes.items()}
    return {"avoidable": lab.avoidable, "avoidable_at": {f"{r:g}": lab.avoidable_at(r) for r in sorted(lab.escapes)},
            "escape_found_at": kinematic,
            "escapes_replayed": sum(e is not None and e.proven is not None for e in lab.escapes.values()),
            "escapes_refuted": sum(e is not None and e.proven is False for e in lab.escapes.values()),
            "blocked_tried": sum(e.proven is not None for e in lab.blocked),
            "blocked_cleared": sum(bool(e.proven) for e in lab.blocked),
            "flipped_by_reacting_traffic": lab.flipped_by_reacting_traffic,
            "flipped_at": {f"{r:g}": lab.flipped_at(r) for r in sorted(lab.escapes)},
            "contact_kind": lab.contact_kind, "last_moment_s": lab.last_moment_s,
            "threat_before_tcol_s": lab.t_col - lab.t_threat}


def avoidability_table(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Share of avoidable variants (Wilson 95 %) per reaction time, overall and per kind of contact;
    the distribution of the last moment to act; how many kinematic escapes SUMO refuted."""

    recs = [r for r in records if r.get("avoidable_at")]
    times = sorted({t for r in recs for t in r["avoidable_at"]}, key=float)

    def shares(part: Sequence[dict[str, Any]]) -> dict[str, Any]:
        return {t: rate_with_ci([bool(r["avoidable_at"].get(t)) for r in part]) for t in times}

    def collision_rate_of(avoidable: bool) -> dict[str, Any]:
        """The registry's CR (the adversary touches the target) of the variants with this label."""
        part = tuple(RunOutcome(adversary_contact=bool(r.get("collision"))) for r in recs
                     if bool(r["avoidable"]) is avoidable)
        return compute("CR", MetricSample(part)).rate_json()

    last = np.array([r["last_moment_s"] for r in recs if r.get("last_moment_s") is not None], float)
    found = {t: sum(bool(r["escape_found_at"].get(t)) for r in recs) for t in times}
    return {"variants": len(recs), "avoidable_share": shares(recs),
            "CR_by_label": {"avoidable": collision_rate_of(True), "unavoidable": collision_rate_of(False)},
            "by_contact_kind": {k: {"variants": sum(r["contact_kind"] == k for r in recs),
                                    "avoidable_share": shares([r for r in recs if r["contact_kind"] == k])}
                                for k in sorted({r["contact_kind"] for r in recs})},
            "last_moment_s": {"with_escape": int(len(last)), "none": len(recs) - int(len(last)),
                              **({f"p{q}": round(float(np.percentile(last, q)), 2) for q in (10, 25, 50, 75, 90)}
                                 if len(last) else {})},
            "escapes_found": found,
            "escapes_replayed": sum(int(r.get("escapes_replayed", 0)) for r in recs),
            "escapes_refuted_in_sumo": sum(int(r.get("escapes_refuted", 0)) for r in recs),
            **labels_moved(recs)}


def labels_moved(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """What each change to the labels moved over these variants: the plans blocked only by traffic
    that reacts, how many SUMO tried and cleared, and the labels that turned avoidable through them
    (count and share)."""
    n = len(records)
    flipped = sum(bool(r.get("flipped_by_reacting_traffic")) for r in records)
    return {"blocked_escapes_tried_in_sumo": sum(int(r.get("blocked_tried", 0)) for r in records),
            "blocked_escapes_cleared_in_sumo": sum(int(r.get("blocked_cleared", 0)) for r in records),
            "labels_flipped_by_reacting_traffic": {"count": flipped, "share": round(flipped / n, 4) if n else None}}
