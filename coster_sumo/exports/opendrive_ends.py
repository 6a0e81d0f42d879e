"""Where a fitted road starts and ends when the lanes of its SUMO edge do not (converted WOMD maps).

The lanes of a converted WOMD edge keep their logged centre lines, so they start and end at
different stations: a lane opens a few decimetres (up to ~4 m on the four samples) after its
neighbours, or runs on past them. OpenDRIVE links lanes only at a road's two ends, and readers
want a linked lane to have a width there (ASAM's checker: ``new_lane_appear``,
``zero_width_at_end``; a zero width at a link also leaves the connecting road's borders metres
from the lane's). So a road spans only the stretch where every lane that a junction connection
enters has begun (its start) and every lane that one leaves has not ended yet (its end):

- the edge's axis (the smoothed reference polyline) runs from the latest start of a lane with an
  incoming connection to the earliest end of a lane with an outgoing connection (from the first
  start and to the last end of all its lanes where no connection enters or leaves there);
- every lane is cut on the normal of the road's reference line at each end: what lies before the
  start (its *head*) joins the connecting roads that enter the lane, what lies past the end (its
  *tail*) those that leave it. A vehicle drives the same path; only the border between road and
  junction moves (by the same amount for every lane of the end). A lane that no connection enters
  (leaves) loses its head (tail) where it sticks out past a linked lane's; that length is counted.

A road whose linked lanes do not overlap by :data:`MIN_TRIMMED_M` keeps its old extent.
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.ops import substring

MIN_TRIMMED_M = 1.0  # [m] shortest road left after moving its ends (else the ends stay)
EXTEND_M = 50.0  # [m] straight run added to an axis's ends while locating lane ends beside it
CUT_EPS_M = 1e-3  # [m] a piece shorter than this beyond a cut line is no piece


def road_span(axis: np.ndarray, shapes: list[np.ndarray], enters: list[bool], leaves: list[bool],
              inset: tuple[float, float] = (0.0, 0.0)) -> tuple[np.ndarray, bool]:
    """The axis polyline (N, 2) [m] clipped (or lengthened straight) to the span of :func:`module
    docstring <coster_sumo.exports.opendrive_ends>`, and whether linked lanes set an end of it.

    Args:
        axis: (N, 2) [m] the smoothed reference polyline of the edge (N >= 2).
        shapes: the edge's lane shapes (K, 2) [m].
        enters, leaves: per lane, a connection enters it at its start / leaves it at its end.
        inset: [m] the start moved on and the end moved back by so much more (where the smooth
            reference line's end normals, which cut the lanes, lean against the axis's).
    """
    d0 = _unit(axis[1] - axis[0])
    d1 = _unit(axis[-1] - axis[-2])
    line = shapely.LineString(np.vstack([axis[0] - EXTEND_M * d0, axis, axis[-1] + EXTEND_M * d1]))
    firsts, lasts = [], []
    for shape in shapes:
        if len(shape) < 2:
            firsts.append(np.nan)
            lasts.append(np.nan)
            continue
        firsts.append(float(line.project(shapely.Point(shape[0]))))
        lasts.append(float(line.project(shapely.Point(shape[-1]))))
    first, last = np.array(firsts), np.array(lasts)
    ok = np.isfinite(first)
    if not ok.any():
        return axis, False
    lo_all, hi_all = float(first[ok].min()), float(last[ok].max())
    entering = ok & np.asarray(enters, bool)
    leaving = ok & np.asarray(leaves, bool)
    lo = float(first[entering].max()) + inset[0] if entering.any() else lo_all
    hi = float(last[leaving].min()) - inset[1] if leaving.any() else hi_all
    # (lanes that all start and end together, as netconvert's, keep their road as it was unless an
    # inset moves its ends: opendrive_net.NetLanes.tight_cutbacks)
    moved = lo > lo_all + CUT_EPS_M or hi < hi_all - CUT_EPS_M
    if not moved or hi - lo < MIN_TRIMMED_M:
        lo, hi, moved = lo_all, hi_all, False
    part = substring(line, lo, hi)
    return shapely.get_coordinates(part), moved


def shortfall(shapes: list[np.ndarray], enters: list[bool], leaves: list[bool], start: np.ndarray,
              start_heading: float, end: np.ndarray, end_heading: float) -> tuple[float, float]:
    """[m] how far the latest-starting lane that a connection enters starts after the normal through
    a road's ``start`` (heading ``start_heading`` [rad]), and the earliest-ending lane that one
    leaves ends before the normal through its ``end`` (0 where none does)."""
    d0 = np.array([np.cos(start_heading), np.sin(start_heading)])
    d1 = np.array([np.cos(end_heading), np.sin(end_heading)])
    lo = max([float((sh[0] - start) @ d0) for sh, e in zip(shapes, enters, strict=True) if e and len(sh) > 1],
             default=0.0)
    hi = max([float((end - sh[-1]) @ d1) for sh, f in zip(shapes, leaves, strict=True) if f and len(sh) > 1],
             default=0.0)
    return max(lo, 0.0), max(hi, 0.0)


def cut(shape: np.ndarray, point: np.ndarray, heading: float) -> tuple[np.ndarray | None, np.ndarray]:
    """Split a polyline (K, 2) where it first crosses the normal through ``point`` (2,) of
    ``heading`` [rad] from behind to ahead: (the piece behind, ending at the crossing, or None when
    shorter than :data:`CUT_EPS_M`; the rest, starting at the crossing)."""
    d = np.array([np.cos(heading), np.sin(heading)])
    along = (shape - point) @ d  # (K,) [m] ahead of the line
    if len(shape) < 2 or along[0] >= -CUT_EPS_M:
        return None, shape
    ahead = np.flatnonzero(along > 0)
    if len(ahead) == 0:  # wholly behind: nothing of the lane is on the road
        return shape, shape[-1:]
    j = int(ahead[0])
    u = along[j - 1] / (along[j - 1] - along[j])
    at = shape[j - 1] + u * (shape[j] - shape[j - 1])
    before = np.vstack([shape[:j], at])
    rest = np.vstack([at, shape[j:]]) if np.hypot(*(shape[j] - at)) > 1e-9 else shape[j:]
    return before, rest


def cut_both(shape: np.ndarray, start: np.ndarray, start_heading: float, end: np.ndarray, end_heading: float
             ) -> tuple[np.ndarray | None, np.ndarray, np.ndarray | None]:
    """A lane shape (K, 2) cut at a road's start and end lines (:func:`cut`): (head, on the road,
    tail); head and tail None where the lane does not reach past that line."""
    head, rest = cut(shape, start, start_heading)
    tail_rev, mid_rev = cut(rest[::-1], end, end_heading + np.pi)
    return head, mid_rev[::-1], (None if tail_rev is None else tail_rev[::-1])


def length(shape: np.ndarray | None) -> float:
    """[m] length of a polyline (0 for None or a point)."""
    if shape is None or len(shape) < 2:
        return 0.0
    return float(np.hypot(*np.diff(shape, axis=0).T).sum())


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.hypot(*v))
    return v / n if n > 0 else np.array([1.0, 0.0])
