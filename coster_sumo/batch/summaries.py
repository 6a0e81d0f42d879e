"""The summaries of the batch commands as types: what ``regress`` and ``eval scenarios`` return.

``regress`` returns a :class:`RegressionSummary` (per planner a :class:`PlannerSummary` with its
:class:`DefectRates`); ``eval scenarios`` returns an :class:`EvalSummary` (per generator a
:class:`GeneratorResult`). Their ``to_json()`` is the content of ``OUT/summary.json`` (the README
documents the keys, in s, m/s and deg), written as the last step; ``from_json()`` reads it back.
Rates are :class:`~coster_sumo.metrics.MetricValue` (value, Wilson 95 % interval, k of n) and are
written as ``{"rate", "ci_low", "ci_high", "k", "n"}``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from coster_sumo.metrics import MetricSample, MetricValue, RunOutcome, compute


def rate_from_json(d: Mapping[str, Any]) -> MetricValue:
    """A rate as written by :meth:`~coster_sumo.metrics.MetricValue.rate_json`."""
    return MetricValue(d["rate"], d["ci_low"], d["ci_high"], d["k"], d["n"])


# ============================================================================ regression


@dataclass(frozen=True)
class LabelRates:
    """A planner's rates on the runs of the variants with one avoidability label.

    Attributes:
        CR: the target touched anyone; RCR: the target completed its route; ORR: the target left the road.
    """

    CR: MetricValue
    RCR: MetricValue
    ORR: MetricValue

    def to_json(self) -> dict[str, Any]:
        return {"CR": self.CR.rate_json(), "RCR": self.RCR.rate_json(), "ORR": self.ORR.rate_json()}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> LabelRates:
        return cls(rate_from_json(d["CR"]), rate_from_json(d["RCR"]), rate_from_json(d["ORR"]))


@dataclass(frozen=True)
class DefectRates:
    """One planner's defects (:func:`defect_rates`).

    Attributes:
        defect_rate: runs on avoidable variants with a contact of the target (within the label's horizon).
        unavoidable_contact_rate: runs on unavoidable variants with such a contact.
        avoidable_runs, unavoidable_runs, unlabelled_runs: the finished runs by their variant's label.
        avoidable, unavoidable: the planner's rates split by the label (JSON ``by_label``).
    """

    defect_rate: MetricValue
    unavoidable_contact_rate: MetricValue
    avoidable_runs: int
    unavoidable_runs: int
    unlabelled_runs: int
    avoidable: LabelRates
    unavoidable: LabelRates

    def to_json(self) -> dict[str, Any]:
        return {"defect_rate": self.defect_rate.rate_json(),
                "unavoidable_contact_rate": self.unavoidable_contact_rate.rate_json(),
                "avoidable_runs": self.avoidable_runs, "unavoidable_runs": self.unavoidable_runs,
                "unlabelled_runs": self.unlabelled_runs,
                "by_label": {"avoidable": self.avoidable.to_json(), "unavoidable": self.unavoidable.to_json()}}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> DefectRates:
        return cls(rate_from_json(d["defect_rate"]), rate_from_json(d["unavoidable_contact_rate"]),
                   d["avoidable_runs"], d["unavoidable_runs"], d["unlabelled_runs"],
                   LabelRates.from_json(d["by_label"]["avoidable"]), LabelRates.from_json(d["by_label"]["unavoidable"]))


@dataclass(frozen=True)
class PlannerSummary:
    """One planner of a regression (summary.json ``planners[name]``).

    Attributes:
        runs: the runs recorded; failed: those that did not finish (not in the rates).
        RCR, CR, ORR: the target's route completion, collision (with anyone) and off-road rates.
        adversary_contact_rate: the adversary touched the target.
        median_min_ttc_s: [s] over the runs without contact; mean_relative_speed_mps: [m/s] at contact
            (None: no such run).
        defects: the defect and unavoidable-contact rates.
    """

    runs: int
    failed: int
    RCR: MetricValue
    CR: MetricValue
    ORR: MetricValue
    adversary_contact_rate: MetricValue
    median_min_ttc_s: float | None
    mean_relative_speed_mps: float | None
    defects: DefectRates

    def to_json(self) -> dict[str, Any]:
        return {"runs": self.runs, "failed": self.failed, "RCR": self.RCR.rate_json(), "CR": self.CR.rate_json(),
                "ORR": self.ORR.rate_json(), "adversary_contact_rate": self.adversary_contact_rate.rate_json(),
                "median_min_ttc_s": self.median_min_ttc_s, "mean_relative_speed_mps": self.mean_relative_speed_mps,
                "defects": self.defects.to_json()}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> PlannerSummary:
        return cls(d["runs"], d["failed"], rate_from_json(d["RCR"]), rate_from_json(d["CR"]), rate_from_json(d["ORR"]),
                   rate_from_json(d["adversary_contact_rate"]), d["median_min_ttc_s"], d["mean_relative_speed_mps"],
                   DefectRates.from_json(d["defects"]))


@dataclass(frozen=True)
class GenerationFailure:
    """A scene of a regression whose variants were not generated: its key, its label, why."""

    scene_key: str
    scene: str
    reason: str | None

    def to_json(self) -> dict[str, Any]:
        return {"scene_key": self.scene_key, "scene": self.scene, "reason": self.reason}


@dataclass(frozen=True)
class RunFailure:
    """A run of a regression that did not finish: its key and why (timeout, crash, ...)."""

    run_key: str
    reason: str | None

    def to_json(self) -> dict[str, Any]:
        return {"run_key": self.run_key, "reason": self.reason}


@dataclass(frozen=True)
class SceneCounts:
    """The scenes of a regression: how many, how many generated their variants, the others."""

    total: int
    generated: int
    failed: tuple[GenerationFailure, ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {"total": self.total, "generated": self.generated, "failed": [f.to_json() for f in self.failed]}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> SceneCounts:
        return cls(d["total"], d["generated"], tuple(GenerationFailure(**f) for f in d["failed"]))


@dataclass(frozen=True)
class RunCounts:
    """The runs of a regression: expected (variants x planners), recorded, finished, failed (and why)."""

    expected: int
    recorded: int
    ok: int
    failed: int
    failures: tuple[RunFailure, ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {"expected": self.expected, "recorded": self.recorded, "ok": self.ok, "failed": self.failed,
                "failures": [f.to_json() for f in self.failures]}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> RunCounts:
        return cls(d["expected"], d["recorded"], d["ok"], d["failed"], tuple(RunFailure(**f) for f in d["failures"]))


@dataclass(frozen=True)
class RegressionRunOptions:
    """The options a regression ran with, as summary.json records them (``timeout_s``: None, none)."""

    variants: int
    workers: int
    executor: str
    timeout_s: float | None
    init: str
    rollout: str
    collision_time: str
    samples: int
    seed: int
    adversary: str = "vehicle"

    def to_json(self) -> dict[str, Any]:
        return {"variants": self.variants, "workers": self.workers, "executor": self.executor,
                "timeout_s": self.timeout_s, "init": self.init, "rollout": self.rollout,
                "collision_time": self.collision_time, "samples": self.samples, "seed": self.seed,
                "adversary": self.adversary}


REGRESSION_UNITS: Mapping[str, str] = {
    "rates": "fraction of runs, Wilson 95% interval",
    "defect_rate": "fraction of runs on avoidable variants with a contact of the target",
    "min_ttc": "s", "relative_speed": "m/s", "impact_angle": "deg"}
RESULTS_NOTE = "results/ (Parquet dataset, one part per run)"


@dataclass(frozen=True)
class RegressionSummary:
    """What ``coster-sumo regress`` returns and writes to ``OUT/summary.json``.

    Attributes:
        scenes: the scenes and those without variants; runs: the runs and those that failed.
        variants: generated over all scenes; avoidable_variants: those with an escape proven in
            SUMO; variants_tried: variants drawn (more than ``variants`` with ``--avoidable only``).
        planners: per planner (in the order given) its rates.
        wall_time_s: [s] the whole command; options: what it ran with (None: not recorded, as for a
            summary computed outside the command).
        report: the report's files relative to OUT (None: ``--no-report``).
        labels_moved: what each change to the labels moved (:func:`coster_sumo.avoidability.labels.labels_moved`
            over the variants' labels; empty: not recorded).
        defects_by_class: planner -> adversary class -> its defect rates (:mod:`coster_sumo.batch.by_class`).
    """

    scenes: SceneCounts
    variants: int
    avoidable_variants: int
    variants_tried: int
    runs: RunCounts
    planners: dict[str, PlannerSummary]
    results: str = RESULTS_NOTE
    units: Mapping[str, str] = field(default_factory=lambda: dict(REGRESSION_UNITS))
    wall_time_s: float | None = None
    options: RegressionRunOptions | None = None
    report: tuple[str, ...] | None = None
    labels_moved: Mapping[str, Any] = field(default_factory=dict)
    defects_by_class: Mapping[str, Any] = field(default_factory=dict)

    def moved_words(self) -> str:
        """One sentence on the labels that plans blocked only by reacting traffic moved ('' without)."""
        m = self.labels_moved
        if not m:
            return ""
        f = m["labels_flipped_by_reacting_traffic"]
        return (f" SUMO tried {m['blocked_escapes_tried_in_sumo']} escapes that only traffic which reacts was in the"
                f" way of and cleared {m['blocked_escapes_cleared_in_sumo']}; {f['count']} of {self.variants} labels"
                f" ({100 * (f['share'] or 0.0):.1f} %) turned avoidable through them.")

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "command": "regress", "scenes": self.scenes.to_json(), "variants": self.variants,
            "avoidable_variants": self.avoidable_variants, "variants_tried": self.variants_tried,
            "runs": self.runs.to_json(), "planners": {k: p.to_json() for k, p in self.planners.items()},
            "results": self.results, "units": dict(self.units)}
        if self.wall_time_s is not None:
            out["wall_time_s"] = self.wall_time_s
        if self.options is not None:
            out["options"] = self.options.to_json()
        if self.report is not None:
            out["report"] = list(self.report)
        if self.labels_moved:
            out["labels_moved"] = dict(self.labels_moved)
        if self.defects_by_class:
            out["defects_by_class"] = dict(self.defects_by_class)
        return out

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> RegressionSummary:
        return cls(SceneCounts.from_json(d["scenes"]), d["variants"], d.get("avoidable_variants", 0),
                   d.get("variants_tried", d["variants"]), RunCounts.from_json(d["runs"]),
                   {k: PlannerSummary.from_json(p) for k, p in d["planners"].items()},
                   d.get("results", RESULTS_NOTE), dict(d.get("units", REGRESSION_UNITS)), d.get("wall_time_s"),
                   RegressionRunOptions(**d["options"]) if "options" in d else None,
                   tuple(d["report"]) if "report" in d else None, labels_moved=d.get("labels_moved") or {},
                   defects_by_class=d.get("defects_by_class") or {})


# a planner's rates in a regression: key of summary.json -> the metric of coster_sumo.metrics.REGISTRY
# (the target is under test: CR and ORR are the target's)
PLANNER_RATES = {"RCR": "RCR", "CR": "CR_target", "ORR": "ORR_target"}


def defect_rates(outcomes: Sequence[RunOutcome]) -> DefectRates:
    """The defect rate (a contact of the target in an avoidable variant) beside the unavoidable-contact
    rate, and :data:`PLANNER_RATES` split by the label, of one planner's finished runs, all from the
    metrics' registry.

    A contact counts up to the label's horizon (:data:`~coster_sumo.avoidability.search.HORIZON_AFTER_TCOL_S` after
    t_col): that is what an escape is proven for; what happens later (the pass goes on until the
    target arrives) stays in the plain collision rate.
    """
    every = MetricSample(tuple(outcomes))
    avoidable = MetricSample(tuple(o for o in outcomes if o.avoidable is True))
    unavoidable = MetricSample(tuple(o for o in outcomes if o.avoidable is False))
    av, un = len(avoidable.outcomes), len(unavoidable.outcomes)
    return DefectRates(defect_rate=compute("defect_rate", every),
                       unavoidable_contact_rate=compute("unavoidable_contact_rate", every),
                       avoidable_runs=av, unavoidable_runs=un, unlabelled_runs=len(outcomes) - av - un,
                       avoidable=_label_rates(avoidable), unavoidable=_label_rates(unavoidable))


def _label_rates(part: MetricSample) -> LabelRates:
    """:data:`PLANNER_RATES` of the runs of one label."""
    return LabelRates(CR=compute(PLANNER_RATES["CR"], part), RCR=compute(PLANNER_RATES["RCR"], part),
                      ORR=compute(PLANNER_RATES["ORR"], part))
