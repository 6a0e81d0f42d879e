"""WOMD -> SUMO conversion: fidelity on synthetic scenes, bad geometry, bad inputs, real samples."""

from __future__ import annotations

import dataclasses
import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from coster_sumo.converters.tfrecord import write_tfrecord
from coster_sumo.converters.to_sumo import STAGING_EDGE, convert_scene
from coster_sumo.converters.to_sumo_net import build_plain_net, lane_width, turn_width_cap
from coster_sumo.converters.womd import scene_to_scenario

from coster_sumo.cli.command_line import main
from coster_sumo.core.scene import Lanes, ObjectType, Ragged, RoadMap, Scene, SignalStates
from coster_sumo.data import synthetic
from coster_sumo.errors import InputError
from coster_sumo.formats.scene_file import load_scene
from coster_sumo.formats.scene_folder import is_converted_scene
from coster_sumo.sim.session import SumoSession
from tests.conftest import NO_WOMD_REASON, WOMD_PKL, WOMD_PROTO
from tests.drive_connections import drive_every_connection

pytestmark = pytest.mark.sumo

CONVERTED_FILES = ("scene.npz", "lane_map.json", "summary.json")


def lane_shapes(net: Path) -> dict[str, np.ndarray]:
    out = {}
    for ln in ET.parse(net).getroot().iter("lane"):
        pts = [tuple(map(float, p.split(","))) for p in ln.get("shape", "").split()]
        out[ln.get("id", "")] = np.asarray(pts)
    return out


@pytest.mark.parametrize("name", sorted(synthetic.ALL))
def test_synthetic_scene_converts_with_exact_geometry(name, tmp_path):
    scene = synthetic.ALL[name]()
    result = convert_scene(scene, tmp_path)
    folder = result.folder
    assert folder == tmp_path / scene.scenario_id and is_converted_scene(folder)
    sid = scene.scenario_id
    for f in (*CONVERTED_FILES, f"{sid}.net.xml", f"{sid}.rou.xml", f"{sid}.sumocfg"):
        assert (folder / f).is_file(), f
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left
    fid = result.summary["fidelity"]
    assert fid["lanes_matched_share"] == 1.0
    assert fid["links_realised_share"] == 1.0
    assert fid["centreline_mean_m"] < 0.01 and fid["centreline_max_m"] < 0.01
    assert fid["continuity"]["joints_over_tolerance"] == 0
    # coordinates are WOMD's: no offset in the net
    loc = ET.parse(folder / f"{sid}.net.xml").getroot().find("location")
    assert loc is not None and [float(v) for v in loc.get("netOffset", "").split(",")] == [0.0, 0.0]
    # the net loads and runs in SUMO
    with SumoSession(folder / f"{sid}.sumocfg") as sim:
        sim.step()
        assert f"{STAGING_EDGE}_0" in sim.api.lane.getIDList()


def test_sumo_drives_every_connection_of_a_junction_without_a_jump(tmp_path):
    folder = convert_scene(synthetic.four_way_junction(), tmp_path).folder
    got = drive_every_connection(next(folder.glob("*.net.xml")), tmp_path, frozenset({STAGING_EDGE}))
    assert got.routes >= 12 and got.arrived == got.routes and got.teleports == 0
    assert got.jumps == []


def test_parallel_lanes_become_one_edge(tmp_path):
    result = convert_scene(synthetic.two_lane_road(), tmp_path)
    lane_map = json.loads((result.folder / "lane_map.json").read_text())["lanes"]
    (right,), (left,) = lane_map["100"], lane_map["101"]
    assert right.rsplit("_", 1)[0] == left.rsplit("_", 1)[0]  # same edge
    assert (right[-1], left[-1]) == ("0", "1")  # rightmost lane is index 0
    assert result.summary["counts"]["multi_lane_edges"] == 1


def test_junction_interior_lanes_are_internal_lanes_and_signals_map(tmp_path):
    scene = synthetic.four_way_junction()
    result = convert_scene(scene, tmp_path)
    lane_map = json.loads((result.folder / "lane_map.json").read_text())
    lanes = scene.road_map.lanes
    interior = [str(lanes.ids[i]) for i in np.flatnonzero(lanes.is_junction)]
    assert len(interior) == 12
    for lid in interior:  # every interior lane is realised by SUMO internal lanes
        assert lane_map["lanes"][lid] and all(s.startswith(":") for s in lane_map["lanes"][lid])
    (tls,) = lane_map["tls"].values()
    controlled = {str(lanes.ids[i]) for i in scene.signals.lane_index}
    assert len(tls["links"]) == 12 and set(tls["links"]) == controlled
    assert result.summary["counts"]["traffic_lights"] == 1
    assert (result.folder / f"{scene.scenario_id}.tll.xml").is_file()


def test_scene_npz_keeps_womd_coordinates_on_sumo_clock(tmp_path):
    scene = synthetic.merge()
    result = convert_scene(scene, tmp_path)
    saved = load_scene(result.folder / "scene.npz")
    np.testing.assert_array_equal(saved.tracks.x, scene.tracks.x)
    offset = saved.meta["sumo_time_offset_s"]
    assert offset == pytest.approx(0.2)
    np.testing.assert_allclose(saved.timestamps, scene.timestamps + offset)


def _with_lanes(scene: Scene, extra: list[np.ndarray]) -> Scene:
    """``scene`` plus unlinked lanes with the given polylines."""
    lanes = scene.road_map.lanes
    n = len(lanes)
    k = len(extra)
    rag = [list(r) for r in lanes.centerline]

    def grow(r: Ragged) -> Ragged:
        return Ragged.from_list([*list(r), *([np.zeros(0, np.int64)] * k)], np.int64)

    new = Lanes(ids=np.array([*lanes.ids.tolist(), *[str(900 + i) for i in range(k)]]),
                centerline=Ragged.from_list([*[np.asarray(p) for p in rag], *extra], np.float64, (2,)),
                width=np.concatenate([lanes.width, np.full(k, 3.5)]),
                lane_type=np.concatenate([lanes.lane_type, np.full(k, 2, np.int8)]),
                speed_limit=np.concatenate([lanes.speed_limit, np.zeros(k)]),
                is_junction=np.concatenate([lanes.is_junction, np.zeros(k, bool)]),
                predecessors=grow(lanes.predecessors), successors=grow(lanes.successors),
                left_neighbors=grow(lanes.left_neighbors), right_neighbors=grow(lanes.right_neighbors))
    assert len(new) == n + k
    return dataclasses.replace(scene, road_map=dataclasses.replace(scene.road_map, lanes=new)).validate()


def test_bad_lane_geometry_is_skipped_with_a_warning(tmp_path):
    scene = synthetic.two_lane_road()
    x0, y0 = scene.road_map.lanes.centerline[0][0]
    dup = np.array([[x0, y0 - 50], [x0, y0 - 50], [x0 + 10, y0 - 50], [x0 + 10, y0 - 50], [x0 + 20, y0 - 50]])
    bad = _with_lanes(scene, [np.array([[x0, y0 - 20]]), np.array([[x0, y0 - 30], [x0, y0 - 30]]), dup])
    result = convert_scene(bad, tmp_path)
    warnings = result.summary["warnings"]
    assert any("900" in w for w in warnings) and any("901" in w for w in warnings)
    lane_map = json.loads((result.folder / "lane_map.json").read_text())["lanes"]
    assert lane_map["900"] == [] and lane_map["901"] == [] and lane_map["902"]  # duplicates removed
    assert result.summary["fidelity"]["lanes_matched"] == len(bad.road_map.lanes) - 2


def test_lanes_of_one_point_are_realised_where_they_sit(tmp_path):
    """WOMD's map crop leaves lanes of one point at another lane's end (6 in the real samples): no
    SUMO lane can hold them, so a lane before one links straight to the lane after it, and one that
    ends the map lies on its neighbour's end."""
    scene = synthetic.two_lane_road()
    ox, oy = scene.road_map.lanes.centerline[0][0]
    b = synthetic._MapBuilder()
    a = b.lane(synthetic._line((ox, oy), (ox + 100, oy)))
    p = b.lane(np.array([[ox + 100, oy]]))
    c = b.lane(synthetic._line((ox + 100, oy), (ox + 200, oy)))
    stub = b.lane(np.array([[ox + 200, oy]]))
    lost = b.lane(np.array([[ox + 100, oy + 30]]))  # links a lane it does not touch
    b.link(a, p)
    b.link(p, c)
    b.link(c, stub)
    b.link(a, lost)
    road_map = b.build()
    signals = SignalStates(lane_index=np.array([p]), state=np.full((len(scene.timestamps), 1), 6, np.int8),
                           stop_point=np.array([[ox + 100, oy]]))
    plain = build_plain_net(road_map, signals)
    (across,) = [k for k in plain.connections if (k.src, k.dst) == (plain.lane_pieces[a][-1], plain.lane_pieces[c][0])]
    assert across.links == [(a, p), (p, c)] and across.signal_lane == p  # its signal controls a -> c
    result = convert_scene(dataclasses.replace(scene, road_map=road_map).validate(), tmp_path)
    fid = result.summary["fidelity"]
    ids = road_map.lanes.ids
    assert fid["unmatched_lanes"] == [ids[lost]] and fid["lanes_matched"] == 4
    assert (fid["links"], fid["links_realised"]) == (4, 3)  # all but the one to the lost point
    lane_map = json.loads((result.folder / "lane_map.json").read_text())["lanes"]
    assert lane_map[ids[p]] == lane_map[ids[a]] + lane_map[ids[c]] and lane_map[ids[stub]] == lane_map[ids[c]]
    # SUMO drives from a to c across the point
    got = drive_every_connection(next(result.folder.glob("*.net.xml")), tmp_path, frozenset({STAGING_EDGE}))
    assert got.routes >= 1 and got.arrived == got.routes and got.jumps == []


def test_a_lane_is_no_wider_than_its_turn():
    # a lane wider than the diameter of its turn has an inner edge that runs backwards
    a = np.linspace(0.0, math.pi / 2, 40)
    arc = np.column_stack([2.5 * np.sin(a), 2.5 - 2.5 * np.cos(a)])
    assert turn_width_cap(arc) == pytest.approx(1.8 * 2.5, rel=0.02)
    assert turn_width_cap(np.array([[0.0, 0.0], [50.0, 0.0]])) == math.inf
    b = synthetic._MapBuilder()
    b.lane(arc)
    road_map = b.build()
    road_map.lanes.width[0] = 5.5
    assert lane_width(road_map, 0) == pytest.approx(4.5, rel=0.02)


def _empty_map(scene: Scene) -> Scene:
    empty = Lanes(ids=np.zeros(0, str), centerline=Ragged.empty(0, np.float64, (2,)), width=np.zeros(0),
                  lane_type=np.zeros(0, np.int8), speed_limit=np.zeros(0), is_junction=np.zeros(0, bool),
                  predecessors=Ragged.empty(0), successors=Ragged.empty(0), left_neighbors=Ragged.empty(0),
                  right_neighbors=Ragged.empty(0))
    return dataclasses.replace(scene, road_map=RoadMap(lanes=empty), scenario_id="empty_map",
                               signals=dataclasses.replace(scene.signals))


def _no_vehicles(scene: Scene) -> Scene:
    tracks = dataclasses.replace(scene.tracks, object_type=np.full(scene.tracks.num_agents,
                                                                   int(ObjectType.PEDESTRIAN), np.int8))
    return dataclasses.replace(scene, tracks=tracks, scenario_id="no_vehicles")


def test_unconvertible_scenes_raise_input_error(tmp_path):
    with pytest.raises(InputError, match="no lanes"):
        convert_scene(_empty_map(synthetic.two_lane_road()), tmp_path)
    with pytest.raises(InputError, match="no vehicle"):
        convert_scene(_no_vehicles(synthetic.two_lane_road()), tmp_path)
    assert list(tmp_path.iterdir()) == []


@pytest.fixture()
def inputs(tmp_path) -> dict[str, Path]:
    """One good TFRecord and one of each kind of bad input."""
    d = tmp_path / "in"
    d.mkdir()
    good_bytes = scene_to_scenario(synthetic.merge())
    files = {"good": write_tfrecord(d / "good.tfrecord", [good_bytes])}
    raw = files["good"].read_bytes()
    files["truncated"] = d / "truncated.tfrecord"
    files["truncated"].write_bytes(raw[: len(raw) // 2])
    flipped = bytearray(raw)
    flipped[len(raw) // 2] ^= 0xFF
    files["flipped"] = d / "flipped.tfrecord"
    files["flipped"].write_bytes(bytes(flipped))
    files["junk"] = d / "junk.tfrecord"
    files["junk"].write_bytes(b"this is not a tfrecord at all\n" * 10)
    two_lane = synthetic.two_lane_road()
    files["empty_map"] = write_tfrecord(d / "empty_map.tfrecord", [scene_to_scenario(_empty_map(two_lane))])
    files["no_vehicles"] = write_tfrecord(d / "no_vehicles.tfrecord",
                                          [scene_to_scenario(_no_vehicles(two_lane))])
    return files


def test_cli_bad_inputs_one_line_each_others_convert(inputs, tmp_path, capsys):
    out = tmp_path / "out"
    order = ["truncated", "good", "flipped", "junk", "empty_map", "no_vehicles"]
    rc = main(["-q", "convert", *[str(inputs[k]) for k in order], "-o", str(out)])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 1
    assert "Traceback" not in err
    assert len(lines) == 5, err
    for name in ("truncated", "flipped", "junk", "empty_map", "no_vehicles"):
        (line,) = [ln for ln in lines if f"{name}.tfrecord" in ln]
        assert line.startswith("coster-sumo: error: ") and "record" in line
    assert is_converted_scene(out / "synthetic_merge")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["converted"] == 1 and summary["failed"] == 5


def test_cli_exit_codes(inputs, tmp_path, capsys):
    assert main(["-q", "convert", str(inputs["good"]), "-o", str(tmp_path / "a")]) == 0
    assert main(["-q", "convert", str(inputs["junk"]), "-o", str(tmp_path / "b")]) == 2  # nothing read
    assert main(["-q", "convert", str(tmp_path / "missing.tfrecord"), "-o", str(tmp_path / "c")]) == 2
    with pytest.raises(SystemExit) as exc:  # usage error: no -o
        main(["convert", str(inputs["good"])])
    assert exc.value.code == 2
    capsys.readouterr()


def test_cli_prints_fidelity(inputs, tmp_path, capsys):
    assert main(["convert", str(inputs["good"]), "-o", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "synthetic_merge: lanes matched 3/3 (100.0%), links realised 2/2 (100.0%)" in out


REAL = [*WOMD_PROTO, *WOMD_PKL]


@pytest.mark.realdata
@pytest.mark.slow
@pytest.mark.skipif(not REAL, reason=NO_WOMD_REASON)
def test_real_samples_meet_fidelity_targets(tmp_path, capsys):
    rc = main(["-q", "convert", *map(str, REAL), "-o", str(tmp_path)])
    assert rc == 0, capsys.readouterr().err
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["converted"] == 4
    for row in summary["scenes"]:
        fid = row["fidelity"]
        assert fid["lanes_matched_share"] >= 0.995, row["scenario_id"]
        assert fid["links_realised_share"] >= 0.90, row["scenario_id"]
        assert fid["centreline_mean_m"] < 0.1, row["scenario_id"]
        # every lane end meets the internal lane of each of its connections (issue 46: 41-136 joints
        # per sample were 0.5-31 m apart before), and SUMO drives every connection without a jump
        assert fid["continuity"]["joints"] > 150 and fid["continuity"]["joints_over_tolerance"] == 0, row
        got = drive_every_connection(Path(row["folder"]) / f"{row['scenario_id']}.net.xml", tmp_path,
                                     frozenset({STAGING_EDGE}))
        assert got.arrived == got.routes > 40 and got.teleports == 0, row["scenario_id"]
        assert got.jumps == [], (row["scenario_id"], got.jumps[:5])
        with SumoSession(Path(row["folder"]) / f"{row['scenario_id']}.sumocfg") as sim:
            sim.step()
