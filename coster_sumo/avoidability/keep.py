"""One label-and-keep for every path that generates: ``run``, the API (:func:`coster_sumo.api.plan_adversaries`).

Every plan is labelled (its escapes proven in SUMO, :func:`coster_sumo.avoidability.labels.label_plans`); with
``--avoidable only`` the unavoidable plans are dropped and replaced by plans of further draws until enough are
avoidable (docs/method.md, step 8). The caller brings ``label``: which SUMO, which workers, which timings.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from coster_sumo.avoidability.evasion import Avoidability
from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.core.results import AvoidableOnly
from coster_sumo.core.spec import GenerationConfig, LabelOptions
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.method.generation import EXTRA_DRAWS, DrawMemo, PlannedScenario, further_draw

Label = Callable[[list[AdversaryPlan]], list[Avoidability]]


def label_and_keep(planned: list[PlannedScenario], label: Label, wanted: LabelOptions, variants: int, *,
                   seed: int, gen: GenerationConfig, drivable: DrivableArea, memo: DrawMemo
                   ) -> tuple[list[PlannedScenario], dict[str, Avoidability], AvoidableOnly | None]:
    """Label every plan of ``planned`` with ``label``; with ``wanted.avoidable == "only"`` keep the
    avoidable ones, up to ``variants``, drawing again for the others (:func:`keep_avoidable`).

    Returns the scenarios kept (``planned`` itself without ``only``), every label by adversary id (the
    dropped ones too) and, with ``only``, what was tried (None without).
    """
    plans = [pl for p in planned for pl in p.plans]
    labels = dict(zip((pl.vehicle_id for pl in plans), label(plans), strict=True))
    if wanted.avoidable != "only":
        return planned, labels, None
    kept, tried = keep_avoidable(planned, labels, label, variants, seed=seed, gen=gen, drivable=drivable,
                                 memo=memo)
    return kept, labels, tried


def keep_avoidable(planned: list[PlannedScenario], labels: dict[str, Avoidability], label: Label, wanted: int, *,
                   seed: int, gen: GenerationConfig, drivable: DrivableArea, memo: DrawMemo
                   ) -> tuple[list[PlannedScenario], AvoidableOnly]:
    """``--avoidable only``: drop the unavoidable plans of ``planned`` (``labels`` by adversary id,
    of the scene and target of ``planned``) and replace them by plans of :func:`further_draw` (with
    ``seed``, ``gen``, ``drivable``) until ``wanted`` are avoidable or :data:`EXTRA_DRAWS` more draws
    are spent. ``label(plans)`` gives the labels of a further draw's plans (``labels`` gains them).
    ``memo``: the one :func:`~coster_sumo.method.generation.plan_scenarios` drew ``planned`` with.

    Returns the kept scenarios (at least one, maybe without plans) and what was tried.
    """
    tried = sum(len(p.plans) for p in planned)
    for p in planned:
        p.plans = [pl for pl in p.plans if labels[pl.vehicle_id].avoidable]
    kept = sum(len(p.plans) for p in planned)
    draws = 0
    for j in range(1, EXTRA_DRAWS + 1):
        if kept >= wanted:
            break
        extra = further_draw(planned[0].scene, planned[0].target_index, seed, gen, drivable, j, memo)
        draws += 1
        if extra is None:
            continue
        ids = [f"adversary{tried + i}" for i in range(len(extra.plans))]
        extra.plans = [dataclasses.replace(pl, vehicle_id=v) for pl, v in zip(extra.plans, ids, strict=True)]
        tried += len(extra.plans)
        for pl, lab in zip(extra.plans, label(extra.plans), strict=True):
            labels[pl.vehicle_id] = lab
        extra.plans = [pl for pl in extra.plans if labels[pl.vehicle_id].avoidable][:wanted - kept]
        kept += len(extra.plans)
        if extra.plans:
            planned.append(extra)
    planned = [p for p in planned if p.plans] or planned[:1]
    return planned, AvoidableOnly(tried=tried, kept=kept, extra_draws=draws)
