"""The formats layer: one sumocfg reader, the converted-scene folder, atomic writes."""

from __future__ import annotations

import gzip
import json
import os
from pathlib import Path

import numpy as np
import pytest

from coster_sumo.errors import InputError
from coster_sumo.formats.scene_folder import converted_scene_file, is_converted_scene
from coster_sumo.formats.sumocfg import parse_time, read_sumocfg
from coster_sumo.infra.atomic import atomic_path, write_json

REPO = Path(__file__).resolve().parents[2]


def test_reads_inputs_window_and_step_of_a_project_network():
    cfg = read_sumocfg(REPO / "networks/intersection/intersection.sumocfg")
    assert cfg.net_file == REPO / "networks/intersection/intersection.net.xml"
    assert [p.name for p in cfg.route_files] == ["intersection.rou.xml"]
    assert cfg.end == 120.0 and cfg.step_length == 0.1 and cfg.has_demand


def test_attribute_spelling_lists_gzip_and_clock_times(tmp_path):
    text = ('<configuration><input net-file="a.net.xml" route-files="r1.rou.xml, r2.rou.xml"/>'
            '<time><begin value="16:00:00"/><end value="57600.5"/></time></configuration>')
    (tmp_path / "x.sumocfg").write_bytes(gzip.compress(text.encode()))
    cfg = read_sumocfg(tmp_path / "x.sumocfg")
    assert cfg.net_files == (tmp_path / "a.net.xml",)
    assert [p.name for p in cfg.route_files] == ["r1.rou.xml", "r2.rou.xml"]
    assert cfg.begin == 57600.0 and cfg.end == 57600.5 and cfg.step_length is None


def test_every_name_sumo_knows_an_option_by(tmp_path):
    # sumolib's RiLSA scenarios write <net>; sumo also takes the one-letter names in a configuration
    (tmp_path / "long.sumocfg").write_text('<c><net value="a.net.xml"/><routes value="r.rou.xml"/>'
                                           '<additional value="x.add.xml"/></c>')
    cfg = read_sumocfg(tmp_path / "long.sumocfg")
    assert cfg.net_file == tmp_path / "a.net.xml" and cfg.has_demand
    assert cfg.additional_files == (tmp_path / "x.add.xml",)
    (tmp_path / "short.sumocfg").write_text('<configuration><n value="a.net.xml"/><r value="r.rou.xml"/>'
                                            '<a value="x.add.xml"/><b value="10"/><e value="1:00"/></configuration>')
    cfg = read_sumocfg(tmp_path / "short.sumocfg")
    assert cfg.net_files == (tmp_path / "a.net.xml",) and cfg.route_files == (tmp_path / "r.rou.xml",)
    assert cfg.additional_files == (tmp_path / "x.add.xml",) and (cfg.begin, cfg.end) == (10.0, 60.0)


@pytest.mark.parametrize(("text", "seconds"), [("3600", 3600.0), ("0.1", 0.1), ("1:00", 60.0), ("1:0:1", 3601.0),
                                               ("1:00:00:00", 86400.0)])
def test_sumo_time_values(text, seconds):
    assert parse_time(text, "x") == pytest.approx(seconds)


@pytest.mark.parametrize("content", ["<configuration><input>", "not xml at all",
                                     '<!DOCTYPE c [<!ENTITY a "aaaa">]><configuration>&a;</configuration>',
                                     '<configuration><time><end value="soon"/></time></configuration>'])
def test_a_bad_configuration_is_one_line_naming_the_file(tmp_path, content):
    path = tmp_path / "bad.sumocfg"
    path.write_text(content)
    with pytest.raises(InputError) as err:
        read_sumocfg(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_missing_configuration(tmp_path):
    with pytest.raises(InputError, match="nope.sumocfg: no such file"):
        read_sumocfg(tmp_path / "nope.sumocfg")


def test_converted_scene_needs_its_log_and_lane_map_beside_the_config(tmp_path):
    cfg = tmp_path / "s.sumocfg"
    cfg.write_text("<configuration/>")
    (tmp_path / "scene.npz").write_bytes(b"")
    assert converted_scene_file(cfg) is None and not is_converted_scene(tmp_path)
    (tmp_path / "lane_map.json").write_text("{}")
    assert converted_scene_file(cfg) == tmp_path / "scene.npz" and is_converted_scene(tmp_path)
    assert converted_scene_file(REPO / "networks/merge/merge.sumocfg") is None


def test_atomic_write_leaves_the_old_file_when_the_writer_fails(tmp_path):
    path = write_json(tmp_path / "a.json", {"x": np.float32(1.5), "v": np.arange(2)})
    assert json.loads(path.read_text()) == {"x": 1.5, "v": [0, 1]}
    with pytest.raises(RuntimeError), atomic_path(path) as tmp:
        tmp.write_text("half")
        raise RuntimeError("killed")
    assert json.loads(path.read_text())["x"] == 1.5
    assert os.listdir(tmp_path) == ["a.json"]


def test_atomic_path_keeps_the_suffix_numpy_appends(tmp_path):
    with atomic_path(tmp_path / "arrays.npz") as tmp:
        np.savez(tmp, a=np.ones(3))
    assert os.listdir(tmp_path) == ["arrays.npz"]
