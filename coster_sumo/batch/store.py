"""Results of a batch: one Parquet part file per run (written atomically).

The figures of a batch come from the rows through :func:`row_outcome` and the registry of
:mod:`coster_sumo.metrics`.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from coster_sumo.infra.atomic import atomic_path
from coster_sumo.metrics import RunOutcome

RESULT_FIELDS: dict[str, str] = {
    # name: pyarrow type name; see the README "regress" section for meanings and units
    "run_key": "string", "scene_key": "string", "config": "string", "seed": "int64", "variant": "int64",
    "planner": "string", "status": "string", "reason": "string",
    "collision": "bool", "adversary_contact": "bool", "target_other_collision": "bool",
    "target_off_road": "bool", "adversary_off_road": "bool", "route_completed": "bool", "target_arrived": "bool",
    "min_ttc": "float64", "contact_time": "float64", "contact_offset_s": "float64", "relative_speed": "float64",
    "impact_angle": "float64", "sumo_reported_contact": "bool", "t_col": "float64",
    "sim_wall_time_s": "float64", "wall_time_s": "float64", "target_path": "string", "finished_at": "string",
    "avoidable": "bool", "contact_kind": "string", "outcome": "string", "contact_in_horizon": "bool",  # defects
    "adversary_class": "string",  # vehicle | pedestrian | cyclist (--adversary)
}


@dataclass(frozen=True, kw_only=True)
class ResultRow:
    """One run of a batch (one planner on one variant of one scene): a row of ``OUT/results/``, with
    the fields of :data:`RESULT_FIELDS` in their order (None: not recorded, e.g. a failed run's
    outcome). Units: s, m/s, deg; ``target_path`` is JSON ([[x, y], ...] in m)."""

    run_key: str
    scene_key: str
    config: str | None = None
    seed: int | None = None
    variant: int
    planner: str
    status: str
    reason: str | None = None
    collision: bool | None = None
    adversary_contact: bool | None = None
    target_other_collision: bool | None = None
    target_off_road: bool | None = None
    adversary_off_road: bool | None = None
    route_completed: bool | None = None
    target_arrived: bool | None = None
    min_ttc: float | None = None
    contact_time: float | None = None
    contact_offset_s: float | None = None
    relative_speed: float | None = None
    impact_angle: float | None = None
    sumo_reported_contact: bool | None = None
    t_col: float | None = None
    sim_wall_time_s: float | None = None
    wall_time_s: float | None = None
    target_path: str | None = None
    finished_at: str | None = None
    avoidable: bool | None = None
    contact_kind: str | None = None
    outcome: str | None = None
    contact_in_horizon: bool | None = None
    adversary_class: str | None = None

    @property
    def ok(self) -> bool:
        """The run finished (its outcome is recorded)."""
        return self.status == "ok"

    def to_json(self) -> dict[str, Any]:
        """The row as the Parquet part stores it (the fields in their order)."""
        return {name: getattr(self, name) for name in RESULT_FIELDS}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> ResultRow:
        return cls(**{name: d[name] for name in RESULT_FIELDS if name in d})


def result_row(payload: Mapping[str, Any], **values: Any) -> ResultRow:
    """The row of the run ``payload`` names (its keys, scene, variant, planner) with ``values``;
    every other field None."""
    return ResultRow(**{"run_key": payload["run_key"], "scene_key": payload["scene_key"],
                        "config": payload.get("config"), "seed": payload.get("seed"),
                        "variant": int(payload["variant"]), "planner": payload["planner"], **values})


def row_outcome(row: ResultRow) -> RunOutcome:
    """A finished run's row as the metrics read it (:class:`~coster_sumo.metrics.RunOutcome`)."""
    return RunOutcome(scene=row.scene_key, adversary_contact=bool(row.adversary_contact),
                      target_collision=bool(row.collision), adversary_off_road=bool(row.adversary_off_road),
                      target_off_road=bool(row.target_off_road), route_completed=bool(row.route_completed),
                      relative_speed=row.relative_speed, impact_angle=row.impact_angle, min_ttc=row.min_ttc,
                      avoidable=row.avoidable, contact_in_horizon=row.contact_in_horizon)


def result_schema() -> Any:
    import pyarrow as pa

    types = {"string": pa.string(), "int64": pa.int64(), "float64": pa.float64(), "bool": pa.bool_()}
    return pa.schema([(k, types[t]) for k, t in RESULT_FIELDS.items()])


class ResultStore:
    """``OUT/results/``: one Parquet part file per run, ``<run_key>.parquet``, written atomically.

    Temporary files start with "." so that readers (``pyarrow.dataset``) ignore them.
    """

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)

    def path(self, run_key: str) -> Path:
        return self.folder / f"{run_key}.parquet"

    def write(self, row: ResultRow) -> Path:
        """The row's part file (replacing one of the same run key); ``finished_at`` now unless set,
        a time or speed that is not finite stored as None."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        full = {**row.to_json(), "finished_at": row.finished_at or time.strftime("%Y-%m-%dT%H:%M:%S")}
        for k in ("min_ttc", "contact_time", "contact_offset_s", "relative_speed", "impact_angle"):
            if isinstance(full[k], float) and not math.isfinite(full[k]):
                full[k] = None
        table = pa.Table.from_pylist([full], schema=result_schema())
        final = self.path(row.run_key)
        with atomic_path(final) as tmp:  # hidden while written: readers skip names starting with "."
            pq.write_table(table, tmp)
        return final

    def keys(self) -> set[str]:
        return {p.stem for p in self.folder.glob("*.parquet") if not p.name.startswith(".")}

    def read(self) -> list[ResultRow]:
        import pyarrow.dataset as ds

        if not self.keys():
            return []
        rows = ds.dataset(self.folder, format="parquet", schema=result_schema()).to_table().to_pylist()
        return [ResultRow.from_json(r) for r in rows]


def read_json(path: Path) -> dict[str, Any] | None:
    """A JSON file written by a batch, or None when it is missing or unreadable (not done yet)."""
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None
