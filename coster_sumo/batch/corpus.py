"""The nominal-traffic corpus: many road networks, demand from free flow to congestion, every
vehicle class, mixed driver models, part of it sublane, recorded as 9.1 s clips (docs/corpus.md).

The corpus is a fixed catalogue of networks (:func:`catalogue`), each recorded with its provenance:

- ``wheel-osm``: the real, OSM-derived networks shipped in the eclipse-sumo wheel (``tools/game``:
  the A10 motorway interchange, Braunschweig, Ingolstadt, ...); ``wheel-synthetic``: that folder's
  hand-made game levels. Their own demand where it covers a run, else random trips.
- ``freeway``, ``roundabout``, ``rural``, ``netgenerate``: networks this project authors
  (:mod:`coster_sumo.batch.nets`), deterministic in the corpus seed, written to ``DATASET/nets/``.
- ``project``: the repository's ``networks/``.

Every network gets ``runs_per_network`` runs (:func:`plan_corpus`). Run ``j`` (counted over the
whole catalogue, so that a reduced build with one run per network still covers every variant)
takes a demand level (free, moderate, heavy, jammed: random-trip insertion density or SUMO
``--scale`` of the network's own demand), a lateral model (every third run the sublane model,
``--lateral-resolution``; the others continuous lane changes, ``--lanechange.duration``), and a
vType mix whose car-following models (Krauss, IDM, EIDM) and imperfection (sigma) are drawn per
type. Held-out networks (:data:`HELDOUT`) write their clips to ``DATASET/heldout/``, which no
training split ever lists (:func:`coster_sumo.data.dataset.list_scenes`).
"""

from __future__ import annotations

import dataclasses
import sys
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.batch import nets
from coster_sumo.batch.pedestrians import PED_DENSITY, Walkable, walkable
from coster_sumo.batch.records import BatchCounts, CorpusSummary, NetworkRecord
from coster_sumo.batch.simulate import DEFAULT_TIMEOUT_S, RunTask, Source, run_batch
from coster_sumo.data import dataset as ds
from coster_sumo.errors import InputError
from coster_sumo.formats.sumocfg import read_sumocfg
from coster_sumo.infra.atomic import write_json

REPO_NETWORKS = Path(__file__).resolve().parents[2] / "networks"
RUN_DURATION_S = 300.0  # [s] simulated per run
WARMUP_S = 60.0  # [s] simulated before clips are cut (every run starts from an empty network)
CLIPS_PER_RUN = 30
# held-out networks: never trained on (at least a freeway, two real OSM networks, generated ones)
HELDOUT = ("fkk_in", "DRT", "freeway03", "grid_family03", "roundabout02")

# (name, family, builder, count): the networks this project authors
_AUTHORED: tuple[tuple[str, str, Callable[[Path, int, int], dict[str, Any]], int], ...] = (
    ("freeway", "freeway", nets.freeway, 8),
    ("roundabout", "roundabout", nets.roundabout, 5),
    ("rural", "rural", nets.rural, 4),
    ("family", "netgenerate", nets.family, 12),
)

# wheel networks: name -> (family, net, own route files, additional files, demand window [s] or 0)
_WHEEL: dict[str, tuple[str, str, tuple[str, ...], tuple[str, ...], tuple[float, float]]] = {
    "A10KW": ("wheel-osm", "A10KW/osm.net.xml",
              tuple(f"A10KW/osm.{v}.rou.xml" for v in ("passenger", "truck", "passenger_mw", "truck_mw",
                                                       "passenger_mwb", "truck_mwb")) + ("A10KW/extra.rou.xml",),
              (), (0.0, 1800.0)),
    "bs3d": ("wheel-osm", "bs3d/bs.net.xml", (), (), (0.0, 0.0)),  # bs3d.sumocfg and bs3Dosm.sumocfg share it
    "DRT": ("wheel-osm", "DRT/osm.net.xml", (), (), (0.0, 0.0)),  # its own demand is one taxi service
    "fkk_in": ("wheel-osm", "fkk_in/ingolstadt.net.xml.gz", (), ("fkk_in/fkk_in.tls.add.xml",), (0.0, 0.0)),
    "fokr_bs_demo": ("wheel-osm", "fokr_bs_demo/fokr_bs.net.xml.gz",
                     ("fokr_bs_demo/15_16_veh.trips.xml.gz", "fokr_bs_demo/15_16_bicycle.trips.xml"),
                     ("fokr_bs_demo/vtypes_default.add.xml", "fokr_bs_demo/signalPlan.add.xml"),
                     (54000.0, 57600.0)),
    "corridor": ("wheel-synthetic", "corridor/corridor.net.xml", ("corridor/corridor.rou.xml",), (), (0.0, 600.0)),
    "cross": ("wheel-synthetic", "cross/cross.net.xml", (), ("cross/cross.tls.add.xml",), (0.0, 0.0)),
    "grid6": ("wheel-synthetic", "grid6/grid6.net.xml", (), ("grid6/grid6.tll.xml",), (0.0, 0.0)),
    "ramp": ("wheel-synthetic", "ramp/ramp.net.xml", ("ramp/ramp.rou.xml",), (), (0.0, 400.0)),
    "square": ("wheel-synthetic", "square/square.net.xml", (), ("square/square.tll.xml",), (0.0, 0.0)),
    "highway": ("wheel-synthetic", "highway/highway.net.xml", ("highway/highway.rou.xml",), (), (0.0, 400.0)),
    "kuehne": ("wheel-synthetic", "kuehne/kuehne.net.xml", ("kuehne/kuehne.rou.xml",), (), (0.0, 90000.0)),
}
# wheel folders left out, and why (the card lists them)
WHEEL_EXCLUDED = {"rail": "trains only", "rail_demo": "trains only", "racing": "a race track (Spreewaldring)",
                  "hiking": "pedestrians in a park"}

# demand levels: random-trip insertion density [veh/h per km of lane] and own-demand --scale ranges
LEVELS = ("free", "moderate", "heavy", "jammed")
_DENSITY = {"free": (20.0, 45.0), "moderate": (70.0, 140.0), "heavy": (200.0, 320.0), "jammed": (420.0, 650.0)}
_SCALE = {"free": (0.4, 0.7), "moderate": (0.9, 1.2), "heavy": (1.6, 2.2), "jammed": (2.8, 3.6)}
# [veh/h] random-trip insertions on a non-freeway network at most (a density of hundreds per km of lane
# on a 50-150 km city grid gridlocks it for good instead of congesting it; it also costs hours)
MAX_INSERTIONS_PER_H = 4000.0
BIKE_DENSITY = 15.0  # [bicycles/h per km of lane that allows them]

# vehicle types: id, vClass, length, width [m], share on urban and on freeway networks, extra attributes
_TYPES = (
    ("car_small", "passenger", 3.7, 1.65, 0.22, 0.18, 'accel="2.8" decel="4.5"'),
    ("car_mid", "passenger", 4.4, 1.78, 0.28, 0.26, 'accel="2.6" decel="4.5"'),
    ("car_large", "passenger", 4.9, 1.87, 0.14, 0.15, 'accel="2.6" decel="4.5"'),
    ("suv", "passenger", 4.8, 1.95, 0.08, 0.08, 'accel="2.4" decel="4.5"'),
    ("van", "delivery", 5.6, 2.0, 0.08, 0.08, 'accel="2.0" decel="4.0"'),
    ("truck", "truck", 9.0, 2.45, 0.06, 0.09, 'accel="1.3" decel="4.0" maxSpeed="25" minGap="3"'),
    ("trailer", "trailer", 16.5, 2.55, 0.03, 0.1, 'accel="1.0" decel="4.0" maxSpeed="25" minGap="3"'),
    ("bus", "bus", 12.0, 2.55, 0.04, 0.01, 'accel="1.2" decel="4.0" maxSpeed="22" minGap="3"'),
    ("coach", "coach", 13.5, 2.55, 0.01, 0.02, 'accel="1.2" decel="4.0" maxSpeed="28" minGap="3"'),
    ("moto", "motorcycle", 2.2, 0.8, 0.06, 0.03, 'accel="4.0" decel="7.0"'),
)
_BIKE = ("bike", "bicycle", 1.7, 0.65, 'maxSpeed="7" accel="1.2" decel="3.0"')
_CF_MODELS = ("Krauss", "IDM", "EIDM")
_CF_SHARE = (0.4, 0.3, 0.3)


@dataclass(frozen=True)
class Network:
    """One corpus network and where it comes from (``source`` and ``params`` go to the manifest)."""

    name: str
    family: str
    net: Path
    routes: tuple[Path, ...] = ()
    additional: tuple[Path, ...] = ()
    window: tuple[float, float] = (0.0, 0.0)  # [s] begin, end of its own demand (0, 0: none)
    heldout: bool = False
    source: str = ""  # where it comes from: the wheel, the repository, or the builder and its arguments
    params: dict[str, Any] | None = None  # the builder's parameters (networks this project authors)
    lane_km: float = 0.0  # [km] lane length (internal lanes left out); 0 when unknown

    @property
    def freeway(self) -> bool:
        return self.family == "freeway" or self.name in ("A10KW", "highway", "ramp")

    def own_demand_fits(self, duration_s: float) -> bool:
        return bool(self.routes) and self.window[1] - self.window[0] >= duration_s

    def record(self, dataset: Path) -> NetworkRecord:
        net = str(self.net.relative_to(dataset)) if self.net.is_relative_to(dataset) else str(self.net)
        return NetworkRecord(name=self.name, family=self.family, net=net, heldout=self.heldout, lane_km=self.lane_km,
                             own_demand=tuple(str(p.name) for p in self.routes), freeway=self.freeway,
                             source=self.source, params=self.params)


def catalogue(dataset: Path, seed: int = 0, build: bool = True, only: list[str] | None = None
              ) -> tuple[list[Network], list[str]]:
    """Every corpus network (the authored ones built into ``DATASET/nets/`` unless there already;
    with ``only``, just those are built; ``build=False`` builds none).

    Returns the networks and one line per network that could not be built (left out)."""
    from coster_sumo.infra import sumo_install

    game = sumo_install.sumo_home() / "tools" / "game"
    out: list[Network] = []
    errors: list[str] = []
    for name, (fam, net, routes, adds, window) in _WHEEL.items():
        out.append(Network(name=name, family=fam, net=game / net, routes=tuple(game / r for r in routes),
                           additional=tuple(game / a for a in adds), window=window,
                           source=f"eclipse-sumo wheel: tools/game/{net}"))
    for name in ("intersection", "merge", "arterial"):
        cfg = read_sumocfg(REPO_NETWORKS / name / f"{name}.sumocfg")
        out.append(Network(name=name, family="project", net=cfg.net_file, routes=cfg.route_files,
                           additional=cfg.additional_files, window=(cfg.begin or 0.0, cfg.end or 0.0),
                           source=f"repository: networks/{name}/{name}.sumocfg"))
    folder = dataset / ds.NETS_DIR
    folder.mkdir(parents=True, exist_ok=True)
    for stem, fam, builder, count in _AUTHORED:
        for k in range(count):
            if fam == "netgenerate":
                kind = ("grid", "spider", "random")[k % 3]
                name = f"{kind}_family{k:02d}"
            else:
                name = f"{stem}{k:02d}"
            net_path = folder / f"{name}.net.xml"
            params_file = folder / f"{name}.params.json"
            try:
                if build and (only is None or name in only) and not (net_path.exists() and params_file.exists()):
                    write_json(params_file, builder(net_path, k, seed))
                params = _read_json(params_file) if params_file.exists() else {}
            except RuntimeError as exc:
                errors.append(f"{name}: {exc}")
                continue
            out.append(Network(name=name, family=fam, net=net_path,
                               source=f"authored: coster_sumo.batch.nets.{builder.__name__}(k={k}, seed={seed})",
                               params=params))
    heldout = set(HELDOUT)
    out = [dataclasses.replace(n, heldout=n.name in heldout, lane_km=_lane_km(n.net)) for n in out]
    return out, errors


@dataclass(frozen=True)
class NetSize:
    """The size of a SUMO net, internal lanes and junctions left out: lanes, their length [km]
    (rounded to 0.1 km) and junctions."""

    lanes: int
    lane_km: float
    junctions: int


def net_size(path: Path) -> NetSize:
    """Lanes, lane length [km] and junctions of a SUMO net (internal lanes left out)."""
    from defusedxml.ElementTree import iterparse

    from coster_sumo.formats.sumocfg import open_maybe_gzip

    lanes, km, junctions, internal = 0, 0.0, 0, False
    with open_maybe_gzip(path) as fh:
        for event, el in iterparse(fh, events=("start", "end")):
            tag = el.tag
            if event == "start":
                if tag == "edge":
                    internal = el.get("function") == "internal"
                continue
            if tag == "lane" and not internal:
                lanes += 1
                km += float(el.get("length", 0.0)) / 1000.0
            elif tag == "junction" and el.get("type") != "internal":
                junctions += 1
            if tag in ("edge", "junction", "connection", "tlLogic"):
                el.clear()
    return NetSize(lanes=lanes, lane_km=round(km, 1), junctions=junctions)


def _lane_km(net: Path) -> float:
    """[km] of lanes of a net (cached beside authored nets; 0 when the net is not there)."""

    if not net.exists():
        return 0.0
    st = net.stat()
    key = (str(net), st.st_mtime_ns, st.st_size)
    if key not in _LANE_KM:
        _LANE_KM[key] = net_size(net).lane_km
    return _LANE_KM[key]


_LANE_KM: dict[tuple[str, int, int], float] = {}


def _read_json(path: Path) -> Any:
    import json

    return json.loads(path.read_text())


def vtypes_xml(rng: np.random.Generator, freeway: bool) -> tuple[str, dict[str, str]]:
    """The run's vType mix (distribution ``mix``) plus a ``bike`` type; returns the XML and each
    type's car-following model. Car-following model per type drawn from Krauss / IDM / EIDM, driver
    imperfection sigma from U(0.2, 0.8), speed factor normal around 1 (sd 0.1)."""
    lines, models = ["<additional>"], {}
    for tid, vclass, length, width, _urban, _fw, extra in _TYPES:
        model = str(rng.choice(_CF_MODELS, p=_CF_SHARE))
        models[tid] = model
        sigma = float(rng.uniform(0.2, 0.8))
        lat = ' latAlignment="arbitrary" minGapLat="0.3"' if vclass == "motorcycle" else ""
        lines.append(f'    <vType id="{tid}" vClass="{vclass}" length="{length}" width="{width}" '
                     f'carFollowModel="{model}" sigma="{sigma:.2f}" speedFactor="normc(1,0.1,0.6,1.4)" '
                     f'{extra}{lat}/>')
    tid, vclass, length, width, extra = _BIKE
    lines.append(f'    <vType id="{tid}" vClass="{vclass}" length="{length}" width="{width}" sigma="0.3" '
                 f'speedFactor="normc(1,0.15,0.6,1.4)" latAlignment="right" {extra}/>')
    share = [t[5] if freeway else t[4] for t in _TYPES]
    lines.append(f'    <vTypeDistribution id="mix" vTypes="{" ".join(t[0] for t in _TYPES)}" '
                 f'probabilities="{" ".join(f"{p:g}" for p in share)}"/>')
    lines.append("</additional>\n")
    return "\n".join(lines), models


@dataclass
class CorpusConfig:
    """What ``coster-sumo corpus build`` does."""

    dataset: Path
    runs_per_network: int = 6
    duration_s: float = RUN_DURATION_S
    seed: int = 0
    workers: int = 1
    networks: list[str] | None = None  # only these (default: the whole catalogue)
    timeout_s: float = DEFAULT_TIMEOUT_S
    card: bool = True  # write DATASET/card.md at the end
    quiet: bool = False
    debug: bool = False
    pedestrians: bool = False  # sidewalks, crossings and walks (coster_sumo.batch.pedestrians)


def plan_corpus(cfg: CorpusConfig, networks: list[Network], walk: dict[str, Walkable] | None = None
                ) -> list[RunTask]:
    """Every run of the corpus (deterministic in the configuration). ``walk``: the networks that
    get pedestrians, as they walk them (:func:`coster_sumo.batch.pedestrians.walkable`; with
    ``cfg.pedestrians`` only)."""
    tasks = []
    walk = walk or {}
    for n_index, net in enumerate(networks):
        for i in range(cfg.runs_per_network):
            j = n_index + i  # run variant: rotates over the catalogue, so one run per network covers all
            seed = cfg.seed * 1000 + i
            rng = np.random.default_rng([cfg.seed, i, zlib.crc32(net.name.encode())])
            level = LEVELS[j % len(LEVELS)]
            sublane = j % 3 == 0
            options = ({"--lateral-resolution": "0.8"} if sublane
                       else {"--lanechange.duration": f"{rng.uniform(2.0, 4.0):.1f}"})
            options["--time-to-teleport"] = "300"
            own = net.own_demand_fits(cfg.duration_s)
            begin = 0.0
            if own:
                lo, hi = _SCALE[level]
                scale, density = float(rng.uniform(lo, hi)), 0.0
                span = net.window[1] - net.window[0] - cfg.duration_s
                begin = net.window[0] + float(np.floor(rng.uniform(0, max(span, 0.0)) / 10.0) * 10.0)
            else:
                lo, hi = _DENSITY[level]
                scale, density = 1.0, float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
                if not net.freeway and net.lane_km > 0:  # big city grids would gridlock, not congest
                    density = min(density, MAX_INSERTIONS_PER_H / net.lane_km)
            xml, models = vtypes_xml(rng, net.freeway)
            bikes = 0.0 if (own or net.freeway) else BIKE_DENSITY
            src = Source(name=net.name, path=net.net, is_config=False, has_demand=own, begin_s=begin,
                         routes=net.routes if own else (), additional=net.additional)
            ped = walk.get(net.name)
            if ped is not None:  # the walkable net; randomTrips' vehicle densities count lanes, sidewalks not
                src = dataclasses.replace(src, path=ped.net, additional=ped.additional)
                density, bikes = density * ped.vehicle_factor, bikes * ped.bike_factor
            tasks.append(RunTask(
                run_id=f"{net.name}_r{i}", source=src, seed=seed, scale=scale, duration_s=cfg.duration_s,
                warmup_s=WARMUP_S, max_clips=CLIPS_PER_RUN, targets_per_window=3, dataset=cfg.dataset,
                options=options, trip_density=density or 1.0, bike_density=bikes, vtypes=xml, network=net.name,
                ped_density=PED_DENSITY if ped is not None else 0.0, sidewalk_km=ped.sidewalk_km if ped else 0.0,
                heldout=net.heldout, stats=True,
                info={"family": net.family, "level": level, "sublane": sublane, "begin_s": begin,
                      "car_following": models}))
    return tasks


def build_corpus(cfg: CorpusConfig) -> CorpusSummary:
    """Build (or finish building) the corpus; returns the summary (``DATASET/summary.json``)."""
    t_wall = time.perf_counter()
    if cfg.runs_per_network < 1 or cfg.workers < 1 or cfg.duration_s <= WARMUP_S:
        raise InputError(f"--runs-per-network and --workers must be >= 1, --duration > {WARMUP_S:g} s")
    cfg.dataset.mkdir(parents=True, exist_ok=True)
    networks, errors = catalogue(cfg.dataset, cfg.seed, only=cfg.networks)
    for e in errors:
        print(f"coster-sumo corpus: network {e}", file=sys.stderr)
    manifest = ds.read_manifest(cfg.dataset)
    manifest["corpus"] = {"seed": cfg.seed, "runs_per_network": cfg.runs_per_network,
                          "duration_s": cfg.duration_s, "warmup_s": WARMUP_S,
                          "wheel_excluded": WHEEL_EXCLUDED} | ({"pedestrians": True} if cfg.pedestrians else {})
    manifest["networks"] = [n.record(cfg.dataset).to_json() for n in networks]  # the whole catalogue
    manifest["heldout_networks"] = sorted(n.name for n in networks if n.heldout)
    if cfg.networks:
        unknown = set(cfg.networks) - {n.name for n in networks}
        if unknown:
            raise InputError(f"unknown networks: {', '.join(sorted(unknown))}")
        networks = [n for n in networks if n.name in cfg.networks]
    walk: dict[str, Walkable] = {}
    for n in networks if cfg.pedestrians else ():
        try:
            ped = walkable(n, cfg.dataset)
        except RuntimeError as exc:  # netconvert failed: the network's runs go on without pedestrians
            errors.append(f"{n.name}: {exc}")
            print(f"coster-sumo corpus: network {n.name}: no pedestrians: {exc}", file=sys.stderr)
            continue
        if ped is not None:
            walk[n.name] = ped
    tasks = plan_corpus(cfg, networks, walk)
    result = run_batch(tasks, cfg.dataset, manifest, workers=cfg.workers, timeout_s=cfg.timeout_s,
                       quiet=cfg.quiet, debug=cfg.debug, what="corpus")
    manifest = ds.read_manifest(cfg.dataset)
    counts = BatchCounts(runs_planned=result.planned, runs_done_now=result.done_now,
                         runs_failed_now=len(result.failures), clips_now=result.clips,
                         failures=errors + result.failures, total_clips=manifest["counts"]["scenes"],
                         simulated_hours=manifest["simulated_hours"], wall_s=round(time.perf_counter() - t_wall, 2))
    summary = CorpusSummary(dataset=str(cfg.dataset), networks=len(networks), counts=counts)
    write_json(cfg.dataset / "summary.json", summary.to_json())
    return summary
