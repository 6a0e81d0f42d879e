"""The OpenDRIVE export of generated scenes nobody tuned it on (issue 64): a subset of the scenes of
``bench/xodr_scenes.py`` (WOMD crops rotated, mirrored, clipped and with lanes dropped; netconvert's
cuts of wheel and netgenerate nets and those cuts converted by the project's converter), each read
by ASAM's checker, commonroad and pyxodr in their own environments (``make xodr-readers``; skipped
where absent). The full set: ``python bench/bench_xodr_checker.py``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from defusedxml import ElementTree as SafeET
from test_xodr_readers import VERSION_SKIPPED, _probe

from coster_sumo.exports import opendrive as odr
from tests.conftest import WOMD_PKL, WOMD_PROTO

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
import xodr_scenes  # noqa: E402

NETS = ["square", "grid6", "cross", "grid_corner", "spider_tight", "rand_lanes"]


@pytest.fixture(scope="module")
def exports(tmp_path_factory) -> dict[str, Path]:
    work = tmp_path_factory.mktemp("scenes")
    only = NETS + (["womd"] if WOMD_PROTO or WOMD_PKL else [])
    out = {}
    for test in xodr_scenes.all_nets(work, seed=1, per_sample=3, per_net=1, only=only):
        out[test.name] = odr.write_xodr(test.net, work / f"{test.name}.xodr")
    assert len(out) >= 12
    return out


def test_transforms_keep_lane_geometry() -> None:
    """A rotation and a mirror move every point; a mirror swaps left and right neighbours."""
    from coster_sumo.core.scene import Lanes, Ragged, RoadMap, Scene, SignalStates

    line = np.column_stack([np.linspace(0.0, 10.0, 11), np.zeros(11)])
    lanes = Lanes(ids=np.array(["a", "b"]), centerline=Ragged.from_list([line, line + [0, 3.5]], np.float64, (2,)),
                  width=np.full(2, 3.5), lane_type=np.ones(2, np.int8), speed_limit=np.zeros(2),
                  is_junction=np.zeros(2, bool), predecessors=Ragged.from_list([np.zeros(0, np.int64)] * 2, np.int64),
                  successors=Ragged.from_list([np.zeros(0, np.int64)] * 2, np.int64),
                  left_neighbors=Ragged.from_list([np.array([1]), np.zeros(0, np.int64)], np.int64),
                  right_neighbors=Ragged.from_list([np.zeros(0, np.int64), np.array([0])], np.int64))
    road_map = RoadMap(lanes=lanes)
    scene = Scene(scenario_id="t", timestamps=np.arange(3) * 0.1, tracks=xodr_scenes._one_vehicle(road_map, 3),
                  road_map=road_map, signals=SignalStates.empty(3))
    turned = xodr_scenes.transform_scene(scene, xodr_scenes.rotation(np.pi / 2), np.zeros(2))
    assert np.allclose(turned.road_map.lanes.centerline[1][[0, -1]], [[-3.5, 0.0], [-3.5, 10.0]])
    mirrored = xodr_scenes.transform_scene(scene, np.diag([-1.0, 1.0]), np.zeros(2))
    assert list(mirrored.road_map.lanes.left_neighbors[1]) == [0]
    clipped = xodr_scenes.clip_lanes(scene, np.array([0.0, 0.0]), 5.0)
    assert len(clipped.road_map.lanes) == 2 and clipped.road_map.lanes.centerline[0][-1][0] == 5.0
    assert [len(v) for v in clipped.road_map.lanes.left_neighbors] == [1, 0]


@pytest.mark.sumo
@pytest.mark.slow
def test_asam_checker_finds_nothing(exports):
    found = _probe("xodr-asam", "asam", list(exports.values()))
    assert set(found) == set(exports)
    for name, row in found.items():
        for cid, ch in row["checkers"].items():
            assert ch["status"] == ("skipped" if cid in VERSION_SKIPPED else "completed"), (name, cid, ch)
        issues = {cid: ch["issues"] for cid, ch in row["checkers"].items() if ch["issues"]}
        assert issues == {}, (name, issues)


@pytest.mark.sumo
@pytest.mark.slow
def test_commonroad_and_pyxodr_read_everything(exports):
    lanelets = _probe("xodr-readers", "commonroad", list(exports.values()))
    roads = _probe("xodr-readers", "pyxodr", list(exports.values()))
    assert set(lanelets) == set(roads) == set(exports)
    for name, path in exports.items():
        assert "error" not in lanelets[name] and lanelets[name]["invalid"] == [], (name, lanelets[name])
        count = len(SafeET.parse(str(path)).getroot().findall("road"))
        assert "error" not in roads[name] and roads[name]["failed"] == [], (name, roads[name])
        assert roads[name]["roads"] == count, (name, roads[name])
