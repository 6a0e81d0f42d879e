from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from coster_sumo.core.scene import ObjectType, SignalState
from coster_sumo.data import synthetic
from coster_sumo.prior import regions as rg


@pytest.fixture(scope="module")
def road():
    return synthetic.two_lane_road()  # two 200 m lanes along +x


@pytest.fixture(scope="module")
def junction():
    return synthetic.four_way_junction()


def test_region_count_and_geometry_on_straight_lanes(road):
    regions = rg.build_regions(road.road_map)
    assert len(regions) == 2 * 40  # 200 m / 5 m per lane
    np.testing.assert_allclose(regions.height, 5.0)
    np.testing.assert_allclose(regions.heading, 0.0, atol=1e-12)
    assert np.all(np.isin(regions.lane_index, [0, 1]))
    first = regions.select(regions.lane_index == 0)
    np.testing.assert_allclose(first.q1[0], road.road_map.lanes.centerline[0][0])
    np.testing.assert_allclose(first.q2[-1], road.road_map.lanes.centerline[0][-1])
    np.testing.assert_allclose(first.q2[:-1], first.q1[1:])  # contiguous along the lane


def test_uneven_lane_lengths_are_covered_evenly():
    scene = synthetic.merge()  # lanes 125 m, 125 m and the 84.85 m ramp
    regions = rg.build_regions(scene.road_map)
    ramp = regions.select(regions.lane_index == 2)
    assert len(ramp) == round(60 * np.sqrt(2) / 5)
    np.testing.assert_allclose(ramp.height, 60 * np.sqrt(2) / len(ramp), rtol=1e-6)
    np.testing.assert_allclose(ramp.heading, np.pi / 4, atol=1e-9)


def test_region_frame_axes():
    scene = synthetic.merge()
    regions = rg.build_regions(scene.road_map)
    ramp = regions.select(regions.lane_index == 2)  # heading 45 degrees
    i = np.arange(len(ramp))
    d = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4)])
    right = np.array([d[1], -d[0]])
    pts = ramp.q1 + 2.0 * d + 1.0 * right
    np.testing.assert_allclose(ramp.to_region_frame(pts, i), np.tile([1.0, 2.0], (len(ramp), 1)), atol=1e-9)
    norm = np.tile([0.2, -0.1], (len(ramp), 1))  # 1 m right, 0.4 * height along
    world = ramp.from_normalised(norm, i)
    back = ramp.to_region_frame(world, i)
    np.testing.assert_allclose(back[:, 0], 1.0, atol=1e-9)
    np.testing.assert_allclose(back[:, 1], 0.4 * ramp.height, atol=1e-9)


def test_each_vehicle_sits_in_one_region_with_consistent_frame(road):
    regions = rg.build_regions(road.road_map)
    occ = rg.assign_agents(regions, road.tracks)
    T = road.num_steps
    assert occ.agent.shape == (T, len(regions))
    counts = np.stack([(occ.agent == a).sum(axis=1) for a in range(road.tracks.num_agents)])
    assert np.all(counts == 1)  # every vehicle on its lane centreline at every step
    t, r = np.nonzero(occ.present)
    a = occ.agent[t, r]
    np.testing.assert_array_equal(regions.lane_index[r], [0 if a_ in (0, 1) else 1 for a_ in a])
    assert np.all(np.abs(occ.normalised_xy[t, r]) <= 0.5)
    np.testing.assert_allclose(occ.normalised_xy[t, r, 0], 0.0, atol=1e-9)  # on the centreline
    world = regions.from_normalised(occ.normalised_xy[t, r], r)
    np.testing.assert_allclose(world, road.tracks.xy[a, t], atol=1e-9)
    np.testing.assert_allclose(occ.velocity[t, r, 1], road.tracks.speed[a, t], atol=1e-9)  # along the lane
    np.testing.assert_allclose(occ.length[t, r], 4.5)
    assert np.all(occ.agent[~occ.present] == -1) and np.all(occ.speed[~occ.present] == 0)


def test_assignment_rejects_wrong_heading_type_and_invalid(road):
    regions = rg.build_regions(road.road_map)
    tr = road.tracks
    heading = tr.heading.copy()
    heading[0] += np.radians(60.0)  # disagrees with the lane by 60 degrees
    valid = tr.valid.copy()
    valid[1, :10] = False
    otype = tr.object_type.copy()
    otype[2] = ObjectType.PEDESTRIAN
    occ = rg.assign_agents(regions, dataclasses.replace(tr, heading=heading, valid=valid, object_type=otype))
    assert not np.any(occ.agent == 0) and not np.any(occ.agent == 2)
    assert not np.any(occ.agent[:10] == 1) and np.all(np.any(occ.agent[10:] == 1, axis=1))


def test_one_agent_per_region_nearest_wins(road):
    regions = rg.build_regions(road.road_map)
    tr = road.tracks.select(agents=np.array([0, 0]), steps=np.array([0]))
    tr = dataclasses.replace(tr, ids=np.array(["a", "b"]))
    r0 = int(rg.assign_agents(regions, tr.select(agents=np.array([0]))).agent.argmax())
    centre = regions.centre[r0]
    x = np.array([[centre[0] + 0.3], [centre[0] - 1.0]])
    occ = rg.assign_agents(regions, dataclasses.replace(tr, x=x, y=np.full((2, 1), centre[1])))
    assert occ.agent[0, r0] == 0 and not np.any(occ.agent == 1)


def test_neighbourhood_radius_order_and_padding(road):
    regions = rg.build_regions(road.road_map)
    centres = np.stack([road.tracks.xy[0, 0], road.tracks.xy[0, 0] + [500.0, 0.0]])
    idx, mask = rg.neighbourhood(regions, centres, radius=12.0, max_regions=100)
    assert mask[1].sum() == 0 and np.all(idx[1] == -1)
    d = np.hypot(*(regions.centre[idx[0, mask[0]]] - centres[0]).T)
    assert np.all(d <= 12.0) and np.all(np.diff(d) >= 0)
    inside = np.hypot(*(regions.centre - centres[0]).T) <= 12.0
    assert mask[0].sum() == inside.sum()
    idx2, mask2 = rg.neighbourhood(regions, centres, radius=100.0, max_regions=7)
    assert idx2.shape == (2, 7) and mask2[0].all()


def test_signal_categories_follow_lanes(junction):
    regions = rg.build_regions(junction.road_map)
    sig = rg.region_signals(regions, junction.signals, len(junction.road_map.lanes))
    assert sig.shape == (junction.num_steps, len(regions))
    controlled = np.isin(regions.lane_index, junction.signals.lane_index)
    assert np.all(sig[:, ~controlled] == 0)
    assert set(np.unique(sig[:, controlled])) == {1, 2, 3}
    assert rg.signal_category(np.array([SignalState.FLASHING_STOP, SignalState.ARROW_GO]))[1] == 3


def test_junction_interior_regions_and_all_vehicles_assigned(junction):
    regions = rg.build_regions(junction.road_map)
    assert regions.is_junction.any() and len(regions) > 100
    occ = rg.assign_agents(regions, junction.tracks)
    valid = junction.tracks.valid
    for a in range(junction.tracks.num_agents):
        assigned = np.any(occ.agent == a, axis=1)
        assert assigned[valid[a]].mean() > 0.95
        assert not assigned[~valid[a]].any()
