"""The nominal dataset format: clips, cropping, listing, splitting, manifest (no SUMO needed)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from coster_sumo import InputError, save_scene
from coster_sumo.core.scene import Lanes, Ragged, RoadMap, Scene, SignalStates
from coster_sumo.data import dataset, synthetic


def _long_scene(num_steps: int = 300) -> Scene:
    """The synthetic two-lane road, stretched to ``num_steps`` by constant-velocity extrapolation."""
    base = synthetic.two_lane_road()
    tr = base.tracks
    t = np.arange(num_steps) * 0.1
    x = tr.x[:, :1] + tr.vx[:, :1] * t[None, :]
    y = tr.y[:, :1] + tr.vy[:, :1] * t[None, :]
    wide = {f: np.repeat(getattr(tr, f)[:, :1], num_steps, axis=1)
            for f in ("heading", "vx", "vy", "length", "width")}
    tracks = dataclasses.replace(tr, x=x, y=y, valid=np.ones((tr.num_agents, num_steps), bool), **wide)
    sig = base.signals
    return dataclasses.replace(base, timestamps=t + 100.0, tracks=tracks,
                               signals=SignalStates(sig.lane_index, np.zeros((num_steps, 0), np.int8),
                                                    sig.stop_point)).validate()


def _strip_map(n: int = 5, spacing: float = 100.0) -> RoadMap:
    """``n`` parallel 2-point lanes along x, ``spacing`` metres apart in y, chained by successors."""
    lines = [np.array([[0.0, i * spacing], [400.0, i * spacing]]) for i in range(n)]
    succ = [np.array([i + 1]) if i + 1 < n else np.zeros(0, np.int64) for i in range(n)]
    empty = Ragged.from_list([np.zeros(0, np.int64)] * n, dtype=np.int64)
    lanes = Lanes(ids=np.array([f"l{i}" for i in range(n)]),
                  centerline=Ragged.from_list(lines, inner_shape=(2,)),
                  width=np.full(n, 3.2), lane_type=np.ones(n, np.int8), speed_limit=np.full(n, 13.9),
                  is_junction=np.zeros(n, bool), predecessors=empty,
                  successors=Ragged.from_list(succ, dtype=np.int64), left_neighbors=empty,
                  right_neighbors=empty)
    return RoadMap(lanes=lanes)


def test_crop_map_measures_distance_to_segments_not_vertices():
    road_map = _strip_map()
    # a point in the middle of lane 2, 200 m from both of its vertices
    cropped, index = dataset.crop_map(road_map, np.array([[200.0, 210.0]]), radius_m=20.0)
    assert cropped.lanes.ids.tolist() == ["l2"]
    assert index.tolist() == [-1, -1, 0, -1, -1]
    assert len(cropped.lanes.successors[0]) == 0  # its successor l3 was dropped
    cropped.validate()


def test_crop_map_reindexes_topology():
    cropped, index = dataset.crop_map(_strip_map(), np.array([[200.0, 150.0]]), radius_m=60.0)
    assert cropped.lanes.ids.tolist() == ["l1", "l2"]
    assert cropped.lanes.successors[0].tolist() == [1]  # l1 -> l2, new indices
    assert index[1] == 0 and index[2] == 1


def test_clip_scene_is_womd_like():
    scene = _long_scene()
    clip = dataset.clip_scene(scene, start=50, target=1).validate()
    assert clip.num_steps == dataset.CLIP_STEPS
    assert clip.current_time_index == dataset.CURRENT_TIME_INDEX
    assert clip.timestamps[0] == 0.0 and clip.timestamps[-1] == pytest.approx(9.0)
    assert clip.tracks.ids[clip.sdc_index] == scene.tracks.ids[1]
    assert clip.tracks.valid[clip.sdc_index].all()
    assert clip.meta["start_time_s"] == pytest.approx(105.0)
    np.testing.assert_array_equal(clip.tracks.x[clip.sdc_index], scene.tracks.x[1, 50:141])


def test_crop_scene_drops_far_agents_and_keeps_the_target():
    scene = _long_scene()
    far = dataclasses.replace(scene.tracks, x=scene.tracks.x + np.array([[0.0], [0.0], [5000.0], [0.0]]))
    scene = dataclasses.replace(scene, tracks=far, sdc_index=0)
    cropped = dataset.crop_scene(scene, radius_m=50.0)
    assert scene.tracks.ids[2] not in cropped.tracks.ids.tolist()
    assert cropped.tracks.ids[cropped.sdc_index] == scene.tracks.ids[0]
    cropped.validate()


def test_plan_clips_is_deterministic_and_spreads_over_windows():
    scene = _long_scene(400)  # 4 windows of 91 steps
    a = dataset.plan_clips(scene, 4, np.random.default_rng(3), dataset.ClipRules(min_separation_m=0.0))
    b = dataset.plan_clips(scene, 4, np.random.default_rng(3), dataset.ClipRules(min_separation_m=0.0))
    assert a == b
    assert sorted({start for start, _ in a}) == [0, 91, 182, 273]  # one per window first
    many = dataset.plan_clips(scene, 100, np.random.default_rng(3),
                              dataset.ClipRules(targets_per_window=2, min_separation_m=0.0))
    assert len(many) == 8


def test_plan_clips_skips_warmup_and_parked_cars():
    scene = _long_scene(400)
    picks = dataset.plan_clips(scene, 100, np.random.default_rng(0), dataset.ClipRules(warmup_s=10.0))
    assert all(scene.timestamps[s] >= scene.timestamps[0] + 10.0 for s, _ in picks)
    parked = dataclasses.replace(scene.tracks, vx=scene.tracks.vx * 0, vy=scene.tracks.vy * 0,
                                 x=np.repeat(scene.tracks.x[:, :1], scene.num_steps, axis=1))
    assert dataset.plan_clips(dataclasses.replace(scene, tracks=parked), 10, np.random.default_rng(0)) == []


def test_split_is_deterministic_and_stable(tmp_path):
    names = [tmp_path / f"run_s{i}_{i * 9.1:07.1f}_veh{i}.npz" for i in range(400)]
    train, val = dataset.split(names, 0.2, seed=1)
    assert (train, val) == dataset.split(list(reversed(names)), 0.2, seed=1)
    assert len(train) + len(val) == 400 and not set(train) & set(val)
    assert 40 < len(val) < 120
    # adding files never moves an old one; moving the dataset changes nothing
    train2, val2 = dataset.split(names + [tmp_path / "new.npz"], 0.2, seed=1)
    assert set(val) <= set(val2) and set(train) <= set(train2)
    moved = [p.name for p in dataset.split([tmp_path / "x" / p.name for p in names], 0.2, seed=1)[1]]
    assert moved == [p.name for p in val]
    assert dataset.split(names, 0.2, seed=2)[1] != val
    with pytest.raises(InputError):
        dataset.split(names, 1.5)


def test_list_and_iter_scenes(tmp_path):
    scene = _long_scene()
    folder = dataset.scenes_dir(tmp_path)
    folder.mkdir()
    for i, start in enumerate((0, 91)):
        save_scene(dataset.clip_scene(scene, start, i), folder / f"c{i}.npz")
    (folder / "half.npz.tmp.npz").write_bytes(b"")  # an interrupted write
    paths = dataset.list_scenes(tmp_path)
    assert [p.name for p in paths] == ["c0.npz", "c1.npz"]
    assert [s.num_steps for s in dataset.iter_scenes(tmp_path)] == [91, 91]
    with pytest.raises(InputError):
        dataset.list_scenes(tmp_path / "missing")


def test_manifest_totals(tmp_path):
    m = dataset.read_manifest(tmp_path)
    m["runs"] = [{"run_id": "a", "status": "ok", "clips": 5, "duration_s": 1800.0},
                 {"run_id": "b", "status": "failed", "error": "x", "duration_s": 60.0}]
    dataset.write_manifest(tmp_path, m)
    back = dataset.read_manifest(tmp_path)
    assert back["counts"] == {"runs": 1, "runs_failed": 1, "scenes": 5}
    assert back["simulated_hours"] == 0.5
    (tmp_path / dataset.MANIFEST).write_text("{}")
    with pytest.raises(InputError):
        dataset.read_manifest(tmp_path)


def test_near_items_equals_brute_force_on_random_polylines():
    """The blocked search keeps exactly the polylines a distance to every point and segment keeps."""
    from coster_sumo.core.scene import Ragged

    rng = np.random.default_rng(4)
    polys = [np.cumsum(rng.normal(0, 40, (int(rng.integers(1, 6)), 2)), axis=0) + rng.uniform(-500, 500, 2)
             for _ in range(300)]
    points = np.concatenate([np.repeat(rng.uniform(-300, 300, (1, 2)), 50, axis=0),  # a vehicle standing
                             np.cumsum(rng.normal(0, 3, (700, 2)), axis=0)])
    radius = 60.0

    def dist(poly: np.ndarray) -> float:
        best = np.inf
        for a, b in zip(poly, poly[1:] if len(poly) > 1 else poly, strict=False):
            e = b - a
            t = np.clip(((points - a) @ e) / max(e @ e, 1e-12), 0, 1)
            best = min(best, float(np.min(np.hypot(*(points - a - t[:, None] * e).T))))
        return best

    expected = np.array([dist(p) <= radius for p in polys])
    got = dataset._near_items(Ragged.from_list(polys, dtype=np.float64, inner_shape=(2,)), points, radius)
    assert 0 < expected.sum() < len(polys)
    assert np.array_equal(got, expected)
