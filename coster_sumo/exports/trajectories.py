"""Every vehicle's trajectory of a variant's injection pass, as plain CSV and JSON.

``coster-sumo run`` writes ``variants/<i>/trajectories.csv``: the whole recording of the pass
(:attr:`~coster_sumo.sim.inject.InjectionResult.scene`), one row per vehicle and recorded step.
``coster-sumo export`` reads it back and writes the selection it exports (target, adversary and
the vehicles near the target at t_col) as ``trajectories.csv`` and ``trajectories.json``, the
forms other tools import most easily.

Columns, each named with its unit: ``time_s`` (SUMO simulation time after the step),
``vehicle``, ``type`` (WOMD object type name: VEHICLE, PEDESTRIAN, CYCLIST, OTHER, UNSET), ``x_m``,
``y_m`` (box centre in the SUMO network's own coordinates), ``heading_deg`` (counter-clockwise from
+x, degrees like every angle in the user-facing files), ``speed_mps``, ``length_m``, ``width_m``,
``vclass`` (the SUMO vehicle class: passenger, truck, delivery, bus, motorcycle, bicycle, ...; empty
where the recording does not say). Only the steps where the vehicle was in the simulation are
listed. The reader also takes the older columns (``time``, ``x``, ..., ``heading`` in radians, no
``vclass``) of run folders written before.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.core.scene import ObjectType, Scene
from coster_sumo.errors import InputError

TRAJECTORIES_FILE = "trajectories.csv"
TRAJECTORIES_JSON = "trajectories.json"
COLUMNS = ("time_s", "vehicle", "type", "x_m", "y_m", "heading_deg", "speed_mps", "length_m", "width_m", "vclass")
OLD_COLUMNS = ("time", "vehicle", "type", "x", "y", "heading", "speed", "length", "width")  # heading [rad]
OPTIONAL_COLUMNS = frozenset({"vclass"})
TEXT_COLUMNS = ("vehicle", "type", "vclass")


@dataclass
class Trajectory:
    """One vehicle's recorded states, in time order.

    Attributes:
        vehicle_id: SUMO id.
        kind: object type name (see the module docstring).
        t: (N,) float64 [s] simulation time.
        x, y: (N,) float64 [m] box centre.
        heading: (N,) float64 [rad] counter-clockwise from +x.
        speed: (N,) float64 [m/s].
        length, width: (N,) float64 [m].
        vclass: SUMO vehicle class ("" where unknown).
    """

    vehicle_id: str
    kind: str
    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    length: np.ndarray
    width: np.ndarray
    vclass: str = ""

    def state_at(self, t: float) -> tuple[float, float] | None:
        """Box centre (x, y) [m] linearly interpolated at ``t`` [s]; None outside the recording."""
        if len(self.t) == 0 or t < self.t[0] - 1e-6 or t > self.t[-1] + 1e-6:
            return None
        return float(np.interp(t, self.t, self.x)), float(np.interp(t, self.t, self.y))

    def to_dict(self) -> dict[str, Any]:
        return {"type": self.kind, "vclass": self.vclass, "length_m": float(np.median(self.length)),
                "width_m": float(np.median(self.width)),
                "time_s": _r(self.t, 3), "x_m": _r(self.x, 4), "y_m": _r(self.y, 4),
                "heading_deg": _r(np.degrees(self.heading), 5), "speed_mps": _r(self.speed, 4)}


def _r(a: np.ndarray, digits: int) -> list[float]:
    return [round(float(v), digits) for v in a]


def write_trajectories_csv(path: Path, scene: Scene) -> None:
    """Write every vehicle of a recorded pass (see the module docstring for the columns)."""
    tr = scene.tracks
    speed = tr.speed
    vclasses = scene.meta.get("vehicle_classes") or {}
    with Path(path).open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(COLUMNS)
        for a, vid in enumerate(tr.ids.tolist()):
            kind = _type_name(int(tr.object_type[a]))
            for s in np.flatnonzero(tr.valid[a]):
                w.writerow((f"{scene.timestamps[s]:.3f}", vid, kind, f"{tr.x[a, s]:.4f}", f"{tr.y[a, s]:.4f}",
                            f"{np.degrees(tr.heading[a, s]):.5f}", f"{speed[a, s]:.4f}", f"{tr.length[a, s]:.3f}",
                            f"{tr.width[a, s]:.3f}", str(vclasses.get(vid, ""))))


def _type_name(value: int) -> str:
    try:
        return ObjectType(value).name
    except ValueError:
        return ObjectType.OTHER.name


def read_trajectories_csv(path: Path) -> dict[str, Trajectory]:
    """Vehicle id -> :class:`Trajectory` of a ``trajectories.csv`` (rows of a vehicle in any order)."""
    rows: dict[str, list[tuple[float, ...]]] = {}
    kinds: dict[str, tuple[str, str]] = {}
    try:
        with Path(path).open(newline="") as fh:
            reader = csv.DictReader(fh)
            names = set(reader.fieldnames or ())
            columns = OLD_COLUMNS if not set(COLUMNS) <= names and set(OLD_COLUMNS) <= names else COLUMNS
            missing = set(columns) - OPTIONAL_COLUMNS - names
            if missing:
                raise InputError(f"{path}: not a trajectories file (missing columns {sorted(missing)})")
            for r in reader:
                vid = r["vehicle"]
                kinds[vid] = (r["type"], r.get("vclass") or "")
                rows.setdefault(vid, []).append(tuple(float(r[c]) for c in columns if c not in TEXT_COLUMNS))
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    except ValueError as exc:
        raise InputError(f"{path}: bad number ({exc})") from None
    out = {}
    for vid, rs in rows.items():
        a = np.array(sorted(rs), np.float64)
        if columns is COLUMNS:
            a[:, 3] = np.radians(a[:, 3])  # heading_deg -> the radians of Trajectory
        kind, vclass = kinds[vid]
        out[vid] = Trajectory(vid, kind, a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4], a[:, 5], a[:, 6], vclass)
    return out


def select_near(trajs: dict[str, Trajectory], target: str, adversary: str, t_col: float,
                radius: float) -> list[str]:
    """Target, adversary, then every vehicle whose centre is within ``radius`` [m] of the target's
    centre at ``t_col`` [s] (sorted by distance). Missing target or adversary: left out."""
    first = [v for v in (target, adversary) if v in trajs]
    if target not in trajs:
        return first
    centre = trajs[target].state_at(t_col)
    if centre is None:  # the target is not recorded at t_col: its last recorded pose
        centre = (float(trajs[target].x[-1]), float(trajs[target].y[-1]))
    near = []
    for vid, tr in trajs.items():
        if vid in first:
            continue
        p = tr.state_at(t_col)
        if p is not None:
            d = float(np.hypot(p[0] - centre[0], p[1] - centre[1]))
            if d <= radius:
                near.append((d, vid))
    return first + [vid for _, vid in sorted(near)]


def write_selection(folder: Path, trajs: dict[str, Trajectory], ids: list[str], roles: dict[str, str],
                    header: dict[str, Any]) -> tuple[Path, Path]:
    """``trajectories.csv`` (the columns above plus ``role``) and ``trajectories.json`` of ``ids``.

    ``roles``: vehicle id -> "target" / "adversary" (others: "other"); ``header``: JSON keys put
    before ``vehicles`` (frame, t_col, collision snapshot).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    csv_path, json_path = folder / TRAJECTORIES_FILE, folder / TRAJECTORIES_JSON
    with csv_path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow((*COLUMNS, "role"))
        for vid in ids:
            tr = trajs[vid]
            for k in range(len(tr.t)):
                w.writerow((f"{tr.t[k]:.3f}", vid, tr.kind, f"{tr.x[k]:.4f}", f"{tr.y[k]:.4f}",
                            f"{np.degrees(tr.heading[k]):.5f}", f"{tr.speed[k]:.4f}", f"{tr.length[k]:.3f}",
                            f"{tr.width[k]:.3f}", tr.vclass, roles.get(vid, "other")))
    doc = {**header, "vehicles": {vid: {"role": roles.get(vid, "other"), **trajs[vid].to_dict()} for vid in ids}}
    json_path.write_text(json.dumps(doc, indent=1) + "\n")
    return csv_path, json_path
