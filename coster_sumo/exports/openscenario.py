"""OpenSCENARIO 1.2 + OpenDRIVE export of one variant (optional extra ``coster-sumo[openscenario]``).

Written from what ``coster-sumo run`` leaves in ``variants/<i>/`` (nothing is simulated again):

- ``<name>.xodr``: the variant's SUMO net converted by ``netconvert --opendrive-output`` with
  ``--offset.disable-normalization true``, so the OpenDRIVE inertial frame is the SUMO net's own
  frame (netconvert would otherwise shift the net to start at the origin). netconvert writes one
  road per edge (and one connecting road per junction connection); a road's reference line is
  the left border of its leftmost lane, its lanes are right lanes (negative ids) with their SUMO
  widths. :func:`xodr_lane_centres` samples those lane centre lines back (line, arc and
  paramPoly3 geometries, laneOffset, width polynomials) and :func:`compare_with_net` measures
  them against the SUMO lane shapes (which are lane centre lines).
- ``<name>.xosc``: OpenSCENARIO 1.2 built with the ``scenariogeneration`` package: the road network
  is the .xodr; the entities are the target, the adversary and every vehicle within
  :data:`DEFAULT_RADIUS_M` of the target at t_col; each is teleported to its first recorded pose
  and follows its recorded 10 Hz trajectory as a timed polyline of world positions
  (``FollowTrajectoryAction``, timing ``absolute``, following mode ``position``). An entity's
  reference point is its bounding-box centre (``BoundingBox`` centre at x = y = 0), the position
  the recording holds. Scenario time 0 is the earliest recorded time of the exported vehicles
  (``SumoTimeOffset``); the collision snapshot (t_col, the adversary's state, the contact the pass
  measured) is in the ``ParameterDeclarations`` and the header's description.
  OpenSCENARIO 1.2 entities exist from the start: a vehicle whose recording starts later waits at
  its first pose, one whose recording ends early stays at its last pose.
- ``trajectories.csv`` / ``trajectories.json`` of the same vehicles
  (:mod:`coster_sumo.exports.trajectories`).

Each .xosc is validated against the OpenSCENARIO 1.2 XSD that ``scenariogeneration`` installs
(``<site-packages>/schemas/OpenSCENARIO_1_2.xsd``) with ``xmlschema``.
"""

from __future__ import annotations

import importlib
import math
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from defusedxml import ElementTree as SafeET

from coster_sumo import sumo_env
from coster_sumo.errors import InputError, SumoError
from coster_sumo.exports.trajectories import Trajectory

EXTRA = "openscenario"
EXTRA_HINT = f"pip install 'coster-sumo[{EXTRA}]'"
DEFAULT_RADIUS_M = 50.0
OSC_MINOR = 2
SAMPLE_STEP_M = 0.5  # [m] spacing of the xodr samples in compare_with_net
HEIGHT_M = {"VEHICLE": 1.5, "PEDESTRIAN": 1.8, "CYCLIST": 1.7}


def require_extra() -> None:
    """Raise :class:`InputError` (exit 2), one line naming the extra, when it is not installed."""
    for module in ("scenariogeneration", "xmlschema"):
        try:
            importlib.import_module(module)
        except ImportError:
            raise InputError(f"the OpenSCENARIO export needs the optional extra '{EXTRA}' "
                             f"(module {module} is missing): {EXTRA_HINT}") from None


def schema_path(minor: int = OSC_MINOR) -> Path:
    """The OpenSCENARIO 1.<minor> XSD that scenariogeneration installs beside itself."""
    require_extra()
    import scenariogeneration

    path = Path(scenariogeneration.__file__).resolve().parent.parent / "schemas" / f"OpenSCENARIO_1_{minor}.xsd"
    if not path.is_file():
        raise InputError(f"{path}: the OpenSCENARIO schema scenariogeneration should install is missing")
    return path


def validate_xosc(path: Path) -> list[str]:
    """Schema errors of an .xosc against the OpenSCENARIO 1.2 XSD (empty: valid)."""
    import xmlschema

    schema = xmlschema.XMLSchema(str(schema_path()))
    return [f"{e.path}: {e.reason}" for e in schema.iter_errors(str(path))]


def write_xodr(net_file: Path, out: Path) -> Path:
    """OpenDRIVE of a SUMO net by netconvert, in the net's own coordinates."""
    cmd = [sumo_env.binary("netconvert"), "--sumo-net-file", str(net_file), "--opendrive-output", str(out),
           "--offset.disable-normalization", "true", "--no-warnings", "true"]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=sumo_env.subprocess_env(), timeout=600)
    if proc.returncode != 0 or not out.is_file():
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
        raise SumoError(f"netconvert --opendrive-output failed on {net_file}: {tail[0]}")
    return out


# --- OpenDRIVE sampling ---------------------------------------------------------------------------


@dataclass
class XodrLane:
    """Centre line samples of one OpenDRIVE lane.

    Attributes:
        road: road id; junction: the road's junction id (-1: none); lane: lane id; kind: lane type.
        xy: (N, 2) float64 [m] centre line points in the OpenDRIVE inertial frame.
    """

    road: str
    junction: str
    lane: int
    kind: str
    xy: np.ndarray


def _f(el: Any, key: str, default: float = 0.0) -> float:
    v = el.get(key)
    return float(v) if v is not None else default


def _poly(recs: list[tuple[float, float, float, float, float]], s: np.ndarray) -> np.ndarray:
    """Piecewise cubic (s0, a, b, c, d) records evaluated at ``s`` (each record from its s0 on)."""
    out = np.zeros_like(s)
    if not recs:
        return out
    starts = np.array([r[0] for r in recs])
    idx = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(recs) - 1)
    for k, (s0, a, b, c, d) in enumerate(recs):
        m = idx == k
        ds = s[m] - s0
        out[m] = a + b * ds + c * ds ** 2 + d * ds ** 3
    return out


def _reference_line(plan_view: Any, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x, y [m], heading [rad] of a road's reference line at ``s`` (line, arc, paramPoly3)."""
    x, y, h = np.full_like(s, np.nan), np.full_like(s, np.nan), np.full_like(s, np.nan)
    geos = list(plan_view.iter("geometry"))
    starts = np.array([_f(g, "s") for g in geos])
    which = np.clip(np.searchsorted(starts, s + 1e-9, side="right") - 1, 0, len(geos) - 1)  # last s0 <= s
    for k, g in enumerate(geos):
        s0, length = _f(g, "s"), _f(g, "length")
        m = which == k
        ds = s[m] - s0  # (past the last geometry's end by rounding only: extrapolated)
        x0, y0, h0 = _f(g, "x"), _f(g, "y"), _f(g, "hdg")
        shape = next(iter(g))
        if shape.tag == "line":
            x[m], y[m], h[m] = x0 + ds * math.cos(h0), y0 + ds * math.sin(h0), h0
        elif shape.tag == "arc":
            kc = _f(shape, "curvature")
            if abs(kc) < 1e-12:
                x[m], y[m], h[m] = x0 + ds * math.cos(h0), y0 + ds * math.sin(h0), h0
            else:
                x[m] = x0 + (np.sin(h0 + kc * ds) - math.sin(h0)) / kc
                y[m] = y0 - (np.cos(h0 + kc * ds) - math.cos(h0)) / kc
                h[m] = h0 + kc * ds
        elif shape.tag == "paramPoly3":
            p = ds / length if shape.get("pRange", "normalized") == "normalized" and length > 0 else ds
            cu = [_f(shape, k_) for k_ in ("aU", "bU", "cU", "dU")]
            cv = [_f(shape, k_) for k_ in ("aV", "bV", "cV", "dV")]
            u = cu[0] + cu[1] * p + cu[2] * p ** 2 + cu[3] * p ** 3
            v = cv[0] + cv[1] * p + cv[2] * p ** 2 + cv[3] * p ** 3
            du = cu[1] + 2 * cu[2] * p + 3 * cu[3] * p ** 2
            dv = cv[1] + 2 * cv[2] * p + 3 * cv[3] * p ** 2
            c, sn = math.cos(h0), math.sin(h0)
            x[m], y[m], h[m] = x0 + c * u - sn * v, y0 + sn * u + c * v, h0 + np.arctan2(dv, du)
        else:
            raise InputError(f"OpenDRIVE geometry <{shape.tag}> is not supported by this sampler")
    return x, y, h


def xodr_lane_centres(path: Path, step: float = SAMPLE_STEP_M) -> list[XodrLane]:
    """Every lane's centre line of an OpenDRIVE file, sampled every ``step`` m along its road.

    Lateral position of lane ``-k`` (right): laneOffset - sum of the widths of lanes -1..-(k-1)
    - half its own width; left lanes mirrored. Width records start at their section's s + sOffset.
    """
    root = SafeET.parse(str(path), forbid_dtd=True).getroot()
    out: list[XodrLane] = []
    for road in root.iter("road"):
        length = _f(road, "length")
        s = np.unique(np.append(np.arange(0.0, length, step), length))
        x, y, h = _reference_line(road.find("planView"), s)
        lanes_el = road.find("lanes")
        if lanes_el is None:
            continue
        offset = _poly([(_f(o, "s"), _f(o, "a"), _f(o, "b"), _f(o, "c"), _f(o, "d"))
                        for o in lanes_el.iter("laneOffset")], s)
        sections = list(lanes_el.iter("laneSection"))
        for j, sec in enumerate(sections):
            s_sec = _f(sec, "s")
            s_end = _f(sections[j + 1], "s") if j + 1 < len(sections) else length + 1e-9
            m = (s >= s_sec - 1e-9) & ((s < s_end) if j + 1 < len(sections) else (s <= s_end))
            if not m.any():
                continue
            for side, sign in (("right", -1.0), ("left", 1.0)):
                side_el = sec.find(side)
                if side_el is None:
                    continue
                lanes = sorted(side_el.iter("lane"), key=lambda e: abs(int(e.get("id", "0"))))
                inner = np.zeros(int(m.sum()))
                for lane in lanes:
                    w = _poly([(s_sec + _f(r, "sOffset"), _f(r, "a"), _f(r, "b"), _f(r, "c"), _f(r, "d"))
                               for r in lane.iter("width")], s[m])
                    t = offset[m] + sign * (inner + 0.5 * w)
                    inner = inner + w
                    xy = np.column_stack([x[m] - t * np.sin(h[m]), y[m] + t * np.cos(h[m])])  # t: to the left
                    out.append(XodrLane(road=road.get("id", ""), junction=road.get("junction", "-1"),
                                        lane=int(lane.get("id", "0")), kind=lane.get("type", ""), xy=xy))
    return out


def net_lane_shapes(net_file: Path) -> tuple[list[str], list[np.ndarray], np.ndarray]:
    """SUMO lane ids, shapes (K, 2) [m] and whether each lies in a junction, read with sumolib."""
    from coster_sumo.formats.sumo_net import read_sumolib_net

    net = read_sumolib_net(str(net_file))
    ids, shapes, internal = [], [], []
    for edge in net.getEdges(withInternal=True):
        for lane in edge.getLanes():
            shape = np.asarray(lane.getShape(), np.float64)[:, :2]
            if len(shape) >= 2:
                ids.append(lane.getID())
                shapes.append(shape)
                internal.append(edge.getID().startswith(":"))
    return ids, shapes, np.array(internal, bool)


def compare_with_net(xodr: Path, net_file: Path, step: float = SAMPLE_STEP_M) -> dict[str, Any]:
    """Distances [m] between the OpenDRIVE lane centre lines and the SUMO lane shapes they came from.

    Roads outside junctions are compared with the SUMO lanes outside junctions, connecting roads
    with the junction-internal lanes. ``xodr_to_net``: from every xodr sample to the nearest SUMO
    lane shape (the xodr lies on a SUMO lane); ``net_to_xodr``: from every SUMO lane shape point
    (vertices, and every ``step`` m between them) to the nearest xodr lane centre line (every SUMO
    lane is in the xodr). Max and mean of each, and the sample counts.
    """
    ids, shapes, internal = net_lane_shapes(net_file)
    lanes = xodr_lane_centres(xodr, step)
    res: dict[str, Any] = {}
    for name, in_junction in (("roads", False), ("junctions", True)):
        sumo_lines = [shapely.LineString(sh) for sh, i in zip(shapes, internal, strict=True) if i == in_junction]

        mine = [ln for ln in lanes if (ln.junction != "-1") == in_junction and len(ln.xy) >= 2]
        if not sumo_lines or not mine:
            res[name] = {"xodr_samples": sum(len(ln.xy) for ln in mine), "sumo_lanes": len(sumo_lines)}
            continue
        sumo_geom = shapely.MultiLineString(sumo_lines)
        pts = np.concatenate([ln.xy for ln in mine])
        d1 = shapely.distance(shapely.points(pts), sumo_geom)
        xodr_geom = shapely.MultiLineString([shapely.LineString(ln.xy) for ln in mine])
        # (a zero-length lane, e.g. a dead end's turnaround, is its points)
        sp = np.concatenate([shapely.get_coordinates(shapely.segmentize(ln, step) if ln.length > 0 else ln)
                             for ln in sumo_lines])
        d2 = shapely.distance(shapely.points(sp), xodr_geom)
        res[name] = {"xodr_samples": len(pts), "xodr_to_net_max": float(d1.max()), "xodr_to_net_mean": float(d1.mean()),
                     "xodr_to_net_p99": float(np.percentile(d1, 99)),
                     "xodr_to_net_over_0.1m": float(np.mean(d1 > 0.1)),
                     "sumo_lanes": len(sumo_lines), "sumo_samples": len(sp), "net_to_xodr_max": float(d2.max()),
                     "net_to_xodr_mean": float(d2.mean()), "net_to_xodr_p99": float(np.percentile(d2, 99))}
    return res


# --- OpenSCENARIO -------------------------------------------------------------------------------


def _entity(xosc: Any, tr: Trajectory) -> Any:
    length, width = float(np.median(tr.length)), float(np.median(tr.width))
    height = HEIGHT_M.get(tr.kind, 1.5)
    box = xosc.BoundingBox(width, length, height, 0.0, 0.0, height / 2)
    if tr.kind == "PEDESTRIAN":
        return xosc.Pedestrian(tr.vehicle_id, 80, xosc.PedestrianCategory.pedestrian, box, model="pedestrian")
    category = xosc.VehicleCategory.bicycle if tr.kind == "CYCLIST" else xosc.VehicleCategory.car
    front = xosc.Axle(0.5, 0.7, min(width, 1.8), 0.3 * length, 0.35)
    rear = xosc.Axle(0.0, 0.7, min(width, 1.8), -0.3 * length, 0.35)
    return xosc.Vehicle(tr.vehicle_id, category, box, front, rear, 100.0, 20.0, 20.0)


def write_xosc(path: Path, xodr_name: str, trajs: dict[str, Trajectory], ids: list[str], *, t0: float,
               description: str, parameters: dict[str, float | str]) -> Path:
    """The OpenSCENARIO 1.2 file of ``ids`` (see the module docstring); times are ``t - t0``."""
    require_extra()
    from scenariogeneration import xosc

    params = xosc.ParameterDeclarations()
    for name, value in parameters.items():
        kind = xosc.ParameterType.string if isinstance(value, str) else xosc.ParameterType.double
        params.add_parameter(xosc.Parameter(name, kind, value if isinstance(value, str) else f"{value:.6f}"))
    entities = xosc.Entities()
    init = xosc.Init()
    story = xosc.Story("recorded_pass")
    start = xosc.ValueTrigger("start", 0, xosc.ConditionEdge.none,
                              xosc.SimulationTimeCondition(0, xosc.Rule.greaterOrEqual))
    act = xosc.Act("replay", start)
    end = 0.0
    for vid in ids:
        tr = trajs[vid]
        entities.add_scenario_object(vid, _entity(xosc, tr))
        t = np.round(tr.t - t0, 6)
        end = max(end, float(t[-1]))
        init.add_init_action(vid, xosc.TeleportAction(
            xosc.WorldPosition(float(tr.x[0]), float(tr.y[0]), 0.0, float(tr.heading[0]), 0.0, 0.0)))
        if len(t) < 2:
            continue
        poses = [xosc.WorldPosition(float(a), float(b), 0.0, float(h), 0.0, 0.0)
                 for a, b, h in zip(tr.x, tr.y, np.unwrap(tr.heading), strict=True)]
        traj = xosc.Trajectory(f"{vid}_trajectory", False)
        traj.add_shape(xosc.Polyline([float(v) for v in t], poses))
        action = xosc.FollowTrajectoryAction(traj, xosc.FollowingMode.position, xosc.ReferenceContext.absolute,
                                             1, 0)
        event = xosc.Event(f"{vid}_follow", xosc.Priority.override)
        event.add_action(f"{vid}_follow_trajectory", action)
        event.add_trigger(xosc.ValueTrigger(f"{vid}_start", 0, xosc.ConditionEdge.none,
                                            xosc.SimulationTimeCondition(0, xosc.Rule.greaterOrEqual)))
        man = xosc.Maneuver(f"{vid}_maneuver")
        man.add_event(event)
        group = xosc.ManeuverGroup(f"{vid}_group")
        group.add_actor(vid)
        group.add_maneuver(man)
        act.add_maneuver_group(group)
    story.add_act(act)
    stop = xosc.ValueTrigger("stop", 0, xosc.ConditionEdge.rising,
                             xosc.SimulationTimeCondition(end + 0.5, xosc.Rule.greaterThan), "stop")
    board = xosc.StoryBoard(init, stop)
    board.add_story(story)
    scenario = xosc.Scenario(description, "coster-sumo", params, entities, board,
                             xosc.RoadNetwork(roadfile=xodr_name), xosc.Catalog(), osc_minor_version=OSC_MINOR)
    scenario.write_xml(str(path))
    return path


def read_xosc_trajectories(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Entity name -> (time [s], x [m], y [m], h [rad]) of every Polyline a FollowTrajectoryAction
    in the file's storyboard gives it (plain XML read; ``ParseOpenScenario`` parses the same file)."""
    root = SafeET.parse(str(path), forbid_dtd=True).getroot()
    out = {}
    for group in root.iter("ManeuverGroup"):
        actors = [e.get("entityRef", "") for e in group.iter("EntityRef")]
        for poly in group.iter("Polyline"):
            rows = []
            for v in poly.iter("Vertex"):
                w = v.find("Position/WorldPosition")
                if w is None:
                    continue
                rows.append((_f(v, "time"), _f(w, "x"), _f(w, "y"), _f(w, "h")))
            a = np.array(rows, np.float64).reshape(-1, 4)
            for actor in actors:
                out[actor] = (a[:, 0], a[:, 1], a[:, 2], a[:, 3])
    return out


def read_parameters(path: Path) -> dict[str, str]:
    """The file's top-level ParameterDeclarations: name -> value."""
    root = SafeET.parse(str(path), forbid_dtd=True).getroot()
    decl = root.find("ParameterDeclarations")
    return {} if decl is None else {p.get("name", ""): p.get("value", "") for p in decl.iter("ParameterDeclaration")}
