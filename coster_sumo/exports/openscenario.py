"""OpenSCENARIO 1.2 + OpenDRIVE export of one variant (optional extra ``coster-sumo[openscenario]``).

Written from what ``coster-sumo run`` leaves in ``variants/<i>/`` (nothing is simulated again):

- ``<name>.xodr``: the variant's SUMO net as OpenDRIVE, in the net's own coordinates, its lanes
  on the SUMO lane shapes (:mod:`coster_sumo.exports.opendrive`).
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
from pathlib import Path
from typing import Any

import numpy as np
from defusedxml import ElementTree as SafeET

from coster_sumo.errors import InputError
from coster_sumo.exports.trajectories import Trajectory

EXTRA = "openscenario"
EXTRA_HINT = f"pip install 'coster-sumo[{EXTRA}]'"
DEFAULT_RADIUS_M = 50.0
OSC_MINOR = 2
HEIGHT_M = {"VEHICLE": 1.5, "PEDESTRIAN": 1.8, "CYCLIST": 1.7}
# SUMO vehicle class -> OpenSCENARIO 1.2 VehicleCategory. SUMO's "trailer" is a truck pulling a
# trailer (a combination, like OpenSCENARIO's semitrailer); OpenSCENARIO has no scooter: the
# nearest two-wheeler without an engine of its own is the bicycle. Classes not listed are cars.
VEHICLE_CATEGORY = {
    "passenger": "car", "private": "car", "taxi": "car", "hov": "car", "evehicle": "car", "vip": "car",
    "authority": "car", "army": "car", "emergency": "car", "custom1": "car", "custom2": "car",
    "delivery": "van", "truck": "truck", "trailer": "semitrailer",
    "bus": "bus", "coach": "bus",
    "motorcycle": "motorbike", "moped": "motorbike",
    "bicycle": "bicycle", "scooter": "bicycle",
    "tram": "tram", "rail_urban": "train", "rail": "train", "rail_electric": "train", "rail_fast": "train",
}
PEDESTRIAN_CLASSES = frozenset({"pedestrian", "wheelchair"})


def vehicle_category(vclass: str, kind: str) -> str:
    """The OpenSCENARIO VehicleCategory name of a SUMO vehicle class; without a class, from the
    object type (CYCLIST: bicycle, anything else: car)."""
    if vclass:
        return VEHICLE_CATEGORY.get(vclass, "car")
    return "bicycle" if kind == "CYCLIST" else "car"


def _f(el: Any, key: str, default: float = 0.0) -> float:
    v = el.get(key)
    return float(v) if v is not None else default


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


# --- OpenSCENARIO -------------------------------------------------------------------------------


def _entity(xosc: Any, tr: Trajectory) -> Any:
    length, width = float(np.median(tr.length)), float(np.median(tr.width))
    height = HEIGHT_M.get(tr.kind, 1.5)
    box = xosc.BoundingBox(width, length, height, 0.0, 0.0, height / 2)
    if tr.vclass in PEDESTRIAN_CLASSES or (not tr.vclass and tr.kind == "PEDESTRIAN"):
        return xosc.Pedestrian(tr.vehicle_id, 80, xosc.PedestrianCategory.pedestrian, box, model="pedestrian")
    category = getattr(xosc.VehicleCategory, vehicle_category(tr.vclass, tr.kind))
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
