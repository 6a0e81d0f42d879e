"""Standalone SUMO export of one variant: plain ``sumo -c <name>.sumocfg`` plays it, adversary included.

No Python and no TraCI at play time: SUMO's FCD replay device (``device.fcd-replay.files``, set in
the exported configuration) creates every vehicle id listed in ``traj.fcd.xml`` and moves it every
step to the recorded front-bumper position, SUMO angle and speed; such a vehicle needs no route.

Which vehicles the FCD file drives:

- the adversary, always;
- the target, when the variant was made with the ``replay`` planner (it followed its nominal path,
  so the exported contact happens). SUMO refuses two vehicles with one id, so it leaves the copied
  demand: its ``<vehicle>``/``<trip>`` is dropped, or, for a flow member, the flows are expanded
  into the vehicles they made (:mod:`coster_sumo.exports.demand`). With any other planner SUMO
  drives the target from the copied demand, and whether it still meets the adversary depends on
  SUMO repeating the pass;
- in a converted WOMD scene (``scene.npz`` beside the .sumocfg) every vehicle of the pass: the
  converted net has no routes for logged agents. ``scene.npz`` and ``lane_map.json`` are not
  copied, so ``coster-sumo replay`` runs the export as the plain configuration it is.

The FCD file, what it holds and why: :mod:`coster_sumo.exports.fcd`.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import shapely

from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.errors import InputError
from coster_sumo.exports.demand import EXPANDED_FILE, demand_ids, expand_flows, pass_routes, rewrite_demand
from coster_sumo.exports.fcd import (
    FCD_FILE,
    VTYPES_FILE,
    LaneIndex,
    recorded_vehicles,
    stage_and_park,
    write_fcd,
    write_vtypes,
)
from coster_sumo.exports.sumo_config import (
    GUI_SETTINGS_FILE,
    PassClock,
    source_option,
    write_export_config,
    write_gui_settings,
)
from coster_sumo.formats.scene_folder import LANE_MAP_FILE, converted_scene_file
from coster_sumo.formats.sumocfg import read_sumocfg
from coster_sumo.sim.inject import ADVERSARY_COLOR, InjectionResult

FCD_FILTER_FILE = "fcd_filter.txt"  # edge selection without the staging edge (fcd-output filter)


def _fmt_time(t: float | None) -> str | None:
    return None if t is None else repr(float(t))


def _staging_lane(config: Path) -> str | None:
    """The staging lane a converted scene's ``lane_map.json`` names (None: not converted / none)."""
    p = config.parent / LANE_MAP_FILE
    if not p.is_file():
        return None
    try:
        lane = json.loads(p.read_text()).get("staging_lane")
    except ValueError:
        return None
    return str(lane) if lane else None


def write_sumo_export(folder: Path, config: Path, result: InjectionResult, plan: AdversaryPlan, *,
                      target_id: str, planner: str, seed: int | None,
                      copy_outside: bool = False) -> tuple[Path, dict[str, Any]]:
    """Write a standalone SUMO folder for one variant; plain ``sumo -c`` plays it with the adversary.

    Copies the configuration's net, route and additional files (basenames) into ``folder``, makes
    the copied demand fit for the FCD replay device (:mod:`coster_sumo.exports.demand`: insertion
    checks, the replayed target dropped, flows expanded when the target is a flow member) and
    writes ``traj.fcd.xml`` (see the module docstring for what it holds), ``fcd_vtypes.add.xml``,
    ``gui.settings.xml``, for converted scenes ``fcd_filter.txt``, and ``<config name>``
    (:mod:`coster_sumo.exports.sumo_config`). ``variant.json`` is the caller's.

    Args:
        folder: the export folder (created).
        config: the .sumocfg the variant was generated on.
        result: the variant's injection pass (its recording is what the FCD file replays).
        plan: the variant's adversary plan (its ``vehicle_id`` is the adversary's id).
        target_id: the target's id.
        planner: the target's planner in the pass (``"replay"``: the FCD file drives the target too).
        seed: SUMO seed of the pass (None: SUMO's default).
        copy_outside: also copy the files the configuration names outside its own folder. By
            default they are not copied (an output holds only what lies in the configuration's
            folder or what the tool wrote): the export names them by absolute path, unchanged,
            and ``outside_files`` lists them.

    Returns:
        The exported .sumocfg and a JSON-able description (which vehicles the FCD file drives, who
        drives the target, what was done to the demand, the time-label convention).
    """
    folder = Path(folder)
    config = Path(config)
    folder.mkdir(parents=True, exist_ok=True)
    scene = result.scene
    step = float(scene.meta.get("step_length") or 0.1)
    inputs = read_sumocfg(config).inputs()
    if not inputs["net-file"]:
        raise InputError(f"{config}: the configuration names no net-file")
    names, outside = _copy_inputs(folder, config, inputs, copy_outside)
    converted = converted_scene_file(config) is not None
    notes: list[str] = []
    if outside:
        notes.append(f"{len(outside)} file(s) the configuration names lie outside its folder and are named by "
                     "absolute path, not copied and not adapted (copy them with --copy-outside): "
                     + ", ".join(outside))
    demand_files = [folder / n for n in (*names.get("route-files", []), *names.get("additional-files", []))
                    if not Path(n).is_absolute()]
    end = float(scene.timestamps[-1]) if scene.num_steps else None
    # a converted scene's log drives everyone: every vehicle of the pass, all inserted unchecked
    demand = (_Demand(ids=[str(i) for i in scene.tracks.ids], target_by="fcd-replay") if converted
              else _fit_demand(config, demand_files, plan.vehicle_id, target_id, planner, end, notes))
    lanes = LaneIndex.read(inputs["net-file"][0])
    vehicles = recorded_vehicles(scene, demand.ids, lanes, step, colors={plan.vehicle_id: ADVERSARY_COLOR})
    if plan.vehicle_id not in {v.vehicle_id for v in vehicles}:
        notes.append(f"the adversary {plan.vehicle_id!r} never entered the pass: the export has none")
    staging = _staging_lane(config) if converted else None
    last_label = round(float(scene.timestamps[-1]) - step, 6) if scene.num_steps else 0.0
    parked = stage_and_park(vehicles, lanes, staging, step, last_label)
    n_entries = write_fcd(folder / FCD_FILE, vehicles, lanes)
    write_vtypes(folder / VTYPES_FILE, vehicles)
    names["additional-files"] = [VTYPES_FILE, *names.get("additional-files", [])]
    output = _filter_staging(folder, lanes, staging)
    _write_gui_settings(folder, lanes, plan)
    cfg = folder / config.name
    clock = PassClock(_fmt_time(read_sumocfg(config).begin), end, step, seed)
    expanded = _write_config(cfg, config, names, demand, demand_files, target_id, clock, output)
    info: dict[str, Any] = {
        "sumocfg": cfg.name, "fcd_file": FCD_FILE, "vtypes_file": VTYPES_FILE, "gui_settings": GUI_SETTINGS_FILE,
        "fcd_vehicles": len(vehicles), "fcd_entries": n_entries,
        "adversary": plan.vehicle_id, "target": target_id, "target_driven_by": demand.target_by,
        "staging_lane": staging if output else None, "parked_early": parked,
        "fcd_time_label": "simulation time - step_length", "step_length": step,
        "demand": {"insertion_checks": demand.checks, "dropped": sorted(demand.drop),
                   "expanded_flows": sorted(demand.flows), "expanded_vehicles": len(expanded),
                   "expanded_file": EXPANDED_FILE if demand.flows else None, "expanded_by": demand.expanded_by,
                   "flows_after_end": sorted(demand.after_end)},
        "outside_files": outside,
        "notes": notes,
    }
    return cfg, info


def _write_config(cfg: Path, config: Path, names: dict[str, list[str]], demand: _Demand, demand_files: list[Path],
                  target_id: str, clock: PassClock, output: dict[str, str]) -> list[str]:
    """The export's configuration ``cfg``; where the target is a flow member, every flow becomes the
    vehicles it made first (:mod:`coster_sumo.exports.demand`). Returns those vehicles."""
    # the device routes a vehicle along the edges its entries name; staging, parking and logged
    # agents that leave the lanes make that route disconnected, which SUMO refuses unless told so
    # (route-file vehicles are unaffected: the pass ran them without the option); the device's
    # vehicles are never delayed (demand.py: the configuration's own keep their checks)
    processing = {"ignore-route-errors": "true", "insertion-checks": "none"}

    def write_cfg() -> None:
        write_export_config(cfg, config, names, clock, processing=processing, output=output, fcd_file=FCD_FILE,
                            gui_settings=GUI_SETTINGS_FILE)

    write_cfg()
    if not demand.flows:
        return []
    # the nominal pass's vehroute output where it ran this long, else a plain run of the configuration
    # just written (its demand as SUMO loads it)
    from_pass = pass_routes(config, seed=clock.seed, begin=read_sumocfg(config).begin or 0.0, step=clock.step,
                            end=clock.end)
    expanded = expand_flows(cfg, demand.flows, frozenset({target_id}), cfg.parent / EXPANDED_FILE,
                            checks=demand.checks or "all", same_without=frozenset({FCD_FILE, VTYPES_FILE}),
                            from_pass=from_pass)
    demand.expanded_by = "sumo" if from_pass is None else "the nominal pass"
    for f in demand_files:
        rewrite_demand(f, drop_flows=True)
    names["route-files"] = [*names.get("route-files", []), EXPANDED_FILE]
    write_cfg()
    return expanded


def _write_gui_settings(folder: Path, lanes: LaneIndex, plan: AdversaryPlan) -> None:
    """sumo-gui's view settings: centred on the end of the adversary's plan (the contact), zoomed by the
    span of the lanes outside junctions."""
    xmin, ymin, xmax, ymax = shapely.total_bounds(lanes.lines[~lanes.internal] if (~lanes.internal).any()
                                                  else lanes.lines)
    write_gui_settings(folder / GUI_SETTINGS_FILE, (float(plan.x[-1]), float(plan.y[-1])),
                       float(max(xmax - xmin, ymax - ymin)))


def _copy_inputs(folder: Path, config: Path, inputs: dict[str, list[Path]], copy_outside: bool
                 ) -> tuple[dict[str, list[str]], list[str]]:
    """The configuration's inputs copied into ``folder``: option -> the names the export gives them
    (a basename, or the absolute path of a file outside the configuration's folder that is not
    copied), and those outside files."""
    names: dict[str, list[str]] = {}
    home = config.resolve().parent
    outside: list[str] = []
    for key, paths in inputs.items():
        for p in paths:
            if not copy_outside and home not in p.resolve().parents:
                outside.append(str(p.resolve()))
                names.setdefault(key, []).append(str(p.resolve()))
                continue
            shutil.copy2(p, folder / p.name)
            names.setdefault(key, []).append(p.name)
    return names, outside


@dataclass
class _Demand:
    """Who the FCD file drives and what was done to the copied demand for it."""

    ids: list[str]  # the vehicles the FCD file drives
    target_by: str  # "fcd-replay" or "sumo"
    checks: str | None = None  # insertion checks kept on the copied demand
    drop: frozenset[str] = frozenset()  # vehicles dropped from the demand (the replayed target)
    flows: set[str] = field(default_factory=set)  # flows to expand into their vehicles
    after_end: list[str] = field(default_factory=list)  # flows that begin after the export ends (removed)
    expanded_by: str | None = None  # what ran the flows' members: "the nominal pass" or "sumo"


def _fit_demand(config: Path, demand_files: list[Path], adversary_id: str, target_id: str, planner: str,
                end: float | None, notes: list[str]) -> _Demand:
    """The copied demand of a SUMO configuration made fit for the FCD file (module docstring): the
    adversary always, the target too where the ``replay`` planner drove it (its own ``<vehicle>``
    dropped, or the flows expanded); a note where that is not possible."""
    demand = _Demand(ids=[adversary_id], target_by="sumo",
                     checks=source_option(config, "insertion-checks") or "all")
    found = [demand_ids(f) for f in demand_files]
    if planner == "replay":
        if any(target_id in d["vehicle"] for d in found):
            demand.drop = frozenset({target_id})
        elif target_id.rpartition(".")[0] in set().union(*(d["flow"] for d in found)):
            demand.flows = set().union(*(d["flow"] for d in found))
        else:
            notes.append(f"target {target_id!r} is in no route or additional file (neither a "
                         "<vehicle>/<trip> nor a flow member): SUMO drives it, so the exported contact "
                         "may not happen")
        if demand.drop or demand.flows:
            demand.ids.append(target_id)
            demand.target_by = "fcd-replay"
    for f in demand_files:
        demand.after_end += rewrite_demand(f, checks=demand.checks, drop_vehicles=demand.drop,
                                           end=end)["flows_after_end"]
    return demand


def _filter_staging(folder: Path, lanes: LaneIndex, staging: str | None) -> dict[str, str]:
    """The output options that keep a converted net's staging lane out of FCD output (its filter
    file written into ``folder``); none without a staging lane."""
    if staging is None or staging not in lanes.ids:
        return {}
    staging_edge = lanes.edges[lanes.ids.index(staging)]
    edges = sorted(set(lanes.edges) - {staging_edge})
    (folder / FCD_FILTER_FILE).write_text("".join(f"edge:{e}\n" for e in edges))
    return {"fcd-output.filter-edges.input-file": FCD_FILTER_FILE}
