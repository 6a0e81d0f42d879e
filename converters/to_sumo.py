"""A WOMD scene -> a converted SUMO scene folder (network, vTypes, config, replay data, mapping).

``convert_scene(scene, outdir)`` writes ``outdir/<scenario_id>/``:

- ``<id>.net.xml``: the network, WOMD coordinates kept exactly (plain XML from
  :mod:`converters.to_sumo_net`, then netconvert (:mod:`converters.netconvert`) with
  ``--offset.disable-normalization true --precision 4 --junctions.endpoint-shape true`` and
  ``spreadType="center"``, docs/sumo.md §2); lanes netconvert cut back to its junction polygons get
  their WOMD polyline back and internal lanes the logged interior lanes, joined end to end
  (:func:`converters.restore_geometry.set_womd_geometry`); a staging lane 1 km below the map is
  added for the replay;
- ``<id>.rou.xml``: vTypes for the logged agents (``womd_vehicle`` passenger, ``womd_pedestrian``
  and ``womd_cyclist`` as vehicles of class pedestrian / bicycle, ``womd_other``);
- ``<id>.tll.xml``: the logged signal states as a fixed-time program (only with traffic lights);
- ``<id>.sumocfg``: relative paths, step length 0.1 s, begin 0, end = the scene's end on SUMO's
  clock (the log is shifted by ``sumo_time_offset_s`` = 0.2 s for a WOMD log starting at 0, to
  leave a staging step before it; see :func:`on_sumo_clock` and :mod:`coster_sumo.sim.replay`);
- ``scene.npz``: the scene (:func:`coster_sumo.formats.scene_file.save_scene`), WOMD coordinates, timestamps on
  SUMO's clock;
- ``lane_map.json``: WOMD lane id -> SUMO lane ids, WOMD link -> SUMO connection, and per traffic
  light the WOMD lane whose logged signal drives each link index;
- ``summary.json``: counts, fidelity figures (:mod:`converters.fidelity`), warnings, conversion time.

The folder is written under a temporary name and renamed at the end, so a failed scene leaves
nothing behind. A folder with a ``.sumocfg``, ``scene.npz`` and ``lane_map.json`` is "a converted
scene" for every later stage.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from coster_sumo.core.scene import ObjectType, Scene
from coster_sumo.errors import InputError
from coster_sumo.formats.net_joints import measure_joints
from coster_sumo.formats.scene_file import save_scene
from coster_sumo.formats.scene_folder import (
    STAGING_EDGE,
    folder_name,
    is_converted_scene,
    tls_state_strings,
    vtype_for,
)
from coster_sumo.infra.outdir import check_output, new_staging, publish

from .fidelity import measure_fidelity
from .netconvert import ConversionError, NetInfo, read_net, run_netconvert
from .restore_geometry import set_womd_geometry
from .to_sumo_net import PlainNet, build_plain_net, is_bike_lane, lane_speed, lane_width

__all__ = ["ConversionError", "ConvertResult", "convert_scene", "is_converted_scene", "read_net"]

# An isolated lane far below the map where the replay puts each agent for one step before it first
# appears: a vehicle whose very first placement is off every lane crashes SUMO in its outputs
# (FCD) and in some getters (docs/sumo.md §3).
STAGING_OFFSET_M = 1000.0  # [m] below the map
STAGING_LENGTH_M = 15000.0  # [m] room for 600 agents appearing in one step


@dataclass(frozen=True, slots=True)
class ConvertResult:
    """What :func:`convert_scene` wrote and measured."""

    folder: Path
    summary: dict


# ----------------------------------------------------------------------------- plain XML

def _xy(points: np.ndarray) -> str:
    return " ".join(f"{x:.6f},{y:.6f}" for x, y in points)


def write_plain_xml(plain: PlainNet, scene: Scene, folder: Path, stem: str) -> tuple[Path, Path, Path]:
    """Write ``stem.nod.xml``, ``stem.edg.xml``, ``stem.con.xml``; returns their paths."""
    rm = scene.road_map
    nod, edg, con = (folder / f"{stem}.{k}.xml" for k in ("nod", "edg", "con"))
    rows = ["<nodes>"]
    for nid, xy in plain.nodes.items():
        kind = ' type="traffic_light" tlType="static"' if nid in plain.tls_nodes else ""
        rows.append(f'  <node id="{nid}" x="{xy[0]:.6f}" y="{xy[1]:.6f}"{kind}/>')
    xmin, ymin, _, _ = rm.bounds()
    sx, sy = xmin, ymin - STAGING_OFFSET_M
    rows.append(f'  <node id="{STAGING_EDGE}.a" x="{sx:.3f}" y="{sy:.3f}"/>')
    rows.append(f'  <node id="{STAGING_EDGE}.b" x="{sx + STAGING_LENGTH_M:.3f}" y="{sy:.3f}"/>')
    rows.append("</nodes>")
    nod.write_text("\n".join(rows) + "\n")
    rows = ["<edges>"]
    for eid, grp in plain.edges.items():
        frm, to = plain.edge_nodes[eid]
        pcs = [plain.pieces[m] for m in grp]
        speed = max(lane_speed(rm, p.lane) for p in pcs)
        if len(pcs) == 1:
            shape = pcs[0].points
        else:  # edge line halfway between the outer lanes; each lane carries its own WOMD shape
            shape = 0.5 * (_resample_n(pcs[0].points, 50) + _resample_n(pcs[-1].points, 50))
        rows.append(f'  <edge id={quoteattr(eid)} from="{frm}" to="{to}" numLanes="{len(pcs)}" '
                    f'speed="{speed:.3f}" spreadType="center" shape="{_xy(shape)}">')
        for p in pcs:
            attrs = f'index="{p.index}" width="{lane_width(rm, p.lane):.3f}" speed="{lane_speed(rm, p.lane):.3f}"'
            if is_bike_lane(rm, p.lane):
                attrs += ' allow="bicycle"'
            if len(pcs) > 1:
                attrs += f' shape="{_xy(p.points)}"'
            rows.append(f"    <lane {attrs}/>")
        rows.append("  </edge>")
    rows.append(f'  <edge id="{STAGING_EDGE}" from="{STAGING_EDGE}.a" to="{STAGING_EDGE}.b" numLanes="1" '
                f'speed="30" width="4"/>')
    rows.append("</edges>")
    edg.write_text("\n".join(rows) + "\n")
    rows = ["<connections>"]
    for c in plain.connections:
        a, b = plain.pieces[c.src], plain.pieces[c.dst]
        shape_attr = f' shape="{_xy(c.shape)}"' if c.shape is not None and len(c.shape) >= 2 else ""
        rows.append(f'  <connection from={quoteattr(a.edge)} to={quoteattr(b.edge)} fromLane="{a.index}" '
                    f'toLane="{b.index}"{shape_attr}/>')
    rows.append("</connections>")
    con.write_text("\n".join(rows) + "\n")
    return nod, edg, con


def _resample_n(points: np.ndarray, n: int) -> np.ndarray:
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    s = np.linspace(0.0, cum[-1], n)
    return np.stack([np.interp(s, cum, points[:, 0]), np.interp(s, cum, points[:, 1])], -1)



# ----------------------------------------------------------------------------- signals

def on_sumo_clock(scene: Scene) -> Scene:
    """The scene with its timestamps moved onto the converted network's SUMO clock.

    SUMO starts at 0; the replay needs one staging step before the first log step (see
    :mod:`coster_sumo.sim.replay`), and ``SumoSession.time`` after the step that shows log step 0
    is then ``2 * dt``. ``meta["sumo_time_offset_s"]`` = SUMO time - log time.
    """
    t0 = float(scene.timestamps[0]) if scene.num_steps else 0.0
    offset = round(2 * scene.dt - t0, 9)
    meta = {**scene.meta, "sumo_time_offset_s": offset, "log_t0_s": t0}
    return dataclasses.replace(scene, timestamps=np.round(scene.timestamps + offset, 9), meta=meta)


def _write_tll(path: Path, states: dict[str, list[str]], dt: float, lead_in: float) -> None:
    """The logged signal states as fixed-time programs (``lead_in`` [s] of the first state first)."""
    rows = ["<additional>"]
    for tid, seq in states.items():
        rows.append(f'  <tlLogic id={quoteattr(tid)} type="static" programID="womd_log" offset="0">')
        k = 0
        while k < len(seq):
            j = k
            while j < len(seq) and seq[j] == seq[k]:
                j += 1
            duration = (j - k) * dt + (lead_in if k == 0 else 0.0)
            rows.append(f'    <phase duration="{duration:.3f}" state="{seq[k]}"/>')
            k = j
        rows.append("  </tlLogic>")
    rows.append("</additional>")
    path.write_text("\n".join(rows) + "\n")


# ----------------------------------------------------------------------------- routes and config

def _write_routes(path: Path, scene: Scene) -> None:
    tr = scene.tracks
    rows = ["<routes>"]
    seen: set[str] = set()
    for ot in sorted({int(t) for t in tr.object_type} | {int(ObjectType.VEHICLE)}):
        vid, vclass, shape, length, width = vtype_for(ot)
        if vid in seen:
            continue
        seen.add(vid)
        rows.append(f'  <vType id="{vid}" vClass="{vclass}" guiShape="{shape}" length="{length}" '
                    f'width="{width}" minGap="0.5" speedFactor="10" speedDev="0" maxSpeed="100"/>')
    rows.append("</routes>")
    path.write_text("\n".join(rows) + "\n")


def _write_sumocfg(path: Path, stem: str, scene: Scene, with_tll: bool) -> None:
    dt = scene.dt
    begin = 0.0
    end = float(scene.timestamps[-1]) if scene.num_steps else 0.0  # already on SUMO's clock
    add = f'\n    <additional-files value="{stem}.tll.xml"/>' if with_tll else ""
    path.write_text(f"""<configuration>
  <input>
    <net-file value="{stem}.net.xml"/>
    <route-files value="{stem}.rou.xml"/>{add}
  </input>
  <time>
    <begin value="{begin:.3f}"/>
    <end value="{end:.3f}"/>
    <step-length value="{dt:.3f}"/>
  </time>
</configuration>
""")


# ----------------------------------------------------------------------------- one scene

def check_convertible(scene: Scene) -> None:
    """Raise :class:`InputError` for scenes that cannot become a SUMO scene."""
    if len(scene.road_map.lanes) == 0:
        raise InputError(f"scene {scene.scenario_id}: the map has no lanes")
    veh = scene.tracks.object_type == int(ObjectType.VEHICLE)
    if not np.any(scene.tracks.valid[veh]):
        raise InputError(f"scene {scene.scenario_id}: no vehicle has a valid state")


def _type_name(object_type: int) -> str:
    try:
        return ObjectType(int(object_type)).name.lower()
    except ValueError:
        return f"type_{int(object_type)}"


SCENE_KIND = "scene"  # the marker kind of a converted scene folder (coster_sumo.infra.outdir)


@dataclass(slots=True)
class _BuiltNet:
    """The network step of :func:`convert_scene`: the lane graph, what netconvert made of it, how
    closely it follows WOMD and the WOMD -> SUMO mapping (``lane_map.json`` less its header)."""

    plain: PlainNet
    info: NetInfo
    fidelity: dict
    mapping: dict
    timing_s: dict[str, float]


def convert_scene(scene: Scene, outdir: str | Path, *, overwrite: bool = True, name: str | None = None
                  ) -> ConvertResult:
    """Convert one scene into ``outdir/<name>/`` (atomically); see the module docstring.

    An existing ``outdir/<name>/`` is replaced only with ``overwrite`` and only when it is a scene
    folder coster-sumo wrote (:mod:`coster_sumo.infra.outdir`); otherwise :class:`InputError`.

    ``name`` (folder and file stem) defaults to :func:`~coster_sumo.formats.scene_folder.folder_name`
    of the scenario id: never a path, never empty, whatever the input file says.
    """
    t0 = time.perf_counter()
    check_convertible(scene)
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    stem = folder_name(scene.scenario_id) if name is None else name
    if stem != folder_name(stem):
        raise InputError(f"{stem!r} is not a safe folder name")
    final = outdir / stem
    tmp = new_staging(final)
    try:
        built = _build_net(scene, tmp, stem, t0)
        with_tll = _write_replay_files(scene, tmp, stem, built.mapping)
        summary = _summary(scene, stem, built, with_tll, t0)
        (tmp / "summary.json").write_text(json.dumps(summary, indent=1))
        check_output(final, kind=SCENE_KIND, overwrite=overwrite)  # never replaces a folder we did not write
        publish(tmp, final, kind=SCENE_KIND)
        return ConvertResult(folder=final, summary=summary)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def _build_net(scene: Scene, tmp: Path, stem: str, t0: float) -> _BuiltNet:
    """``tmp/<stem>.net.xml``: the lane graph as plain XML, netconvert, the WOMD geometry given
    back, then measured against WOMD. ``t0``: when the conversion started (for the timings)."""
    plain = build_plain_net(scene.road_map, scene.signals)
    t_plain = time.perf_counter()
    if not plain.edges:
        raise ConversionError(f"scene {scene.scenario_id}: no lane could be converted")
    work = tmp / "plain"
    work.mkdir()
    nod, edg, con = write_plain_xml(plain, scene, work, stem)
    net = tmp / f"{stem}.net.xml"
    run_netconvert(nod, edg, con, net)
    t_net = time.perf_counter() - t0
    t_plain = t_plain - t0
    info = read_net(net)
    restored = set_womd_geometry(net, plain, info)
    t_restore = time.perf_counter() - t0
    fidelity, mapping = measure_fidelity(plain, scene, info)
    fidelity["lanes_restored"] = restored
    fidelity["continuity"] = measure_joints(net).summary()
    t_measure = time.perf_counter() - t0
    shutil.rmtree(work)
    timing = {"lane_graph": round(t_plain, 4), "netconvert": round(t_net - t_plain, 4),
              "restore": round(t_restore - t_net, 4), "measure": round(t_measure - t_restore, 4)}
    return _BuiltNet(plain, info, fidelity, mapping, timing)


def _write_replay_files(scene: Scene, tmp: Path, stem: str, mapping: dict) -> bool:
    """Everything the replay reads besides the net: the signal programs, vTypes, config, the scene
    on SUMO's clock and ``lane_map.json``. Returns whether there are signal programs."""
    tls_states = tls_state_strings(scene, mapping["tls"])
    sumo_scene = on_sumo_clock(scene)
    if tls_states:
        _write_tll(tmp / f"{stem}.tll.xml", tls_states, scene.dt,
                   float(sumo_scene.timestamps[0]) - scene.dt)
    _write_routes(tmp / f"{stem}.rou.xml", scene)
    _write_sumocfg(tmp / f"{stem}.sumocfg", stem, sumo_scene, bool(tls_states))
    save_scene(sumo_scene, tmp / "scene.npz")
    lane_map = {**mapping, "scenario_id": scene.scenario_id, "staging_lane": f"{STAGING_EDGE}_0",
                "sumo_time_offset_s": sumo_scene.meta["sumo_time_offset_s"]}
    (tmp / "lane_map.json").write_text(json.dumps(lane_map, indent=1))
    return bool(tls_states)


def _summary(scene: Scene, stem: str, built: _BuiltNet, with_tll: bool, t0: float) -> dict:
    """``summary.json``: the files, counts, fidelity figures, warnings and timings of one scene."""
    plain = built.plain
    tr = scene.tracks
    counts = {
        "agents": tr.num_agents,
        "agents_by_type": {_type_name(t): int(np.sum(tr.object_type == t))
                           for t in sorted(set(tr.object_type.tolist()))},
        "steps": scene.num_steps,
        "womd_lanes": len(scene.road_map.lanes),
        "sumo_edges": len(plain.edges),
        "sumo_lanes": sum(len(g) for g in plain.edges.values()),
        "multi_lane_edges": sum(len(g) > 1 for g in plain.edges.values()),
        "junction_connections": sum(bool(c.via_lanes) for c in plain.connections),
        "connections": len(plain.connections),
        "traffic_lights": len(built.info.tls),
        "skipped_lanes": len(plain.skipped),
    }
    return {
        "scenario_id": scene.scenario_id, "source": scene.source,
        "files": {"net": f"{stem}.net.xml", "routes": f"{stem}.rou.xml", "config": f"{stem}.sumocfg",
                  "scene": "scene.npz", "lane_map": "lane_map.json",
                  **({"tls": f"{stem}.tll.xml"} if with_tll else {})},
        "counts": counts, "fidelity": built.fidelity, "warnings": plain.warnings,
        "timing_s": built.timing_s,
        "conversion_s": round(time.perf_counter() - t0, 4),
    }
