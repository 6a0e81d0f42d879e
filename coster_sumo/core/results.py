"""The results of ``coster-sumo run`` as objects: a variant's outcome, a target's result, a run's summary.

``run.run`` returns one of them, the command line and the exports read them, and ``summary.json`` is
their JSON (:meth:`to_json`; the README documents the keys, in s, m, m/s and deg). What a later step
adds to a record (the avoidability label, an export error) and keys this version does not know are
kept under ``extra``, so ``from_json(to_json())`` gives the same object and the same JSON back.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from coster_sumo.errors import InputError, not_found
from coster_sumo.metrics import RunOutcome


def split_known(cls: type, d: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """The keys of ``d`` that are fields of ``cls`` (but ``extra``), and the others."""
    names = {f.name for f in fields(cls)} - {"extra"}
    return {k: v for k, v in d.items() if k in names}, {k: v for k, v in d.items() if k not in names}


def _plain(obj: Any, omit: tuple[str, ...] = ()) -> dict[str, Any]:
    """The fields of a record in their order (its JSON's key order), without ``extra`` and
    ``folder``, and without the ``omit`` ones that are None (a key such a summary has only when it
    applies); tuples as lists."""
    out: dict[str, Any] = {}
    for f in fields(obj):
        v = getattr(obj, f.name)
        if f.name in ("extra", "folder") or (f.name in omit and v is None):
            continue
        out[f.name] = list(v) if isinstance(v, tuple) else v
    return out


@dataclass(frozen=True)
class VariantOutcome:
    """One variant of a run (summary.json ``variants[i]``).

    Attributes:
        variant: its number, across the snapshots; snapshot: the snapshot it belongs to.
        adversary_id: the adversary's vehicle id.
        t_col: [s] its snapshot's collision time; plan_start_s: [s] when its adversary appears;
            approach_m: [m] the length of its approach up to t_col.
        collision: the adversary touched the target (our box check); collision_time: [s] then;
            contact_offset_s: [s] after t_col on SUMO's step grid; relative_speed: [m/s];
            impact_angle: [deg] in the target's frame; no_contact_reason: why not, without contact.
        closest_distance_m: [m] the smallest gap of the two boxes (negative: overlap depth).
        adversary_off_road, target_off_road, route_completed, target_arrived: the pass's flags.
        min_ttc: [s] smallest time to collision before contact (None: never closing).
        other_collisions: collisions not between the two; other_collisions_list: one line each.
        sumo_only_collisions: SUMO's own reports of those; sumo_reported_contact: SUMO saw the contact.
        wall_time_s: [s] the pass's wall clock.
        export_error: why its plain-SUMO export is missing (None: it was written).
        avoidability: its label as summary.json holds it (``Avoidability.summary`` of
            :mod:`coster_sumo.avoidability.evasion`, plus ``escape_file``); label: the label in words;
            outcome: how the target's planner fared, in words (None until labelled).
        adversary_class: vehicle, pedestrian or cyclist (for the two last, ``adversary_off_road`` says
            whether it left its class's area: :mod:`coster_sumo.method.vru.areas`).
        extra: keys this version does not know.
    """

    variant: int
    adversary_id: str = ""
    adversary_class: str = "vehicle"
    plan_start_s: float | None = None
    approach_m: float | None = None
    collision: bool = False
    collision_time: float | None = None
    contact_offset_s: float | None = None
    relative_speed: float | None = None
    impact_angle: float | None = None
    no_contact_reason: str | None = None
    closest_distance_m: float | None = None
    adversary_off_road: bool = False
    target_off_road: bool = False
    route_completed: bool = False
    target_arrived: bool = False
    min_ttc: float | None = None
    other_collisions: int = 0
    other_collisions_list: tuple[str, ...] = ()
    sumo_only_collisions: int = 0
    sumo_reported_contact: bool = False
    wall_time_s: float | None = None
    snapshot: int = 0
    t_col: float | None = None
    export_error: str | None = None
    avoidability: Mapping[str, Any] | None = None
    label: str | None = None
    outcome: str | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    _OMITTED = ("export_error", "avoidability", "label", "outcome")

    def to_json(self) -> dict[str, Any]:
        return {**_plain(self, self._OMITTED), **self.extra}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> VariantOutcome:
        known, extra = split_known(cls, d)
        known["other_collisions_list"] = tuple(known.get("other_collisions_list", ()))
        return cls(**known, extra=extra)

    @property
    def avoidable(self) -> bool | None:
        """Whether its contact was avoidable (None: not labelled)."""
        return None if self.avoidability is None else bool(self.avoidability["avoidable"])

    def run_outcome(self) -> RunOutcome:
        """The variant as the metrics read it (:data:`coster_sumo.metrics.REGISTRY`)."""
        return RunOutcome(adversary_contact=self.collision, adversary_off_road=self.adversary_off_road,
                          target_off_road=self.target_off_road, route_completed=self.route_completed,
                          relative_speed=self.relative_speed, impact_angle=self.impact_angle, min_ttc=self.min_ttc)


@dataclass(frozen=True)
class SnapshotRecord:
    """One collision snapshot of a run (summary.json ``snapshots[k]``).

    Attributes:
        snapshot: its number; t_col: [s] its collision time; t_col_sim: [s] the same on SUMO's step
            grid; t_col_index_2hz: its 2 Hz step; collision_time_method, init_method: how it was chosen.
        signed_distance: [m] of the two boxes in the snapshot (<= 0: in contact).
        adversary: the adversary's state in it (x, y [m], heading_deg, speed [m/s], length, width [m]).
        variants: the numbers of its variants; impact_angles_deg: of those in contact.
        generation: what its rollout reported (timings, clusters, and the candidates ``dropped``,
            ``failed`` and ``collision_times_given_up``, with their reasons).
        adversary_class: vehicle, pedestrian or cyclist.
        extra: keys this version does not know.
    """

    snapshot: int = 0
    t_col: float | None = None
    t_col_sim: float | None = None
    t_col_index_2hz: int | None = None
    collision_time_method: str = ""
    init_method: str = ""
    signed_distance: float | None = None
    adversary: Mapping[str, float] = field(default_factory=dict)
    variants: tuple[int, ...] = ()
    generation: Mapping[str, Any] = field(default_factory=dict)
    impact_angles_deg: tuple[float | None, ...] = ()
    adversary_class: str = "vehicle"
    extra: Mapping[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {**_plain(self), **self.extra}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> SnapshotRecord:
        known, extra = split_known(cls, d)
        known["variants"] = tuple(known.get("variants", ()))
        known["impact_angles_deg"] = tuple(known.get("impact_angles_deg", ()))
        return cls(**known, extra=extra)

    @property
    def failed(self) -> list[dict[str, Any]]:
        """Its variants whose SUMO pass failed: adversary, t_col, reason."""
        return list(self.generation.get("failed", []))

    @property
    def dropped(self) -> list[dict[str, Any]]:
        """Its candidates that did not become variants: candidate, reason."""
        return list(self.generation.get("dropped", []))

    @property
    def given_up(self) -> dict[str, str]:
        """Collision times given up before this one ("t_col 20.6 s") -> why."""
        return dict(self.generation.get("collision_times_given_up") or {})


@dataclass(frozen=True)
class TargetMotion:
    """How the target moved in the nominal pass (summary.json ``target_motion``): seconds in the
    recording, seconds standing still, metres driven."""

    in_window_s: float = 0.0
    stopped_s: float = 0.0
    distance_m: float = 0.0

    def to_json(self) -> dict[str, Any]:
        return _plain(self)


@dataclass(frozen=True)
class AvoidableOnly:
    """What ``--avoidable only`` tried (summary.json ``avoidable_only``): variants labelled, those
    kept (avoidable), and the further draws spent."""

    tried: int
    kept: int
    extra_draws: int

    def to_json(self) -> dict[str, Any]:
        return _plain(self)


@dataclass(frozen=True)
class LabelCounts:
    """The labels over a target's variants (summary.json, beside its variants).

    Attributes:
        avoidable_variants: variants whose contact was avoidable; reaction_time_s: [s] the
            reaction time of the labels; defects: contacts that were avoidable;
            unavoidable_contacts: contacts that were not; avoidable_share: avoidable / variants
            (None without variants).
    """

    avoidable_variants: int
    reaction_time_s: float
    defects: int
    unavoidable_contacts: int
    avoidable_share: float | None

    def to_json(self) -> dict[str, Any]:
        return _plain(self)


@dataclass(frozen=True)
class TargetResult:
    """The result of one target (summary.json of a one-target run, or of ``OUT/<target>/``).

    The fields are in summary.json's order; those that are None where a run has nothing to say
    (``nominal_cut_after_s``, ``target_choice``, ``avoidable_only``, ``labels``) are left out of it.

    Attributes:
        folder: where it was written.
        target: the target's id; config: the configuration; planner: the target's planner; seed.
        t_col: [s] the first snapshot's collision time; num_snapshots, num_variants: counts.
        collision_rate, off_road_rate: shares of the variants (None without variants);
            impact_angle_spread_deg: [deg] the circular range of the impact angles.
        variants: every variant's outcome; snapshots: one record per collision snapshot.
        scenario_id: the nominal scene's id; t_col_sim, t_col_index_2hz, collision_time_method,
            init_method, snapshot_signed_distance: of the first snapshot (see :class:`SnapshotRecord`).
        nominal_until_s: [s] the nominal pass's last step; nominal_cut_after_s: [s] after the
            target's departure, where a pass stopped before it arrived (None: it did not stop).
        target_motion: how the target moved in the nominal pass.
        generation: the first snapshot's rollout report (as in :attr:`SnapshotRecord.generation`).
        timings_s: [s] per phase; options: the run's options (``RunOptions.to_json``).
        renders: the PNGs written, relative to :attr:`folder`.
        target_choice: how ``--targets N`` chose (None: it was named).
        avoidable_only: what ``--avoidable only`` tried (None: not asked).
        labels: the labels' counts (None before the labels are attached).
        adversary: the adversary class asked for (``--adversary``; each variant says its own).
        extra: keys this version does not know.
    """

    folder: Path
    target: str
    config: str = ""
    planner: str = ""
    seed: int = 0
    t_col: float | None = None
    num_snapshots: int = 1
    num_variants: int = 0
    collision_rate: float | None = None
    off_road_rate: float | None = None
    impact_angle_spread_deg: float | None = None
    variants: tuple[VariantOutcome, ...] = ()
    snapshots: tuple[SnapshotRecord, ...] = ()
    scenario_id: str = ""
    t_col_sim: float | None = None
    t_col_index_2hz: int | None = None
    collision_time_method: str = ""
    init_method: str = ""
    snapshot_signed_distance: float | None = None
    nominal_until_s: float | None = None
    nominal_cut_after_s: float | None = None
    target_motion: TargetMotion = field(default_factory=TargetMotion)
    generation: Mapping[str, Any] = field(default_factory=dict)
    timings_s: Mapping[str, float] = field(default_factory=dict)
    options: Mapping[str, Any] = field(default_factory=dict)
    renders: tuple[str, ...] = ()
    target_choice: tuple[Mapping[str, Any], ...] | None = None
    avoidable_only: AvoidableOnly | None = None
    labels: LabelCounts | None = None
    adversary: str = "vehicle"
    extra: Mapping[str, Any] = field(default_factory=dict)

    _OMITTED = ("nominal_cut_after_s", "target_choice", "avoidable_only", "labels")

    @property
    def failed(self) -> list[dict[str, Any]]:
        """The variants whose SUMO pass failed (crash, timeout): adversary, t_col, reason."""
        return [f for s in self.snapshots for f in s.failed]

    def to_json(self) -> dict[str, Any]:
        out = _plain(self, self._OMITTED)
        out["variants"] = [v.to_json() for v in self.variants]
        out["snapshots"] = [s.to_json() for s in self.snapshots]
        out["target_motion"] = self.target_motion.to_json()
        if self.avoidable_only is not None:
            out["avoidable_only"] = self.avoidable_only.to_json()
        labels = out.pop("labels", None)
        return {**out, **(labels.to_json() if labels is not None else {}), **self.extra}

    @classmethod
    def from_json(cls, d: Mapping[str, Any], folder: Path) -> TargetResult:
        counted = {f.name for f in fields(LabelCounts)}
        known, extra = split_known(cls, {k: v for k, v in d.items() if k not in counted})
        known.pop("folder", None)
        known.pop("labels", None)
        known["variants"] = tuple(VariantOutcome.from_json(v) for v in d.get("variants", ()))
        known["snapshots"] = tuple(SnapshotRecord.from_json(s) for s in d.get("snapshots", ()))
        known["target"] = str(known.get("target", ""))
        known["target_motion"] = TargetMotion(**known.get("target_motion", {}))
        known["renders"] = tuple(known.get("renders", ()))
        if known.get("target_choice") is not None:
            known["target_choice"] = tuple(known["target_choice"])
        if known.get("avoidable_only") is not None:
            known["avoidable_only"] = AvoidableOnly(**known["avoidable_only"])
        labels = LabelCounts(**{k: d[k] for k in counted}) if counted <= d.keys() else None
        return cls(folder=Path(folder), **known, labels=labels, extra=extra)


@dataclass(frozen=True)
class TargetEntry:
    """One target of a run with several (summary.json ``targets[i]``): its result, or why it has none.

    Attributes:
        target: its id; folder: its folder's name under OUT (None: no scenario); error: why not.
        result: its result (None: no scenario, or read from a summary without it).
        extra: the listed figures (t_col, rates, failed_variants, ...).
    """

    target: str
    folder: str | None = None
    error: str | None = None
    result: TargetResult | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        if self.folder is None:
            return {"target": self.target, "error": self.error, **self.extra}
        return {"target": self.target, "folder": self.folder, **self.extra}

    @classmethod
    def from_json(cls, d: Mapping[str, Any], result: TargetResult | None = None) -> TargetEntry:
        extra = {k: v for k, v in d.items() if k not in ("target", "folder", "error")}
        return cls(str(d["target"]), d.get("folder"), d.get("error"), result, extra)


@dataclass(frozen=True)
class RunSummary:
    """The result of a run with several targets (OUT/summary.json lists them).

    Attributes:
        folder: OUT; config: the configuration; targets: one entry per target, in order.
        extra: the other keys of OUT/summary.json (nominal_until_s, timings_s, options, ...).
    """

    folder: Path
    config: str
    targets: tuple[TargetEntry, ...]
    extra: Mapping[str, Any] = field(default_factory=dict)

    @property
    def results(self) -> list[TargetResult]:
        """The results of the targets that have a scenario."""
        return [t.result for t in self.targets if t.result is not None]

    def to_json(self) -> dict[str, Any]:
        return {"config": self.config, "targets": [t.to_json() for t in self.targets],
                "num_targets": len(self.targets), **{k: v for k, v in self.extra.items() if k != "num_targets"}}

    @classmethod
    def from_json(cls, d: Mapping[str, Any], folder: Path, results: Sequence[TargetResult | None] = ()
                  ) -> RunSummary:
        entries = [TargetEntry.from_json(t, results[i] if i < len(results) else None)
                   for i, t in enumerate(d["targets"])]
        extra = {k: v for k, v in d.items() if k not in ("config", "targets")}
        return cls(Path(folder), str(d["config"]), tuple(entries), extra)


RunResult = TargetResult | RunSummary


def read_run(folder: Path) -> RunResult:
    """The result of a ``coster-sumo run`` output folder, from its summary.json, for a process that
    did not run it (``coster-sumo export``). With several targets their results are not read here
    (:attr:`TargetEntry.result` is None): each is read when it is needed."""
    folder = Path(folder)
    if not folder.is_dir():
        raise not_found(folder, "folder")
    path = folder / "summary.json"
    if not path.is_file():
        raise not_found(path)
    try:
        d = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None
    if not isinstance(d, dict) or not ("targets" in d or "variants" in d):
        raise InputError(f"{path}: not the summary of a `coster-sumo run` output")
    try:
        return RunSummary.from_json(d, folder) if "targets" in d else TargetResult.from_json(d, folder)
    except (TypeError, ValueError, KeyError, AttributeError) as exc:  # a key of the wrong shape
        raise InputError(f"{path}: not the summary of a `coster-sumo run` output ({type(exc).__name__}: "
                         f"{exc})") from None
