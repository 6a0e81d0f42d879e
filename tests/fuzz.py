"""Seeded fuzzing of coster-sumo's input boundary (docs/womd.md, "Hostile inputs").

Library (used by tests/contract/test_fuzz.py) and command line::

    python tests/fuzz.py --count 3000 --seed 0            # 3,000 damaged inputs, report per kind
    python tests/fuzz.py --count 300 --seed 1 --keep DIR  # keep the inputs and outputs in DIR

Every generated input is damaged on purpose and must be refused, or (hostile scenario ids, random
bit flips) may convert but only into a safe place. Inputs are made from the real WOMD samples
(``../shared/data/womd``; cropped so that thousands stay cheap) and the repository's demo network:

- ``tfrecord``: Scenario records mutated at the protobuf level and re-framed with recomputed CRCs
  (non-finite lane points and states, duplicate ids, missing lanes, bad timestamps, short tracks,
  out-of-range indices, truncated payloads, random payloads, WOMD tf.Example records), and file-level
  damage (truncation, bad CRCs, absurd length headers, random bytes, broken gzip);
- ``pickle``: ScenarioNet pickles with missing keys, wrong types, truncated arrays, NaN/Inf,
  truncated or bit-flipped streams, memory bombs through allowed names (a huge memo index,
  ``bytes(10**10)``, ``numpy.ndarray((10**10,))``, ``str(b, codec)``);
- ``crafted``: pickles whose globals would run code (``os.system``, ``exec``, ``open``,
  ``__import__``, ...) trying to create a sentinel file, alone or hidden inside a real scenario;
- ``hostile_id``: scenes whose scenario id is empty, a path, ``..``, or holds control characters;
- ``sumo_xml``: sumocfg / net / route files truncated, random, missing, or declaring entities
  (billion laughs, external entities).

Scene inputs go to ``coster-sumo convert`` in batches (one good input among them); XML inputs to
``coster-sumo replay`` through a small driver process that calls the CLI's ``main`` once per input.
Checked for every input: exit code, no traceback, exactly one error line naming the file (refused
inputs), no output folder for it, no temporary leftovers, the sentinel never created, no file
outside the output folder, the good input of the batch converted, and no CLI process above
:data:`MEMORY_LIMIT_MB` of resident memory.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import gzip
import json
import math
import os
import pickle
import random
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
WOMD_DIR = REPO.parent / "shared" / "data" / "womd"
DEMO_NET = REPO / "networks" / "intersection"
SENTINEL = "PWNED"  # crafted pickles try to create this file in the batch folder
MEMORY_LIMIT_MB = 1500  # [MB] peak resident memory allowed to one CLI process on these small inputs

# share of each input kind in a run
KIND_WEIGHTS = {"tfrecord": 0.36, "pickle": 0.30, "crafted": 0.14, "hostile_id": 0.05, "sumo_xml": 0.15}


@dataclasses.dataclass
class FuzzInput:
    """One generated input. ``expect``: "refused", "safe" (converts into a safe folder) or "any"."""

    kind: str
    mutation: str
    path: Path
    expect: str
    scenario_id: str | None = None  # for "safe": the id the scene carries
    names: Path | None = None  # for sumo_xml: the file the error line must name
    must_say: str | None = None  # the error line must contain this
    must_not_say: str | None = None  # ... and must not contain this


@dataclasses.dataclass
class Outcome:
    """What went wrong with one input (empty ``problems``: fine)."""

    input: FuzzInput
    exit_code: int
    problems: list[str]
    error_lines: int
    peak_mb: int = 0  # peak resident memory of the CLI process that handled the input


# ----------------------------------------------------------------------------- bases (cropped real data)

def _python() -> str:
    return sys.executable


def crop_scenario(data: bytes, tracks: int = 24, features: int = 70) -> bytes:
    """A real Scenario record cut down to its first ``features`` map features and ``tracks`` tracks."""
    from coster_sumo.converters import womd_schema

    msg = womd_schema.Scenario.FromString(data)
    sdc = msg.sdc_track_index if msg.HasField("sdc_track_index") else 0
    keep = sorted({*range(min(tracks, len(msg.tracks))), sdc})
    kept_tracks = [msg.tracks[i] for i in keep]
    del msg.tracks[:]
    msg.tracks.extend(kept_tracks)
    msg.sdc_track_index = keep.index(sdc)
    del msg.tracks_to_predict[:]
    lanes = [f for f in msg.map_features if f.WhichOneof("feature_data") == "lane"][:features]
    rest = [f for f in msg.map_features if f.WhichOneof("feature_data") != "lane"][:features // 2]
    del msg.map_features[:]
    msg.map_features.extend(lanes + rest)
    ids = {f.id for f in lanes}
    for dms in msg.dynamic_map_states:
        states = [s for s in dms.lane_states if s.lane in ids]
        del dms.lane_states[:]
        dms.lane_states.extend(states)
    return bytes(msg.SerializeToString())


def crop_description(sd: dict, tracks: int = 24, features: int = 70) -> dict:
    """A real ScenarioNet description cut down like :func:`crop_scenario`."""
    sd = dict(sd)
    md = dict(sd["metadata"])
    sdc = str(md.get("sdc_id"))
    keys = list(sd["tracks"])[:tracks]
    if sdc in sd["tracks"] and sdc not in keys:
        keys.append(sdc)
    sd["tracks"] = {k: sd["tracks"][k] for k in keys}
    feats = sd["map_features"]
    lanes = [k for k, f in feats.items() if str(f.get("type", "")).startswith("LANE_")][:features]
    rest = [k for k, f in feats.items() if not str(f.get("type", "")).startswith("LANE_")][:features // 2]
    sd["map_features"] = {k: feats[k] for k in lanes + rest}
    lane_ids = {int(k) for k in lanes}
    sd["dynamic_map_states"] = {k: v for k, v in (sd.get("dynamic_map_states") or {}).items()
                                if int(v.get("lane", k)) in lane_ids}
    md["tracks_to_predict"] = {}
    sd["metadata"] = md
    return sd


@dataclasses.dataclass
class Bases:
    """Cropped real inputs the mutations start from."""

    scenarios: list[bytes]  # serialized Scenario records
    descriptions: list[dict]  # ScenarioNet descriptions

    @classmethod
    def load(cls, womd_dir: Path = WOMD_DIR) -> Bases:
        from coster_sumo.converters.scenarionet import load_pickle
        from coster_sumo.converters.tfrecord import read_tfrecord

        scen = [crop_scenario(r) for p in sorted((womd_dir / "scenario_proto").glob("*.tfrecord"))
                for r in read_tfrecord(p)[:1]]
        descs = [crop_description(load_pickle(p)) for p in sorted((womd_dir / "scenarionet_pkl").glob("*.pkl"))]
        if not scen or not descs:
            raise SystemExit(f"fuzz: real WOMD samples not found under {womd_dir}")
        return cls(scen, descs)


# ----------------------------------------------------------------------------- TFRecord mutations

def _frame(records: list[bytes]) -> bytes:
    from coster_sumo.converters.tfrecord import encode_record

    return b"".join(encode_record(r) for r in records)


def _tf_example(rng: random.Random, womd: bool) -> bytes:
    """A serialized tf.train.Example with a few features (hand-written wire format)."""
    def ld(field: int, payload: bytes) -> bytes:
        return _varint((field << 3) | 2) + _varint(len(payload)) + payload

    names = (["roadgraph_samples/xyz", "state/current/x", "traffic_light_state/current/state", "scenario/id"]
             if womd else ["image/encoded", "label"])
    entries = b""
    for name in names:
        floats = struct.pack(f"<{4}f", *(rng.uniform(-100, 100) for _ in range(4)))
        feature = ld(2, ld(1, floats))  # Feature.float_list = 2 { value = 1 packed }
        entries += ld(1, ld(1, name.encode()) + ld(2, feature))
    return ld(1, entries)


def _varint(v: int) -> bytes:
    out = bytearray()
    while True:
        b = v & 0x7F
        v >>= 7
        out.append(b | (0x80 if v else 0))
        if not v:
            return bytes(out)


_NONFINITE = (float("nan"), float("inf"), float("-inf"))


def tfrecord_mutation(rng: random.Random, base: bytes) -> tuple[str, bytes, str]:
    """(mutation name, file bytes, expect) for one damaged TFRecord."""
    from coster_sumo.converters import womd_schema

    msg = womd_schema.Scenario.FromString(base)
    lanes = [f for f in msg.map_features if f.WhichOneof("feature_data") == "lane"]
    name = rng.choice(["lane_nonfinite", "state_nonfinite", "dup_track", "dup_lane", "no_lanes", "timestamps",
                       "short_track", "sdc_range", "empty_lane", "cut_payload", "random_payload", "tf_example",
                       "womd_tf_example", "file_cut", "length_crc", "data_crc", "absurd_length", "random_file",
                       "empty_file", "gzip_cut", "no_vehicle", "stop_nonfinite"])
    if name == "lane_nonfinite":
        pt = rng.choice(lanes).lane.polyline
        p = pt[rng.randrange(len(pt))]
        setattr(p, rng.choice("xyz"), rng.choice(_NONFINITE))
    elif name == "state_nonfinite":
        tr = rng.choice([t for t in msg.tracks if any(s.valid for s in t.states)])
        st = rng.choice([s for s in tr.states if s.valid])
        setattr(st, rng.choice(["center_x", "center_y", "heading", "length", "width", "velocity_x", "velocity_y"]),
                rng.choice(_NONFINITE))
    elif name == "dup_track":
        a, b = rng.sample(range(len(msg.tracks)), 2)
        msg.tracks[b].id = msg.tracks[a].id
    elif name == "dup_lane":
        a, b = rng.sample(range(len(lanes)), 2)
        lanes[b].id = lanes[a].id
    elif name == "no_lanes":
        keep = [f for f in msg.map_features if f.WhichOneof("feature_data") != "lane"]
        del msg.map_features[:]
        msg.map_features.extend(keep)
    elif name == "timestamps":
        k = rng.randrange(1, len(msg.timestamps_seconds))
        msg.timestamps_seconds[k] = rng.choice([msg.timestamps_seconds[k - 1], *_NONFINITE, -1.0])
    elif name == "short_track":
        tr = rng.choice(list(msg.tracks))
        del tr.states[rng.randrange(len(tr.states)):]
    elif name == "sdc_range":
        msg.sdc_track_index = len(msg.tracks) + rng.randrange(1, 1000)
    elif name == "empty_lane":
        del rng.choice(lanes).lane.polyline[:]
    elif name == "no_vehicle":
        for t in msg.tracks:
            t.object_type = 2
    elif name == "stop_nonfinite":
        dms = [d for d in msg.dynamic_map_states if len(d.lane_states)]
        if not dms:
            return tfrecord_mutation(rng, base)
        ls = rng.choice(dms).lane_states[0]
        setattr(ls.stop_point, rng.choice("xy"), rng.choice(_NONFINITE))
    elif name in ("cut_payload", "random_payload"):
        for _ in range(50):
            data = (base[:rng.randrange(1, len(base) - 1)] if name == "cut_payload"
                    else rng.randbytes(rng.randrange(1, 4000)))
            try:
                womd_schema.Scenario.FromString(data)
            except Exception:  # noqa: BLE001 - any parse failure is the damage we want
                return name, _frame([data]), "refused"
        return name, _frame([b"\xff" * 7]), "refused"
    elif name in ("tf_example", "womd_tf_example"):
        return name, _frame([_tf_example(rng, name == "womd_tf_example")]), "refused"
    else:
        framed = _frame([base])
        if name == "file_cut":
            return name, framed[:rng.randrange(1, len(framed) - 1)], "refused"
        if name == "length_crc":
            return name, framed[:8] + bytes([framed[8] ^ 0xFF]) + framed[9:], "refused"
        if name == "data_crc":
            k = rng.randrange(12, len(framed) - 4)
            return name, framed[:k] + bytes([framed[k] ^ (1 << rng.randrange(8))]) + framed[k + 1:], "refused"
        if name == "absurd_length":
            from coster_sumo.converters.tfrecord import masked_crc32c

            length = struct.pack("<Q", rng.choice([2**63 - 1, 2**40, 2**32 + 7, len(base) + 10**6]))
            return name, length + struct.pack("<I", masked_crc32c(length)) + framed[12:], "refused"
        if name == "random_file":
            data = rng.randbytes(rng.randrange(1, 5000))
            return name, (b"\x00" + data if data[:1] in (b"\x80", b"\x1f", b"P") else data), "refused"
        if name == "empty_file":
            return name, b"", "refused"
        if name == "gzip_cut":
            gz = gzip.compress(framed, mtime=0)
            return name, gz[:rng.randrange(2, len(gz) - 8)], "refused"
    return name, _frame([bytes(msg.SerializeToString())]), "refused"


# ----------------------------------------------------------------------------- pickle mutations

def _deep(sd: dict) -> dict:
    """A copy whose containers and arrays can be changed without touching the base."""
    def cp(o: Any) -> Any:
        if isinstance(o, dict):
            return {k: cp(v) for k, v in o.items()}
        if isinstance(o, list):
            return [cp(v) for v in o]
        if isinstance(o, np.ndarray):
            return o.copy()
        return o
    return cp(sd)


def pickle_mutation(rng: random.Random, base: dict) -> tuple[str, bytes, str]:
    """(mutation name, file bytes, expect) for one damaged ScenarioNet pickle."""
    sd = _deep(base)
    tracks = sd["tracks"]
    tid = rng.choice(list(tracks))
    st = tracks[tid]["state"]
    lanes = [k for k, f in sd["map_features"].items() if str(f.get("type", "")).startswith("LANE_")
             and len(np.atleast_2d(f["polyline"])) >= 2]
    name = rng.choice(["missing_top", "missing_state", "missing_polyline", "truncated_array", "ts_length",
                       "state_nonfinite", "lane_nonfinite", "line_nonfinite", "wrong_type", "tracks_list",
                       "length_absurd", "dup_track", "signal_length", "stream_cut", "not_a_dict", "no_lanes",
                       "bitflip", "protocol0", "empty_lane", "memo_bomb", "bytes_bomb", "ndarray_bomb",
                       "str_codec"])
    expect = "refused"
    if name == "memo_bomb":  # LONG_BINPUT with a huge index: the C unpickler would size its memo to it
        import pickletools

        data = pickle.dumps(sd, protocol=2)
        k = rng.choice([pos for _, _, pos in pickletools.genops(data)][1:-1])  # an opcode boundary
        return name, data[:k] + b"N" + b"r" + struct.pack("<I", rng.choice([2**31 - 1, 2**28, 2**32 - 1])) + \
            b"0" + data[k:], expect
    if name in ("bytes_bomb", "ndarray_bomb", "str_codec"):  # allowed names, called to exhaust memory
        call = {"bytes_bomb": _Call("builtins", "bytes", (rng.choice([10**10, 2**40]),)),
                "ndarray_bomb": _Call("numpy", "ndarray", ((rng.choice([10**10, 2**36]),),)),
                "str_codec": _Call("builtins", "str", (b"x", rng.choice(["rot13", "idna", "utf-7"])))}[name]
        sd["metadata"]["dataset"] = call
        return name, pickle.dumps(sd, protocol=rng.choice([2, 3, 4])), expect
    if name == "missing_top":
        del sd[rng.choice(["tracks", "map_features"])]
    elif name == "missing_state":
        del st[rng.choice(["valid", "position", "velocity", "heading", "length", "width"])]
    elif name == "missing_polyline":
        del sd["map_features"][rng.choice(lanes)]["polyline"]
    elif name == "truncated_array":
        key = rng.choice(["valid", "position", "velocity", "heading", "length", "width"])
        st[key] = st[key][:rng.randrange(0, len(st[key]))]
    elif name == "ts_length":
        sd["metadata"]["ts"] = sd["metadata"]["ts"][:rng.randrange(1, len(sd["metadata"]["ts"]))]
    elif name == "state_nonfinite":
        tid = rng.choice([k for k, t in tracks.items() if np.any(t["state"]["valid"])])
        st = tracks[tid]["state"]
        step = rng.choice(np.flatnonzero(st["valid"]).tolist())
        key = rng.choice(["position", "velocity", "heading", "length", "width"])
        arr = np.asarray(st[key], np.float64).copy()
        if arr.ndim == 2:
            arr[step, rng.randrange(2)] = rng.choice(_NONFINITE)
        else:
            arr[step] = rng.choice(_NONFINITE)
        st[key] = arr
    elif name == "lane_nonfinite":
        f = sd["map_features"][rng.choice(lanes)]
        poly = np.asarray(f["polyline"], np.float64).copy()
        poly[rng.randrange(len(poly)), rng.randrange(poly.shape[1])] = rng.choice(_NONFINITE)
        f["polyline"] = poly
    elif name == "line_nonfinite":
        lines = [k for k, f in sd["map_features"].items() if "polyline" in f and not str(f["type"]).startswith("LANE_")
                 and f["polyline"] is not None and len(np.atleast_2d(f["polyline"]))]
        if not lines:
            return pickle_mutation(rng, base)
        f = sd["map_features"][rng.choice(lines)]
        poly = np.atleast_2d(np.asarray(f["polyline"], np.float64)).copy()
        poly[rng.randrange(len(poly)), 0] = rng.choice(_NONFINITE)
        f["polyline"] = poly
    elif name == "wrong_type":
        st[rng.choice(["position", "valid", "heading"])] = rng.choice(["oops", {"a": 1}, None, 3.5])
    elif name == "tracks_list":
        sd["tracks"] = list(tracks.values())
    elif name == "length_absurd":
        sd["length"] = rng.choice([10**12, -5, 2**62])
        sd["metadata"].pop("ts", None)
    elif name == "dup_track":
        sd["tracks"] = {**tracks, int(tid) if tid.isdigit() else tid + " ": tracks[tid]}
        if not tid.isdigit():
            return pickle_mutation(rng, base)
    elif name == "signal_length":
        dms = sd.get("dynamic_map_states") or {}
        if not dms:
            return pickle_mutation(rng, base)
        item = dms[rng.choice(list(dms))]
        item["state"]["object_state"] = ["LANE_STATE_GO"] * rng.randrange(1, len(item["state"]["object_state"]))
    elif name == "no_lanes":
        sd["map_features"] = {k: f for k, f in sd["map_features"].items()
                              if not str(f.get("type", "")).startswith("LANE_")}
    elif name == "empty_lane":
        sd["map_features"][rng.choice(lanes)]["polyline"] = np.zeros((0, 3), np.float32)
    elif name == "not_a_dict":
        return name, pickle.dumps(rng.choice([[1, 2, 3], "scenario", 42, None]), protocol=4), expect
    data = pickle.dumps(sd, protocol=rng.choice([2, 3, 4, 5]))
    if name == "stream_cut":
        return name, data[:rng.randrange(1, len(data) - 1)], expect
    if name == "bitflip":  # may still load and convert: then it must convert cleanly
        buf = bytearray(data)
        for _ in range(rng.randrange(1, 8)):
            k = rng.randrange(2, len(buf))
            buf[k] ^= 1 << rng.randrange(8)
        return name, bytes(buf), "any"
    if name == "protocol0":  # text protocol: does not start with PROTO, must not be unpickled at all
        return name, pickle.dumps(sd["metadata"], protocol=0), expect
    return name, data, expect


# ----------------------------------------------------------------------------- crafted pickles

class _Call:
    """Pickles as ``func(*args)``: what a malicious file does (module and name chosen freely)."""

    def __init__(self, module: str, name: str, args: tuple) -> None:
        self.module, self.name, self.args = module, name, args

    def __reduce__(self) -> tuple:
        return (_global(self.module, self.name), self.args)


def _global(module: str, name: str) -> Callable[..., Any]:
    import importlib

    obj: Any = importlib.import_module(module)
    for part in name.split("."):
        obj = getattr(obj, part)
    return obj  # type: ignore[no-any-return]


def crafted_pickle(rng: random.Random, base: dict, sentinel: Path) -> tuple[str, bytes, str]:
    """A pickle whose globals would create ``sentinel`` (or import a module) when loaded."""
    s = str(sentinel)
    payloads = {
        "os_system": ("os", "system", (f"touch {s}",)),
        "posix_system": ("posix", "system", (f"touch {s}",)),
        "exec": ("builtins", "exec", (f"open({s!r}, 'w').close()",)),
        "eval": ("builtins", "eval", (f"open({s!r}, 'w')",)),
        "open": ("builtins", "open", (s, "w")),
        "subprocess": ("subprocess", "call", (["touch", s],)),
        "import_module": ("importlib", "import_module", ("antigravity",)),
        "dunder_import": ("builtins", "__import__", ("this",)),
        "getattr": ("builtins", "getattr", (_Call("builtins", "__import__", ("os",)), "system")),
        "pathlib_touch": ("pathlib", "Path", (s,)),
        "numpy_load": ("numpy", "load", (s,)),
        "numpy_save": ("numpy", "save", (s, np.zeros(1))),
    }
    name = rng.choice(sorted(payloads))
    call = _Call(*payloads[name])
    where = rng.choice(["alone", "track", "metadata", "feature"])
    if where == "alone":
        obj: Any = call
    else:
        obj = _deep(base)
        if where == "track":
            obj["tracks"][rng.choice(list(obj["tracks"]))]["metadata"] = {"note": call}
        elif where == "metadata":
            obj["metadata"]["dataset"] = call
        else:
            obj["map_features"][rng.choice(list(obj["map_features"]))]["extra"] = [call]
    proto = rng.choice([2, 3, 4, 5])
    return f"{name}@{where}", pickle.dumps(obj, protocol=proto), "refused"


# ----------------------------------------------------------------------------- hostile scenario ids

def hostile_id(rng: random.Random, workdir: Path) -> str:
    return rng.choice([
        "", ".", "..", "../escaped", "../../escaped", str(workdir / "abs-escape"), "a/b/c", "a\\b", "x\ny",
        "\x1b[31mred\x1b[0m", "tab\there", "nul\x00byte", ".hidden", "-dash", "é/ü", "con", "A" * 400,
        " spaced ", "~", "$HOME", "`id`", "semi;colon",
    ])


def hostile_id_input(rng: random.Random, bases: Bases, workdir: Path) -> tuple[str, bytes, str, str]:
    """(mutation, file bytes, expect, scenario id): a good scene carrying a hostile id."""
    from coster_sumo.converters import womd_schema

    sid = hostile_id(rng, workdir)
    if rng.random() < 0.5:
        msg = womd_schema.Scenario.FromString(rng.choice(bases.scenarios))
        msg.scenario_id = sid.replace("\x00", "")  # protobuf strings hold no NUL in practice
        return "tfrecord_id", _frame([bytes(msg.SerializeToString())]), "safe", msg.scenario_id
    sd = _deep(rng.choice(bases.descriptions))
    sd["metadata"]["scenario_id"] = sid
    sd["id"] = sid
    return "pickle_id", pickle.dumps(sd, protocol=rng.choice([2, 3, 4, 5])), "safe", sid


# ----------------------------------------------------------------------------- SUMO XML inputs

BILLION_LAUGHS = """<?xml version="1.0"?>
<!DOCTYPE lolz [
 <!ENTITY lol "lol">
 <!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
 <!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">
 <!ENTITY lol4 "&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;">
 <!ENTITY lol5 "&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;">
 <!ENTITY lol6 "&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;">
 <!ENTITY lol7 "&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;">
 <!ENTITY lol8 "&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;">
 <!ENTITY lol9 "&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;">
]>
"""


def sumo_xml_input(rng: random.Random, folder: Path) -> tuple[str, Path, Path]:
    """Copy the demo network into ``folder`` and damage one file; (mutation, config, damaged file)."""
    folder.mkdir(parents=True)
    for f in DEMO_NET.iterdir():
        if f.suffix in (".sumocfg", ".xml") and not f.name.endswith((".nod.xml", ".edg.xml", ".con.xml")):
            shutil.copy(f, folder / f.name)
    cfg = folder / "intersection.sumocfg"
    target = rng.choice([cfg, folder / "intersection.net.xml", folder / "intersection.rou.xml"])
    text = target.read_text()
    name = rng.choice(["cut", "random", "laughs", "external_entity", "missing", "empty", "dtd", "not_utf8",
                       "unclosed", "gzip_cut"])
    if name == "cut":
        end = text.rfind("</")
        target.write_text(text[:rng.randrange(1, end)])
    elif name == "random":
        target.write_bytes(b"<" + rng.randbytes(rng.randrange(1, 2000)))
    elif name == "laughs":
        root = text[text.index("<", text.index("?>") + 2 if "?>" in text else 0):]
        target.write_text(BILLION_LAUGHS + root.replace(">", ">&lol9;", 1))
    elif name == "external_entity":
        root = text[text.index("<", text.index("?>") + 2 if "?>" in text else 0):]
        target.write_text('<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY xxe SYSTEM "file:///etc/passwd">]>\n'
                          + root.replace(">", ">&xxe;", 1))
    elif name == "missing":
        target.unlink()
    elif name == "empty":
        target.write_text("")
    elif name == "dtd":
        root = text[text.index("<", text.index("?>") + 2 if "?>" in text else 0):]
        target.write_text('<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY a "b">]>\n' + root)
    elif name == "not_utf8":
        target.write_bytes(text.encode()[:200] + b"\xff\xfe\x00<" + text.encode()[200:])
    elif name == "unclosed":
        target.write_text(text.replace("</", "<", 1))
    elif name == "gzip_cut":
        gz = gzip.compress(text.encode(), mtime=0)
        target.write_bytes(gz[:rng.randrange(2, len(gz) - 8)])
    return f"{target.suffix.lstrip('.') if target != cfg else 'sumocfg'}:{name}", cfg, target


# ----------------------------------------------------------------------------- running and checking

def _env() -> dict[str, str]:
    """The CLI's environment; ``FUZZ_CLI_PYTHONPATH`` runs another checkout's CLI against the inputs."""
    env = dict(os.environ)
    if os.environ.get("FUZZ_CLI_PYTHONPATH"):
        env["PYTHONPATH"] = os.environ["FUZZ_CLI_PYTHONPATH"]
    env["PYTHONWARNINGS"] = "ignore"
    env.pop("COSTER_DEBUG", None)
    return env


def _tree(folder: Path, skip: Path) -> set[str]:
    out = set()
    for root, dirs, files in os.walk(folder):
        if Path(root) == skip or skip in Path(root).parents:
            dirs[:] = []
            continue
        for d in dirs:
            if Path(root, d) != skip:
                out.add(str(Path(root, d)))
        for f in files:
            out.add(str(Path(root, f)))
    return out


def run_convert_batch(batch: list[FuzzInput], good: Path, workdir: Path, timeout: float = 600
                      ) -> list[Outcome]:
    """One ``coster-sumo convert`` over ``batch`` + ``good``; per-input checks."""
    from coster_sumo.formats.scene_folder import folder_name

    out = workdir / "OUT"
    before = _tree(workdir, out)
    paths = [i.path for i in batch]
    pos = len(paths) // 2
    argv = [_python(), "-m", "coster_sumo", "-q", "convert", "-o", str(out),
            *map(str, paths[:pos]), str(good), *map(str, paths[pos:])]
    rc, _, stderr, peak = run_measured(argv, timeout, workdir)
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    after = _tree(workdir, out)
    created = sorted(after - before)
    summary: dict = {}
    if (out / "summary.json").is_file():
        summary = json.loads((out / "summary.json").read_text())
    converted = {s["input"]: s for s in summary.get("scenes", [])}
    listed = {Path(s["folder"]).name for s in summary.get("scenes", [])}
    # the scene folders; summary.json and the marker that says coster-sumo wrote the folder are not scenes
    present = {p.name for p in out.iterdir()} - {"summary.json", ".coster-sumo.json"} if out.is_dir() else set()
    batch_problems = []
    if "Traceback" in stderr or rc < 0:
        batch_problems.append(f"traceback or crash (rc {rc})")
    stray = [ln for ln in lines if not ln.startswith("coster-sumo: error: ")]
    if stray:
        batch_problems.append(f"stray stderr: {stray[0][:120]}")
    if rc not in (0, 1):
        batch_problems.append(f"exit {rc} for a batch with a good input")
    if str(good) not in converted:
        batch_problems.append("the good input of the batch was not converted")
    if present != listed:
        batch_problems.append(f"output folders not in summary.json: {sorted(present ^ listed)[:3]}")
    if created:
        batch_problems.append(f"files created outside OUT: {created[:3]}")
    if peak > MEMORY_LIMIT_MB:
        batch_problems.append(f"memory: the CLI process peaked at {peak} MB")
    outcomes = []
    for inp in batch:
        problems = list(batch_problems)
        mine = [ln for ln in lines if ln.startswith(f"coster-sumo: error: {inp.path}:")]
        if inp.expect == "refused":
            if len(mine) != 1:
                problems.append(f"{len(mine)} error lines naming the file")
            elif inp.must_say is not None and inp.must_say not in mine[0]:
                problems.append(f"error line does not say {inp.must_say!r}: {mine[0][:160]}")
            elif inp.must_not_say is not None and inp.must_not_say in mine[0]:
                problems.append(f"error line says {inp.must_not_say!r}: {mine[0][:160]}")
            if str(inp.path) in converted:
                problems.append("converted although damaged")
            if rc != 1:
                problems.append(f"batch exit {rc}, expected 1")
        elif inp.expect == "safe":
            s = converted.get(str(inp.path))
            if s is None:
                problems.append(f"hostile id not converted: {mine[:1]}")
            else:
                folder = Path(s["folder"])
                if folder.parent != out or folder_name(folder.name) != folder.name:  # a safe name, in OUT
                    problems.append(f"unsafe folder {folder}")
                if folder.name != inp.scenario_id and summary.get("renamed", {}).get(folder.name) != inp.scenario_id:
                    problems.append("renaming not recorded in summary.json")
        else:  # any: refused with one line, or converted
            if str(inp.path) not in converted and len(mine) != 1:
                problems.append(f"neither converted nor one error line ({len(mine)})")
        outcomes.append(Outcome(inp, rc, problems, len(mine), peak))
    return outcomes


LAUNCHER = r"""
import os, resource, signal, subprocess, sys
rc = subprocess.call(sys.argv[2:])
with open(sys.argv[1], "w") as f:
    f.write(str(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss))
if rc < 0:
    signal.signal(-rc, signal.SIG_DFL)
    os.kill(os.getpid(), -rc)
sys.exit(rc)
"""


def run_measured(argv: list[str], timeout: float, cwd: Path, stdin: str | None = None
                 ) -> tuple[int, str, str, int]:
    """Run ``argv``; return exit code (-9 after ``timeout``), stdout, stderr and its own peak RSS [MB].

    A process's peak resident memory on Linux includes the memory of the process it was forked
    from, up to its ``exec``: measured straight from the test session (over 1 GB once torch is
    loaded and models were trained), every CLI process looked that large. So a small launcher
    process starts the command and reports the peak of that one child.
    """
    fd, peak_file = tempfile.mkstemp(prefix="coster-fuzz-peak-")
    os.close(fd)
    proc = subprocess.Popen([_python(), "-c", LAUNCHER, peak_file, *argv],
                            stdin=subprocess.PIPE if stdin is not None else subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, errors="replace",
                            env=_env(), cwd=cwd, start_new_session=True)
    try:
        out, err = proc.communicate(stdin, timeout=timeout)
        rc = proc.returncode
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, 9)  # the launcher and the command under it
        proc.communicate()
        rc, out, err = -9, "", "TIMEOUT"
    try:
        peak = int(Path(peak_file).read_text() or 0) // 1024
    finally:
        os.unlink(peak_file)
    return rc, out, err, peak


DRIVER = r"""
import contextlib, io, json, sys, traceback
from coster_sumo.cli.command_line import main
results = []
for argv in json.loads(sys.stdin.read()):
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            rc = main(argv)
        except SystemExit as exc:
            rc = exc.code if isinstance(exc.code, int) else 2
        except BaseException:
            traceback.print_exc()
            rc = -1
    results.append({"rc": rc, "stderr": err.getvalue()})
print(json.dumps(results))
"""


def run_replay_batch(batch: list[FuzzInput], workdir: Path, timeout: float = 600) -> list[Outcome]:
    """``coster-sumo replay`` on each damaged configuration (one driver process calling the CLI's main)."""
    argvs = [["-q", "replay", str(i.path), "-o", str(i.path.parent / "replay-out")] for i in batch]
    rc, stdout, stderr, peak = run_measured([_python(), "-c", DRIVER], timeout, workdir, json.dumps(argvs))
    try:
        results = json.loads(stdout.strip().splitlines()[-1]) if rc == 0 else None
        crash = "" if results is not None else stderr[-300:]
    except (json.JSONDecodeError, IndexError) as exc:
        results, crash = None, str(exc)
    outcomes = []
    for k, inp in enumerate(batch):
        if results is None:
            outcomes.append(Outcome(inp, -1, [f"driver crashed: {crash}"], 0))
            continue
        rc, err = results[k]["rc"], results[k]["stderr"]
        lines = [ln for ln in err.splitlines() if ln.strip()]
        problems = []
        if "Traceback" in err or rc == -1:
            problems.append("traceback")
        if rc not in (1, 2):
            problems.append(f"exit {rc}")
        named = [ln for ln in lines if ln.startswith("coster-sumo: error: ") and inp.names is not None
                 and str(inp.names) in ln]
        if len(lines) != 1 or len(named) != 1:
            problems.append(f"expected one error line naming {inp.names}, got {lines[:2]}")
        if (inp.path.parent / "replay-out").exists() or (inp.path.parent / "replay").exists():
            problems.append("output written")
        if peak > MEMORY_LIMIT_MB:
            problems.append(f"memory: the replay driver process peaked at {peak} MB")
        outcomes.append(Outcome(inp, rc, problems, len(named), peak))
    return outcomes


def run_solo(inp: FuzzInput, workdir: Path) -> list[str]:
    """One damaged scene alone: exit 1 or 2; with 2 nothing is written, with 1 only summary.json."""
    out = workdir / "SOLO"
    proc = subprocess.run([_python(), "-m", "coster_sumo", "-q", "convert", "-o", str(out), str(inp.path)],
                          capture_output=True, text=True, errors="replace", env=_env(), cwd=workdir)
    problems = []
    if proc.returncode not in (1, 2) or "Traceback" in proc.stderr:
        problems.append(f"solo: exit {proc.returncode}")
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    if len(lines) != 1 or not lines[0].startswith(f"coster-sumo: error: {inp.path}:"):
        problems.append(f"solo: expected one error line, got {lines[:2]}")
    left = sorted(p.name for p in out.iterdir()) if out.exists() else []
    if (proc.returncode == 2 and out.exists()) or (proc.returncode == 1 and left != ["summary.json"]):
        problems.append(f"solo: output left behind: {left}")
    shutil.rmtree(out, ignore_errors=True)
    return problems


def fuzz(count: int, seed: int, workdir: Path, batch_size: int = 40, solo_every: int = 25,
         bases: Bases | None = None, log: Callable[[str], None] | None = None) -> list[Outcome]:
    """Generate ``count`` damaged inputs (seeded), run them through the CLI, return every outcome."""
    rng = random.Random(seed)
    bases = bases or Bases.load()
    kinds = list(KIND_WEIGHTS)
    weights = [KIND_WEIGHTS[k] for k in kinds]
    plan = [rng.choices(kinds, weights)[0] for _ in range(count)]
    scene_kinds = [k for k in plan if k != "sumo_xml"]
    xml_count = count - len(scene_kinds)
    outcomes: list[Outcome] = []
    workdir.mkdir(parents=True, exist_ok=True)
    good_dir = workdir / "good"
    good_dir.mkdir(exist_ok=True)
    good = good_dir / "good.tfrecord"
    good.write_bytes(_frame([bases.scenarios[0]]))
    n_batches = math.ceil(len(scene_kinds) / batch_size)
    t0 = time.perf_counter()
    for b in range(n_batches):
        bdir = workdir / f"batch{b:04d}"
        (bdir / "in").mkdir(parents=True)
        sentinel = bdir / SENTINEL
        batch = []
        for j, kind in enumerate(scene_kinds[b * batch_size:(b + 1) * batch_size]):
            sid = None
            if kind == "tfrecord":
                mutation, data, expect = tfrecord_mutation(rng, rng.choice(bases.scenarios))
            elif kind == "pickle":
                mutation, data, expect = pickle_mutation(rng, rng.choice(bases.descriptions))
            elif kind == "crafted":
                mutation, data, expect = crafted_pickle(rng, rng.choice(bases.descriptions), sentinel)
            else:
                mutation, data, expect, sid = hostile_id_input(rng, bases, bdir)
            suffix = "pkl" if data[:1] == b"\x80" else "tfrecord"
            path = bdir / "in" / f"{j:03d}_{kind}.{suffix}"
            path.write_bytes(data)
            refusal = "asks for the global"  # the restricted unpickler's refusal
            batch.append(FuzzInput(kind, mutation, path, expect, scenario_id=sid,
                                   must_say=refusal if kind == "crafted" else None,
                                   must_not_say=refusal if kind == "pickle" and mutation != "bitflip" else None))
        res = run_convert_batch(batch, good, bdir)
        if sentinel.exists():
            for o in res:
                if o.input.kind == "crafted":
                    o.problems.append("sentinel file created")
        for k, o in enumerate(res):
            if o.input.expect == "refused" and (b * batch_size + k) % solo_every == 0:
                o.problems += run_solo(o.input, bdir)
        outcomes += res
        if log:
            bad = sum(bool(o.problems) for o in res)
            log(f"batch {b + 1}/{n_batches}: {len(res)} scene inputs, {bad} bad, {time.perf_counter() - t0:.0f} s, "
                f"peak RSS: CLI {max(o.peak_mb for o in res)} MB, harness {_peak_mb()} MB")
        escaped = sorted(p.name for p in workdir.iterdir() if p.name not in ("good", "xml")
                         and not p.name.startswith("batch"))
        if escaped:
            for o in res:
                o.problems.append(f"files created outside OUT: {escaped[:3]}")
        if not any(o.problems for o in res):
            shutil.rmtree(bdir, ignore_errors=True)
    xml_dir = workdir / "xml"
    xml_inputs = []
    for k in range(xml_count):
        mutation, cfg, target = sumo_xml_input(rng, xml_dir / f"{k:04d}")
        xml_inputs.append(FuzzInput("sumo_xml", mutation, cfg, "refused", names=target))
    for start in range(0, len(xml_inputs), 200):
        res = run_replay_batch(xml_inputs[start:start + 200], workdir)
        outcomes += res
        if log:
            log(f"sumo_xml {start + len(res)}/{len(xml_inputs)}: {sum(bool(o.problems) for o in res)} bad, "
                f"{time.perf_counter() - t0:.0f} s")
    if not any(o.problems for o in outcomes if o.input.kind == "sumo_xml"):
        shutil.rmtree(xml_dir, ignore_errors=True)
    return outcomes


def _peak_mb() -> int:
    """Peak resident memory [MB] of this process (the harness)."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_SELF)
    return int(usage.ru_maxrss / 1024)


def report(outcomes: list[Outcome]) -> dict[str, dict[str, int]]:
    """Per input kind: inputs, refused/converted, and every kind of problem counted."""
    table: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    for o in outcomes:
        row = table[o.input.kind]
        row["inputs"] += 1
        row[f"exit_{o.exit_code}"] += 1
        row["expected_safe_conversion" if o.input.expect == "safe" else
            "may_convert" if o.input.expect == "any" else "must_refuse"] += 1
        for p in o.problems:
            key = ("memory" if p.startswith("memory") else
                   "traceback" if "traceback" in p or "crash" in p else
                   "created_file" if "sentinel" in p or "outside OUT" in p else
                   "partial_output" if "output" in p or "folder" in p else
                   "exit_code" if "exit" in p else "error_lines" if "line" in p else "other")
            row[f"bad_{key}"] += 1
        row["bad_inputs"] += bool(o.problems)
    return {k: dict(v) for k, v in sorted(table.items())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--count", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--batch", type=int, default=40, help="scene inputs per convert process")
    ap.add_argument("--keep", type=Path, help="work folder to keep (default: a temporary one, removed)")
    ap.add_argument("--json", type=Path, help="write the per-kind counts and every problem here")
    args = ap.parse_args(argv)
    work = args.keep or Path(tempfile.mkdtemp(prefix="coster-fuzz-"))
    t0 = time.perf_counter()
    try:
        outcomes = fuzz(args.count, args.seed, work, batch_size=args.batch, log=lambda m: print(m, flush=True))
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    table = report(outcomes)
    wall = time.perf_counter() - t0
    bad = [o for o in outcomes if o.problems]
    print(json.dumps({"count": len(outcomes), "seed": args.seed, "wall_s": round(wall, 1), "kinds": table},
                     indent=1))
    for o in bad[:30]:
        print(f"BAD {o.input.kind} {o.input.mutation} {o.input.path}: {'; '.join(o.problems)}")
    if args.json:
        args.json.write_text(json.dumps({"count": len(outcomes), "seed": args.seed, "wall_s": round(wall, 1),
                                         "kinds": table,
                                         "problems": [{"kind": o.input.kind, "mutation": o.input.mutation,
                                                       "path": str(o.input.path), "problems": o.problems}
                                                      for o in bad]}, indent=1))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
