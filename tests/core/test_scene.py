from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from coster_sumo import InputError, load_scene, resample, save_scene
from coster_sumo.core.scene import Ragged
from coster_sumo.data import synthetic


def test_synthetic_scenes_validate(synthetic_scene):
    synthetic_scene.validate()
    assert synthetic_scene.num_steps == 91
    assert synthetic_scene.sdc_index == 0


def test_resample_to_2hz_keeps_every_fifth_step(synthetic_scene):
    low = resample(synthetic_scene, 2.0)
    assert low.num_steps == 19
    np.testing.assert_allclose(np.diff(low.timestamps), 0.5)
    assert low.current_time_index == 2  # step 10 at 10 Hz is step 2 at 2 Hz
    np.testing.assert_array_equal(low.tracks.x, synthetic_scene.tracks.x[:, ::5])
    low.validate()


def test_save_load_round_trip(tmp_path, synthetic_scene):
    path = save_scene(synthetic_scene, tmp_path / "s.npz")
    back = load_scene(path)
    assert back.scenario_id == synthetic_scene.scenario_id
    np.testing.assert_array_equal(back.tracks.x, synthetic_scene.tracks.x)
    np.testing.assert_array_equal(back.tracks.ids, synthetic_scene.tracks.ids)
    np.testing.assert_array_equal(back.road_map.lanes.centerline.values,
                                  synthetic_scene.road_map.lanes.centerline.values)
    np.testing.assert_array_equal(back.signals.state, synthetic_scene.signals.state)
    back.validate()


def test_load_scene_rejects_other_files(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(InputError, match="bad.npz"):
        load_scene(bad)


def test_validate_catches_shape_mismatch():
    scene = synthetic.two_lane_road()
    broken = dataclasses.replace(scene, timestamps=scene.timestamps[:-1])
    with pytest.raises(InputError, match="timestamps"):
        broken.validate()


def test_ragged_round_trip():
    items = [np.zeros((3, 2)), np.ones((0, 2)), np.full((2, 2), 5.0)]
    r = Ragged.from_list(items, np.float64, (2,))
    assert len(r) == 3
    assert [len(x) for x in r] == [3, 0, 2]
    np.testing.assert_array_equal(r.item_index(), [0, 0, 0, 2, 2])


def test_collision_snapshot_json_is_lossless(tmp_path):
    from coster_sumo.core.snapshot import AgentState, CollisionSnapshot

    snap = CollisionSnapshot(
        scenario_id="s", target_id="ego", t_index=7, time=3.5,
        target=AgentState(1.0 / 3.0, -7785.123456789, 0.1, 9.87654321, 4.5, 1.9),
        adversary=AgentState(2.0, 3.0, -np.pi, 0.0, 4.1, 1.8), region_id=12, presence_prob=0.25,
        position_logprob=-3.3, signed_distance=1e-9, entropy=(float("nan"), 1.5, 2.25),
        collision_time_method="entropy", init_method="snapshot", seed=3)
    back = CollisionSnapshot.load(snap.save(tmp_path / "snap.json"))
    assert back.target == snap.target and back.adversary == snap.adversary
    assert np.isnan(back.entropy[0]) and back.entropy[1:] == snap.entropy[1:]
    assert back.to_dict() == snap.to_dict()


def test_lane_type_at_takes_the_nearest_centreline_whatever_its_point_count():
    from coster_sumo.core.scene import Lanes, LaneType, RoadMap

    shapes = [np.array([[0.0, 0.0], [100.0, 0.0]]),  # a long straight lane of two points
              np.array([[50.0, 3.0]]),  # a degenerate one-point lane: never chosen
              np.array([[0.0, 20.0], [10.0, 20.0], [20.0, 21.0], [30.0, 23.0]])]
    n = len(shapes)
    empty = Ragged.from_list([np.zeros(0, np.int64)] * n, dtype=np.int64)
    lanes = Lanes(ids=np.array(["a", "b", "c"]), centerline=Ragged.from_list(shapes, inner_shape=(2,)),
                  width=np.full(n, 3.2), lane_type=np.array([LaneType.FREEWAY, LaneType.BIKE_LANE,
                                                             LaneType.SURFACE_STREET], np.int8),
                  speed_limit=np.zeros(n), is_junction=np.zeros(n, bool), predecessors=empty, successors=empty,
                  left_neighbors=empty, right_neighbors=empty)
    kinds = RoadMap(lanes=lanes).lane_type_at(np.array([[50.0, 2.9], [25.0, 18.0], [-5.0, 9.0]]))
    assert kinds.tolist() == [LaneType.FREEWAY, LaneType.SURFACE_STREET, LaneType.FREEWAY]
