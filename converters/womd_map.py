"""The map part both WOMD readers share (:mod:`converters.womd` for ``Scenario`` protobufs,
:mod:`converters.scenarionet` for ScenarioNet pickles): raw lanes -> :class:`~coster_sumo.core.scene.Lanes`,
the checks of map geometry, polylines, and the feature types counted in ``scene.meta``.

Lane widths and junction flags are estimated here, the same way for both containers:

- lane width (WOMD has none), :func:`estimate_lane_widths`, first rule that applies:
  (1) the lane lists painted road-line boundaries present in the scene: the sum of the median
  distances from its centreline points (over each boundary's index range) to the left and to the
  right lines, twice the median where only one side has lines; (2) it has neighbour lanes: the
  median distance from its centreline to theirs (centre-to-centre = one lane width for equal
  widths), ignoring points closer than 2 m (WOMD lists merging and splitting lanes, which
  overlap, as neighbours); (3) it lists road-edge (kerb) boundaries: as (1) with the edges,
  which overestimates where there is a shoulder or parking; (4) 3.7 m. Clipped to [2.5, 5.5] m.
- ``is_junction`` (WOMD has no junction flag), :func:`junction_heuristic`: a lane is junction
  interior when either: (a) its centreline properly crosses the centreline of a lane that is not
  related to it (not itself, a predecessor, successor, neighbour, nor sharing a predecessor or
  successor with it) at about the same height (|dz| <= 3 m where heights are known, so overpasses
  do not count); (b) it is one of several branches at both ends: some predecessor has more than one
  successor and some successor has more than one predecessor. Plain merges, splits and approach
  lanes are not flagged. On the real samples (a) also flags 29 of the 34 signal-controlled lanes:
  WOMD attaches signal states to the lanes *inside* the intersection (stop point at their start),
  not to the approach lanes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from coster_sumo.core.scene import Lanes, Polylines, Ragged
from coster_sumo.errors import InputError
from coster_sumo.geometry.frames import MPH_TO_MPS

DEFAULT_LANE_WIDTH = 3.7  # [m]
LANE_WIDTH_RANGE = (2.5, 5.5)  # [m]
MIN_NEIGHBOUR_GAP = 2.0  # [m] closer neighbour points are overlapping (merging/splitting) lanes
FEATURE_TYPES = ("lane", "road_line", "road_edge", "stop_sign", "crosswalk", "speed_bump", "driveway")


@dataclass
class RawLane:
    """A lane as both WOMD readers see it (feature ids, not indices)."""

    fid: int
    polyline: np.ndarray  # (n, 2) [m]
    lane_type: int
    speed_limit_mph: float
    entry: list[int] = field(default_factory=list)
    exit: list[int] = field(default_factory=list)
    # (neighbour feature id, self_start, self_end, neighbour_start, neighbour_end)
    left: list[tuple[int, int, int, int, int]] = field(default_factory=list)
    right: list[tuple[int, int, int, int, int]] = field(default_factory=list)
    # (lane_start, lane_end, boundary feature id)
    left_bounds: list[tuple[int, int, int]] = field(default_factory=list)
    right_bounds: list[tuple[int, int, int]] = field(default_factory=list)
    z: np.ndarray | None = None  # (n,) [m] heights of the polyline points, where known


def point_polyline_distance(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """(n,) distance [m] from each of ``points`` (n, 2) to the polyline (m, 2), m >= 1."""
    points = np.asarray(points, np.float64).reshape(-1, 2)
    poly = np.asarray(polyline, np.float64).reshape(-1, 2)
    if len(points) == 0 or len(poly) == 0:
        return np.full(len(points), np.inf)
    origin = poly[0]
    p, q = points - origin, poly - origin  # large absolute coordinates: work relative
    if len(q) == 1:
        return np.hypot(*(p - q[0]).T)
    a, ab = q[:-1], np.diff(q, axis=0)
    denom = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12)
    rel = p[:, None, :] - a[None, :, :]
    t = np.clip(np.einsum("nmk,mk->nm", rel, ab) / denom, 0.0, 1.0)
    d = rel - t[..., None] * ab[None]
    return np.sqrt(np.min(np.einsum("nmk,nmk->nm", d, d), axis=1))


def _segment(poly: np.ndarray, start: int, end: int, max_points: int = 32) -> np.ndarray:
    """Points ``start..end`` of ``poly`` (clamped), thinned to at most ``max_points`` (for medians)."""
    n = len(poly)
    lo, hi = max(0, min(start, end)), min(n - 1, max(start, end))
    seg = poly[lo:hi + 1] if hi >= lo else poly
    if len(seg) > max_points:
        seg = seg[np.linspace(0, len(seg) - 1, max_points).round().astype(np.int64)]
    return seg


def _side_half_width(ln: RawLane, bounds: list[tuple[int, int, int]], polys: dict[int, np.ndarray]
                     ) -> float | None:
    dists = [point_polyline_distance(_segment(ln.polyline, s, e), polys[fid])
             for s, e, fid in bounds if fid in polys and len(polys[fid])]
    return float(np.median(np.concatenate(dists))) if dists else None


def estimate_lane_widths(lanes: Sequence[RawLane], road_lines: dict[int, np.ndarray],
                         road_edges: dict[int, np.ndarray]) -> np.ndarray:
    """(num_lanes,) estimated full lane width [m]; see the module docstring for the rule."""
    by_id = {ln.fid: ln for ln in lanes}
    out = np.full(len(lanes), DEFAULT_LANE_WIDTH)
    for i, ln in enumerate(lanes):
        if len(ln.polyline) == 0:
            continue
        width = _width_from_sides(ln, road_lines)  # painted lines: the best evidence
        if width is None:
            dists = [point_polyline_distance(_segment(ln.polyline, s0, s1), by_id[nid].polyline)
                     for nid, s0, s1, _, _ in (*ln.left, *ln.right)
                     if nid in by_id and len(by_id[nid].polyline)]
            all_d = np.concatenate(dists) if dists else np.zeros(0)
            apart = all_d[all_d >= MIN_NEIGHBOUR_GAP]
            if len(apart):
                width = float(np.median(apart))
        if width is None:  # kerbs may include a shoulder or parking: overestimates, clipped below
            width = _width_from_sides(ln, road_edges)
        if width is not None:
            out[i] = width
    return np.clip(out, *LANE_WIDTH_RANGE)


def _width_from_sides(ln: RawLane, polys: dict[int, np.ndarray]) -> float | None:
    sides = [h for h in (_side_half_width(ln, ln.left_bounds, polys),
                         _side_half_width(ln, ln.right_bounds, polys)) if h is not None]
    if not sides:
        return None
    return sides[0] + sides[1] if len(sides) == 2 else 2.0 * sides[0]


def _crossing_lanes(lanes: Sequence[RawLane], related: list[set[int]], max_dz: float = 3.0) -> np.ndarray:
    """(num_lanes,) bool: the centreline properly crosses an unrelated lane's at about the same height."""
    import shapely
    from shapely.strtree import STRtree

    geoms = [shapely.LineString(ln.polyline) if len(ln.polyline) >= 2 else shapely.LineString()
             for ln in lanes]
    out = np.zeros(len(lanes), bool)
    if not geoms:
        return out
    tree = STRtree(geoms)
    a_idx, b_idx = tree.query(geoms, predicate="crosses")
    for a, b in zip(a_idx.tolist(), b_idx.tolist(), strict=True):
        if a >= b or b in related[a] or (out[a] and out[b]):
            continue
        za, zb = lanes[a].z, lanes[b].z
        if za is not None and zb is not None and len(za) and len(zb):  # overpasses do not cross
            hit = shapely.get_coordinates(geoms[a].intersection(geoms[b]))[:1]
            if len(hit):
                ka = np.argmin(np.hypot(*(lanes[a].polyline - hit[0]).T))
                kb = np.argmin(np.hypot(*(lanes[b].polyline - hit[0]).T))
                if abs(float(za[ka]) - float(zb[kb])) > max_dz:
                    continue
        out[a] = out[b] = True
    return out


def junction_heuristic(lanes: Sequence[RawLane], predecessors: Ragged, successors: Ragged, left: Ragged,
                       right: Ragged) -> np.ndarray:
    """(num_lanes,) bool best-effort junction-interior flag; see the module docstring."""
    n = len(predecessors)
    n_pred, n_succ = predecessors.lengths(), successors.lengths()
    related: list[set[int]] = []
    for i in range(n):
        rel = {i, *predecessors[i].tolist(), *successors[i].tolist(), *left[i].tolist(), *right[i].tolist()}
        for p in predecessors[i]:
            rel.update(successors[p].tolist())
        for s in successors[i]:
            rel.update(predecessors[s].tolist())
        related.append(rel)
    out = _crossing_lanes(lanes, related)
    for i in range(n):
        fan_out = bool(np.any(n_succ[predecessors[i]] > 1))
        fan_in = bool(np.any(n_pred[successors[i]] > 1))
        out[i] |= fan_out and fan_in
    return out


def _first_bad_point(points: np.ndarray) -> int:
    """Index of the first point with a non-finite coordinate, or -1."""
    pts = np.asarray(points, np.float64)
    bad = ~np.isfinite(pts.reshape(len(pts), -1)).all(axis=1) if len(pts) else np.zeros(0, bool)
    return int(np.flatnonzero(bad)[0]) if bad.any() else -1


def check_raw_map(lanes: Sequence[RawLane], others: Sequence[tuple[str, int, np.ndarray]] = ()) -> None:
    """Refuse map geometry the net builder cannot use, naming the feature (both readers call it).

    Lanes: unique ids, at least one point (a single point is kept: real WOMD maps have them, and the
    net builder skips them), finite coordinates, heights and speed limit. ``others``: (kind, feature
    id, points) of road lines, edges, crosswalks, stop signs: finite coordinates.
    """
    seen: set[int] = set()
    for ln in lanes:
        where = f"lane {ln.fid}"
        if ln.fid in seen:
            raise InputError(f"{where}: duplicate lane id")
        seen.add(ln.fid)
        if len(ln.polyline) == 0:
            raise InputError(f"{where}: the polyline has no points")
        k = _first_bad_point(ln.polyline)
        if k >= 0:
            x, y = ln.polyline[k]
            raise InputError(f"{where}: polyline point {k} ({x}, {y}) is not finite")
        if ln.z is not None and len(ln.z) and not np.all(np.isfinite(ln.z)):
            k = int(np.flatnonzero(~np.isfinite(ln.z))[0])
            raise InputError(f"{where}: polyline point {k} has a non-finite height ({ln.z[k]})")
        if not np.isfinite(ln.speed_limit_mph):
            raise InputError(f"{where}: speed limit {ln.speed_limit_mph} is not finite")
    for kind, fid, pts in others:
        k = _first_bad_point(pts)
        if k >= 0:
            raise InputError(f"{kind} {fid}: point {k} ({pts[k][0]}, {pts[k][1]}) is not finite")


def build_lanes(lanes: Sequence[RawLane], road_lines: dict[int, np.ndarray], road_edges: dict[int, np.ndarray]
                ) -> tuple[Lanes, dict[int, int]]:
    """:class:`Lanes` from raw lanes, and the feature id -> lane index map.

    ``road_lines`` / ``road_edges``: boundary polylines by feature id (for the width estimate).
    """
    index = {ln.fid: i for i, ln in enumerate(lanes)}

    def rag(lists: list[list[int]]) -> Ragged:
        cleaned = []
        for ids in lists:
            seen: dict[int, None] = {}
            for fid in ids:
                if fid in index:
                    seen.setdefault(index[fid], None)
            cleaned.append(np.fromiter(seen, np.int64, len(seen)))
        return Ragged.from_list(cleaned, np.int64)

    pred = rag([ln.entry for ln in lanes])
    succ = rag([ln.exit for ln in lanes])
    left = rag([[nb[0] for nb in ln.left] for ln in lanes])
    right = rag([[nb[0] for nb in ln.right] for ln in lanes])
    result = Lanes(
        ids=np.asarray([str(ln.fid) for ln in lanes], dtype=str).reshape(-1),
        centerline=Ragged.from_list([ln.polyline for ln in lanes], np.float64, (2,)),
        width=estimate_lane_widths(lanes, road_lines, road_edges),
        lane_type=np.asarray([ln.lane_type for ln in lanes], np.int8).reshape(-1),
        speed_limit=np.asarray([ln.speed_limit_mph for ln in lanes], np.float64).reshape(-1) * MPH_TO_MPS,
        is_junction=junction_heuristic(lanes, pred, succ, left, right),
        predecessors=pred, successors=succ, left_neighbors=left, right_neighbors=right)
    return result, index


def polylines(items: Sequence[tuple[int, np.ndarray]]) -> Polylines:
    """:class:`Polylines` from (kind, (n, 2) points) pairs."""
    return Polylines(points=Ragged.from_list([p for _, p in items], np.float64, (2,)),
                     kind=np.asarray([k for k, _ in items], np.int8).reshape(-1))
