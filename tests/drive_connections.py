"""SUMO's own driver over every connection of a net: does any vehicle jump?

One vehicle per (incoming edge, incoming lane, outgoing edge) of the net's connections, with the
route ``incoming outgoing``, departing on that lane and never changing lanes (so it takes exactly
that lane's connection), vehicles on one edge :data:`HEADWAY_S` apart; plain ``sumo`` with the
traffic lights off (a light's default program may never give some links green: that would be a
signal question, not a geometry one). From the FCD output: every step's displacement against the
speeds at both ends of the step. A vehicle moves at most ``max(v0, v1) * dt`` per step; a joint
whose lanes do not meet moves it further at once.
"""

from __future__ import annotations

import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from defusedxml import ElementTree as SafeET

from coster_sumo.infra import sumo_install

HEADWAY_S = 6.0  # [s] between departures from one edge
STEP_S = 0.1  # [s]
JUMP_SLACK_M = 0.1  # [m] displacement beyond max(v0, v1) * dt that counts as a jump
NO_LANE_CHANGE = 'lcStrategic="-1" lcCooperative="0" lcSpeedGain="0" lcKeepRight="0"'


@dataclass
class DriveResult:
    """What happened to the vehicles: routes tried, arrived, teleports and jumps (vehicle, metres,
    lane before, lane after)."""

    routes: int
    arrived: int
    teleports: int
    jumps: list[tuple[str, float, str, str]]


def drive_every_connection(net: Path, work: Path, skip_edges: frozenset[str] = frozenset()) -> DriveResult:
    """Drive one SUMO vehicle over every connection of ``net`` (see the module docstring)."""
    root = SafeET.parse(str(net)).getroot()
    allow: dict[str, set[str]] = {}
    for edge in root.iter("edge"):
        for lane in edge.iter("lane"):
            allow[lane.get("id", "")] = set(lane.get("allow", "").split())
    routes: dict[tuple[str, int, str], bool] = {}
    for c in root.iter("connection"):
        frm, to = c.get("from", ""), c.get("to", "")
        if frm.startswith(":") or frm in skip_edges:
            continue
        lane = f"{frm}_{c.get('fromLane')}"
        routes.setdefault((frm, int(c.get("fromLane", "0")), to), allow.get(lane) == {"bicycle"})
    vehicles = []
    per_edge: dict[str, int] = {}
    for k, ((frm, lane_index, to), bike) in enumerate(sorted(routes.items())):
        n = per_edge.get(frm, 0)
        per_edge[frm] = n + 1
        vehicles.append((HEADWAY_S * n, f'  <vehicle id="v{k}" type="{"bike" if bike else "car"}" '
                                        f'depart="{HEADWAY_S * n:.1f}" departLane="{lane_index}">'
                                        f'<route edges="{frm} {to}"/></vehicle>'))
    rows = ["<routes>", f'  <vType id="car" vClass="passenger" length="3" minGap="1" {NO_LANE_CHANGE}/>',
            f'  <vType id="bike" vClass="bicycle" length="1.6" minGap="1" {NO_LANE_CHANGE}/>',
            *(row for _, row in sorted(vehicles, key=lambda v: v[0])), "</routes>"]
    (work / "every.rou.xml").write_text("\n".join(rows) + "\n")
    fcd, trips = work / "every.fcd.xml", work / "every.trips.xml"
    cmd = [sumo_install.binary("sumo"), "-n", str(net), "-r", str(work / "every.rou.xml"), "--step-length", str(STEP_S),
           "--fcd-output", str(fcd), "--tripinfo-output", str(trips), "--no-step-log", "true",
           "--time-to-teleport", "60", "--tls.all-off", "true", "--end", "3600"]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=sumo_install.subprocess_env(), timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    arrived = sum(1 for _ in SafeET.parse(str(trips)).getroot().iter("tripinfo"))
    last: dict[str, tuple[float, float, float, str]] = {}
    jumps = []
    for ts in SafeET.parse(str(fcd)).getroot().iter("timestep"):
        for v in ts.iter("vehicle"):
            vid, lane = v.get("id", ""), v.get("lane", "")
            x, y, speed = float(v.get("x", "nan")), float(v.get("y", "nan")), float(v.get("speed", "nan"))
            if vid in last:
                px, py, pspeed, plane = last[vid]
                moved = float(np.hypot(x - px, y - py))
                if moved > max(speed, pspeed) * STEP_S + JUMP_SLACK_M:
                    jumps.append((vid, moved, plane, lane))
            last[vid] = (x, y, speed, lane)
    return DriveResult(routes=len(routes), arrived=arrived, teleports=proc.stderr.count("Teleporting vehicle"),
                       jumps=jumps)
