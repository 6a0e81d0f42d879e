"""coster_sumo.formats.sumo_net: any SUMO net -> RoadMap, and the traffic-light links."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

from coster_sumo.core.scene import LaneType
from coster_sumo.errors import InputError
from coster_sumo.formats.sumo_net import (
    ROAD_LINE_SOLID_DOUBLE_YELLOW,
    load_sumo_net,
    offset_polyline,
    read_sumo_net,
)
from coster_sumo.infra import sumo_install

NETGENERATE = {
    "grid_tls": ["--grid", "--grid.number", "3", "--grid.length", "100", "-L", "2",
                 "--default-junction-type", "traffic_light"],
    "grid_walk": ["--grid", "--grid.number", "3", "--grid.length", "100", "-L", "2", "--sidewalks.guess",
                  "true", "--crossings.guess", "true", "--default-junction-type", "traffic_light"],
    "grid_no_internal": ["--grid", "--grid.number", "3", "-L", "2", "--no-internal-links", "true",
                         "--default-junction-type", "traffic_light"],
    "spider": ["--spider", "--spider.arm-number", "5", "--spider.circle-number", "2"],
    "random": ["--rand", "--rand.iterations", "40", "--seed", "3", "-L", "2", "--tls.guess", "true"],
    "fast_grid": ["--grid", "--grid.number", "2", "--default.speed", "30"],
}


@pytest.fixture(scope="module")
def nets(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("nets")
    out = {}
    for name, args in NETGENERATE.items():
        path = folder / f"{name}.net.xml"
        subprocess.run([sumo_install.binary("netgenerate"), *args, "-o", str(path)], check=True,
                       capture_output=True, env=sumo_install.subprocess_env())
        out[name] = path
    return out


pytestmark = pytest.mark.sumo


@pytest.mark.parametrize("name", sorted(NETGENERATE))
def test_every_generated_net_converts_to_a_valid_map(nets, name):
    net = read_sumo_net(nets[name])
    net.road_map.validate()
    lanes = net.road_map.lanes
    assert len(lanes) > 0
    assert np.all(lanes.width > 0) and np.all(lanes.speed_limit > 0)
    assert np.all(lanes.centerline.lengths() >= 2)
    assert np.array_equal(lanes.is_junction, np.char.startswith(lanes.ids.astype(str), ":"))
    assert len(net.road_map.junctions) > 0 and len(net.road_map.road_edges) > 0


def test_grid_topology_runs_through_junction_lanes(nets):
    net = read_sumo_net(nets["grid_tls"])
    lanes = net.road_map.lanes
    ids = lanes.ids
    i = lanes.index_of("A0A1_0")
    succ = set(ids[lanes.successors[i]])
    assert succ and all(s.startswith(":A1_") for s in succ)  # via internal lanes of junction A1
    for s in lanes.successors[i]:
        assert i in lanes.predecessors[s]
    # follow internal lanes until a normal lane: A0A1 continues to A1A2, A1B1 (and the u-turn)
    reached = set()
    frontier = list(lanes.successors[i])
    while frontier:
        j = frontier.pop()
        if lanes.is_junction[j]:
            frontier += list(lanes.successors[j])
        else:
            reached.add(str(ids[j]).split("_")[0])
    assert {"A1A2", "A1B1"} <= reached
    # SUMO: lane index + 1 is to the left
    assert list(ids[lanes.left_neighbors[i]]) == ["A0A1_1"] and len(lanes.right_neighbors[i]) == 0
    assert list(ids[lanes.right_neighbors[lanes.index_of("A0A1_1")]]) == ["A0A1_0"]


def test_lane_types(nets):
    assert set(read_sumo_net(nets["grid_tls"]).road_map.lanes.lane_type) == {LaneType.SURFACE_STREET}
    assert set(read_sumo_net(nets["fast_grid"]).road_map.lanes.lane_type) == {LaneType.FREEWAY}


def test_sidewalks_are_left_out_and_crossings_become_crosswalks(nets):
    net = read_sumo_net(nets["grid_walk"])
    lanes = net.road_map.lanes
    assert "A0A1_0" not in set(lanes.ids)  # lane 0 is the sidewalk
    assert {"A0A1_1", "A0A1_2"} <= set(lanes.ids)
    assert len(net.road_map.crosswalks) > 0
    assert all(len(p) >= 4 for p in net.road_map.crosswalks.points)
    with_walks = read_sumo_net(nets["grid_walk"], include_non_road=True).road_map.lanes
    assert "A0A1_0" in set(with_walks.ids)
    assert with_walks.lane_type[with_walks.index_of("A0A1_0")] == LaneType.UNDEFINED


def test_two_way_roads_get_one_centre_line(nets):
    rm = read_sumo_net(nets["grid_tls"]).road_map
    # 3x3 grid: 12 two-way streets, each with one centre line
    assert int(np.sum(rm.road_lines.kind == ROAD_LINE_SOLID_DOUBLE_YELLOW)) == 12


def test_signal_links_cover_the_state_strings(nets):
    net = read_sumo_net(nets["grid_tls"])
    assert set(net.signal_links) == {f"{c}{r}" for c in "ABC" for r in "012"}
    links = net.signal_links["B1"]
    assert [s.link_index for s in links] == sorted(s.link_index for s in links)
    assert {s.link_index for s in links} == set(range(max(s.link_index for s in links) + 1))
    lane_ids = set(net.road_map.lanes.ids)
    for s in links:
        assert s.from_lane in lane_ids and s.to_lane in lane_ids and s.via_lane.startswith(":B1_")
    no_internal = read_sumo_net(nets["grid_no_internal"])
    assert all(s.via_lane == "" for links in no_internal.signal_links.values() for s in links)


def test_load_is_cached_and_reloads_changed_files(nets, tmp_path):
    path = tmp_path / "g.net.xml"
    path.write_bytes(nets["spider"].read_bytes())
    a = load_sumo_net(path)
    assert load_sumo_net(path) is a
    path.write_bytes(nets["grid_tls"].read_bytes())
    assert load_sumo_net(path) is not a


def test_missing_or_broken_net_names_the_file(tmp_path):
    with pytest.raises(InputError, match="nope.net.xml"):
        read_sumo_net(tmp_path / "nope.net.xml")
    bad = tmp_path / "bad.net.xml"
    bad.write_text("<net><edge id='x'")
    with pytest.raises(InputError, match="bad.net.xml"):
        read_sumo_net(bad)


def test_offset_polyline_keeps_segments_parallel():
    pts = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [10.0, 10.0]])
    left = offset_polyline(pts, 1.0)
    np.testing.assert_allclose(left, [[0.0, 1.0], [9.0, 1.0], [9.0, 10.0]], atol=1e-12)
    np.testing.assert_allclose(offset_polyline(pts[:2], -2.0), [[0.0, -2.0], [10.0, -2.0]])
