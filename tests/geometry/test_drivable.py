from __future__ import annotations

import numpy as np

from coster_sumo.data import synthetic
from coster_sumo.geometry.drivable import DrivableArea


def test_vehicles_of_synthetic_scenes_are_on_road(synthetic_scene):
    area = DrivableArea.from_road_map(synthetic_scene.road_map)
    t = synthetic_scene.tracks
    off = area.off_road(t.x[t.valid], t.y[t.valid], t.heading[t.valid], t.length[t.valid], t.width[t.valid])
    assert not off.any()


def test_box_beside_the_road_is_off_road():
    scene = synthetic.two_lane_road()
    area = DrivableArea.from_road_map(scene.road_map)
    x0, y0 = scene.road_map.lanes.centerline[0][10]
    # 10 m to the right of the right lane: fully off; 1.2 m: mostly on (within tolerance)
    off = area.off_road(np.array([x0, x0, x0]), np.array([y0 - 10.0, y0 - 1.2, y0 - 0.5]),
                        np.zeros(3), np.full(3, 4.5), np.full(3, 1.9))
    np.testing.assert_array_equal(off, [True, True, False])
    out = area.outside_area(x0, y0 - 10.0, 0.0, 4.5, 1.9)
    assert abs(float(out) - 4.5 * 1.9) < 1e-9


def test_junction_interior_is_drivable():
    scene = synthetic.four_way_junction()
    area = DrivableArea.from_road_map(scene.road_map)
    cx, cy = 8123.45, -3456.78
    assert not area.off_road(np.array([cx]), np.array([cy]), np.zeros(1), np.full(1, 4.5), np.full(1, 1.9))[0]


def test_area_outside_from_pieces_equals_the_whole_area(monkeypatch):
    import shapely

    import coster_sumo.geometry.drivable as drivable_mod

    for scene, min_pieces in ((synthetic.two_lane_road(), 1), (synthetic.four_way_junction(), 4)):
        monkeypatch.setattr(drivable_mod, "PIECE_VERTICES", 12)  # force a deep split
        area = DrivableArea.from_road_map(scene.road_map)
        rng = np.random.default_rng(0)
        xmin, ymin, xmax, ymax = area.geometry.bounds
        n = 400
        cx, cy = rng.uniform(xmin, xmax, n), rng.uniform(ymin, ymax, n)
        yaw, length, width = rng.uniform(-np.pi, np.pi, n), np.full(n, 4.8), np.full(n, 2.0)
        got = area.outside_area(cx, cy, yaw, length, width)
        _, pieces = area._index()
        assert len(pieces) >= min_pieces
        assert np.isclose(shapely.area(pieces).sum(), area.geometry.area)
        boxes = shapely.polygons(drivable_mod._corners(cx, cy, yaw, length, width))
        want = shapely.area(boxes) - shapely.area(shapely.intersection(boxes, area.geometry))
        assert np.allclose(got, want, atol=1e-6)
        assert (got > 1.0).any() and (got < 1e-9).any()


def test_narrow_gaps_between_lanes_are_road_wide_ones_are_not():
    """Lanes that do not quite reach each other leave a sliver that is road; a median is not."""
    scene = synthetic.two_lane_road()  # centrelines 3.7 m apart
    lanes = scene.road_map.lanes
    x0, y0 = lanes.centerline[0][10]
    mid = y0 + 1.85  # between the two lanes
    box = (np.array([x0]), np.array([mid]), np.zeros(1), np.full(1, 4.5), np.full(1, 1.9))
    for width, off in ((3.0, False), (1.5, True)):  # gaps of 0.7 m and of 2.2 m
        lanes.width[:] = width
        area = DrivableArea.from_road_map(scene.road_map)
        assert bool(area.off_road(*box)[0]) is off, width
        gap = area.outside_area(np.array([x0]), np.array([mid]), np.zeros(1), np.full(1, 4.5), np.full(1, 0.6))[0]
        assert bool(gap > 1.0) is off  # a 0.6 m strip across the gap: fully road once the gap is closed


def test_osm_network_whose_closed_area_self_intersects_still_answers():
    """The wheel's Braunschweig OSM network (not ours): the closing leaves a self-intersecting ring
    there, and every area query failed with a GEOS TopologyException before it was repaired."""
    import shapely

    from coster_sumo.formats.sumo_net import read_sumolib_net, sumo_net_to_road_map
    from coster_sumo.infra import sumo_install

    net = sumo_install.sumo_home() / "tools" / "game" / "DRT" / "osm.net.xml"
    road_map, _ = sumo_net_to_road_map(read_sumolib_net(net))
    area = DrivableArea.from_road_map(road_map)
    assert shapely.is_valid(area.geometry)
    lane = road_map.lanes.centerline[0]
    x0, y0 = lane[len(lane) // 2]
    # a box far outside has a corner out, so it takes the piecewise path that used to raise
    out = area.outside_area(np.array([2181.5, x0]), np.array([-3.7 + 500.0, y0]), np.zeros(2),
                            np.full(2, 4.5), np.full(2, 1.9))
    assert out.shape == (2,) and np.isfinite(out).all() and (out >= 0).all()
    assert out[0] > 0  # the far box really went through the pieces


def test_any_off_road_answers_as_off_road_of_every_pose():
    """A path is off the road when any of its footprints is; any_off_road stops at the first."""
    scene = synthetic.four_way_junction()
    area = DrivableArea.from_road_map(scene.road_map)
    t = scene.tracks
    rng = np.random.default_rng(3)
    start = rng.integers(0, int(t.valid.sum()), 60)
    x = t.x[t.valid][start][:, None] + np.cumsum(rng.normal(0.0, 2.0, (60, 8)), axis=1)  # (paths, poses)
    y = t.y[t.valid][start][:, None] + np.cumsum(rng.normal(0.0, 2.0, (60, 8)), axis=1)
    yaw, length, width = rng.uniform(-np.pi, np.pi, (60, 8)), np.full((60, 8), 4.5), np.full((60, 8), 1.9)
    every = area.off_road(x, y, yaw, length, width).any(axis=-1)
    assert 0 < every.sum() < len(every)  # both kinds of path are there
    np.testing.assert_array_equal(area.any_off_road(x, y, yaw, length, width), every)
    # only the footprints ``where`` names count (the search forgives those before acting)
    where = rng.random((60, 8)) < 0.5
    counted = (area.off_road(x, y, yaw, length, width) & where).any(axis=-1)
    assert counted.sum() < every.sum()
    np.testing.assert_array_equal(area.any_off_road(x, y, yaw, length, width, where=where), counted)
