"""Adversary sizes of real vehicle classes; no standstill in moving traffic."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from coster_sumo.data import synthetic
from coster_sumo.method.plausible import (
    CONGESTED_SPEED_MPS,
    VEHICLE_CLASSES,
    local_speed,
    moving_speed_class,
    stop_plausible,
    vehicle_size,
)


@pytest.mark.parametrize(("sample", "cls"), [((2.125, 2.05), "passenger"), ((2.2, 0.9), "motorcycle"),
                                             ((1.7, 0.6), "bicycle"), ((4.4, 1.8), "passenger"),
                                             ((10.0, 2.5), "truck"), ((15.0, 2.6), "bus"), ((6.0, 2.1), "delivery")])
def test_sizes_move_to_the_nearest_corpus_class(sample, cls):
    length, width, name = vehicle_size(*sample)
    assert name == cls
    (l0, l1), (w0, w1) = VEHICLE_CLASSES[cls]
    assert l0 <= length <= l1 and w0 <= width <= w1
    if l0 <= sample[0] <= l1 and w0 <= sample[1] <= w1:
        assert (length, width) == sample  # a size that already fits is kept


def test_the_demo_cube_becomes_a_small_car():
    assert vehicle_size(2.125, 2.05) == (3.7, 1.95, "passenger")


def _scene_at_speed(speed: float):
    scene = synthetic.two_lane_road()
    tr = scene.tracks
    yaw = tr.heading
    tracks = dataclasses.replace(tr, vx=speed * np.cos(yaw), vy=speed * np.sin(yaw))
    return dataclasses.replace(scene, tracks=tracks)


def test_standstill_only_where_traffic_stands_or_queues():
    moving, jammed = _scene_at_speed(20.0), _scene_at_speed(1.0)
    target = 0
    assert local_speed(moving, 0, target) == pytest.approx(20.0)
    lane = 0  # 200 m long, no successor: its last 30 m are a lane end
    far = moving.road_map.lanes.centerline[lane][0] + np.array([20.0, 0.0])
    end = moving.road_map.lanes.centerline[lane][-1] - np.array([10.0, 0.0])
    mid = lane
    assert stop_plausible(moving, 0, target, lane, end)  # vehicles wait where the lane ends
    assert not stop_plausible(moving, 0, target, mid, far)
    assert local_speed(jammed, 0, target) < CONGESTED_SPEED_MPS
    assert stop_plausible(jammed, 0, target, mid, far)


def test_moving_speed_never_draws_the_stopped_class_nor_outruns_the_traffic():
    rng = np.random.default_rng(0)
    probs = np.array([0.7, 0.05, 0.05, 0.2])
    centres = np.array([0.0, 3.0, 10.0, 30.0])
    draws = {moving_speed_class(probs, centres, 0, rng, fastest=12.0) for _ in range(200)}
    assert draws == {1, 2}  # not 0 (stopped), not 30 m/s (> 1.1 x the fastest vehicle around)
    assert moving_speed_class(np.array([1.0, 0.0, 0.0, 0.0]), centres, 0, rng, fastest=12.0) == 2


def test_a_cyclist_target_gets_a_snapshot():
    """The prior's regions follow the target's own pose, whatever its object type (fkk_in's target is a bicycle)."""
    from coster_sumo.core.scene import ObjectType, resample
    from coster_sumo.method.snapshot import SNAPSHOT_INITS, PlacementRequest

    scene = synthetic.two_lane_road()
    kinds = scene.tracks.object_type.copy()
    kinds[0] = ObjectType.CYCLIST
    cyclist = dataclasses.replace(scene, tracks=dataclasses.replace(scene.tracks, object_type=kinds))
    snaps = [SNAPSHOT_INITS["snapshot"].place(PlacementRequest(resample(s, 2.0), 0, np.random.default_rng(0), None,
                                                               "entropy")) for s in (scene, cyclist)]
    assert all(np.isfinite(s.entropy[s.t_index]) for s in snaps)


def _unsignalised_junction(lane_type):
    from coster_sumo.core.scene import SignalStates

    scene = synthetic.four_way_junction()
    lanes = dataclasses.replace(scene.road_map.lanes,
                                lane_type=np.full(len(scene.road_map.lanes), lane_type, np.int8))
    none = SignalStates(lane_index=np.zeros(0, np.int64), state=np.zeros((scene.num_steps, 0), np.int8),
                        stop_point=np.zeros((0, 2)))
    return dataclasses.replace(scene, road_map=dataclasses.replace(scene.road_map, lanes=lanes), signals=none)


def test_standstill_where_a_street_lane_enters_a_junction_not_on_a_freeway():
    """Vehicles yield at priority junctions and roundabout entries with no signal: a standstill is
    plausible near the end of a street lane that enters a junction, and inside the junction; not
    far from it, and not on a freeway lane whatever it enters."""
    from coster_sumo.core.scene import LaneType

    street, freeway = _unsignalised_junction(LaneType.SURFACE_STREET), _unsignalised_junction(LaneType.FREEWAY)
    target = 0
    assert local_speed(street, 0, target) >= CONGESTED_SPEED_MPS
    lanes = street.road_map.lanes
    west_in = 4  # the incoming lane of the west arm (synthetic.four_way_junction builds in, out per arm)
    assert not lanes.is_junction[west_in] and lanes.is_junction[np.asarray(lanes.successors[west_in])].all()
    near_end = lanes.centerline[west_in][-1] - np.array([10.0, 0.0])
    far = lanes.centerline[west_in][-1] - np.array([60.0, 0.0])
    inside = int(np.asarray(lanes.successors[west_in])[0])
    mid_junction = lanes.centerline[inside][len(lanes.centerline[inside]) // 2]
    assert stop_plausible(street, 0, target, west_in, near_end)
    assert stop_plausible(street, 0, target, inside, mid_junction)
    assert not stop_plausible(street, 0, target, west_in, far)
    assert not stop_plausible(freeway, 0, target, west_in, near_end)
    assert not stop_plausible(freeway, 0, target, inside, mid_junction)
