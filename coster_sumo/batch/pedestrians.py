"""Pedestrians in the corpus (``corpus build --pedestrians``; docs/corpus.md, "Pedestrians").

Three parts, each used only when pedestrians are switched on, so that a build without them is what
it was:

- **Networks** (:func:`walkable`): a network without a sidewalk gets netconvert's own guesses: a
  sidewalk on every edge that allows pedestrians (``--sidewalks.guess.from-permissions``; the road
  lanes then forbid them) and crossings where netconvert's heuristic puts them
  (``--crossings.guess``), written once to ``DATASET/nets/<name>.walk.net.xml``. Its traffic-light
  programs from additional files go through netconvert (``--tllogic-files``), which gives the new
  crossings their own signal states; the run then loads them from the net. Networks that already
  have sidewalks keep theirs; freeways and rural roads get no pedestrians.
- **Demand** (:func:`pedestrian_trips`): SUMO's ``randomTrips.py --pedestrians``, seeded like the
  vehicles, at :data:`PED_DENSITY` per km of sidewalk, in two sets: pedestrians who obey the
  signals and :data:`RED_WALKER_SHARE` of them who walk against the light (vType ``ped_red``).
- **Types** (:func:`pedestrian_vtypes_xml`): walking speeds and the junction-model parameters.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from coster_sumo.batch.nets import run_tool
from coster_sumo.data import dataset as ds
from coster_sumo.infra.atomic import atomic_path, write_text

if TYPE_CHECKING:
    from coster_sumo.batch.corpus import Network
    from coster_sumo.batch.simulate import RunTask

# [pedestrians/h per km of sidewalk] walks inserted (see docs/corpus.md for the choice)
PED_DENSITY = 25.0
# share of pedestrians who cross against the light (observed at signalised crossings; docs/corpus.md)
RED_WALKER_SHARE = 0.17
# [s] ``jmDriveAfterRedTime`` of those: SUMO lets a person start across a red crossing while the red
# has lasted less than this; longer than any red phase in the corpus, so the red never stops them
RED_WALKER_IGNORE_RED_S = 3600.0
MAX_WALK_M = 1000.0  # [m] air distance of a walk at the most (randomTrips --max-distance)
# families whose networks get no pedestrians: rural roads at 70-100 km/h have no sidewalks
NO_PEDESTRIANS = ("freeway", "rural")

# Walking speed: SUMO's desiredMaxSpeed of a person (1.39 m/s) times a speed factor normal around 1
# (sd 0.18, kept in 0.6-1.5): mean about 1.4 m/s, sd 0.25 m/s, 0.83-2.1 m/s, the pedestrian class of
# docs/method.md. Sizes: SUMO's own person defaults (0.215 m long, 0.478 m wide).
_SPEED_FACTOR = "normc(1,0.18,0.6,1.5)"


def pedestrian_vtypes_xml() -> str:
    """The two pedestrian vTypes a run's pedestrian trips use: ``ped`` (obeys the signals; at an
    unprioritised crossing waits for a gap that no vehicle has to brake for) and ``ped_red``
    (walks against the red, ``jmDriveAfterRedTime``; takes gaps that make vehicles brake,
    ``impatience`` 1)."""
    return ("<additional>\n"
            f'    <vType id="ped" vClass="pedestrian" speedFactor="{_SPEED_FACTOR}"/>\n'
            f'    <vType id="ped_red" vClass="pedestrian" speedFactor="{_SPEED_FACTOR}" '
            f'jmDriveAfterRedTime="{RED_WALKER_IGNORE_RED_S:g}" impatience="1"/>\n'
            "</additional>\n")


@dataclass(frozen=True)
class Walkable:
    """A network as pedestrians walk it: its net (``.walk.net.xml`` when sidewalks were guessed),
    the additional files the run still loads, and its sidewalks' length [km].

    ``vehicle_factor`` and ``bike_factor`` keep the vehicle and bicycle demand what it is without
    pedestrians: randomTrips' ``--insertion-density`` counts every lane of an edge that allows the
    class, so a guessed sidewalk would add inserted vehicles; the densities are multiplied by the
    lane km before over the lane km after (1 where nothing was guessed)."""

    net: Path
    additional: tuple[Path, ...]
    sidewalk_km: float
    guessed: bool
    vehicle_factor: float = 1.0
    bike_factor: float = 1.0


def sidewalk_km(net: Path) -> float:
    """[km] of sidewalk in a net: lanes (internal ones left out) that allow pedestrians only."""
    from defusedxml.ElementTree import iterparse

    from coster_sumo.formats.sumocfg import open_maybe_gzip

    km, internal = 0.0, False
    with open_maybe_gzip(net) as fh:
        for event, el in iterparse(fh, events=("start", "end")):
            if event == "start":
                if el.tag == "edge":
                    internal = el.get("function") in ("internal", "crossing", "walkingarea")
                continue
            if el.tag == "lane" and not internal and el.get("allow") == "pedestrian":
                km += float(el.get("length", 0.0)) / 1000.0
            if el.tag in ("edge", "junction", "connection", "tlLogic"):
                el.clear()
    return round(km, 3)


def _is_signal_file(path: Path) -> bool:
    """Whether an additional file holds traffic-light programs (they have to follow new crossings)."""
    return "<tlLogic" in path.read_text(errors="replace")


def walkable(net: Network, dataset: Path) -> Walkable | None:
    """``net`` with sidewalks and crossings (guessed by netconvert when it has no sidewalk; the
    guessed net is written once to ``DATASET/nets/``); None for networks that get no pedestrians
    (freeways, rural roads, nets where no edge allows pedestrians)."""
    from coster_sumo.infra import sumo_install

    if net.freeway or net.family in NO_PEDESTRIANS:
        return None
    own = sidewalk_km(net.net)
    if own > 0:
        return Walkable(net=net.net, additional=net.additional, sidewalk_km=own, guessed=False)
    signals = tuple(p for p in net.additional if _is_signal_file(p))
    path = dataset / ds.NETS_DIR / f"{net.name}.walk.net.xml"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            cmd = [sumo_install.binary("netconvert"), "--sumo-net-file", str(net.net),
                   "--sidewalks.guess.from-permissions", "--crossings.guess", "--output-file", str(tmp)]
            if signals:
                cmd += ["--tllogic-files", ",".join(str(p) for p in signals)]
            run_tool(cmd, "netconvert (sidewalks, crossings)")
    km = sidewalk_km(path)
    if km <= 0:
        return None
    before, after = trip_lane_km(net.net), trip_lane_km(path)
    return Walkable(net=path, additional=tuple(p for p in net.additional if p not in signals), sidewalk_km=km,
                    guessed=True, vehicle_factor=_ratio(before[0], after[0]), bike_factor=_ratio(before[1], after[1]))


def trip_lane_km(net: Path) -> tuple[float, float]:
    """[km] the lane length randomTrips' ``--insertion-density`` counts for passenger cars and for
    bicycles: every lane of each edge that allows the class on any lane."""
    from coster_sumo.infra import sumo_install

    sumolib = sumo_install.import_sumolib()
    edges = sumolib.net.readNet(str(net)).getEdges()

    def km(vclass: str) -> float:
        return sum(e.getLaneNumber() * e.getLength() for e in edges if e.allows(vclass)) / 1000.0

    return km("passenger"), km("bicycle")


def _ratio(before: float, after: float) -> float:
    return before / after if after > 0 else 1.0


def pedestrian_trips(task: RunTask) -> list[Path]:
    """Seeded random walks (``randomTrips.py --pedestrians``, validated by duarouter) over the run:
    ``task.ped_density`` per hour and km of sidewalk, :data:`RED_WALKER_SHARE` of them of type
    ``ped_red``. Returns the route files written (none when no walk could be routed)."""
    from coster_sumo.infra import sumo_install

    work = task.work
    types = write_text(work / "pedtypes.add.xml", pedestrian_vtypes_xml())
    begin = task.source.begin_s
    rate = task.ped_density * task.sidewalk_km  # [pedestrians/h]
    out = []
    for k, (vtype, share) in enumerate((("ped", 1.0 - RED_WALKER_SHARE), ("ped_red", RED_WALKER_SHARE))):
        if rate * share <= 0:
            continue
        routes = work / f"{vtype}.rou.xml"
        cmd = [sys.executable, sumo_install.tool("randomTrips.py"), "-n", str(task.source.path.resolve()),
               "--pedestrians", "-o", str(work / f"{vtype}.trips.xml"), "-r", str(routes), "-a", str(types),
               "-b", f"{begin:g}", "-e", f"{begin + task.duration_s:g}", "--seed", str(task.seed * 2 + k),
               "--insertion-rate", f"{rate * share:.3f}", "--random-depart", "--validate",
               "--max-distance", f"{MAX_WALK_M:g}", "--min-distance", "50", "--prefix", vtype,
               "--trip-attributes", f'type="{vtype}"']
        run_tool(cmd, f"randomTrips (pedestrians, {vtype})", cwd=work)
        if routes.exists() and "<person " in routes.read_text():
            out.append(routes)
    return out
