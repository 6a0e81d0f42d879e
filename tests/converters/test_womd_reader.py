"""WOMD Scenario <-> Scene on synthetic scenes written as TFRecords; dispatch; errors."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest
from coster_sumo.converters.read import iter_scenes, read_scenes, sniff
from coster_sumo.converters.tfrecord import write_tfrecord
from coster_sumo.converters.womd import (
    point_polyline_distance,
    scenario_to_scene,
    scene_to_scenario,
)
from coster_sumo.converters.womd_schema import Scenario

from coster_sumo import save_scene
from coster_sumo.core.scene import Scene, SignalState
from coster_sumo.data import synthetic
from coster_sumo.errors import InputError


def _numeric_ids(scene: Scene) -> Scene:
    """WOMD track ids are int32: give the synthetic agents decimal ids."""
    ids = np.asarray([str(1000 + i) for i in range(scene.tracks.num_agents)])
    return dataclasses.replace(scene, tracks=dataclasses.replace(scene.tracks, ids=ids))


def _assert_same(back: Scene, ref: Scene) -> None:
    assert back.scenario_id == ref.scenario_id and back.source == "womd"
    assert (back.sdc_index, back.current_time_index) == (ref.sdc_index, ref.current_time_index)
    np.testing.assert_array_equal(back.timestamps, ref.timestamps)
    a, b = back.tracks, ref.tracks
    np.testing.assert_array_equal(a.ids, b.ids)
    np.testing.assert_array_equal(a.object_type, b.object_type)
    np.testing.assert_array_equal(a.valid, b.valid)
    v = b.valid
    np.testing.assert_array_equal(a.x[v], b.x[v])  # doubles on the wire: exact
    np.testing.assert_array_equal(a.y[v], b.y[v])
    for f in ("heading", "vx", "vy", "length", "width"):  # float32 on the wire
        np.testing.assert_allclose(getattr(a, f)[v], getattr(b, f)[v], rtol=1e-6, atol=1e-5)
    assert np.all(a.x[~v] == 0.0)  # invalid states are zero-filled, as in WOMD
    la, lb = back.road_map.lanes, ref.road_map.lanes
    np.testing.assert_array_equal(la.ids, lb.ids)
    np.testing.assert_array_equal(la.centerline.values, lb.centerline.values)
    np.testing.assert_array_equal(la.centerline.offsets, lb.centerline.offsets)
    np.testing.assert_array_equal(la.lane_type, lb.lane_type)
    np.testing.assert_allclose(la.speed_limit, lb.speed_limit, rtol=1e-12)
    np.testing.assert_array_equal(la.is_junction, lb.is_junction)  # the heuristic recovers it here
    np.testing.assert_allclose(la.width, lb.width)  # neighbour distance or the 3.7 m default
    for f in ("predecessors", "successors", "left_neighbors", "right_neighbors"):
        np.testing.assert_array_equal(getattr(la, f).values, getattr(lb, f).values)
        np.testing.assert_array_equal(getattr(la, f).offsets, getattr(lb, f).offsets)
    ea, eb = back.road_map.road_edges, ref.road_map.road_edges
    np.testing.assert_array_equal(ea.points.values, eb.points.values)
    np.testing.assert_array_equal(ea.kind, eb.kind)
    sa, sb = back.signals, ref.signals
    np.testing.assert_array_equal(sa.lane_index, sb.lane_index)
    np.testing.assert_array_equal(sa.state, sb.state)
    np.testing.assert_array_equal(sa.stop_point, sb.stop_point)


def test_scenario_round_trip_in_memory(synthetic_scene):
    ref = _numeric_ids(synthetic_scene)
    back = scenario_to_scene(Scenario.FromString(scene_to_scenario(ref)), "mem")
    _assert_same(back, ref)
    counts = back.meta["map_feature_counts"]
    assert counts["lane"] == len(ref.road_map.lanes)
    assert counts["road_edge"] == len(ref.road_map.road_edges)
    assert set(back.meta["lane_states_per_step"]) <= {len(ref.signals.lane_index)}


@pytest.mark.parametrize("compress", [False, True])
def test_tfrecord_files_round_trip(tmp_path, compress):
    """Several records per file, several files, plain and gzip, read back through iter_scenes."""
    refs = [_numeric_ids(make()) for make in synthetic.ALL.values()]
    paths = [write_tfrecord(tmp_path / "a.tfrecord", [scene_to_scenario(s) for s in refs], gzip=compress),
             write_tfrecord(tmp_path / "b.data", [scene_to_scenario(s) for s in refs[::-1]], gzip=compress)]
    assert sniff(paths[1]) == ("tfrecord.gz" if compress else "tfrecord")
    got = [s for p in paths for s in iter_scenes(p)]
    assert len(got) == 2 * len(refs)
    for back, ref in zip(got, refs + refs[::-1], strict=True):
        _assert_same(back, ref)


def test_non_numeric_ids_are_written_as_indices():
    scene = synthetic.two_lane_road()
    back = scenario_to_scene(Scenario.FromString(scene_to_scenario(scene)))
    assert back.tracks.ids.tolist() == [str(i) for i in range(scene.tracks.num_agents)]


def test_junction_and_signals_of_four_way():
    back = scenario_to_scene(Scenario.FromString(scene_to_scenario(synthetic.four_way_junction())))
    lanes = back.road_map.lanes
    assert lanes.is_junction.sum() == 12  # 4 arms x (straight, left, right)
    assert not lanes.is_junction[back.signals.lane_index].any()  # synthetic: approach lanes
    assert SignalState.GO in back.signals.state and SignalState.STOP in back.signals.state


def test_unknown_fields_are_tolerated():
    data = scene_to_scenario(_numeric_ids(synthetic.merge()))
    extra = b"\x1a\x00" + b"\xa2\x06\x03abc"  # field 3 (empty bytes) and field 100 (bytes)
    back = scenario_to_scene(Scenario.FromString(data + extra))
    assert back.scenario_id == "synthetic_merge"


def test_bad_record_names_file_and_record(tmp_path):
    good = scene_to_scenario(_numeric_ids(synthetic.merge()))
    path = write_tfrecord(tmp_path / "womd.tfrecord", [good, good, b"\xff\xff\xff\xff"])
    with pytest.raises(InputError, match=r"womd\.tfrecord: record 2: not a WOMD Scenario"):
        read_scenes(path)
    raw = bytearray(path.read_bytes())
    raw[12 + 40] ^= 0xFF  # inside record 0's data
    path.write_bytes(bytes(raw))
    with pytest.raises(InputError, match=r"womd\.tfrecord: record 0: data CRC mismatch"):
        read_scenes(path)


def test_empty_and_foreign_files(tmp_path):
    empty = tmp_path / "empty.tfrecord"
    empty.write_bytes(b"")
    with pytest.raises(InputError, match="empty.tfrecord: empty file"):
        read_scenes(empty)
    text = tmp_path / "x.csv"
    text.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(InputError, match=r"x\.csv: record 0: not a TFRecord file"):
        read_scenes(text)
    bad_pickle = tmp_path / "bad.pkl"
    bad_pickle.write_bytes(pickle.dumps([1, 2, 3]))
    with pytest.raises(InputError, match="bad.pkl: not a ScenarioNet"):
        read_scenes(bad_pickle)


def test_npz_scenes_are_read_too(tmp_path):
    path = save_scene(synthetic.merge(), tmp_path / "m.npz")
    (scene,) = read_scenes(path)
    assert scene.scenario_id == "synthetic_merge"


def _description(scene: Scene) -> dict:
    """A minimal ScenarioNet scenario description of a synthetic scene."""
    tr, lanes = scene.tracks, scene.road_map.lanes
    tracks = {str(tid): {"type": "VEHICLE", "state": {
        "position": np.stack([tr.x[i], tr.y[i], np.zeros(tr.num_steps)], -1).astype(np.float32),
        "heading": tr.heading[i].astype(np.float32), "velocity": np.stack([tr.vx[i], tr.vy[i]], -1),
        "length": tr.length[i], "width": tr.width[i], "height": np.ones(tr.num_steps), "valid": tr.valid[i]}}
        for i, tid in enumerate(tr.ids)}
    feats: dict = {}
    for i, lid in enumerate(lanes.ids):
        feats[lid] = {"type": "LANE_SURFACE_STREET", "polyline": lanes.centerline[i],
                      "speed_limit_mph": 30.0,
                      "entry_lanes": [int(lanes.ids[j]) for j in lanes.predecessors[i]],
                      "exit_lanes": [int(lanes.ids[j]) for j in lanes.successors[i]],
                      "left_neighbor": [], "right_neighbor": [],
                      "left_boundaries": [], "right_boundaries": []}
    feats["900"] = {"type": "ROAD_EDGE_MEDIAN", "polyline": np.zeros((3, 3))}
    feats["901"] = {"type": "DRIVEWAY", "polygon": np.zeros((4, 3))}
    dms = {str(lanes.ids[li]): {"lane": int(lanes.ids[li]),
                                "stop_point": np.r_[scene.signals.stop_point[c], 0.0],
                                "state": {"object_state": [f"LANE_STATE_{SignalState(v).name}" if v else None
                                                           for v in scene.signals.state[:, c]]}}
           for c, li in enumerate(scene.signals.lane_index)}
    return {"id": scene.scenario_id, "version": "test", "length": scene.num_steps, "tracks": tracks,
            "map_features": feats, "dynamic_map_states": dms,
            "metadata": {"scenario_id": scene.scenario_id, "sdc_id": str(tr.ids[scene.sdc_index]),
                         "ts": scene.timestamps, "current_time_index": scene.current_time_index}}


def test_scenarionet_pickle(tmp_path):
    ref = synthetic.four_way_junction()
    path = tmp_path / "sd_x.pkl"
    path.write_bytes(pickle.dumps(_description(ref), protocol=4))
    (scene,) = read_scenes(path)
    assert scene.source == "scenarionet" and scene.sdc_index == ref.sdc_index
    np.testing.assert_array_equal(scene.tracks.ids, ref.tracks.ids)
    np.testing.assert_allclose(scene.tracks.x[ref.tracks.valid], ref.tracks.x[ref.tracks.valid], atol=1e-3)
    np.testing.assert_array_equal(scene.signals.state, ref.signals.state)
    la, lb = scene.road_map.lanes, ref.road_map.lanes
    np.testing.assert_array_equal(la.successors.values, lb.successors.values)
    np.testing.assert_array_equal(la.is_junction, lb.is_junction)
    assert scene.meta["map_feature_counts"]["driveway"] == 1
    assert scene.road_map.road_edges.kind.tolist() == [2]


def test_point_polyline_distance():
    poly = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]) + 5000.0
    pts = np.array([[5.0, 2.0], [12.0, 5.0], [-3.0, -4.0]]) + 5000.0
    np.testing.assert_allclose(point_polyline_distance(pts, poly), [2.0, 2.0, 5.0])
