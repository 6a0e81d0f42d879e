"""The summary of ``coster-sumo eval scenarios`` as types: per generator its metrics.

:class:`EvalSummary` is what :func:`coster_sumo.batch.evaluate.evaluate_generators` returns; its
``to_json()`` is ``OUT/summary.json`` and ``from_json()`` reads it back. A figure with an interval
(a rate's Wilson interval, a diversity's scene bootstrap) is a :class:`~coster_sumo.metrics.MetricValue`,
written as the value under its name and ``[ci_low, ci_high]`` under ``<name>_ci``.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, ClassVar, TypeVar

from coster_sumo.batch.summaries import rate_from_json
from coster_sumo.core.results import split_known
from coster_sumo.metrics import MetricValue


@dataclass(frozen=True)
class GeneratorMethod:
    """One scenario generator of the evaluation table."""

    name: str
    init: str
    rollout: str
    collision_time: str = "entropy"
    group: str = "main"  # "main" | "ablation" (collision time) | "baseline"

    def to_json(self) -> dict[str, Any]:
        """The method's columns of its table entry (its name is the entry's key)."""
        return {"group": self.group, "init": self.init, "rollout": self.rollout, "collision_time": self.collision_time}


@dataclass(frozen=True)
class SceneFailure:
    """A scene (or one generator's task on it) without a result: its key and why."""

    scene_key: str
    reason: str | None

    def to_json(self) -> dict[str, Any]:
        return {"scene_key": self.scene_key, "reason": self.reason}


@dataclass(frozen=True)
class VariantRecord:
    """One variant of a generator, injected with the target's planner: a record of a part file
    (``OUT/parts/<part_key>.json`` ``records[i]``).

    Attributes:
        variant: its number on its scene; t_col: [s] its collision time.
        collision: the adversary touched the target; relative_speed: [m/s], impact_angle: [deg] then.
        adversary_off_road: the adversary left the drivable area.
        adversary_speed: [m/s], adversary_length, adversary_width: [m] the adversary at t_col;
            adversary_lane_type: the :class:`~coster_sumo.core.scene.LaneType` name under it then (None:
            not recorded).
        avoidable: its avoidability label (None: unlabelled).
        extra: the label's other fields as :func:`coster_sumo.avoidability.labels.label_record` writes them, and
            keys this version does not know.
        snapshot: the key of its collision snapshot (set by the aggregation, not stored).
    """

    variant: int = 0
    collision: bool = False
    adversary_off_road: bool = False
    relative_speed: float | None = None
    impact_angle: float | None = None
    t_col: float | None = None
    adversary_speed: float | None = None
    adversary_length: float | None = None
    adversary_width: float | None = None
    adversary_lane_type: str | None = None
    avoidable: bool | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)
    snapshot: str | None = None

    def to_json(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("extra", "snapshot")}
        out |= self.extra
        if self.snapshot is not None:
            out["snapshot"] = self.snapshot
        return out

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> VariantRecord:
        known, extra = split_known(cls, d)
        return cls(**known, extra=extra)


@dataclass(frozen=True)
class ScenePart:
    """``OUT/parts/<scene_key>__scene.json``: a scene's nominal pass (status "ok", or "failed" with
    ``reason``): its cached scene file and the histograms of its vehicles' speeds, (100,) over
    :data:`~coster_sumo.metrics.SPEED_BINS`, and accelerations, (200,) over
    :data:`~coster_sumo.metrics.ACCEL_BINS`, all vehicles and per lane type name; ``by_class``: the
    same of its pedestrians and of its cyclists, where it has any (a VRU adversary's reference)."""

    status: str
    reason: str | None = None
    scene_file: str = ""
    speed_hist: list[int] = field(default_factory=list)
    accel_hist: list[int] = field(default_factory=list)
    speed_hist_by_lane_type: dict[str, list[int]] = field(default_factory=dict)
    by_class: dict[str, dict[str, Any]] = field(default_factory=dict)  # the same three for its pedestrians, cyclists

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> ScenePart:
        return cls(str(d.get("status")), d.get("reason"), d.get("scene_file", ""), list(d.get("speed_hist") or ()),
                   list(d.get("accel_hist") or ()), dict(d.get("speed_hist_by_lane_type") or {}),
                   dict(d.get("by_class") or {}))


@dataclass(frozen=True)
class MethodPart:
    """``OUT/parts/<part_key>.json``: one generator on one scene.

    Attributes:
        scene_key, method: which; status: "ok", "skipped" (weights missing), "no_scenario" (no
            snapshot) or "failed" (the task), with ``reason`` but for "ok".
        records: its variants; generation_s, avoidability_s: [s] the generation and the labels.
        speed_hist, accel_hist: the adversaries' speeds and accelerations (histograms as in
            :class:`ScenePart`; empty but for "ok").
    """

    scene_key: str
    status: str
    method: str = ""
    reason: str | None = None
    records: tuple[VariantRecord, ...] = ()
    generation_s: float | None = None
    avoidability_s: float | None = None
    speed_hist: list[int] = field(default_factory=list)
    accel_hist: list[int] = field(default_factory=list)

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> MethodPart:
        return cls(str(d.get("scene_key", "")), str(d.get("status")), str(d.get("method", "")), d.get("reason"),
                   tuple(VariantRecord.from_json(r) for r in d.get("records") or ()), d.get("generation_s"),
                   d.get("avoidability_s"), list(d.get("speed_hist") or ()), list(d.get("accel_hist") or ()))


def _read(path: Path) -> Mapping[str, Any] | None:
    if not path.exists():
        return None
    try:
        d = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) else None


def read_scene_part(path: Path) -> ScenePart | None:
    """A scene's part file, or None when it is missing or unreadable (not done yet)."""
    return _parsed(path, ScenePart.from_json)


def read_method_part(path: Path) -> MethodPart | None:
    """A generator's part file, or None when it is missing or unreadable (not done yet)."""
    return _parsed(path, MethodPart.from_json)


P = TypeVar("P")


def _parsed(path: Path, parse: Callable[[Mapping[str, Any]], P]) -> P | None:
    """``parse`` of a part file; None when it is missing, no JSON object, or of another shape (a
    part of that shape is done again rather than stopping the batch)."""
    d = _read(path)
    if d is None:
        return None
    try:
        return parse(d)
    except (TypeError, ValueError, KeyError, AttributeError):
        return None


def _rates(d: Mapping[str, Any]) -> dict[str, MetricValue]:
    return {k: rate_from_json(v) for k, v in d.items()}


def _rates_json(d: Mapping[str, MetricValue]) -> dict[str, Any]:
    return {k: v.rate_json() for k, v in d.items()}


@dataclass(frozen=True)
class ContactKindShares:
    """The variants of one kind of contact: how many, and the avoidable share per reaction time [s]."""

    variants: int
    avoidable_share: dict[str, MetricValue]

    def to_json(self) -> dict[str, Any]:
        return {"variants": self.variants, "avoidable_share": _rates_json(self.avoidable_share)}


@dataclass(frozen=True)
class AvoidabilityStats:
    """The labels of one generator's variants (:func:`coster_sumo.avoidability.labels.avoidability_table`).

    Attributes:
        variants: the labelled variants; avoidable_share: per reaction time (its ``{:g}`` [s]) the
            share with an escape proven in SUMO.
        CR_avoidable, CR_unavoidable: the collision rate of the variants of each label.
        by_contact_kind: per kind of contact, its variants and their avoidable shares.
        last_moment_with_escape, last_moment_none: variants with and without a last moment to act;
            last_moment_percentiles: [s] ``p10`` .. ``p90`` of it (empty without one).
        escapes_found: kinematic escapes per reaction time; escapes_replayed, escapes_refuted_in_sumo:
            how many SUMO replayed and refuted.
        labels_moved: what each change to the labels moved (:func:`coster_sumo.avoidability.labels.labels_moved`;
            empty: not recorded).
    """

    variants: int
    avoidable_share: dict[str, MetricValue]
    CR_avoidable: MetricValue
    CR_unavoidable: MetricValue
    by_contact_kind: dict[str, ContactKindShares]
    last_moment_with_escape: int
    last_moment_none: int
    last_moment_percentiles: dict[str, float]
    escapes_found: dict[str, int]
    escapes_replayed: int
    escapes_refuted_in_sumo: int
    labels_moved: Mapping[str, Any] = field(default_factory=dict)

    def moved_cell(self) -> str:
        """The labels turned avoidable by plans SUMO's traffic cleared, for a report's table cell."""
        f = self.labels_moved.get("labels_flipped_by_reacting_traffic")
        if not f:
            return "n/a"
        return (f"{f['count']} ({100 * (f['share'] or 0.0):.1f} %; "
                f"{self.labels_moved['blocked_escapes_cleared_in_sumo']} of "
                f"{self.labels_moved['blocked_escapes_tried_in_sumo']} blocked escapes cleared)")

    def to_json(self) -> dict[str, Any]:
        return {"variants": self.variants, "avoidable_share": _rates_json(self.avoidable_share),
                "CR_by_label": {"avoidable": self.CR_avoidable.rate_json(),
                                "unavoidable": self.CR_unavoidable.rate_json()},
                "by_contact_kind": {k: v.to_json() for k, v in self.by_contact_kind.items()},
                "last_moment_s": {"with_escape": self.last_moment_with_escape, "none": self.last_moment_none,
                                  **self.last_moment_percentiles},
                "escapes_found": dict(self.escapes_found), "escapes_replayed": self.escapes_replayed,
                "escapes_refuted_in_sumo": self.escapes_refuted_in_sumo, **self.labels_moved}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> AvoidabilityStats:
        last = dict(d["last_moment_s"])
        return cls(d["variants"], _rates(d["avoidable_share"]), rate_from_json(d["CR_by_label"]["avoidable"]),
                   rate_from_json(d["CR_by_label"]["unavoidable"]),
                   {k: ContactKindShares(v["variants"], _rates(v["avoidable_share"]))
                    for k, v in d["by_contact_kind"].items()},
                   last.pop("with_escape"), last.pop("none"), last, dict(d["escapes_found"]),
                   d["escapes_replayed"], d["escapes_refuted_in_sumo"],
                   {k: d[k] for k in _MOVED if k in d})


_MOVED = ("blocked_escapes_tried_in_sumo", "blocked_escapes_cleared_in_sumo", "labels_flipped_by_reacting_traffic")


def _ci(v: MetricValue) -> list[float | None]:
    return [v.ci_low, v.ci_high]


def _with_ci(d: Mapping[str, Any], name: str) -> MetricValue:
    low, high = d.get(f"{name}_ci") or (None, None)
    return MetricValue(d[name], low, high)


@dataclass(frozen=True)
class GeneratorResult:
    """One generator that ran (summary.json ``methods.table[name]`` with status ``ok``).

    Attributes:
        method: the generator; scenes: the scenes it ran on; variants: its variants over all of them.
        failed_tasks: its scenes whose task failed.
        SUR, CR, ORR: success, collision and off-road rates with Wilson intervals.
        VDD, ADD: [nats] divergences of speeds / accelerations against the nominal traffic.
        CSD: [m/s], CPD, CPD_circular: [deg] diversities with intervals from resampling scenes.
        generation_s_per_variant: [s] (None: no variant).
        avoidability: the labels of its variants.
        relative_speeds: [m/s], impact_angles: [deg] at each contact (summary.json only).
        VDD_tcol, VDD_tcol_floor: [nats] the adversaries' speeds at t_col against the nominal ones
            on lanes of their type, and the floor of that; size_in_class: [fraction].
        adversaries_by_lane_type: adversaries per lane type name.
    """

    method: GeneratorMethod
    scenes: int
    variants: int
    failed_tasks: tuple[SceneFailure, ...]
    SUR: MetricValue
    CR: MetricValue
    ORR: MetricValue
    VDD: float | None
    ADD: float | None
    CSD: MetricValue
    CPD: MetricValue
    CPD_circular: MetricValue
    generation_s_per_variant: float | None
    avoidability: AvoidabilityStats
    relative_speeds: tuple[float | None, ...]
    impact_angles: tuple[float | None, ...]
    VDD_tcol: float | None
    VDD_tcol_floor: float | None
    size_in_class: float | None
    adversaries_by_lane_type: dict[str, int] = field(default_factory=dict)
    status: ClassVar[str] = "ok"

    def to_json(self, contacts: bool = True) -> dict[str, Any]:
        """The entry; ``contacts``: with the per-contact relative speeds and impact angles."""
        out: dict[str, Any] = {
            **self.method.to_json(), "status": "ok", "scenes": self.scenes, "variants": self.variants,
            "failed_tasks": [f.to_json() for f in self.failed_tasks],
            "SUR": self.SUR.value, "CR": self.CR.value, "ORR": self.ORR.value,
            "SUR_ci": _ci(self.SUR), "CR_ci": _ci(self.CR), "ORR_ci": _ci(self.ORR), "VDD": self.VDD, "ADD": self.ADD,
            "CSD": self.CSD.value, "CPD": self.CPD.value, "CPD_circular": self.CPD_circular.value,
            "generation_s_per_variant": self.generation_s_per_variant, "avoidability": self.avoidability.to_json()}
        if contacts:
            out |= {"relative_speeds": list(self.relative_speeds), "impact_angles": list(self.impact_angles)}
        return out | {"VDD_tcol": self.VDD_tcol, "VDD_tcol_floor": self.VDD_tcol_floor,
                      "size_in_class": self.size_in_class,
                      "adversaries_by_lane_type": dict(self.adversaries_by_lane_type),
                      "CSD_ci": _ci(self.CSD), "CPD_ci": _ci(self.CPD), "CPD_circular_ci": _ci(self.CPD_circular)}

    @classmethod
    def from_json(cls, name: str, d: Mapping[str, Any]) -> GeneratorResult:
        return cls(GeneratorMethod(name, d["init"], d["rollout"], d["collision_time"], d["group"]), d["scenes"],
                   d["variants"], tuple(SceneFailure(**f) for f in d["failed_tasks"]), _with_ci(d, "SUR"),
                   _with_ci(d, "CR"), _with_ci(d, "ORR"), d["VDD"], d["ADD"], _with_ci(d, "CSD"), _with_ci(d, "CPD"),
                   _with_ci(d, "CPD_circular"), d["generation_s_per_variant"],
                   AvoidabilityStats.from_json(d["avoidability"]), tuple(d.get("relative_speeds", ())),
                   tuple(d.get("impact_angles", ())), d.get("VDD_tcol"), d.get("VDD_tcol_floor"),
                   d.get("size_in_class"), dict(d.get("adversaries_by_lane_type", {})))


@dataclass(frozen=True)
class SkippedGenerator:
    """A generator that did not run (its weights are missing): the method and why."""

    method: GeneratorMethod
    reason: str
    status: ClassVar[str] = "skipped"

    def to_json(self, contacts: bool = True) -> dict[str, Any]:
        return {**self.method.to_json(), "status": "skipped", "reason": self.reason}


GeneratorEntry = GeneratorResult | SkippedGenerator


def entry_from_json(name: str, d: Mapping[str, Any]) -> GeneratorEntry:
    """A generator's entry of summary.json."""
    if d["status"] == "ok":
        return GeneratorResult.from_json(name, d)
    return SkippedGenerator(GeneratorMethod(name, d["init"], d["rollout"], d["collision_time"], d["group"]),
                            d["reason"])


@dataclass(frozen=True)
class PairedDiversity:
    """The reference generator's diversities minus another's, on the scenes both generated for:
    each ``(difference, low, high)`` with a 95 % interval from resampling those scenes.

    Attributes:
        scenes: the scenes shared; CSD: [m/s]; CPD, CPD_circular: [deg].
    """

    scenes: int
    CSD: tuple[float, float, float]
    CPD: tuple[float, float, float]
    CPD_circular: tuple[float, float, float]

    def to_json(self) -> dict[str, Any]:
        return {"scenes": self.scenes, "CSD": list(self.CSD), "CPD": list(self.CPD),
                "CPD_circular": list(self.CPD_circular)}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> PairedDiversity:
        return cls(d["scenes"], tuple(d["CSD"]), tuple(d["CPD"]), tuple(d["CPD_circular"]))  # type: ignore[arg-type]


@dataclass(frozen=True)
class GeneratorTable:
    """Every generator's entry (in the order asked), the scenes that failed, and the paired
    differences (``"COSTER - <other>"`` -> :class:`PairedDiversity`; empty without COSTER)."""

    table: dict[str, GeneratorEntry]
    failed_scenes: tuple[SceneFailure, ...] = ()
    paired: dict[str, PairedDiversity] = field(default_factory=dict)

    @property
    def ran(self) -> dict[str, GeneratorResult]:
        """The generators that ran."""
        return {k: m for k, m in self.table.items() if isinstance(m, GeneratorResult)}

    def to_json(self) -> dict[str, Any]:
        return {"table": {k: m.to_json() for k, m in self.table.items()},
                "failed_scenes": [f.to_json() for f in self.failed_scenes],
                "paired": {k: p.to_json() for k, p in self.paired.items()}}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> GeneratorTable:
        return cls({k: entry_from_json(k, m) for k, m in d["table"].items()},
                   tuple(SceneFailure(**f) for f in d["failed_scenes"]),
                   {k: PairedDiversity.from_json(p) for k, p in d.get("paired", {}).items()})


EVAL_UNITS: Mapping[str, str] = {
    "SUR/CR/ORR": "fraction", "VDD/ADD": "Jensen-Shannon divergence, nats (max ln 2)", "CSD": "m/s",
    "CPD/CPD_circular": "deg", "generation_s_per_variant": "s"}


@dataclass(frozen=True)
class EvalSummary:
    """What ``coster-sumo eval scenarios`` returns and writes to ``OUT/summary.json``.

    Attributes:
        scenes: scene key -> its label; planner: who drove the target; variants: asked per scene and
            method; samples: CVAE trajectories oversampled; methods: the generators' table.
        wall_time_s: [s] the whole command; report: the report's files relative to OUT (None: not yet).
        adversary: the adversary class generated (``--adversary``).
        traffic: a converted scene's agents in the labels' proofs and the injections (``--traffic``).
    """

    scenes: dict[str, str]
    planner: str
    variants: int
    samples: int
    methods: GeneratorTable
    wall_time_s: float | None = None
    units: Mapping[str, str] = field(default_factory=lambda: dict(EVAL_UNITS))
    report: tuple[str, ...] | None = None
    adversary: str = "vehicle"
    traffic: str = "log"

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"command": "eval scenarios", "adversary": self.adversary, "traffic": self.traffic,
                               "scenes": dict(self.scenes), "planner": self.planner,
                               "variants": self.variants, "samples": self.samples, "methods": self.methods.to_json()}
        if self.wall_time_s is not None:
            out["wall_time_s"] = self.wall_time_s
        out["units"] = dict(self.units)
        if self.report is not None:
            out["report"] = list(self.report)
        return out

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> EvalSummary:
        return cls(dict(d["scenes"]), d["planner"], d["variants"], d["samples"], GeneratorTable.from_json(d["methods"]),
                   d.get("wall_time_s"), dict(d.get("units", EVAL_UNITS)),
                   tuple(d["report"]) if "report" in d else None, str(d.get("adversary", "vehicle")),
                   str(d.get("traffic", "log")))
