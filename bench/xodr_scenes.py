"""Many small test scenes for the OpenDRIVE export (issue 64), made from what the project has.

Each scene is a SUMO net, written under a work folder and exported by the caller through
:func:`coster_sumo.exports.opendrive.write_xodr`:

- ``womd``: the real WOMD samples, cropped around other places of their maps (every lane that comes
  within ``radius`` of a centre), each crop as it is, rotated, mirrored (left and right neighbours
  swap), with its lanes clipped at a circle (lanes that end at arbitrary stations), or with part of
  its lanes dropped (lane counts that change inside a road: splits and merges); converted by the
  project's own converter (:func:`coster_sumo.converters.to_sumo.convert_scene`).
- ``clip``: SUMO nets (the wheel's ``tools/game`` nets, the corpus' authored and netgenerate
  networks, the repository's ``networks/``, extra netgenerate grids, spiders and random nets with
  other junction shapes) cut by netconvert to a small box around one of their junctions: the
  export of netconvert's own junction shapes.
- ``conv``: the same cut read as a scene map (as a corpus clip's map is) and converted back by the
  project's converter.

Every scene gets a single synthetic vehicle (the converter wants one); what is measured is the map.
Randomness comes from one seed; the same seed gives the same scenes.
"""

from __future__ import annotations

import dataclasses
import math
import re
import subprocess
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from defusedxml.ElementTree import iterparse

from coster_sumo.core.scene import Lanes, ObjectType, Polylines, Ragged, RoadMap, Scene, SignalStates, Tracks
from coster_sumo.data.dataset import crop_map
from coster_sumo.formats.sumo_net import read_sumo_net
from coster_sumo.infra import sumo_install

REPO = Path(__file__).resolve().parents[1]
WOMD = REPO.parent / "shared" / "data" / "womd"
GAME_NETS = ("A10KW/osm.net.xml", "bs3d/bs.net.xml", "DRT/osm.net.xml", "fkk_in/ingolstadt.net.xml.gz",
             "fokr_bs_demo/fokr_bs.net.xml.gz", "corridor/corridor.net.xml", "cross/cross.net.xml",
             "grid6/grid6.net.xml", "ramp/ramp.net.xml", "square/square.net.xml", "highway/highway.net.xml",
             "kuehne/kuehne.net.xml")
WOMD_TRANSFORMS = ("plain", "rotate", "mirror", "clip", "drop")
# extra netgenerate networks: junction shapes the corpus' families draw rarely
EXTRA_NETGENERATE = {
    "grid_corner": ["--grid", "--grid.number", "3", "--grid.length", "60", "--default.lanenumber", "2",
                    "--junctions.corner-detail", "8", "--default-junction-type", "priority"],
    "grid_tls3": ["--grid", "--grid.number", "3", "--grid.length", "80", "--default.lanenumber", "3",
                  "--default-junction-type", "traffic_light", "--junctions.internal-link-detail", "10"],
    "spider_tight": ["--spider", "--spider.arm-number", "7", "--spider.circle-number", "2",
                     "--spider.space-radius", "40", "--default.lanenumber", "2"],
    "spider_wide": ["--spider", "--spider.arm-number", "3", "--spider.circle-number", "3",
                    "--spider.space-radius", "120", "--default.lanenumber", "3", "--spider.omit-center"],
    "rand_lanes": ["--rand", "--rand.iterations", "60", "--rand.random-lanenumber", "--rand.max-distance", "150",
                   "--rand.min-distance", "40", "--rand.min-angle", "30", "--seed", "3"],
    "rand_grid": ["--rand", "--rand.iterations", "60", "--rand.grid", "--rand.random-lanenumber", "--seed", "5"],
    "rand_rbl": ["--rand", "--rand.iterations", "50", "--default-junction-type", "right_before_left",
                 "--rand.min-angle", "20", "--seed", "11"],
    "rand_allway": ["--rand", "--rand.iterations", "50", "--default-junction-type", "allway_stop",
                    "--default.lanenumber", "2", "--seed", "13"],
}


@dataclass(frozen=True)
class TestNet:
    """One generated scene: ``name`` (unique, a safe file stem), ``family`` and its SUMO net."""

    name: str
    family: str
    net: Path


# --- scene transforms -----------------------------------------------------------------------------


def transform_scene(scene: Scene, matrix: np.ndarray, shift: np.ndarray) -> Scene:
    """The scene moved by ``p -> matrix @ p + shift`` (a rotation or a mirror); a mirror swaps every
    lane's left and right neighbours, since lanes keep their driving direction."""
    def move(xy: np.ndarray) -> np.ndarray:
        return np.asarray(xy, np.float64).reshape(-1, 2) @ matrix.T + shift

    def lines(p: Polylines) -> Polylines:
        return Polylines(points=Ragged(values=move(p.points.values), offsets=p.points.offsets), kind=p.kind)

    rm, lanes = scene.road_map, scene.road_map.lanes
    mirrored = float(np.linalg.det(matrix)) < 0
    lanes = dataclasses.replace(
        lanes, centerline=Ragged(values=move(lanes.centerline.values), offsets=lanes.centerline.offsets),
        left_neighbors=lanes.right_neighbors if mirrored else lanes.left_neighbors,
        right_neighbors=lanes.left_neighbors if mirrored else lanes.right_neighbors)
    road_map = RoadMap(lanes=lanes, road_lines=lines(rm.road_lines), road_edges=lines(rm.road_edges),
                       crosswalks=lines(rm.crosswalks), junctions=lines(rm.junctions),
                       stop_sign_xy=move(rm.stop_sign_xy), stop_sign_lanes=rm.stop_sign_lanes)
    sig = scene.signals
    signals = SignalStates(lane_index=sig.lane_index, state=sig.state, stop_point=move(sig.stop_point))
    return dataclasses.replace(scene, road_map=road_map, signals=signals,
                               tracks=_one_vehicle(road_map, len(scene.timestamps)))


def keep_lanes(scene: Scene, keep: np.ndarray, lines: list[np.ndarray] | None = None,
               cut_ends: tuple[np.ndarray, np.ndarray] | None = None) -> Scene:
    """The scene with only the lanes where ``keep``; ``lines``: new centre lines for every lane of
    the old map; ``cut_ends``: (start cut, end cut) per old lane, whose links at that end go too."""
    lanes = scene.road_map.lanes
    new = np.full(len(lanes), -1, np.int64)
    new[keep] = np.arange(int(keep.sum()))
    idx = np.flatnonzero(keep)
    starts, ends = cut_ends if cut_ends is not None else (np.zeros(len(lanes), bool), np.zeros(len(lanes), bool))

    def links(field: str, cut: np.ndarray | None) -> Ragged:
        items = []
        for i in idx:
            v = new[getattr(lanes, field)[int(i)]]
            items.append(np.zeros(0, np.int64) if cut is not None and cut[i] else v[v >= 0])
        return Ragged.from_list(items, np.int64)

    centre = [lines[i] if lines is not None else lanes.centerline[int(i)] for i in idx]
    out = Lanes(ids=lanes.ids[idx], centerline=Ragged.from_list(centre, np.float64, (2,)), width=lanes.width[idx],
                lane_type=lanes.lane_type[idx], speed_limit=lanes.speed_limit[idx],
                is_junction=lanes.is_junction[idx], predecessors=links("predecessors", starts),
                successors=links("successors", ends), left_neighbors=links("left_neighbors", None),
                right_neighbors=links("right_neighbors", None))
    rm = scene.road_map
    stop_lanes = [new[rm.stop_sign_lanes[k]] for k in range(len(rm.stop_sign_xy))]
    road_map = dataclasses.replace(rm, lanes=out, stop_sign_lanes=Ragged.from_list(
        [v[v >= 0] for v in stop_lanes], np.int64))
    sig = scene.signals
    ok = new[sig.lane_index] >= 0 if len(sig.lane_index) else np.zeros(0, bool)
    signals = SignalStates(lane_index=new[sig.lane_index][ok], state=sig.state[:, ok], stop_point=sig.stop_point[ok])
    return dataclasses.replace(scene, road_map=road_map, signals=signals,
                               tracks=_one_vehicle(road_map, len(scene.timestamps)))


def crop_at(scene: Scene, centre: np.ndarray, radius: float) -> Scene:
    """Every lane (and line, and stop sign) that comes within ``radius`` [m] of ``centre``."""
    road_map, new = crop_map(scene.road_map, centre.reshape(1, 2), radius)
    sig = scene.signals
    lane_new = new[sig.lane_index] if len(sig.lane_index) else np.zeros(0, np.int64)
    ok = lane_new >= 0
    signals = SignalStates(lane_index=lane_new[ok], state=sig.state[:, ok], stop_point=sig.stop_point[ok])
    return dataclasses.replace(scene, road_map=road_map, signals=signals,
                               tracks=_one_vehicle(road_map, len(scene.timestamps)))


def clip_lanes(scene: Scene, centre: np.ndarray, radius: float) -> Scene:
    """Lanes cut where they leave a circle: each keeps its longest run of points inside (at least
    2 points and 2 m); links at a cut end are dropped."""
    lanes = scene.road_map.lanes
    keep = np.zeros(len(lanes), bool)
    cut_start, cut_end = np.zeros(len(lanes), bool), np.zeros(len(lanes), bool)
    lines: list[np.ndarray] = []
    for i in range(len(lanes)):
        line = lanes.centerline[i]
        inside = np.hypot(*(line - centre).T) <= radius
        best, run = (0, 0), None
        for k, v in enumerate([*inside, False]):
            if v and run is None:
                run = k
            elif not v and run is not None:
                best = max(best, (run, k), key=lambda r: r[1] - r[0])
                run = None
        piece = line[best[0]:best[1]]
        lines.append(piece if len(piece) else line)
        keep[i] = len(piece) >= 2 and float(np.hypot(*np.diff(piece, axis=0).T).sum()) >= 2.0
        cut_start[i], cut_end[i] = best[0] > 0, best[1] < len(line)
    return keep_lanes(scene, keep, lines, (cut_start, cut_end))


def _one_vehicle(road_map: RoadMap, steps: int) -> Tracks:
    """One car standing at the start of the map's first lane for ``steps`` steps."""
    steps = max(steps, 2)
    line = road_map.lanes.centerline[0] if len(road_map.lanes) else np.zeros((2, 2))
    h = math.atan2(*(line[1] - line[0])[::-1]) if len(line) >= 2 else 0.0
    full = np.ones((1, steps))
    return Tracks(ids=np.array(["car"]), object_type=np.array([int(ObjectType.VEHICLE)], np.int8),
                  x=full * line[0, 0], y=full * line[0, 1], heading=full * h, vx=full * 0.0, vy=full * 0.0,
                  length=full * 4.5, width=full * 1.8, valid=np.ones((1, steps), bool))


def rotation(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])


def womd_variants(scene: Scene, count: int, radius: float, rng: np.random.Generator) -> Iterator[tuple[str, Scene]]:
    """``count`` crops of a scene, each with the next transform of :data:`WOMD_TRANSFORMS`."""
    lanes = scene.road_map.lanes
    points = lanes.centerline.values[~np.repeat(lanes.is_junction, np.diff(lanes.centerline.offsets))]
    for k in range(count):
        centre = points[int(rng.integers(len(points)))]
        kind = WOMD_TRANSFORMS[k % len(WOMD_TRANSFORMS)]
        crop = crop_at(scene, centre, radius)
        if len(crop.road_map.lanes) == 0:
            continue
        if kind == "rotate":
            crop = transform_scene(crop, rotation(float(rng.uniform(0.3, 2 * math.pi - 0.3))), -centre)
        elif kind == "mirror":
            crop = transform_scene(crop, np.diag([-1.0, 1.0]), np.array([2 * centre[0], 0.0]))
        elif kind == "clip":
            crop = clip_lanes(crop, centre, radius * 0.8)
        elif kind == "drop":
            drop = rng.random(len(crop.road_map.lanes)) < 0.2
            crop = keep_lanes(crop, ~drop)
        if len(crop.road_map.lanes):
            yield f"{kind}{k:02d}", crop


# --- SUMO nets ------------------------------------------------------------------------------------


def node_points(net: Path) -> np.ndarray:
    """(N, 2) positions of a SUMO net's junctions that are not internal or dead ends."""
    pts = []
    for _, el in iterparse(_open(net), events=("end",)):
        if el.tag == "junction" and el.get("type") not in ("internal", "dead_end"):
            pts.append((float(el.get("x", "0")), float(el.get("y", "0"))))
        el.clear()
    return np.array(pts, np.float64).reshape(-1, 2)


def _open(net: Path):  # type: ignore[no-untyped-def]
    import gzip

    return gzip.open(net, "rb") if net.suffix == ".gz" else open(net, "rb")  # noqa: SIM115


def clip_net(net: Path, centre: np.ndarray, half: float, out: Path) -> Path | None:
    """``out``: netconvert's cut of ``net`` to the box of half side ``half`` [m] around ``centre``
    (edges wholly inside), in the net's own frame; None when nothing is left."""
    x, y = centre
    cmd = [sumo_install.binary("netconvert"), "-s", str(net), "-o", str(out), "--no-warnings", "true",
           "--keep-edges.in-boundary", f"{x - half},{y - half},{x + half},{y + half}",
           "--offset.disable-normalization", "true", "--ignore-errors", "true"]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=sumo_install.subprocess_env(), timeout=600)
    if proc.returncode != 0 or not out.is_file() or re.search(rb'<edge id="[^:]', out.read_bytes()) is None:
        return None
    return out


def sumo_scene(net: Path, name: str) -> Scene | None:
    """A SUMO net as a scene map (as the corpus reads one), with one synthetic vehicle."""
    road_map = read_sumo_net(net).road_map
    if len(road_map.lanes) == 0:
        return None
    steps = 11
    return Scene(scenario_id=name, timestamps=np.arange(steps) * 0.1, tracks=_one_vehicle(road_map, steps),
                 road_map=road_map, signals=SignalStates.empty(steps), sdc_index=0, source="sumo")


def source_nets(work: Path, seed: int, only: list[str] | None = None) -> list[tuple[str, str, Path]]:
    """(name, family, net) of every SUMO net to cut: the corpus catalogue (the wheel's nets, the
    repository's, the authored families, built into ``work``) and :data:`EXTRA_NETGENERATE`; with
    ``only``, just the nets of those names."""
    from coster_sumo.batch import nets
    from coster_sumo.batch.corpus import catalogue

    found, _ = catalogue(work / "corpus", seed=seed, only=only)
    out = [(n.name, n.family, n.net) for n in found if n.net.is_file() and (not only or n.name in only)]
    for name, opts in EXTRA_NETGENERATE.items():
        if only and name not in only:
            continue
        path = work / "extra" / f"{name}.net.xml"
        path.parent.mkdir(parents=True, exist_ok=True)
        if not path.is_file():
            nets.netgenerate(path, opts)
        out.append((name, "netgenerate-extra", path))
    return out


def sumo_clips(work: Path, per_net: int, half: float, rng: np.random.Generator,
               only: list[str] | None = None, names: set[str] | None = None) -> Iterator[tuple[TestNet, Scene | None]]:
    """Per source net, ``per_net`` cuts around random junctions: each as a :class:`TestNet` of
    family ``clip`` and with its scene (to convert: family ``conv``); with ``names``, only the cuts
    that scenes of those names need (the random draws stay those of the whole list)."""
    for name, family, net in source_nets(work, int(rng.integers(1 << 16)), only):
        pts = node_points(net)
        if len(pts) == 0:
            continue
        for k in range(per_net):
            centre = pts[int(rng.integers(len(pts)))]
            if names is not None and not {f"clip_{name}_{k}", f"conv_{name}_{k}"} & names:
                continue
            out = work / "clips" / f"{name}_{k}.net.xml"
            out.parent.mkdir(parents=True, exist_ok=True)
            if clip_net(net, centre, half, out) is None:
                continue
            yield TestNet(f"clip_{name}_{k}", f"clip:{family}", out), sumo_scene(out, f"conv_{name}_{k}")


def convert(scene: Scene, name: str, work: Path) -> Path | None:
    """The project's conversion of a scene; its net (None when the converter refuses the scene)."""
    from coster_sumo.converters.to_sumo import convert_scene

    from coster_sumo.errors import CosterError

    try:
        return next(convert_scene(scene, work / "conv", name=name).folder.glob("*.net.xml"))
    except (CosterError, StopIteration):
        return None


def womd_nets(work: Path, per_sample: int, radius: float, rng: np.random.Generator,
              names: set[str] | None = None) -> Iterator[TestNet]:
    """The WOMD samples' crops and transforms (:func:`womd_variants`), converted (with ``names``,
    only those of these names)."""
    from coster_sumo.converters.read import read_scenes

    files = sorted((WOMD / "scenario_proto").glob("*.tfrecord")) + sorted((WOMD / "scenarionet_pkl").glob("*.pkl"))
    for path in files:
        for scene in read_scenes(path):
            for tag, variant in womd_variants(scene, per_sample, radius, rng):
                name = f"womd_{scene.scenario_id}_{tag}"
                if names is not None and name not in names:
                    continue
                net = convert(dataclasses.replace(variant, scenario_id=name), name, work)
                if net is not None:
                    yield TestNet(name, "womd", net)


def all_nets(work: Path, seed: int = 0, per_sample: int = 15, per_net: int = 2, radius: float = 45.0,
             half: float = 90.0, only: list[str] | None = None, names: set[str] | None = None
             ) -> Iterator[TestNet]:
    """Every generated scene: WOMD variants first, then per SUMO net its cuts and their conversions.
    ``names``: only the scenes of these names, the same nets as in the whole list (every random
    draw is made; only the conversions and cuts those scenes need are built)."""
    rng = np.random.default_rng(seed)
    if not only or "womd" in only:
        yield from womd_nets(work, per_sample, radius, rng, names)
    for clip, scene in sumo_clips(work, per_net, half, rng, only, names):
        if names is None or clip.name in names:
            yield clip
        name = clip.name.replace("clip_", "conv_", 1)
        if scene is not None and (names is None or name in names):
            net = convert(dataclasses.replace(scene, scenario_id=name), name, work)
            if net is not None:
                yield TestNet(name, clip.family.replace("clip:", "conv:"), net)


def scratch() -> Path:
    return Path(tempfile.mkdtemp(prefix="xodr_scenes_"))
