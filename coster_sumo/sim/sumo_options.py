"""The SUMO options and TraCI magic values every session uses, each with what it means."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

# Options always passed to SUMO unless the caller overrides them (docs/sumo.md §7). Why each one:
RECOMMENDED_OPTIONS: dict[str, str] = {
    "--step-length": "0.1",                 # 10 Hz like WOMD; SUMO's default is 1 s
    "--collision.action": "warn",           # the default "teleport" hides collisions caused by moveToXY
    "--collision.mingap-factor": "0",       # collision = geometric overlap, not gap < minGap
    "--collision.check-junctions": "true",  # also check inside junctions (approximate, see docs/sumo.md §4)
    "--time-to-teleport": "-1",             # never teleport vehicles stuck behind a replayed agent
    "--no-step-log": "true",
    "--no-warnings": "true",                # collisions still come back through the API
    "--verbose": "false",                   # configs that set it would print over the progress bars
    "--duration-log.statistics": "false",
}

# --- TraCI magic values ------------------------------------------------------------------------
# moveToXY keepRoute is a bit set:
#   bit0 (1): map onto the closest position *within the vehicle's current route*;
#   bit1 (2): place the vehicle at the exact x, y (including its lateral offset), on any edge, and
#             even off the road network: the vehicle then does not move by itself while off-road;
#   bit2 (4): map onto the closest edge regardless of route and permissions.
# We use 2: exact placement anywhere. SUMO rewrites the route to the edge(s) it maps onto, so the
# lane and route SUMO reports for a moved vehicle mean little (docs/sumo.md §3).
KEEP_ROUTE_EXACT_ANYWHERE = 2
# moveToXY matchThreshold [m]: how far from any lane a placement may be before the command fails;
# with keepRoute=2 a placement off the network is legal, so the threshold only bounds lane matching;
# 5 m keeps moveToXY at ~30 us on WOMD nets (100 m cost ~0.9 ms per call) and placements stay exact.
MOVE_MATCH_THRESHOLD_M = 5.0
# speed mode is a bit set; bit set = "respect": bit0 safe speed (car following), bit1 max
# acceleration, bit2 max deceleration, bit3 right of way at intersections, bit4 brake hard to not
# pass a red light, bit5 *disregard* right of way within intersections, bit6 speed limits.
# 0 = SUMO checks nothing for this vehicle: our commands are final.
SPEED_MODE_ALL_CHECKS_OFF = 0
SPEED_MODE_SUMO_DEFAULT = 31  # bits 0-4: what SUMO's own driver respects by default
# lane-change mode is a bit set (strategic, cooperative, speed gain, keep right, how TraCI requests
# interact with the others, sublane); 0 = the vehicle never changes lanes on its own.
LANE_CHANGE_MODE_NO_AUTONOMOUS = 0
LANE_CHANGE_MODE_SUMO_DEFAULT = 1621  # SUMO's default: every lane-change reason on, TraCI requests yield
# Reported speed of a moveToXY vehicle = min(displacement / dt, lane limit * speedFactor, maxSpeed)
# (docs/sumo.md §7). Large values lift the cap so getSpeed (and followers) see the true speed.
REMOTE_SPEED_FACTOR = 10.0  # [-]
REMOTE_MAX_SPEED_MPS = 100.0  # [m/s]
TRACI_CONNECT_TIMEOUT_S = 60.0  # [s] a big net takes a while to load before SUMO listens

# SUMO vehicle classes mapped onto our object types elsewhere; kept as strings here.
SHORT_TO_LONG = {"-c": "--configuration-file", "-n": "--net-file", "-r": "--route-files",
                  "-a": "--additional-files", "-b": "--begin", "-e": "--end"}


def as_list(v: str | Path | Sequence[str | Path] | None) -> list[str | Path]:
    """One path or several as a list (None: empty)."""
    if v is None:
        return []
    if isinstance(v, str | Path):
        return [v]
    return list(v)


def fmt(v: object) -> str:
    """A value as SUMO's command line wants it (true/false, 3 rather than 3.0)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float) and math.isfinite(v) and v == int(v) and abs(v) < 1e15:
        return str(int(v)) if abs(v) >= 1 else repr(v)
    return str(v)
