"""Do a SUMO net's lanes join? Gaps and kinks at every joint of every connection, and how sharply
internal lanes bend.

A SUMO ``<connection from=A fromLane=i to=B toLane=j via=V>`` is driven as lane ``A_i`` ->
internal lane ``V`` -> ... -> lane ``B_j``; an internal lane split at an internal junction
continues through a connection of its own (``from=":n_3" ... via=":n_3_1"``), and the last internal
lane ends in a connection without ``via``. So every ``<connection>`` is one **joint**: the end of
its ``from`` lane against the start of its ``via`` lane, or of its ``to`` lane where there is no
``via``. A vehicle that SUMO drives over a joint jumps by the joint's gap.

Per joint: the **gap** [m] between the two points, and the **kink** [rad], the heading change
between the last :data:`HEADING_BASE_M` of the first lane and the first :data:`HEADING_BASE_M` of
the second (chords over that length, so that centimetre jitter of logged polylines does not count
as a kink). **Curvature** [1/m] of an internal lane: the heading change between consecutive chords
of :data:`CURVATURE_STEP_M` along the lane, divided by that step.

The net is read with defusedxml (plain XML, no DTD, no entities), like every file the project
parses itself.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from defusedxml import ElementTree as SafeET

from coster_sumo.errors import InputError

JOINT_TOLERANCE_M = 0.05  # [m] a joint whose lanes are further apart than this is a gap
HEADING_BASE_M = 0.25  # [m] length of the chords whose headings give a joint's kink (in a curve of
# curvature k the chords of both sides differ by about k * HEADING_BASE_M as well)
CURVATURE_STEP_M = 1.0  # [m] chord length for the curvature of internal lanes


@dataclass(frozen=True, slots=True)
class Joint:
    """One joint of a connection.

    Attributes:
        from_lane, to_lane: SUMO lane ids (``to_lane`` is the ``via`` lane where there is one).
        gap_m: [m] distance between the end of ``from_lane`` and the start of ``to_lane``.
        kink_rad: [rad] heading change across the joint (absolute, in [0, pi]).
    """

    from_lane: str
    to_lane: str
    gap_m: float
    kink_rad: float


@dataclass(frozen=True, slots=True)
class JointReport:
    """Every joint of a net, and the curvature of its internal lanes.

    Attributes:
        joints: one per ``<connection>`` whose lanes both have a shape.
        internal_curvature: internal lane id -> [1/m] its largest curvature (0 for a lane shorter
            than two chords).
    """

    joints: tuple[Joint, ...]
    internal_curvature: dict[str, float]

    @property
    def gaps(self) -> np.ndarray:
        """(J,) float64 [m] every joint's gap."""
        return np.array([j.gap_m for j in self.joints], np.float64)

    def summary(self, tolerance_m: float = JOINT_TOLERANCE_M) -> dict[str, Any]:
        """JSON-able figures: joint count, joints over ``tolerance_m``, largest gap [m], largest kink
        [deg], largest internal-lane curvature [1/m]."""
        gaps = self.gaps
        kinks = np.array([j.kink_rad for j in self.joints], np.float64)
        curv = np.array(list(self.internal_curvature.values()), np.float64)
        return {
            "joints": len(self.joints),
            "joints_over_tolerance": int(np.sum(gaps > tolerance_m)),
            "tolerance_m": tolerance_m,
            "max_gap_m": float(gaps.max()) if len(gaps) else 0.0,
            "max_kink_deg": float(np.degrees(kinks.max())) if len(kinks) else 0.0,
            "internal_lanes": len(curv),
            "max_internal_curvature_per_m": float(curv.max()) if len(curv) else 0.0,
        }


def _shape(el: Any) -> np.ndarray:
    pts = [tuple(float(v) for v in p.split(",")[:2]) for p in el.get("shape", "").split()]
    return np.asarray(pts, np.float64).reshape(-1, 2)


def _chord_heading(shape: np.ndarray, at_end: bool) -> float | None:
    """Heading [rad] of the chord over the first (last) :data:`HEADING_BASE_M` of a shape, or of
    the whole shape where it is shorter (None: no length at all)."""
    pts = shape[::-1] if at_end else shape
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
    if cum[-1] <= 1e-9:
        return None
    s = min(HEADING_BASE_M, float(cum[-1]))
    far = np.array([np.interp(s, cum, pts[:, 0]), np.interp(s, cum, pts[:, 1])])
    d = (far - pts[0]) if not at_end else (pts[0] - far)
    return float(np.arctan2(d[1], d[0]))


def max_curvature(shape: np.ndarray, step: float = CURVATURE_STEP_M) -> float:
    """[1/m] largest heading change between consecutive ``step`` chords of a polyline (K, 2),
    divided by ``step`` (0 where the line is shorter than two chords)."""
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(shape, axis=0).T))])
    if cum[-1] < 2 * step:
        return 0.0
    s = np.arange(0.0, cum[-1] + 1e-9, step)
    pts = np.column_stack([np.interp(s, cum, shape[:, 0]), np.interp(s, cum, shape[:, 1])])
    d = np.diff(pts, axis=0)
    h = np.arctan2(d[:, 1], d[:, 0])
    turn = np.abs((np.diff(h) + np.pi) % (2 * np.pi) - np.pi)
    return float(turn.max() / step) if len(turn) else 0.0


def measure_joints(net_file: str | Path) -> JointReport:
    """The :class:`JointReport` of a ``.net.xml`` (see the module docstring)."""
    path = Path(net_file)
    try:
        root = SafeET.parse(str(path), forbid_dtd=True).getroot()
    except Exception as exc:  # noqa: BLE001 - ParseError, DTDForbidden, EntitiesForbidden, OSError
        raise InputError(f"{path}: not a readable SUMO net ({type(exc).__name__}: {exc})") from None
    shapes: dict[str, np.ndarray] = {}
    internal: set[str] = set()
    for edge in root.iter("edge"):
        for lane in edge.iter("lane"):
            lid = lane.get("id", "")
            shapes[lid] = _shape(lane)
            if edge.get("function") == "internal":
                internal.add(lid)
    joints = []
    for c in root.iter("connection"):
        a = f"{c.get('from')}_{c.get('fromLane')}"
        b = c.get("via") or f"{c.get('to')}_{c.get('toLane')}"
        sa, sb = shapes.get(a), shapes.get(b)
        if sa is None or sb is None or len(sa) == 0 or len(sb) == 0:
            continue
        gap = float(np.hypot(*(sa[-1] - sb[0])))
        ha, hb = _chord_heading(sa, True), _chord_heading(sb, False)
        kink = 0.0 if ha is None or hb is None else abs((hb - ha + np.pi) % (2 * np.pi) - np.pi)
        joints.append(Joint(a, b, gap, float(kink)))
    curvature = {lid: max_curvature(shapes[lid]) for lid in sorted(internal) if len(shapes[lid]) >= 2}
    return JointReport(tuple(joints), curvature)
