"""The real WOMD samples in ../shared/data/womd (skipped when absent): counts from its README."""

from __future__ import annotations

import time
from collections import Counter

import numpy as np
import pytest
from coster_sumo.converters.read import read_scenes

from coster_sumo.core.scene import ObjectType, Scene, SignalState
from tests.conftest import WOMD_PKL, WOMD_PROTO, requires_womd

pytestmark = [pytest.mark.realdata, requires_womd()]

V, P, C = int(ObjectType.VEHICLE), int(ObjectType.PEDESTRIAN), int(ObjectType.CYCLIST)

# README table of scenario_proto/
PROTO = {
    "motion_data_one_scenario.tfrecord": dict(
        scenario_id="637f20cafde22ff8", tracks=83, types={V: 70, P: 10, C: 3}, sdc=82,
        features={"lane": 199, "road_line": 59, "road_edge": 28, "stop_sign": 8, "crosswalk": 4,
                  "speed_bump": 3, "driveway": 0},
        lane_states=12),
    "womd_scenario_input.tfrecord": dict(
        scenario_id="ee519cf571686d19", tracks=257, types={V: 189, P: 68}, sdc=256,
        features={"lane": 114, "road_edge": 75, "road_line": 12, "speed_bump": 6, "stop_sign": 4,
                  "crosswalk": 4, "driveway": 0},
        lane_states=0),
}
PKL = {  # (steps, current_time_index, traffic-lit lanes)
    "sd_training.tfrecord-00000-of-01000_2a1e44d405a6833f.pkl": (91, 10, 8),
    "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl": (199, 0, 14),
}
_TIMES: dict[str, float] = {}


def _read_one(path) -> Scene:
    t0 = time.perf_counter()
    scenes = read_scenes(path)
    _TIMES[path.name] = time.perf_counter() - t0
    print(f"read {path.name}: {_TIMES[path.name] * 1000:.0f} ms")
    assert len(scenes) == 1
    return scenes[0]


def _check_common(scene: Scene) -> None:
    scene.validate()
    assert np.all(np.diff(scene.timestamps) > 0.05) and abs(scene.dt - 0.1) < 0.01
    valid = scene.tracks.valid
    assert valid[scene.sdc_index].sum() > 0
    lanes = scene.road_map.lanes
    assert np.all((lanes.width >= 2.5) & (lanes.width <= 5.5))
    assert 0 < lanes.is_junction.sum() < len(lanes)
    assert np.all(lanes.centerline.lengths() >= 1)  # some real lanes have a single point
    # large absolute coordinates are kept, not normalised
    assert np.abs(scene.tracks.x[valid]).max() > 1000.0


@pytest.mark.parametrize("path", WOMD_PROTO, ids=lambda p: p.name)
def test_scenario_protos_match_readme(path):
    want = PROTO[path.name]
    scene = _read_one(path)
    _check_common(scene)
    assert scene.source == "womd" and scene.scenario_id == want["scenario_id"]
    assert scene.num_steps == 91 and scene.current_time_index == 10
    assert scene.tracks.num_agents == want["tracks"] and scene.sdc_index == want["sdc"]
    assert dict(Counter(scene.tracks.object_type.tolist())) == want["types"]
    assert scene.tracks.object_type[scene.sdc_index] == V
    assert scene.meta["map_feature_counts"] == want["features"]
    assert sum(scene.meta["map_feature_counts"].values()) == sum(want["features"].values())
    assert scene.meta["lane_states_per_step"] == [want["lane_states"]] * 91
    rm = scene.road_map
    assert len(rm.lanes) == want["features"]["lane"]
    assert len(rm.road_lines) == want["features"]["road_line"]
    assert len(rm.road_edges) == want["features"]["road_edge"]
    assert len(rm.crosswalks) == want["features"]["crosswalk"]
    assert len(rm.stop_sign_xy) == want["features"]["stop_sign"]
    assert len(scene.signals.lane_index) == want["lane_states"]
    # invalid states are mostly zero-filled (motion_data_one_scenario has 80 that are not): the
    # reader keeps them as they are, callers mask with valid
    inval = ~scene.tracks.valid
    assert np.mean(scene.tracks.x[inval] == 0.0) > 0.9
    assert scene.road_map.lanes.speed_limit.max() > 0.0


def test_motion_data_signals_and_topology():
    path = next((p for p in WOMD_PROTO if p.name == "motion_data_one_scenario.tfrecord"), None)
    if path is None:
        pytest.skip("motion_data_one_scenario.tfrecord not present")
    scene = read_scenes(path)[0]
    sig = scene.signals
    assert sig.state.shape == (91, 12)
    assert {int(SignalState.STOP), int(SignalState.ARROW_STOP)} <= set(np.unique(sig.state).tolist())
    lanes = scene.road_map.lanes
    # stop points lie at the start of the controlled (junction-interior) lanes
    starts = np.stack([lanes.centerline[i][0] for i in sig.lane_index])
    assert np.hypot(*(starts - sig.stop_point).T).max() < 0.5
    assert lanes.successors.values.size > 0 and lanes.left_neighbors.values.size > 0
    # predecessor/successor symmetric where both lanes are present
    for i in range(len(lanes)):
        for j in lanes.successors[i]:
            assert i in lanes.predecessors[j]


@pytest.mark.parametrize("path", WOMD_PKL, ids=lambda p: p.name)
def test_scenarionet_pickles(path):
    steps, cti, lit = PKL[path.name]
    scene = _read_one(path)
    _check_common(scene)
    assert scene.source == "scenarionet"
    assert scene.num_steps == steps and scene.current_time_index == cti
    assert len(scene.signals.lane_index) == lit
    assert scene.scenario_id in path.name
    counts = scene.meta["map_feature_counts"]
    assert counts["lane"] == len(scene.road_map.lanes) > 0
    assert all(isinstance(i, str) for i in scene.tracks.ids.tolist())
    if "v1.2" in path.name:
        assert set(np.unique(scene.road_map.lanes.lane_type).tolist()) == {1, 2}  # freeway + surface
