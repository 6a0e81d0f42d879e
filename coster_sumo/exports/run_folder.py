"""``coster-sumo export RUN_OUT``: the exports of every variant of a finished run, from its files.

Per variant ``RUN_OUT/variants/<i>/``:

- ``sumo``: ``export/`` is written by ``run`` itself (the FCD replay file needs the pass's full
  recording and the source configuration's route files); ``export`` checks that it is complete
  (configuration, net, FCD file, vTypes, variant.json) and names it.
- ``openscenario``: ``openscenario/`` with ``<name>.xosc`` (validated against the OpenSCENARIO 1.2
  XSD), ``<name>.xodr``, ``trajectories.csv`` and ``trajectories.json``
  (:mod:`coster_sumo.exports.openscenario`), from ``export/`` (net, plan), ``trajectories.csv``
  (every vehicle of the pass) and ``summary.json`` (the collision snapshot).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from coster_sumo.core.results import RunResult, RunSummary, TargetResult, read_run
from coster_sumo.errors import InputError, not_found
from coster_sumo.exports.fcd import FCD_FILE, VTYPES_FILE
from coster_sumo.exports.trajectories import TRAJECTORIES_FILE, read_trajectories_csv, select_near, write_selection
from coster_sumo.formats.sumocfg import read_sumocfg
from coster_sumo.infra.outdir import refresh_marker

FORMATS = ("sumo", "openscenario", "all")
OSC_DIR = "openscenario"


def _load_json(path: Path) -> Any:
    if not path.is_file():
        raise not_found(path)
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None


def sumo_export(vdir: Path) -> dict[str, Any]:
    """Check a variant's standalone SUMO folder; returns its configuration and files."""
    export = vdir / "export"
    variant = _load_json(export / "variant.json")
    cfg = export / variant["export"]["sumocfg"]
    net = read_sumocfg(cfg).inputs()["net-file"]
    missing = [p.name for p in (cfg, export / FCD_FILE, export / VTYPES_FILE, *net) if not p.is_file()]
    if missing or not net:
        raise InputError(f"{export}: incomplete SUMO export (missing {missing or ['net-file']}); run it again")
    return {"sumocfg": str(cfg), "net": str(net[0]), "fcd": str(export / FCD_FILE)}


def openscenario_export(vdir: Path, summary: dict[str, Any], record: dict[str, Any], radius: float
                        ) -> dict[str, Any]:
    """Write ``vdir/openscenario/`` for one variant (see the module docstring); returns what it wrote."""
    from coster_sumo.exports import openscenario as osc
    from coster_sumo.exports.opendrive import write_xodr

    export = vdir / "export"
    variant = _load_json(export / "variant.json")
    cfg = export / variant["export"]["sumocfg"]
    net = read_sumocfg(cfg).inputs()["net-file"][0]
    src = vdir / TRAJECTORIES_FILE
    if not src.is_file():
        raise InputError(f"{src}: missing (runs before the OpenSCENARIO export existed do not write it); "
                         "run the scenario again")
    trajs = read_trajectories_csv(src)
    target, adversary = str(variant["target_id"]), str(variant["plan"]["vehicle_id"])
    t_col = float(record["t_col"])
    ids = select_near(trajs, target, adversary, t_col, radius)
    if adversary not in ids:
        raise InputError(f"{src}: the adversary {adversary!r} is not in the recording")
    roles = {target: "target", adversary: "adversary"}
    snap = summary["snapshots"][int(record.get("snapshot", 0))]
    t0 = min(float(trajs[v].t[0]) for v in ids)
    adv = snap["adversary"]
    params: dict[str, float | str] = {
        "SumoTimeOffset": t0, "CollisionTime": t_col - t0, "CollisionTimeSumo": t_col,
        "Target": target, "Adversary": adversary,
        "AdversaryX": adv["x"], "AdversaryY": adv["y"], "AdversaryHeadingDeg": adv["heading_deg"],
        "AdversarySpeed": adv["speed"], "AdversaryLength": adv["length"], "AdversaryWidth": adv["width"],
        "NearRadius": radius,
    }
    if record.get("collision"):
        params.update({"ContactTime": float(record["collision_time"]) - t0,
                       "ContactRelativeSpeed": float(record["relative_speed"]),
                       "ContactImpactAngleDeg": float(record["impact_angle"])})
    contact = (f"contact at {record['collision_time']:.2f} s (SUMO time), {record['relative_speed']:.2f} m/s, "
               f"impact angle {record['impact_angle']:.1f} deg" if record.get("collision") else "no contact")
    description = (f"coster-sumo variant {record['variant']} of {summary.get('scenario_id') or cfg.stem}: "
                   f"adversary {adversary} vs target {target}, t_col {t_col:.2f} s SUMO time "
                   f"(scenario time {t_col - t0:.2f} s; scenario time = SUMO time - {t0:.2f} s); "
                   f"snapshot adversary x {adv['x']:.3f} m, y {adv['y']:.3f} m, heading {adv['heading_deg']:.2f} deg, "
                   f"speed {adv['speed']:.3f} m/s; {contact}; world coordinates = SUMO net coordinates, "
                   f"positions = bounding-box centres")
    out = vdir / OSC_DIR
    out.mkdir(parents=True, exist_ok=True)
    name = cfg.stem
    xodr = write_xodr(net, out / f"{name}.xodr")
    xosc = osc.write_xosc(out / f"{name}.xosc", xodr.name, trajs, ids, t0=t0, description=description,
                          parameters=params)
    errors = osc.validate_xosc(xosc)
    if errors:
        raise InputError(f"{xosc}: not valid OpenSCENARIO 1.2 ({len(errors)} errors, first: {errors[0]})")
    header = {"frame": "SUMO network coordinates (= the .xodr inertial frame); x, y = box centre [m], heading "
                       "[rad] counter-clockwise from +x, time = SUMO simulation time [s]",
              "scenario_time_offset_s": t0, "t_col": t_col, "target": target, "adversary": adversary,
              "near_radius_m": radius, "snapshot_adversary": adv, "contact": contact}
    csv_path, json_path = write_selection(out, trajs, ids, roles, header)
    return {"xosc": str(xosc), "xodr": str(xodr), "csv": str(csv_path), "json": str(json_path),
            "vehicles": len(ids), "schema_valid": True}


def available_formats() -> str:
    """The widest format whose dependencies are installed: ``all`` with the OpenSCENARIO extra,
    else ``sumo``."""
    from coster_sumo.exports.openscenario import require_extra

    try:
        require_extra()
    except InputError:
        return "sumo"
    return "all"


def export_run(run: Path | RunResult, fmt: str = "all", radius: float | None = None,
               progress: Callable[[int, int], None] | None = None) -> list[dict[str, Any]]:
    """Export every variant of a run in ``fmt`` (sumo | openscenario | all); one dict per variant
    (``skipped``: why a variant has no export, where the run could not write its SUMO folder).

    ``run``: the result :func:`coster_sumo.pipeline.run.run` returned, or the output folder of an earlier run
    (its summary.json is read). ``progress(done, total)`` is called after every variant."""
    if fmt not in FORMATS:
        raise InputError(f"unknown export format {fmt!r} (choose from {', '.join(FORMATS)})")
    if fmt in ("openscenario", "all"):
        from coster_sumo.exports.openscenario import DEFAULT_RADIUS_M, require_extra

        require_extra()
        radius = DEFAULT_RADIUS_M if radius is None else radius
    result = run if isinstance(run, TargetResult | RunSummary) else read_run(Path(run))
    if isinstance(result, RunSummary):  # a run with several targets: one run folder per target
        results = [{**r, "target": t.target} for t in result.targets if t.folder is not None
                   for r in export_run(t.result or result.folder / t.folder, fmt, radius, progress)]
        refresh_marker(result.folder)
        return results
    return _export_target(result, fmt, float(radius or 0.0), progress)


def _export_target(result: TargetResult, fmt: str, radius: float,
                   progress: Callable[[int, int], None] | None) -> list[dict[str, Any]]:
    """:func:`export_run` of one target's result."""
    summary = result.to_json()
    results: list[dict[str, Any]] = []
    for variant in result.variants:
        if progress is not None:
            progress(len(results), len(result.variants))
        vdir = result.folder / "variants" / str(variant.variant)
        res: dict[str, Any] = {"variant": variant.variant}
        if variant.export_error:  # the run could not write its SUMO folder, which both formats read
            results.append({**res, "skipped": variant.export_error})
            continue
        if fmt in ("sumo", "all"):
            res["sumo"] = sumo_export(vdir)
        if fmt in ("openscenario", "all"):
            res["openscenario"] = openscenario_export(vdir, summary, variant.to_json(), radius)
        results.append(res)
    if progress is not None:
        progress(len(results), len(result.variants))
    refresh_marker(result.folder)  # the files written here are the tool's: a later --overwrite may replace them
    return results
