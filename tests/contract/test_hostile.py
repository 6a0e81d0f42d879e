"""Hostile and broken inputs: no code runs from a file, no traceback, every bad input named in one line.

Payloads are built here in code (docs/womd.md, "Hostile inputs"); the seeded fuzz harness over the
whole CLI is tests/fuzz.py (tests/contract/test_fuzz.py runs a few hundred inputs).
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import pickle
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from coster_sumo.converters.read import read_scenes
from coster_sumo.converters.scenarionet import ALLOWED_GLOBALS, RestrictedUnpickler, load_pickle
from coster_sumo.converters.tf_example import example_keys
from coster_sumo.converters.tfrecord import masked_crc32c, write_tfrecord
from coster_sumo.converters.womd import scene_to_scenario

from coster_sumo.cli.command_line import main
from coster_sumo.core.scene import Ragged
from coster_sumo.data import synthetic
from coster_sumo.errors import InputError, one_line
from coster_sumo.formats.scene_file import load_scene, save_scene
from coster_sumo.formats.scene_folder import folder_name
from tests.conftest import REPO, WOMD_PKL, requires_womd
from tests.converters.test_womd_reader import _description


class _Call:
    """Pickles as ``func(*args)`` with ``func`` named by module and attribute: a crafted payload."""

    def __init__(self, func, *args) -> None:  # type: ignore[no-untyped-def]
        self.func, self.args = func, args

    def __reduce__(self):  # type: ignore[no-untyped-def]
        return (self.func, self.args)


def creates_file(sentinel: Path) -> _Call:
    return _Call(os.system, f"touch {sentinel}")


def imports_module() -> _Call:
    import importlib

    return _Call(importlib.import_module, "antigravity")


def crafted_scenario(payload: _Call, protocol: int = 4) -> bytes:
    """A valid-looking ScenarioNet description with ``payload`` hidden in a track's metadata."""
    sd = _description(synthetic.two_lane_road())
    first = next(iter(sd["tracks"]))
    sd["tracks"][first]["metadata"] = {"note": payload}
    return pickle.dumps(sd, protocol=protocol)


@pytest.fixture
def crafted(tmp_path):
    """(pickle path, sentinel path): loading the pickle with plain pickle.load would create the sentinel."""
    sentinel = tmp_path / "SENTINEL"
    path = tmp_path / "crafted.pkl"
    path.write_bytes(crafted_scenario(creates_file(sentinel)))
    return path, sentinel


def run_cli(*argv: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "coster_sumo", "-q", *argv], capture_output=True, text=True,
                          cwd=cwd, timeout=300)


# ----------------------------------------------------------------------------- restricted unpickling

def test_the_fixture_payload_really_runs_with_plain_pickle(tmp_path):
    sentinel = tmp_path / "SENTINEL"
    pickle.loads(pickle.dumps(creates_file(sentinel)))  # what a plain pickle.load would do
    assert sentinel.exists()


@pytest.mark.parametrize("protocol", [2, 3, 4, 5])
def test_crafted_pickle_is_refused_and_runs_nothing(crafted, protocol):
    path, sentinel = crafted
    path.write_bytes(crafted_scenario(creates_file(sentinel), protocol))
    with pytest.raises(InputError) as exc:
        load_pickle(path)
    msg = str(exc.value)
    assert msg.startswith(f"{path}: refused") and "posix.system" in msg and "\n" not in msg
    assert not sentinel.exists()


def test_importing_pickle_is_refused(tmp_path):
    path = tmp_path / "imports.pkl"
    path.write_bytes(crafted_scenario(imports_module()))
    before = set(sys.modules)
    with pytest.raises(InputError, match="importlib.import_module"):
        load_pickle(path)
    assert "antigravity" not in set(sys.modules) - before


@pytest.mark.parametrize("protocol", [2, 3, 4, 5])
def test_plain_containers_and_numpy_values_load(protocol):
    from collections import OrderedDict, defaultdict

    obj = {"a": [1, 2.5, None, True, "x", b"raw"], "s": {1, 2}, "f": frozenset({3}), "t": (1, 2),
           "arr": np.arange(6, dtype=np.float32).reshape(2, 3), "mask": np.array([True, False]),
           "scalar": np.float64(1.5), "i": np.int64(3), "dd": defaultdict(int, {"k": 1}),
           "od": OrderedDict(z=1), "text": np.array(["ab", "c"])}
    got = RestrictedUnpickler(io.BytesIO(pickle.dumps(obj, protocol=protocol))).load()
    assert got["a"] == obj["a"] and got["s"] == {1, 2} and got["dd"]["k"] == 1
    np.testing.assert_array_equal(got["arr"], obj["arr"])
    assert got["arr"].dtype == np.float32 and got["scalar"] == 1.5


@pytest.mark.parametrize("payload, expected", [
    (_Call(bytes, 10**10), "bytes called with"),
    (_Call(np.ndarray, (10**10,)), "numpy.ndarray called directly"),
    (_Call(str, b"x", "rot13"), "str called with"),
])
def test_allowed_names_cannot_exhaust_memory_or_load_codecs(tmp_path, payload, expected):
    path = tmp_path / "bomb.pkl"
    path.write_bytes(crafted_scenario(payload))
    with pytest.raises(InputError, match=expected):
        load_pickle(path)


def test_memo_index_bomb_is_refused_before_loading(tmp_path):
    # NONE, LONG_BINPUT 2**31 - 1, STOP: the C unpickler would size its memo table to 16 GB
    path = tmp_path / "memo.pkl"
    path.write_bytes(b"\x80\x02N" + b"r" + struct.pack("<I", 2**31 - 1) + b".")
    with pytest.raises(InputError, match="memo index 2147483647"):
        load_pickle(path)


def test_allow_list_holds_no_callable_that_runs_code():
    names = {f"{m}.{n}" for m, n in ALLOWED_GLOBALS}
    for bad in ("builtins.eval", "builtins.exec", "builtins.getattr", "builtins.open", "builtins.__import__",
                "os.system", "posix.system", "builtins.bytearray", "builtins.type", "builtins.object"):
        assert bad not in names


@requires_womd()
def test_real_pickles_need_only_allowed_globals():
    for path in WOMD_PKL:
        sd = load_pickle(path)
        assert isinstance(sd, dict) and "tracks" in sd


# ----------------------------------------------------------------------------- every command that reads scenes

def test_convert_refuses_crafted_pickle_writes_nothing(crafted, tmp_path):
    path, sentinel = crafted
    out = tmp_path / "OUT"
    proc = run_cli("convert", "-o", str(out), str(path))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"coster-sumo: error: {path}: record 0: refused")
    assert "posix.system" in lines[0]
    assert not out.exists() and not sentinel.exists()


@pytest.mark.slow
@pytest.mark.sumo
def test_no_command_that_reads_scenes_runs_a_crafted_pickle(crafted, tmp_path):
    path, sentinel = crafted
    # a converted scene folder whose scene.npz is the crafted pickle
    folder = tmp_path / "scene"
    scene = synthetic.two_lane_road()
    assert main(["-q", "convert", "-o", str(tmp_path / "conv"), _write_tfrecord(tmp_path, scene)]) == 0
    (tmp_path / "conv" / scene.scenario_id).rename(folder)
    cfg = folder / f"{scene.scenario_id}.sumocfg"
    (folder / "scene.npz").write_bytes(path.read_bytes())
    prior, rollout = REPO / "models" / "prior.pt", REPO / "models" / "rollout.pt"
    commands = {
        "convert": ["convert", "-o", str(tmp_path / "o1"), str(path)],
        "snapshot": ["snapshot", str(path), "-o", str(tmp_path / "o2")],
        "snapshot_npz": ["snapshot", str(folder / "scene.npz"), "-o", str(tmp_path / "o3")],
        "eval_rollout": ["eval", "rollout", "--data", str(path), "--checkpoint", str(rollout),
                         "--json", str(tmp_path / "r.json")],
        "eval_prior": ["eval", "prior", "--data", str(path), "--checkpoint", str(prior),
                       "--json", str(tmp_path / "p.json")],
        "run_pickle": ["run", str(path), "--no-render", "--samples", "2", "-o", str(tmp_path / "o4")],
        "run_folder": ["run", str(cfg), "--no-render", "--samples", "2", "-o", str(tmp_path / "o5")],
        "replay_folder": ["replay", str(cfg), "-o", str(tmp_path / "o6")],
    }
    for name, argv in commands.items():
        proc = run_cli(*argv, cwd=tmp_path)
        assert proc.returncode in (1, 2), (name, proc.returncode, proc.stderr[-500:])
        assert "Traceback" not in proc.stderr, name
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("coster-sumo: error: "), (name, lines)
        assert str(path) in lines[0] or str(folder / "scene.npz") in lines[0], (name, lines)
        assert not sentinel.exists(), name
    for o in ("o1", "o2", "o3", "o4", "o5", "o6", "r.json", "p.json"):
        assert not (tmp_path / o).exists(), o


def _write_tfrecord(tmp_path: Path, scene) -> str:  # type: ignore[no-untyped-def]
    path = tmp_path / f"{scene.scenario_id}.tfrecord"
    write_tfrecord(path, [scene_to_scenario(scene)])
    return str(path)


# ----------------------------------------------------------------------------- validation at the boundary

def _pickle_file(tmp_path: Path, sd: dict, name: str = "sd.pkl") -> Path:
    path = tmp_path / name
    path.write_bytes(pickle.dumps(sd, protocol=4))
    return path


def _refusal(path: Path) -> str:
    with pytest.raises(InputError) as exc:
        read_scenes(path)
    msg = str(exc.value)
    assert msg.startswith(f"{path}") and "\n" not in msg
    return msg


def test_nonfinite_lane_point_names_the_lane(tmp_path):
    scene = synthetic.two_lane_road()
    lanes = scene.road_map.lanes
    values = lanes.centerline.values.copy()
    values[lanes.centerline.offsets[1] + 3, 0] = np.nan
    bad = dataclasses.replace(scene, road_map=dataclasses.replace(
        scene.road_map, lanes=dataclasses.replace(lanes, centerline=Ragged(values, lanes.centerline.offsets))))
    with pytest.raises(InputError):
        bad.validate()
    # through the TFRecord reader (scene_to_scenario writes whatever the scene holds)
    path = tmp_path / "nan_lane.tfrecord"
    write_tfrecord(path, [scene_to_scenario(bad)])
    msg = _refusal(path)
    assert f"record 0: lane {lanes.ids[1]}: polyline point 3" in msg and "GEOS" not in msg
    # through the pickle reader, with +inf
    sd = _description(scene)
    sd["map_features"][str(lanes.ids[0])]["polyline"] = np.asarray(lanes.centerline[0], np.float64).copy()
    sd["map_features"][str(lanes.ids[0])]["polyline"][5, 1] = np.inf
    assert f"lane {lanes.ids[0]}: polyline point 5" in _refusal(_pickle_file(tmp_path, sd))


def test_nonfinite_valid_state_names_track_and_step(tmp_path):
    scene = synthetic.two_lane_road()
    sd = _description(scene)
    tid = next(iter(sd["tracks"]))
    st = sd["tracks"][tid]["state"]
    step = int(np.flatnonzero(st["valid"])[4])
    st["heading"] = st["heading"].copy()
    st["heading"][step] = np.nan
    assert f"track {tid} step {step}: heading is nan" in _refusal(_pickle_file(tmp_path, sd))
    # an invalid state may hold anything
    st["heading"][step] = 0.0
    st["valid"] = st["valid"].copy()
    st["valid"][step] = False
    st["length"] = np.asarray(st["length"], np.float64).copy()
    st["length"][step] = np.inf
    (got,) = read_scenes(_pickle_file(tmp_path, sd, "ok.pkl"))
    assert got.tracks.num_agents == scene.tracks.num_agents


@pytest.mark.parametrize("damage, expected", [
    (lambda sd, t: sd["tracks"][t]["state"].pop("velocity"), "missing key 'velocity'"),
    (lambda sd, t: sd["tracks"][t]["state"].__setitem__("position", sd["tracks"][t]["state"]["position"][:50]),
     "state arrays disagree with the 91 steps"),
    (lambda sd, t: sd["metadata"].__setitem__("ts", sd["metadata"]["ts"][:10]), "metadata.ts has 10 timestamps"),
    (lambda sd, t: sd["tracks"].update({7: sd["tracks"][t], "7": sd["tracks"][t]}), "track 7 appears twice"),
    (lambda sd, t: sd["tracks"].__setitem__("", sd["tracks"][t]), "empty id"),
    (lambda sd, t: sd["map_features"][next(iter(sd["map_features"]))].__setitem__("polyline", np.zeros((0, 3))),
     "the polyline has no points"),
    (lambda sd, t: sd.__setitem__("length", 10**12) or sd["metadata"].pop("ts"), "is not a step count"),
    (lambda sd, t: sd.__setitem__("map_features", [1, 2]), "map_features is a list"),
])
def test_damaged_description_is_named(tmp_path, damage, expected):
    sd = _description(synthetic.two_lane_road())
    damage(sd, next(iter(sd["tracks"])))
    assert expected in _refusal(_pickle_file(tmp_path, sd))


def test_short_womd_track_and_absurd_length_header(tmp_path):
    from coster_sumo.converters import womd_schema

    msg = womd_schema.Scenario.FromString(scene_to_scenario(synthetic.two_lane_road()))
    del msg.tracks[1].states[40:]
    path = tmp_path / "short.tfrecord"
    write_tfrecord(path, [msg.SerializeToString()])
    assert f"track {msg.tracks[1].id}: 40 states for 91 timestamps" in _refusal(path)
    length = struct.pack("<Q", 2**62)
    path.write_bytes(length + struct.pack("<I", masked_crc32c(length)) + b"x" * 20)
    assert "truncated record" in _refusal(path)


def test_damaged_npz_scene_is_one_line(tmp_path):
    path = tmp_path / "scene.npz"
    save_scene(synthetic.merge(), path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="not a scene file"):
        load_scene(path)


# ----------------------------------------------------------------------------- scenario ids as folder names

@pytest.mark.parametrize("sid", ["", ".", "..", "../escaped", "/tmp/x", "a/b", "a\\b", "x\ny", "\x1b[2J", ".hidden",
                                 "A" * 300, "é"])
def test_folder_names_are_safe(sid):
    name = folder_name(sid)
    assert name and name not in (".", "..") and not name.startswith(".")
    assert "/" not in name and "\\" not in name and name.isprintable() and len(name) <= 100
    assert name == folder_name(name)  # a safe name stays as it is


def test_real_ids_are_kept():
    for sid in ("637f20cafde22ff8", "ee519cf571686d19", "two_lane_road", "a-b.c_1"):
        assert folder_name(sid) == sid
    assert folder_name("a/b") != folder_name("a_b")


@pytest.mark.sumo
def test_hostile_ids_convert_into_out_with_the_mapping_recorded(tmp_path):
    sd = _description(synthetic.two_lane_road())
    inputs = []
    for k, sid in enumerate(["", "../escaped", str(tmp_path / "abs"), "A" * 300, "A" * 300]):
        sd["id"] = sd["metadata"]["scenario_id"] = sid
        inputs.append(str(_pickle_file(tmp_path, sd, f"id{k}.pkl")))
    out = tmp_path / "OUT"
    assert main(["-q", "convert", "-o", str(out), *inputs]) == 0
    summary = json.loads((out / "summary.json").read_text())
    folders = [Path(s["folder"]) for s in summary["scenes"]]
    assert len(folders) == 5 and all(f.parent == out and f.is_dir() for f in folders)
    assert len({f.name for f in folders}) == 5 and all(len(f.name) <= 100 for f in folders)
    assert sorted(summary["renamed"].values()) == sorted(["", "../escaped", str(tmp_path / "abs"), "A" * 300,
                                                          "A" * 300])
    assert not (tmp_path / "escaped").exists() and not (tmp_path / "abs").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["OUT", *(f"id{k}.pkl" for k in range(5))])


def test_error_lines_are_one_line():
    assert one_line("a\nb\x1b[31m") == "a\\nb\\x1b[31m"


# ----------------------------------------------------------------------------- tf.Example (the tf_example release)

def _ld(field: int, payload: bytes) -> bytes:
    """A length-delimited protobuf field (lengths < 128 here, so one varint byte each)."""
    assert len(payload) < 128 and field < 16
    return bytes([(field << 3) | 2, len(payload)]) + payload


def womd_tf_example() -> bytes:
    """A tiny ``tf.train.Example`` with WOMD tf_example feature names (Features.feature map entries)."""
    def feature(values: list[float]) -> bytes:  # Feature { float_list = 2 { value = 1 (packed) } }
        return _ld(2, _ld(1, struct.pack(f"<{len(values)}f", *values)))

    entries = b"".join(_ld(1, _ld(1, key.encode()) + _ld(2, feature(vals))) for key, vals in (
        ("roadgraph_samples/xyz", [1.0, 2.0, 0.0]), ("state/current/x", [5.0]),
        ("traffic_light_state/current/state", [4.0])))
    return _ld(1, entries)


def test_womd_tf_example_is_recognised_and_refused(tmp_path):
    record = womd_tf_example()
    assert example_keys(record) == ["roadgraph_samples/xyz", "state/current/x", "traffic_light_state/current/state"]
    assert example_keys(scene_to_scenario(synthetic.four_way_junction())) is None
    path = tmp_path / "training_tfexample.tfrecord-00000"
    write_tfrecord(path, [record])
    msg = _refusal(path)
    assert "WOMD tf.Example" in msg and "Scenario protobuf" in msg
    out = tmp_path / "OUT"
    assert main(["-q", "convert", "-o", str(out), str(path)]) == 2 and not out.exists()


# ----------------------------------------------------------------------------- XML we parse ourselves

LAUGHS = ('<?xml version="1.0"?>\n<!DOCTYPE n [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;">'
          '<!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;">]>\n<net><edge id="&c;"/></net>\n')


def test_net_read_back_refuses_entities(tmp_path):
    from coster_sumo.converters.to_sumo import ConversionError, read_net

    net = tmp_path / "x.net.xml"
    net.write_text(LAUGHS)
    with pytest.raises(ConversionError, match="x.net.xml"):
        read_net(net)


def test_sumolib_net_and_sumocfg_readers_refuse_entities(tmp_path):
    from coster_sumo.batch.simulate import resolve_sources
    from coster_sumo.formats.sumo_net import read_sumolib_net

    net = tmp_path / "bomb.net.xml"
    net.write_text(LAUGHS)
    with pytest.raises(InputError, match="declares an XML entity"):
        read_sumolib_net(net)
    cfg = tmp_path / "bomb.sumocfg"
    cfg.write_text(LAUGHS.replace("<net>", "<configuration>").replace("</net>", "</configuration>"))
    with pytest.raises(InputError, match="bomb.sumocfg"):
        resolve_sources([cfg])


def test_no_module_parses_xml_without_defusedxml():
    """Our own XML reads go through defusedxml (or the entity-refusing check); writers may use ElementTree."""
    import re

    plain = re.compile(r"(?<![A-Za-z])(ET|ElementTree|etree|minidom|expatbuilder)\."
                       r"(parse|fromstring|iterparse|XMLParser)\(")
    offenders = []
    for path in [*REPO.joinpath("coster_sumo").rglob("*.py"), *REPO.joinpath("converters").rglob("*.py")]:
        offenders += [f"{path.relative_to(REPO)}: {m.group(0)}" for m in plain.finditer(path.read_text())]
    assert not offenders


def test_fuzz_memory_check_measures_each_cli_process_alone(tmp_path):
    """The fuzz harness's memory figure is the one process's own peak, not the largest child of the
    whole test session (a training run earlier in the same pytest process once failed every input)."""
    from tests.fuzz import run_measured

    big = "x = bytearray(400 * 2**20); x[::4096] = b'1' * len(x[::4096]); print('ok')"
    rc, out, _, peak_big = run_measured([sys.executable, "-c", big], 60, tmp_path)
    assert (rc, out.strip()) == (0, "ok") and peak_big >= 400
    ballast = bytearray(600 * 2**20)  # this process grows, as the test session does
    ballast[::4096] = b"1" * len(ballast[::4096])
    rc, out, err, peak_small = run_measured([sys.executable, "-c", "import sys; sys.stderr.write('e'); print(input())"],
                                            60, tmp_path, stdin="in\n")
    del ballast
    assert (rc, out.strip(), err) == (0, "in", "e") and peak_small < 100  # not the parent's size
    rc, _, err, _ = run_measured([sys.executable, "-c", "import time; time.sleep(30)"], 0.5, tmp_path)
    assert (rc, err) == (-9, "TIMEOUT")
