"""The drivable area of a road map, and off-road checks of vehicle footprints.

The area is the union of every vehicle lane's centreline buffered by half its width (flat caps,
mitred joins) and of every junction polygon. WOMD maps have no junction polygons; their
junction-interior lanes cover the junction instead. Bike lanes count as drivable (WOMD puts them
beside the road, and vehicles legitimately cross them when turning).

A footprint is **off-road** when more than ``tolerance_m2`` of its area lies outside the drivable
area (default 0.5 m^2, about a 10 cm strip along a car's side): buffered polylines leave slivers at
sharp bends and lane ends that should not count as leaving the road.

Built once per map (shapely, prepared), then queried vectorised for many boxes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from coster_sumo.scene import RoadMap

OFF_ROAD_TOLERANCE_M2 = 0.5  # [m^2] footprint area allowed outside the drivable area


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
            boxes = shapely.polygons(flat[todo])
            out[todo] = shapely.area(boxes) - shapely.area(shapely.intersection(boxes, self.geometry))
        return out.reshape(shape)

    def off_road(self, cx: np.ndarray, cy: np.ndarray, yaw: np.ndarray, length: np.ndarray,
                 width: np.ndarray) -> np.ndarray:
        """bool (...): footprint has more than ``tolerance_m2`` outside the drivable area."""
        return self.outside_area(cx, cy, yaw, length, width) > self.tolerance_m2
