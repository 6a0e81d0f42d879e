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

from coster_sumo.atomic import json_default
from coster_sumo.errors import InputError, not_found
from coster_sumo.metrics import RunOutcome


def plain_json(obj: Any) -> Any:
    """``obj`` as the plain JSON values a reader of its file gets (numpy numbers as floats, paths as
    strings, tuples as lists), without writing it anywhere."""
    return json.loads(json.dumps(obj, default=json_default))


def _split(cls: type, d: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """The keys of ``d`` that are fields of ``cls`` (but ``extra``), and the others."""
    names = {f.name for f in fields(cls)} - {"extra"}
    return {k: v for k, v in d.items() if k in names}, {k: v for k, v in d.items() if k not in names}


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
        extra: what later steps add (``export_error``, ``avoidability``, ``label``, ``outcome``).
    """

    variant: int
    adversary_id: str = ""
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
    extra: Mapping[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "extra"}
        out["other_collisions_list"] = list(self.other_collisions_list)
        return {**out, **self.extra}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> VariantOutcome:
        known, extra = _split(cls, d)
        known["other_collisions_list"] = tuple(known.get("other_collisions_list", ()))
        return cls(**known, extra=extra)

    def run_outcome(self) -> RunOutcome:
        """The variant as the metrics read it (:data:`coster_sumo.metrics.REGISTRY`)."""
        return RunOutcome(adversary_contact=self.collision, adversary_off_road=self.adversary_off_road,
                          target_off_road=self.target_off_road, route_completed=self.route_completed,
                          relative_speed=self.relative_speed, impact_angle=self.impact_angle, min_ttc=self.min_ttc)


@dataclass(frozen=True)
class TargetResult:
    """The result of one target (summary.json of a one-target run, or of ``OUT/<target>/``).

    Attributes:
        folder: where it was written.
        target: the target's id; config: the configuration; planner: the target's planner; seed.
        t_col: [s] the first snapshot's collision time; num_snapshots, num_variants: counts.
        collision_rate, off_road_rate: shares of the variants (None without variants);
            impact_angle_spread_deg: [deg] the circular range of the impact angles.
        variants: every variant's outcome; snapshots: one record per collision snapshot.
        extra: every other key of summary.json, as written (timings, options, generation,
            avoidability counts, ...).
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
    snapshots: tuple[Mapping[str, Any], ...] = ()
    extra: Mapping[str, Any] = field(default_factory=dict)

    @property
    def failed(self) -> list[dict[str, Any]]:
        """The variants whose SUMO pass failed (crash, timeout): adversary, t_col, reason."""
        return [f for s in self.snapshots for f in s.get("generation", {}).get("failed", [])]

    def to_json(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("extra", "folder")}
        out["variants"] = [v.to_json() for v in self.variants]
        out["snapshots"] = [dict(s) for s in self.snapshots]
        return {**out, **self.extra}

    @classmethod
    def from_json(cls, d: Mapping[str, Any], folder: Path) -> TargetResult:
        known, extra = _split(cls, d)
        known.pop("folder", None)
        known["variants"] = tuple(VariantOutcome.from_json(v) for v in d.get("variants", ()))
        known["snapshots"] = tuple(d.get("snapshots", ()))
        known["target"] = str(known.get("target", ""))
        return cls(folder=Path(folder), **known, extra=extra)


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
    if isinstance(d, dict) and "targets" in d:
        return RunSummary.from_json(d, folder)
    if not isinstance(d, dict) or "variants" not in d:
        raise InputError(f"{path}: not the summary of a `coster-sumo run` output")
    return TargetResult.from_json(d, folder)
