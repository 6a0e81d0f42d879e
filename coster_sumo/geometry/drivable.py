"""The drivable area of a road map, and off-road checks of vehicle footprints.

The area is the union of every vehicle lane's centreline buffered by half its width (flat caps,
mitred joins) and of every junction polygon. WOMD maps have no junction polygons; their
junction-interior lanes cover the junction instead. Bike lanes count as drivable (WOMD puts them
beside the road, and vehicles legitimately cross them when turning).

Gaps narrower than ``GAP_CLOSED_M`` between the pieces are closed (a morphological closing: grow
by half of it, shrink back). Neighbouring lanes whose widths do not quite reach each other (lane
width smaller than the spacing of their centrelines, lanes that fan out after a junction) leave
slivers between the strips; a car changing lanes across one is not leaving the road. On the
held-out fkk_in network a 0.5-0.9 m wide wedge between two lanes of one road flagged every
adversary that crossed it. Wider gaps (medians, islands, verges) stay outside.

A footprint is **off-road** when more than ``tolerance_m2`` of its area lies outside the drivable
area (default 0.5 m^2, about a 10 cm strip along a car's side): buffered polylines leave slivers at
sharp bends and lane ends that should not count as leaving the road.

Built once per map (shapely, prepared), then queried vectorised for many boxes. The area outside
is computed against pieces of the area (a quadtree split to at most ``PIECE_VERTICES`` vertices,
in an STRtree), so one box costs the same on a junction and on a 2,000-lane OSM network.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from coster_sumo.core.scene import RoadMap

OFF_ROAD_TOLERANCE_M2 = 0.5  # [m^2] footprint area allowed outside the drivable area
GAP_CLOSED_M = 1.0  # [m] narrower gaps between lane strips and junctions count as road
PIECE_VERTICES = 256  # the area is split until every piece has at most this many vertices


_UNIT_CORNERS = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])  # FL, RL, RR, FR


def _corners(cx: np.ndarray, cy: np.ndarray, yaw: np.ndarray, length: np.ndarray, width: np.ndarray
             ) -> np.ndarray:
    """(..., 4, 2) corners of oriented boxes (front-left, rear-left, rear-right, front-right)."""
    yaw = np.asarray(yaw, float)
    c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
    lon = _UNIT_CORNERS[:, 0] * (0.5 * np.asarray(length, float))[..., None]  # (..., 4)
    lat = _UNIT_CORNERS[:, 1] * (0.5 * np.asarray(width, float))[..., None]
    out = np.empty(np.broadcast_shapes(lon.shape, c.shape) + (2,))
    out[..., 0] = np.asarray(cx, float)[..., None] + lon * c - lat * s
    out[..., 1] = np.asarray(cy, float)[..., None] + lon * s + lat * c
    return out


@dataclass
class DrivableArea:
    """Prepared union of lanes and junctions; ``geometry`` is a shapely (Multi)Polygon."""

    geometry: BaseGeometry
    tolerance_m2: float = OFF_ROAD_TOLERANCE_M2
    _tree: shapely.STRtree | None = field(default=None, init=False, repr=False, compare=False)
    _pieces: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)

    @classmethod
    def from_road_map(cls, road_map: RoadMap, tolerance_m2: float = OFF_ROAD_TOLERANCE_M2,
                      bbox: tuple[float, float, float, float] | None = None) -> DrivableArea:
        """Build from a road map; ``bbox`` (xmin, ymin, xmax, ymax) limits it to lanes touching it."""
        lanes = road_map.lanes
        parts: list[BaseGeometry] = []
        lines = []
        widths = []
        for i, pts in enumerate(lanes.centerline):
            if len(pts) < 2:
                continue
            if bbox is not None and (pts[:, 0].max() < bbox[0] or pts[:, 0].min() > bbox[2]
                                     or pts[:, 1].max() < bbox[1] or pts[:, 1].min() > bbox[3]):
                continue
            lines.append(shapely.linestrings(pts))
            widths.append(max(float(lanes.width[i]), 1.0))
        if lines:
            # cap_style flat (2), join_style mitre (2) would over-extend at sharp corners; round joins
            # cost little and keep curves covered.
            parts.extend(shapely.buffer(np.asarray(lines, dtype=object), 0.5 * np.asarray(widths),
                                        cap_style="flat", join_style="round"))
        for poly in road_map.junctions.points:
            if len(poly) >= 3:
                parts.append(shapely.make_valid(shapely.polygons(poly)))
        geom = shapely.union_all(parts) if parts else shapely.Polygon()
        if not geom.is_empty:
            geom = _valid_area(shapely.buffer(shapely.buffer(geom, 0.5 * GAP_CLOSED_M), -0.5 * GAP_CLOSED_M))
        shapely.prepare(geom)
        return cls(geometry=geom, tolerance_m2=tolerance_m2)

    def outside_area(self, cx: np.ndarray, cy: np.ndarray, yaw: np.ndarray, length: np.ndarray,
                     width: np.ndarray) -> np.ndarray:
        """Area [m^2] of each footprint outside the drivable area; inputs broadcast to (...)."""
        corners = _corners(np.asarray(cx, float), np.asarray(cy, float), np.asarray(yaw, float),
                           np.asarray(length, float), np.asarray(width, float))
        shape = corners.shape[:-2]
        flat = corners.reshape(-1, 4, 2)
        # fast path: all four corners inside (prepared point-in-polygon) -> treated as fully inside;
        # the area is computed only for boxes with a corner out
        corner_in = shapely.contains_xy(self.geometry, flat[..., 0], flat[..., 1]).all(axis=-1)
        out = np.zeros(len(flat))
        todo = ~corner_in
        if todo.any():
            out[todo] = self._area_outside(flat[todo])
        return out.reshape(shape)

    def _area_outside(self, corners: np.ndarray) -> np.ndarray:
        """(N,) [m^2] of the boxes with corners (N, 4, 2) outside the area (the exact intersection)."""
        boxes = shapely.polygons(corners)
        tree, pieces = self._index()
        bi, pi = tree.query(boxes, predicate="intersects")
        inside = np.bincount(bi, weights=shapely.area(shapely.intersection(boxes[bi], pieces[pi])),
                             minlength=len(boxes))
        return np.maximum(shapely.area(boxes) - inside, 0.0)  # type: ignore[no-any-return]

    def any_off_road(self, cx: np.ndarray, cy: np.ndarray, yaw: np.ndarray, length: np.ndarray,
                     width: np.ndarray, where: np.ndarray | None = None) -> np.ndarray:
        """bool (...): :meth:`off_road` of any footprint along the inputs' last axis (a path's poses).

        The same answer as ``off_road(...).any(-1)``, box for box the same areas, but a path's
        areas are computed only up to its first footprint off the road: oversampled paths that leave
        the road leave it at several poses, and the exact areas are most of the check's cost.
        ``where`` (bool, broadcast to the poses): only these footprints count (the others are
        never tested): ``(off_road(...) & where).any(-1)``.
        """
        corners = _corners(np.asarray(cx, float), np.asarray(cy, float), np.asarray(yaw, float),
                           np.asarray(length, float), np.asarray(width, float))  # (..., T, 4, 2)
        lead, steps = corners.shape[:-3], corners.shape[-3]
        flat = corners.reshape(-1, steps, 4, 2)
        todo = ~shapely.contains_xy(self.geometry, flat[..., 0], flat[..., 1]).all(axis=-1)  # (P, T)
        if where is not None:
            todo &= np.broadcast_to(where, (*lead, steps)).reshape(-1, steps)
        off = np.zeros(len(flat), bool)
        pending = todo.any(axis=1)
        while pending.any():  # each round: every undecided path's next footprint with a corner out
            rows = np.flatnonzero(pending)
            cols = np.argmax(todo[rows], axis=1)
            off[rows] = self._area_outside(flat[rows, cols]) > self.tolerance_m2
            todo[rows, cols] = False
            pending = todo.any(axis=1) & ~off
        return off.reshape(lead)

    def _index(self) -> tuple[shapely.STRtree, np.ndarray]:
        """The area split into small disjoint pieces and their STRtree (built on first use)."""
        if self._tree is None or self._pieces is None:
            self._pieces = np.asarray(_subdivide(self.geometry, PIECE_VERTICES), dtype=object)
            self._tree = shapely.STRtree(self._pieces)
        return self._tree, self._pieces

    def off_road(self, cx: np.ndarray, cy: np.ndarray, yaw: np.ndarray, length: np.ndarray,
                 width: np.ndarray) -> np.ndarray:
        """bool (...): footprint has more than ``tolerance_m2`` outside the drivable area."""
        return self.outside_area(cx, cy, yaw, length, width) > self.tolerance_m2


def _valid_area(geom: BaseGeometry) -> BaseGeometry:
    """``geom`` repaired where GEOS finds it invalid, its polygonal parts only.

    The inward buffer of the closing can leave a self-intersecting ring on large OSM networks (the
    wheel's Braunschweig DRT network does, near (2181, -3.7)); set operations on it then fail with
    a TopologyException. There the repair changed the area by 0.0002 m^2 (of 295,230 m^2) and moved
    no boundary point by more than 1e-13 m.
    """
    if shapely.is_valid(geom):
        return geom
    fixed = shapely.make_valid(geom)
    polys = [q for q in shapely.get_parts(fixed) if q.geom_type in ("Polygon", "MultiPolygon")]
    return shapely.union_all(polys) if polys else shapely.Polygon()


def _subdivide(geom: BaseGeometry, max_vertices: int, min_size_m: float = 1.0) -> list[BaseGeometry]:
    """Split ``geom`` into disjoint polygonal pieces of at most ``max_vertices`` vertices.

    Halves the bounding box along its longer side until a piece is small enough (or narrower than
    ``min_size_m``); the pieces cover ``geom`` exactly, so areas add up.
    """
    out: list[BaseGeometry] = []
    stack = [geom]
    while stack:
        g = stack.pop()
        if g.is_empty:
            continue
        xmin, ymin, xmax, ymax = g.bounds
        if shapely.get_num_coordinates(g) <= max_vertices or max(xmax - xmin, ymax - ymin) < min_size_m:
            out.append(g)
            continue
        if xmax - xmin >= ymax - ymin:
            mid = 0.5 * (xmin + xmax)
            halves = [shapely.box(xmin, ymin, mid, ymax), shapely.box(mid, ymin, xmax, ymax)]
        else:
            mid = 0.5 * (ymin + ymax)
            halves = [shapely.box(xmin, ymin, xmax, mid), shapely.box(xmin, mid, xmax, ymax)]
        for h in halves:
            part = shapely.intersection(g, h)
            if part.geom_type in ("Polygon", "MultiPolygon"):
                stack.append(part)
            elif part.geom_type == "GeometryCollection":  # a cut along an edge leaves lines or points
                polys = [q for q in shapely.get_parts(part) if q.geom_type in ("Polygon", "MultiPolygon")]
                if polys:
                    stack.append(shapely.union_all(polys))
    return out
