"""What SUMO's driver sees of a pedestrian- or bicycle-class adversary placed with moveToXY (docs/sumo.md §13a).

    python tests/method/vru/sumo_sees_vru.py

1. networks/intersection: SUMO's driver on W2C -> C2E at 13 m/s; the adversary (vClass pedestrian,
   bicycle, passenger) stands 200 m ahead on the driver's lane, or 2.5 m beside it.
2. The same intersection with netconvert's guessed sidewalks and crossings: the adversary (those
   vehicles, or a SUMO person) stands on the crossing of the driver's exit arm.
Prints whether the driver saw it as leader, its lowest speed and SUMO's collision reports.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import libsumo as t

from coster_sumo.infra import sumo_install

REPO = Path(__file__).resolve().parents[3]
NET = REPO / "networks" / "intersection" / "intersection.net.xml"
OPTS = ["--step-length", "0.1", "--no-step-log", "true", "--no-warnings", "true", "--collision.action", "warn",
        "--collision.mingap-factor", "0", "--collision.check-junctions", "true"]
CLASSES = (("pedestrian", "DEFAULT_PEDTYPE"), ("bicycle", "DEFAULT_BIKETYPE"), ("passenger", "DEFAULT_VEHTYPE"))


def start(net: Path, depart_pos: str, depart_lane: str) -> None:
    t.start(["sumo", "-n", str(net), *OPTS])
    t.route.add("r", ["W2C", "C2E"])
    t.vehicle.add("ego", "r", depart="0", departSpeed="13", departPos=depart_pos, departLane=depart_lane)


def add_adversary(vclass: str, base: str) -> None:
    t.vehicletype.copy(base, "adv")
    t.vehicletype.setVehicleClass("adv", vclass)
    t.vehicle.add("adv", "", typeID="adv", depart="0")


def drive(place: Callable[[], None], steps: int, leader: bool = True) -> tuple[bool, float, list[float]]:
    """Steps with ``place`` before each: (seen as leader, ego's lowest speed, SUMO collision times).
    ``leader=False``: no ``getLeader`` (with the adversary first placed on a crossing it killed the
    process with a segmentation fault, docs/sumo.md §13a)."""
    seen, low, hits = False, 99.0, []
    for _ in range(steps):
        place()
        t.simulationStep()
        if "ego" not in t.vehicle.getIDList():
            break
        if leader:
            lead = t.vehicle.getLeader("ego", 100.0)
            seen |= bool(lead and lead[0] == "adv")
        low = min(low, t.vehicle.getSpeed("ego"))
        hits += [round(t.simulation.getTime(), 1) for _ in t.simulation.getCollisions()]
    t.close()
    return seen, low, hits


def on_lanes() -> None:
    for vclass, base in CLASSES:
        for lateral, where in ((0.0, "on the driver's lane, ahead"), (2.5, "2.5 m beside the driver's lane")):
            start(NET, "10", "first")
            add_adversary(vclass, base)
            t.simulationStep()
            y = t.lane.getShape(t.vehicle.getLaneID("ego"))[0][1] + lateral
            seen, low, hits = drive(lambda y=y: t.vehicle.moveToXY("adv", "", -1, -40.0, y, angle=0.0, keepRoute=2),
                                    200)
            print(f"{vclass:10s} {where:32s} leader={seen} lowest speed {low:.1f} m/s collisions {hits[:1]}")


def on_crossing(net: Path) -> None:
    x, y = 8.4, -2.9  # on the crossing of the east arm, in the driver's path
    for vclass, base in CLASSES:
        start(net, "150", "1")
        add_adversary(vclass, base)
        _, low, hits = drive(lambda: t.vehicle.moveToXY("adv", "", -1, x, y, angle=0.0, keepRoute=2), 150, False)
        print(f"{vclass:10s} on the crossing                  lowest speed {low:.1f} m/s collisions {hits[:1]}")
    start(net, "150", "1")
    t.person.add("p", "C2E", 1.0, depart=0.0)
    t.person.appendWalkingStage("p", ["C2E"], 0.0)
    _, low, hits = drive(lambda: t.person.moveToXY("p", "", x, y, angle=0.0, keepRoute=2), 150, False)
    print(f"{'person':10s} on the crossing                  lowest speed {low:.1f} m/s collisions {hits[:1]}")


def main() -> None:
    if sys.argv[1:] != ["crossing"]:
        on_lanes()
        # libsumo on another network after these six simulations in one process died with a
        # segmentation fault; the crossing part runs in its own process
        subprocess.run([sys.executable, __file__, "crossing"], check=True)
        return
    with tempfile.TemporaryDirectory() as td:
        net = Path(td) / "sidewalks.net.xml"
        subprocess.run([sumo_install.binary("netconvert"), "-s", str(NET), "--sidewalks.guess", "true",
                        "--crossings.guess", "true", "-o", str(net)], check=True, capture_output=True,
                       env=sumo_install.subprocess_env())
        on_crossing(net)


if __name__ == "__main__":
    main()
