"""What a variant's SUMO pass must show to be kept in a run's outputs (data flow step 5).

A variant is kept only when it played out as generated: its pass did not fail
(:func:`drop_failed_variants`), and its adversary ran into no other vehicle before t_col, where the
other vehicles react to it (:func:`drop_bystander_wrecks`). The generation's own filters, on the
nominal scene before any simulation, are :mod:`coster_sumo.method.filters`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol, TypeVar

from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.sim.inject import InjectionResult, VariantFailure


class _Snapshot(Protocol):
    """What the filters after the simulation work on: a collision snapshot's plans and its report
    (:class:`coster_sumo.method.generation.PlannedScenario`)."""

    plans: list[AdversaryPlan]
    info: dict[str, Any]


P = TypeVar("P", bound=_Snapshot)


def _leave_out(planned: list[P], outcomes: Sequence[Any],
               verdict: Callable[[AdversaryPlan, Any], tuple[str, dict[str, Any]] | None]
               ) -> tuple[list[P], list[Any]]:
    """The plans and outcomes (one per plan, in order) that ``verdict`` keeps (it returns None);
    a left-out one is recorded under its snapshot's ``info[key]`` with the entry ``verdict`` gives."""
    it = iter(outcomes)
    kept_outcomes: list[Any] = []
    for p in planned:
        kept = []
        for plan in p.plans:
            res = next(it)
            why = verdict(plan, res)
            if why is None:
                kept.append(plan)
                kept_outcomes.append(res)
            else:
                p.info.setdefault(why[0], []).append(why[1])
        p.plans = kept
    return planned, kept_outcomes


def drop_failed_variants(planned: list[P], outcomes: list[InjectionResult | VariantFailure]
                         ) -> tuple[list[P], list[InjectionResult]]:
    """The plans and results without the variants whose pass failed (SUMO crashed, timed out).

    Each failure is kept in its snapshot's ``info["failed"]`` (summary.json ``generation.failed``:
    the adversary, its t_col and the reason), which ``coster-sumo run`` prints as one line each; the
    other variants go on.
    """
    def failed(plan: AdversaryPlan, res: InjectionResult | VariantFailure) -> tuple[str, dict[str, Any]] | None:
        if not isinstance(res, VariantFailure):
            return None
        return "failed", {"candidate": plan.vehicle_id, "t_col": plan.t_col, "reason": f"its SUMO pass {res.reason}"}

    return _leave_out(planned, outcomes, failed)


def drop_bystander_wrecks(planned: list[P], results: list[InjectionResult], target_id: str
                          ) -> tuple[list[P], list[InjectionResult]]:
    """The plans and results without the variants whose adversary ran into another vehicle before
    t_col in the simulation (their ``info["dropped"]`` says so).

    The generation already drops plans that overlap another vehicle's nominal path
    (:func:`coster_sumo.method.filters.bystander_contact`), but in the simulation the other vehicles react to
    the adversary (they brake or change lanes when it appears): on A10KW a car 5.9 m clear of the
    plan's path in the nominal pass ran into it 0.8 s before t_col. Such an adversary stops there as
    a wreck (:class:`~coster_sumo.sim.inject.AdversaryController`), so the variant is not the
    generated scenario, even when the target then runs into the wreck at t_col (the demo's
    adversary hit a car 1 s before t_col and the target hit both: its export no longer followed the
    plan).
    """
    def wrecked(plan: AdversaryPlan, res: InjectionResult) -> tuple[str, dict[str, Any]] | None:
        wreck = next((e for e in res.events if e.kind == "collision" and plan.vehicle_id in e.vehicles
                      and target_id not in e.vehicles and e.time < plan.t_col - 0.1 - 1e-6), None)
        if wreck is None:
            return None
        other = next(v for v in wreck.vehicles if v != plan.vehicle_id)
        return "dropped", {"candidate": plan.vehicle_id,
                           "reason": f"ran into {other} at {wreck.time:.1f} s in the simulation, before t_col"}

    return _leave_out(planned, results, wrecked)
