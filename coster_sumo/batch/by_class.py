"""A regression's defect rate per adversary class (vehicle, pedestrian, cyclist): the runs of each
planner split by the class of the variant's adversary (``--adversary``; ``any`` mixes them)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from coster_sumo.batch.store import ResultRow, row_outcome
from coster_sumo.batch.summaries import defect_rates


def defects_by_class(rows: Sequence[ResultRow], planners: Sequence[str]) -> dict[str, dict[str, Any]]:
    """planner -> class -> its defect rates (``DefectRates.to_json``) over the planner's finished runs;
    a row stored without a class (before ``--adversary`` existed) counts as ``vehicle``."""
    out: dict[str, dict[str, Any]] = {}
    for p in planners:
        mine = [r for r in rows if r.planner == p and r.ok]
        classes = sorted({r.adversary_class or "vehicle" for r in mine})
        out[p] = {c: defect_rates([row_outcome(r) for r in mine if (r.adversary_class or "vehicle") == c]).to_json()
                  for c in classes}
    return out


def class_table(by_class: Mapping[str, Mapping[str, Any]]) -> tuple[list[str], list[list[str]]]:
    """Per planner and class: runs on avoidable variants and the defect rate with its interval."""
    head = ["planner", "adversary", "avoidable runs", "defect rate [95% CI]"]
    rows = []
    for planner, classes in by_class.items():
        for name, d in classes.items():
            r = d["defect_rate"]
            rate = "n/a" if r.get("rate") is None else (
                f"{100 * r['rate']:.1f} % [{100 * r['ci_low']:.1f}, {100 * r['ci_high']:.1f}]"
                if r.get("ci_low") is not None else f"{100 * r['rate']:.1f} %")
            rows.append([planner, name, str(d["avoidable_runs"]), rate])
    return head, rows
