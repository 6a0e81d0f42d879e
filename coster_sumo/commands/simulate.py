"""``coster-sumo simulate``: nominal traffic from SUMO into a dataset of WOMD-like clips.

Each SOURCE (a ``.sumocfg``, or a ``.net.xml`` without demand) is simulated ``--seeds`` times,
every run with its own SUMO ``--seed`` and a demand scale (SUMO's ``--scale``) drawn from
``--scale-range``. Sources without demand get random trips (SUMO's ``randomTrips.py``, seeded with
the run's seed). ``--netgenerate K`` adds K networks made by ``netgenerate`` (grid, spider and
random, with varied lanes, speeds and junction control) under ``DATASET/nets/``.

Every run is recorded at 10 Hz (:mod:`coster_sumo.sim.record`) in chunks, and clips are cut from
it with several targets each (:func:`coster_sumo.dataset.plan_clips`) and written to
``DATASET/scenes/`` as they come; ``DATASET/manifest.json`` is rewritten after every run. Runs go
in parallel, each in its own process (libsumo holds one simulation per process). A run that fails
is reported in one line and the others go on; the exit code is then 1. Running the same command
again skips the runs the manifest lists as done.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import multiprocessing as mp
import shutil
import subprocess
import sys
import time
import traceback
import zlib
from dataclasses import dataclass
from multiprocessing.connection import wait
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo import dataset as ds
from coster_sumo.errors import InputError

DEFAULT_DURATION_S = 300.0  # [s] per run when neither --duration nor the configuration says
CHUNK_S = 7 * 9.1  # [s] recorded at a time (7 clip windows): bounds memory; clips never span chunks
RANDOM_TRIPS_DENSITY = 100.0  # [veh/h per km of lane] randomTrips --insertion-density before --scale
GENERATED_WARMUP_S = 60.0  # [s] networks that start empty are filled this long before clips are cut
WORK_DIR = ".work"

# vTypes for random trips: mostly cars, some vans, trucks and motorcycles (duarouter copies them
# into the route file, so the file is self-contained)
_VTYPES = """<additional>
    <vType id="car" vClass="passenger" length="4.6" width="1.8" sigma="0.5" speedDev="0.1"/>
    <vType id="van" vClass="delivery" length="6.5" width="2.1" sigma="0.5" speedDev="0.1"/>
    <vType id="truck" vClass="truck" length="12.0" width="2.5" minGap="3.0" sigma="0.5" speedDev="0.05"
           maxSpeed="25"/>
    <vType id="moto" vClass="motorcycle" length="2.2" width="0.9" sigma="0.5" speedDev="0.15"/>
    <vTypeDistribution id="mix" vTypes="car van truck moto" probabilities="0.78 0.1 0.07 0.05"/>
</additional>
"""


@dataclass(frozen=True)
class Source:
    """Something to simulate.

    Attributes:
        name: unique short name (file stem), used in run and scene names.
        path: the ``.sumocfg`` or ``.net.xml``.
        is_config: a ``.sumocfg`` (else a bare net).
        has_demand: the configuration names route files (else random trips are made).
        end_s: [s] the configuration's own end time, if it sets one.
    """

    name: str
    path: Path
    is_config: bool
    has_demand: bool
    end_s: float | None = None


@dataclass(frozen=True)
class RunTask:
    """One simulation run (picklable: it crosses into a worker process)."""

    run_id: str
    source: Source
    seed: int
    scale: float  # SUMO --scale [-]
    duration_s: float  # [s]
    warmup_s: float  # [s] simulated but not cut into clips
    max_clips: int
    targets_per_window: int
    dataset: Path

    @property
    def work(self) -> Path:
        return self.dataset / WORK_DIR / self.run_id

    def manifest_entry(self) -> dict[str, Any]:
        return {"run_id": self.run_id, "source": str(self.source.path), "kind":
                "sumocfg" if self.source.is_config else "net",
                "demand": "config" if self.source.has_demand else "randomTrips", "seed": self.seed,
                "scale": round(self.scale, 4), "duration_s": self.duration_s, "warmup_s": self.warmup_s}


# ----------------------------------------------------------------------------- sources

def _config_info(cfg: Path) -> tuple[bool, float | None]:
    """(names route files, end time) of a ``.sumocfg`` (read by the one, defusedxml-based reader)."""
    from coster_sumo.formats.sumocfg import read_sumocfg

    sc = read_sumocfg(cfg)
    return sc.has_demand, sc.end


def resolve_sources(paths: list[Path]) -> list[Source]:
    """Check every input exists and is a ``.sumocfg`` or ``.net.xml``; give each a unique name."""
    out: list[Source] = []
    used: set[str] = set()
    for p in paths:
        if not p.is_file():
            raise InputError(f"{p}: file not found")
        is_cfg = p.suffix == ".sumocfg"
        if not is_cfg and not p.name.endswith(".net.xml"):
            raise InputError(f"{p}: expected a .sumocfg or a .net.xml")
        has_demand, end = _config_info(p) if is_cfg else (False, None)
        stem = p.name.split(".")[0]
        name = ds.safe_name(stem)
        if name in used:
            name = ds.safe_name(f"{p.parent.name}-{stem}")
        k = 2
        base = name
        while name in used:
            name, k = f"{base}-{k}", k + 1
        used.add(name)
        out.append(Source(name=name, path=p, is_config=is_cfg, has_demand=has_demand, end_s=end))
    return out


# ----------------------------------------------------------------------------- netgenerate

_SPEEDS_MPS = (8.33, 11.11, 13.89, 16.67, 22.22)  # 30 / 40 / 50 / 60 / 80 km/h
_JUNCTIONS = ("traffic_light", "priority", "right_before_left", "allway_stop")


def netgenerate_options(k: int, seed: int) -> tuple[str, list[str]]:
    """The kind ("grid", "spider", "random") and netgenerate options of generated network ``k``.

    Kinds cycle through the three; sizes, lane counts, speeds and junction control are drawn from
    a generator seeded with (seed, k), so the same k and seed give the same network.
    """
    rng = np.random.default_rng([seed, k, 7])
    kind = ("grid", "spider", "random")[k % 3]
    lanes = int(rng.integers(1, 4))
    speed = float(rng.choice(_SPEEDS_MPS))
    junction = str(rng.choice(_JUNCTIONS, p=[0.45, 0.3, 0.15, 0.1]))
    opts = ["--default.lanenumber", str(lanes), "--default.speed", f"{speed:g}",
            "--default-junction-type", junction, "--tls.default-type",
            str(rng.choice(["static", "actuated"])), "--seed", str(seed * 1000 + k)]
    if kind == "grid":
        opts = ["--grid", "--grid.x-number", str(int(rng.integers(3, 7))),
                "--grid.y-number", str(int(rng.integers(3, 6))),
                "--grid.x-length", f"{rng.uniform(90, 250):.0f}",
                "--grid.y-length", f"{rng.uniform(90, 250):.0f}",
                "--grid.attach-length", f"{rng.uniform(60, 150):.0f}", *opts]
    elif kind == "spider":
        opts = ["--spider", "--spider.arm-number", str(int(rng.integers(4, 8))),
                "--spider.circle-number", str(int(rng.integers(2, 5))),
                "--spider.space-radius", f"{rng.uniform(60, 140):.0f}",
                "--spider.attach-length", f"{rng.uniform(60, 150):.0f}", *opts]
        if rng.random() < 0.5:
            opts.append("--spider.omit-center")
    else:
        opts = ["--rand", "--rand.iterations", str(int(rng.integers(40, 140))),
                "--rand.min-distance", "80", "--rand.max-distance", "250",
                "--rand.random-lanenumber", "--rand.random-priority", "--tls.guess", "true", *opts]
        if rng.random() < 0.5:
            opts.append("--rand.grid")
    return kind, opts


def generate_nets(dataset: Path, count: int, seed: int) -> tuple[list[Source], list[dict], list[str]]:
    """Make ``count`` networks under ``DATASET/nets/`` (kept when already there).

    Returns the sources, their manifest records, and one-line errors for nets that failed.
    """
    from coster_sumo import sumo_env

    sources, records, errors = [], [], []
    for k in range(count):
        kind, opts = netgenerate_options(k, seed)
        name = f"gen{k:03d}_{kind}"
        path = dataset / ds.NETS_DIR / f"{name}.net.xml"
        path.parent.mkdir(parents=True, exist_ok=True)
        if not path.exists():
            tmp = path.with_name(f"{name}.tmp.net.xml")
            proc = subprocess.run([sumo_env.binary("netgenerate"), *opts, "--output-file", str(tmp)],
                                  capture_output=True, text=True, env=sumo_env.subprocess_env())
            if proc.returncode != 0 or not tmp.exists():
                msg = " ".join((proc.stderr or proc.stdout).split())[-300:]
                errors.append(f"netgenerate {name}: {msg or f'exit code {proc.returncode}'}")
                tmp.unlink(missing_ok=True)
                continue
            tmp.replace(path)
        sources.append(Source(name=name, path=path, is_config=False, has_demand=False))
        records.append({"name": name, "kind": kind, "path": str(path.relative_to(dataset)),
                        "netgenerate": opts})
    return sources, records, errors


# ----------------------------------------------------------------------------- one run (in a worker)

def _random_trips(task: RunTask) -> Path:
    """Seeded random trips over the run's duration, validated by duarouter into routes."""
    from coster_sumo import sumo_env

    work = task.work
    types = work / "vtypes.add.xml"
    types.write_text(_VTYPES)
    routes = work / "trips.rou.xml"
    cmd = [sys.executable, sumo_env.tool("randomTrips.py"), "-n", str(task.source.path.resolve()),
           "-o", str(work / "trips.trips.xml"), "-r", str(routes), "-a", str(types),
           "-b", "0", "-e", f"{task.duration_s:g}", "--seed", str(task.seed),
           "--insertion-density", f"{RANDOM_TRIPS_DENSITY:g}", "--fringe-factor", "5",
           "--min-distance", "150", "--random-depart", "--validate", "--edge-permission", "passenger",
           "--trip-attributes", 'type="mix" departLane="best" departSpeed="max"']
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=work, env=sumo_env.subprocess_env())
    if proc.returncode != 0 or not routes.exists():
        msg = " ".join((proc.stderr or proc.stdout).split())[-300:]
        raise RuntimeError(f"randomTrips failed: {msg or f'exit code {proc.returncode}'}")
    return routes


def simulate_run(task: RunTask) -> dict[str, Any]:
    """Simulate, record in chunks, cut and write clips. Returns counts for the manifest."""
    from coster_sumo.scene import save_scene
    from coster_sumo.sim.record import record
    from coster_sumo.sim.session import SumoSession

    t_wall = time.perf_counter()
    task.work.mkdir(parents=True, exist_ok=True)
    scenes = ds.scenes_dir(task.dataset)
    scenes.mkdir(parents=True, exist_ok=True)
    options = {"--scale": f"{task.scale:.4f}", "--ignore-route-errors": "true"}
    if task.source.is_config:
        session = SumoSession(task.source.path, seed=task.seed, end=task.duration_s, options=options)
    else:
        routes = _random_trips(task)
        session = SumoSession(net=task.source.path, routes=routes, seed=task.seed, begin=0.0,
                              end=task.duration_s, options=options)
    rng = np.random.default_rng([task.seed, zlib.crc32(task.run_id.encode())])
    clips = 0
    vehicles: set[str] = set()
    sim_end = 0.0
    with session:
        chunk_start = 0.0
        num_chunks = max(1, math.ceil(task.duration_s / CHUNK_S - 1e-9))
        for chunk in range(num_chunks):
            chunk_end = min(task.duration_s, round((chunk + 1) * CHUNK_S, 6))
            scene = record(session, end=chunk_end, scenario_id=task.run_id,
                           meta={"run_id": task.run_id, "scale": task.scale, "seed": task.seed,
                                 "source": str(task.source.path)})
            sim_end = session.time
            vehicles.update(scene.tracks.ids.tolist())
            budget = math.ceil((task.max_clips - clips) / (num_chunks - chunk))
            warmup = max(0.0, task.warmup_s - chunk_start)
            if scene.num_steps >= ds.CLIP_STEPS and budget > 0 and warmup < chunk_end - chunk_start:
                picks = ds.plan_clips(scene, budget, rng, targets_per_window=task.targets_per_window,
                                      warmup_s=warmup)
                for start, target in picks:
                    t0 = float(scene.timestamps[start])
                    name = f"{task.run_id}_{t0:07.1f}_{ds.safe_name(str(scene.tracks.ids[target]))}"
                    clip = ds.clip_scene(scene, start, target, scenario_id=name)
                    save_scene(clip, scenes / f"{name}.npz")
                    clips += 1
            chunk_start = chunk_end
            if session.min_expected_number() == 0 or sim_end >= task.duration_s - 1e-6:
                break
    return {"status": "ok", "clips": clips, "vehicles": len(vehicles), "simulated_s": round(sim_end, 3),
            "wall_s": round(time.perf_counter() - t_wall, 2)}


def _worker(task: RunTask, result_path: str, debug: bool) -> None:
    """Process entry point: run the task, write its result (or its error) as JSON."""
    try:
        result = simulate_run(task)
    except Exception as exc:  # noqa: BLE001 -- a failed run is reported, the batch goes on
        text = " ".join(str(exc).split()) or type(exc).__name__
        result = {"status": "failed", "error": text}
        if debug:
            result["traceback"] = traceback.format_exc()
    tmp = Path(result_path + ".tmp")
    tmp.write_text(json.dumps(result))
    tmp.replace(result_path)


# ----------------------------------------------------------------------------- the batch

@dataclass
class SimulateConfig:
    """What ``coster-sumo simulate`` does (built from the command line, or in code)."""

    sources: list[Path]
    dataset: Path
    seeds: int = 3
    seed: int = 0
    duration_s: float | None = None
    warmup_s: float | None = None
    workers: int = 1
    netgenerate: int = 0
    clips_per_run: int = 20
    targets_per_window: int = 3
    scale_range: tuple[float, float] = (0.6, 1.4)
    quiet: bool = False
    debug: bool = False


def plan_runs(cfg: SimulateConfig, sources: list[Source]) -> list[RunTask]:
    """Every (source, seed) run with its scale, duration and warm-up."""
    lo, hi = cfg.scale_range
    tasks = []
    for src in sources:
        duration = cfg.duration_s or src.end_s or DEFAULT_DURATION_S
        if cfg.warmup_s is not None:
            warmup = cfg.warmup_s
        else:  # shipped configurations preload traffic; random trips start from an empty network
            warmup = 0.0 if src.has_demand else min(GENERATED_WARMUP_S, duration / 3.0)
        for i in range(cfg.seeds):
            seed = cfg.seed + i
            u = np.random.default_rng([seed, zlib.crc32(src.name.encode())]).random()
            tasks.append(RunTask(run_id=f"{src.name}_s{seed}", source=src, seed=seed,
                                 scale=lo + (hi - lo) * u, duration_s=float(duration), warmup_s=float(warmup),
                                 max_clips=cfg.clips_per_run, targets_per_window=cfg.targets_per_window,
                                 dataset=cfg.dataset))
    return tasks


def _context() -> Any:
    # fork is cheapest and fine here (the parent never starts SUMO: docs/sumo.md §6); spawn elsewhere
    return mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")


def run_simulate(cfg: SimulateConfig) -> dict[str, Any]:
    """Run the batch; returns the summary (also written to ``DATASET/summary.json``)."""
    from tqdm import tqdm

    t_wall = time.perf_counter()
    sources = resolve_sources(cfg.sources)
    if not sources and not cfg.netgenerate:
        raise InputError("nothing to simulate: give .sumocfg / .net.xml files or --netgenerate K")
    if cfg.seeds < 1 or cfg.workers < 1 or cfg.clips_per_run < 0 or cfg.netgenerate < 0:
        raise InputError("--seeds and --workers must be >= 1, --clips-per-run and --netgenerate >= 0")
    if not (0.0 < cfg.scale_range[0] <= cfg.scale_range[1]):
        raise InputError(f"--scale-range must be 0 < LO <= HI, got {cfg.scale_range}")
    cfg.dataset.mkdir(parents=True, exist_ok=True)
    manifest = ds.read_manifest(cfg.dataset)
    failures: list[str] = []
    if cfg.netgenerate:
        gen_sources, gen_records, gen_errors = generate_nets(cfg.dataset, cfg.netgenerate, cfg.seed)
        sources += gen_sources
        known = {r["name"] for r in manifest.get("generated_nets", [])}
        manifest.setdefault("generated_nets", []).extend(r for r in gen_records if r["name"] not in known)
        failures += gen_errors
        for e in gen_errors:
            print(f"coster-sumo simulate: {e}", file=sys.stderr)
    tasks = plan_runs(cfg, sources)
    done = {r["run_id"] for r in manifest["runs"] if r.get("status") == "ok"}
    todo = [t for t in tasks if t.run_id not in done]
    manifest["runs"] = [r for r in manifest["runs"] if r.get("status") == "ok"]  # failed runs are retried
    ds.write_manifest(cfg.dataset, manifest)

    ctx = _context()
    tqdm.monitor_interval = 0  # no monitor thread in a parent that forks workers
    clips = 0
    bar = tqdm(total=len(tasks), initial=len(tasks) - len(todo), unit="run", disable=cfg.quiet,
               desc="simulate", dynamic_ncols=True)
    running: dict[Any, tuple[Any, RunTask, Path]] = {}
    queue = list(todo)
    try:
        while queue or running:
            while queue and len(running) < cfg.workers:
                task = queue.pop(0)
                task.work.mkdir(parents=True, exist_ok=True)
                result_path = task.work / "result.json"
                result_path.unlink(missing_ok=True)
                proc = ctx.Process(target=_worker, args=(task, str(result_path), cfg.debug), daemon=True)
                proc.start()
                running[proc.sentinel] = (proc, task, result_path)
            for sentinel in wait(list(running)):
                proc, task, result_path = running.pop(sentinel)
                proc.join()
                if result_path.exists():
                    result = json.loads(result_path.read_text())
                else:
                    result = {"status": "failed",
                              "error": f"the worker process died (exit code {proc.exitcode}; "
                                       "a negative code is the signal, e.g. -11 = SUMO crashed)"}
                entry = task.manifest_entry() | result
                if result["status"] == "ok":
                    clips += int(result["clips"])
                    shutil.rmtree(task.work, ignore_errors=True)
                else:
                    failures.append(f"{task.source.path} (seed {task.seed}): {result['error']}")
                    msg = f"coster-sumo simulate: {failures[-1]}"
                    if cfg.debug and "traceback" in result:
                        msg += "\n" + result.pop("traceback")
                    if cfg.quiet:
                        print(msg, file=sys.stderr)
                    else:
                        tqdm.write(msg, file=sys.stderr)
                    entry.pop("traceback", None)
                manifest["runs"].append(entry)
                ds.write_manifest(cfg.dataset, manifest)
                bar.update(1)
                bar.set_postfix(clips=clips, failed=len(failures))
    finally:
        for proc, _, _ in running.values():  # interrupted: stop our own workers
            proc.terminate()
        bar.close()
    work = cfg.dataset / WORK_DIR
    if work.is_dir() and not any(work.iterdir()):
        work.rmdir()
    manifest = ds.read_manifest(cfg.dataset)
    summary = {"dataset": str(cfg.dataset), "runs_planned": len(tasks), "runs_done_now": len(todo),
               "runs_failed_now": len(failures), "clips_now": clips, "failures": failures,
               "total_scenes": manifest["counts"]["scenes"], "simulated_hours": manifest["simulated_hours"],
               "wall_s": round(time.perf_counter() - t_wall, 2),
               "config": {k: (str(v) if isinstance(v, Path) else v)
                          for k, v in dataclasses.asdict(cfg).items() if k not in ("quiet", "debug")}
               | {"sources": [str(p) for p in cfg.sources]}}
    tmp = cfg.dataset / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=1) + "\n")
    tmp.replace(cfg.dataset / "summary.json")
    return summary


# ----------------------------------------------------------------------------- command line

def _cmd(args: argparse.Namespace) -> int:
    cfg = SimulateConfig(
        sources=[Path(p) for p in args.sources], dataset=Path(args.output), seeds=args.seeds, seed=args.seed,
        duration_s=args.duration, warmup_s=args.warmup, workers=args.workers, netgenerate=args.netgenerate,
        clips_per_run=args.clips_per_run, targets_per_window=args.targets_per_window,
        scale_range=(args.scale_range[0], args.scale_range[1]), quiet=args.quiet, debug=args.debug)
    summary = run_simulate(cfg)
    if not args.quiet:
        print(f"{summary['runs_done_now'] - summary['runs_failed_now']} runs done, "
              f"{summary['runs_failed_now']} failed, {summary['clips_now']} clips written; dataset "
              f"{cfg.dataset}: {summary['total_scenes']} scenes, "
              f"{summary['simulated_hours']:.3f} h simulated")
    return 1 if summary["failures"] else 0


def register(cli: Any) -> None:
    p = cli.commands.add_parser(
        "simulate", help="simulate nominal traffic into a dataset of WOMD-like clips",
        description=__doc__.split("\n\n")[1] if __doc__ else None)
    p.add_argument("sources", nargs="*", metavar="CFG",
                   help=".sumocfg files (their own demand) or .net.xml files (random trips)")
    p.add_argument("-o", "--output", required=True, metavar="DATASET", help="dataset folder (created)")
    p.add_argument("--seeds", type=int, default=3, metavar="N", help="runs per source (default 3)")
    p.add_argument("--seed", type=int, default=0, help="first seed; runs use seed, seed+1, ... (default 0)")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help=f"simulated seconds per run (default: the configuration's end, else "
                        f"{DEFAULT_DURATION_S:g})")
    p.add_argument("--warmup", type=float, default=None, metavar="S",
                   help="seconds simulated before clips are cut (default 0 for configurations with "
                        f"demand, {GENERATED_WARMUP_S:g} for random trips)")
    p.add_argument("--workers", type=int, default=1, metavar="W", help="parallel runs (processes)")
    p.add_argument("--netgenerate", type=int, default=0, metavar="K",
                   help="also generate K networks (grid / spider / random) into DATASET/nets/")
    p.add_argument("--clips-per-run", type=int, default=20, metavar="M", help="at most M clips per run")
    p.add_argument("--targets-per-window", type=int, default=3, metavar="T",
                   help="targets per 9.1 s window (default 3)")
    p.add_argument("--scale-range", type=float, nargs=2, default=(0.6, 1.4), metavar=("LO", "HI"),
                   help="demand scale (SUMO --scale) drawn per run from [LO, HI] (default 0.6 1.4)")
    p.set_defaults(func=_cmd)
