"""``OUT/plans/<scene_key>.json`` of ``coster-sumo regress``: one scene's variants, generated once.

The generation task writes a :class:`ScenePlans` (or one that says why it failed); every run of a
planner on the scene reads it back, as do the summary and the report's failure examples.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from coster_sumo.method.generation import Variant


@dataclass(frozen=True)
class ScenePlans:
    """One scene's generated variants with their avoidability labels and escapes.

    Attributes:
        scene_key: the scene's key; status: "ok", or "failed" with ``reason``.
        spec: the scene (:meth:`~coster_sumo.core.spec.ScenarioSpec.to_dict`); generation: the generation's
            settings (:meth:`~coster_sumo.core.spec.GenerationConfig.to_dict`), as the task was given them.
        converted: the configuration was converted; scene_file: the nominal scene's ``.npz`` beside
            this file; target_id: the target's vehicle id; end: [s] the nominal scene's last time.
        variants: each :meth:`~coster_sumo.method.generation.Variant.to_dict`; info: what the
            generation reports of itself.
        avoidability: per variant its label (:meth:`~coster_sumo.avoidability.evasion.Avoidability.summary`);
            escapes: per variant its proven escape at 10 Hz (:func:`coster_sumo.avoidability.labels.escape_dict`,
            None: unavoidable).
        avoidable_only: with ``--avoidable only``: variants tried, kept and extra draws (None: not asked).
        timings_s: [s] nominal pass, generation and avoidability.
    """

    scene_key: str
    status: str
    spec: dict[str, Any]
    generation: Mapping[str, Any]
    reason: str | None = None
    converted: bool = False
    scene_file: str = ""
    target_id: str = ""
    end: float | None = None
    variants: tuple[dict[str, Any], ...] = ()
    info: Mapping[str, Any] = field(default_factory=dict)
    avoidability: tuple[dict[str, Any], ...] = ()
    escapes: tuple[dict[str, Any] | None, ...] = ()
    avoidable_only: Mapping[str, int] | None = None
    timings_s: Mapping[str, float] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def variant(self, i: int) -> Variant:
        return Variant.from_dict(self.variants[i])

    def label(self, i: int) -> dict[str, Any] | None:
        """Variant ``i``'s avoidability label (None: not labelled)."""
        return self.avoidability[i] if i < len(self.avoidability) else None

    def escape(self, i: int) -> dict[str, Any] | None:
        """Variant ``i``'s proven escape (None: none, or not recorded)."""
        return self.escapes[i] if i < len(self.escapes) else None

    @property
    def avoidable_variants(self) -> int:
        return sum(bool(a["avoidable"]) for a in self.avoidability)

    @property
    def variants_tried(self) -> int:
        """The variants drawn: more than kept with ``--avoidable only``."""
        return self.avoidable_only["tried"] if self.avoidable_only else len(self.variants)

    def to_json(self) -> dict[str, Any]:
        if not self.ok:
            return {"scene_key": self.scene_key, "status": self.status, "reason": self.reason, "spec": self.spec,
                    "generation": self.generation}
        return {"scene_key": self.scene_key, "status": self.status, "spec": self.spec, "converted": self.converted,
                "scene_file": self.scene_file, "target_id": self.target_id, "end": self.end,
                "generation": self.generation, "variants": list(self.variants), "info": self.info,
                "avoidability": list(self.avoidability), "escapes": list(self.escapes),
                **({"avoidable_only": self.avoidable_only} if self.avoidable_only is not None else {}),
                "timings_s": self.timings_s}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> ScenePlans:
        return cls(scene_key=d["scene_key"], status=d["status"], spec=d.get("spec", {}),
                   generation=d.get("generation", {}), reason=d.get("reason"), converted=bool(d.get("converted")),
                   scene_file=d.get("scene_file", ""), target_id=str(d.get("target_id", "")), end=d.get("end"),
                   variants=tuple(d.get("variants") or ()), info=d.get("info") or {},
                   avoidability=tuple(d.get("avoidability") or ()), escapes=tuple(d.get("escapes") or ()),
                   avoidable_only=d.get("avoidable_only"), timings_s=d.get("timings_s") or {})


def read_plans(path: Path) -> ScenePlans | None:
    """A scene's plans file, or None when it is missing or unreadable (not generated yet)."""
    if not path.exists():
        return None
    try:
        return ScenePlans.from_json(json.loads(path.read_text()))
    except (OSError, ValueError, KeyError):
        return None
