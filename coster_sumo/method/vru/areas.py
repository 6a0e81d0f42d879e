"""Where a vulnerable road user may be: its class's area, and the off-area check of the metrics.

- **walkable** (pedestrian): the road surface (a pedestrian adversary crosses it, on a crossing or
  not), the crossings the map holds, and a band of :attr:`~coster_sumo.method.vru.classes.VruClass.area_band`
  beyond the road surface: the sidewalk or verge. The road maps leave sidewalk lanes out
  (:mod:`coster_sumo.formats.sumo_net`), so a net's sidewalks count through that band.
- **rideable** (cyclist): the road surface (bike lanes included) and a narrower band (the shoulder).

A trajectory is *off* its area when a centre point leaves it (:meth:`ClassArea.off_area`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.core.scene import RoadMap, Scene
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.method.vru.classes import VruClass


@dataclass(frozen=True)
class ClassArea:
    """The area one class may use, and the road surface it is built on.

    Attributes:
        cls: the class.
        geometry: the class's area (shapely, prepared).
        road: the road surface (the drivable area's geometry).
        crossings: the map's crossings (a shapely geometry, maybe empty).
    """

    cls: VruClass
    geometry: BaseGeometry
    road: BaseGeometry
    crossings: BaseGeometry

    @classmethod
    def build(cls, vru: VruClass, road_map: RoadMap, drivable: DrivableArea) -> ClassArea:
        road = drivable.geometry
        polys = [shapely.polygons(p) for p in road_map.crosswalks.points if len(p) >= 3]
        crossings = shapely.make_valid(shapely.union_all(polys)) if polys else shapely.Polygon()
        parts = [shapely.buffer(road, vru.area_band)] if not road.is_empty else []
        if vru.name == "pedestrian" and not crossings.is_empty:
            parts.append(crossings)
        geom = shapely.union_all(parts) if parts else shapely.Polygon()
        shapely.prepare(geom)
        return cls(vru, geom, road, crossings)

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """(...) bool: points (..., 2) [m] inside the class's area."""
        xy = np.asarray(xy, np.float64)
        flat = xy.reshape(-1, 2)
        inside = shapely.contains_xy(self.geometry, flat[:, 0], flat[:, 1])
        return np.asarray(inside, bool).reshape(xy.shape[:-1])

    def off_area(self, xy: np.ndarray) -> np.ndarray:
        """(N,) bool: trajectories (N, T, 2) [m] with a centre point outside the class's area."""
        return np.asarray(~self.contains(xy).all(axis=-1), bool)

    def edge_distance(self, xy: np.ndarray) -> np.ndarray:
        """(N,) [m] distance of points (N, 2) to the road surface's boundary (0 on a crossing)."""
        pts = shapely.points(np.asarray(xy, np.float64))
        d = np.asarray(shapely.distance(self.road.boundary, pts), np.float64) if not self.road.is_empty \
            else np.full(len(pts), np.inf)
        if not self.crossings.is_empty:
            d = np.where(shapely.contains(self.crossings, pts), 0.0, d)
        return d

    def on_road(self, xy: np.ndarray) -> np.ndarray:
        """(N,) bool: points (N, 2) [m] on the road surface."""
        xy = np.asarray(xy, np.float64)
        return np.asarray(shapely.contains_xy(self.road, xy[:, 0], xy[:, 1]), bool)


CHECK_STEP_S = 0.1  # [s] a plan's centre is checked at SUMO's step
_AREAS: dict[int, tuple[RoadMap, dict[str, ClassArea]]] = {}  # by id of the road map (kept alive here)


def area_of(vclass: str, road_map: RoadMap) -> ClassArea:
    """The class area of SUMO class ``vclass`` on ``road_map``, built once per road map and class."""
    from coster_sumo.method.vru.classes import VRU_CLASSES, class_of_vclass

    held = _AREAS.get(id(road_map))
    if held is None or held[0] is not road_map:
        if len(_AREAS) > 8:
            _AREAS.clear()
        held = _AREAS[id(road_map)] = (road_map, {})
    name = class_of_vclass(vclass)
    if name not in held[1]:
        held[1][name] = ClassArea.build(VRU_CLASSES[name], road_map, DrivableArea.from_road_map(road_map))
    return held[1][name]


def off_class_area(plan: AdversaryPlan, scene: Scene) -> bool:
    """Whether a pedestrian or cyclist plan's centre leaves its class's area from its start to t_col
    (the off-walkable / off-rideable flag of the metrics), checked every :data:`CHECK_STEP_S`."""
    t = np.arange(plan.t_start, plan.t_col + 1e-9, CHECK_STEP_S)
    x, y, _, _ = plan.sample(t)
    return bool(area_of(plan.vclass, scene.road_map).off_area(np.stack([x, y], -1)[None])[0])
