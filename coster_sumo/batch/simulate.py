"""Nominal traffic from SUMO into a dataset of WOMD-like clips (the library behind ``coster-sumo simulate``).

Each :class:`Source` (a ``.sumocfg``, a net with its own route files, or a bare ``.net.xml``) is
simulated in one or more :class:`RunTask` s, every run with its own SUMO ``--seed``, a demand
scale (SUMO's ``--scale``) and, for nets without demand, seeded random trips (SUMO's
``randomTrips.py``) of a vType mix. Runs go through the project's one executor
(:func:`coster_sumo.batch.executor.execute`: one process per run, since libsumo holds one simulation
per process, docs/sumo.md §6; a timeout per run; a progress bar).

A run records at 10 Hz (:mod:`coster_sumo.sim.record`) in chunks and cuts clips from each chunk
(:func:`coster_sumo.data.dataset.plan_clips`), written to ``DATASET/scenes/`` (or ``DATASET/heldout/``
for runs on held-out networks, which training never lists). With ``stats`` it also samples every
vehicle once per simulated second (speed, acceleration, lateral speed, lane speed limit, class,
size) and summarises every clip, into ``DATASET/stats/<run>.npz`` for the corpus card.
``DATASET/manifest.json`` is rewritten after every run; a run that fails is reported in one line
and the others go on. Running the same batch again runs only the runs the manifest does not list
as done (after a crash or a SIGKILL too: clip names are deterministic, a rerun overwrites).
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.batch.executor import ExecutorSettings, Outcome, Task, execute
from coster_sumo.batch.nets import Source, generate_nets, run_tool
from coster_sumo.batch.records import BatchCounts, RunOutcome, SimulateSummary
from coster_sumo.batch.run_stats import Sampler, clip_summary, clip_vru_seconds
from coster_sumo.core.scene import ObjectType
from coster_sumo.data import dataset as ds
from coster_sumo.errors import InputError, not_found
from coster_sumo.formats.sumocfg import read_sumocfg
from coster_sumo.infra.atomic import atomic_path, write_json, write_text
from coster_sumo.infra.outdir import MARKER, OutputLock, check_output, write_marker

DEFAULT_DURATION_S = 300.0  # [s] per run when neither --duration nor the configuration says
DEFAULT_TIMEOUT_S = 1800.0  # [s] wall clock per run
CHUNK_S = 7 * 9.1  # [s] recorded at a time (7 clip windows): bounds memory; clips never span chunks
RANDOM_TRIPS_DENSITY = 100.0  # [veh/h per km of lane] randomTrips --insertion-density before --scale
GENERATED_WARMUP_S = 60.0  # [s] networks that start empty are filled this long before clips are cut
WORK_DIR = ".work"
STATS_DIR = "stats"

# vTypes for random trips: mostly cars, some vans, trucks and motorcycles (duarouter copies them
# into the route file, so the file is self-contained)
DEFAULT_VTYPES = """<additional>
    <vType id="car" vClass="passenger" length="4.6" width="1.8" sigma="0.5" speedDev="0.1"/>
    <vType id="van" vClass="delivery" length="6.5" width="2.1" sigma="0.5" speedDev="0.1"/>
    <vType id="truck" vClass="truck" length="12.0" width="2.5" minGap="3.0" sigma="0.5" speedDev="0.05"
           maxSpeed="25"/>
    <vType id="moto" vClass="motorcycle" length="2.2" width="0.9" sigma="0.5" speedDev="0.15"/>
    <vTypeDistribution id="mix" vTypes="car van truck moto" probabilities="0.78 0.1 0.07 0.05"/>
</additional>
"""


@dataclass(frozen=True)
class RunTask:
    """One simulation run (plain, picklable data: it crosses into a task process).

    Attributes beyond the obvious: ``options`` are extra SUMO options (e.g. ``--carfollow.model``,
    ``--lateral-resolution``); ``trip_density`` the randomTrips insertion density [veh/h/km of
    lane] before ``scale``; ``bike_density`` that of a second, bicycle-only trip set (0: none);
    ``vtypes`` the vType XML random trips draw from (type ``mix``); ``ped_density`` random walks
    per hour and km of sidewalk (``sidewalk_km`` of them in the net; 0: no pedestrians, and none
    recorded: :mod:`coster_sumo.batch.pedestrians`); ``heldout`` sends the clips to
    ``DATASET/heldout/``; ``stats`` writes ``DATASET/stats/<run>.npz``; ``info`` goes to the
    manifest as it is.
    """

    run_id: str
    source: Source
    seed: int
    scale: float  # SUMO --scale [-]
    duration_s: float  # [s]
    warmup_s: float  # [s] simulated but not cut into clips
    max_clips: int
    targets_per_window: int
    dataset: Path
    options: dict[str, str] = field(default_factory=dict)
    trip_density: float = RANDOM_TRIPS_DENSITY
    bike_density: float = 0.0
    vtypes: str = DEFAULT_VTYPES
    ped_density: float = 0.0
    sidewalk_km: float = 0.0
    network: str = ""
    heldout: bool = False
    stats: bool = False
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def work(self) -> Path:
        # absolute: SUMO's tools run inside it (``cwd``) and are handed paths below it
        return self.dataset.resolve() / WORK_DIR / self.run_id

    @property
    def clips_dir(self) -> Path:
        return ds.heldout_dir(self.dataset) if self.heldout else ds.scenes_dir(self.dataset)

    def manifest_entry(self) -> dict[str, Any]:
        entry: dict[str, Any] = {"run_id": self.run_id, "source": str(self.source.path),
                 "kind": "sumocfg" if self.source.is_config else "net",
                 "demand": "config" if self.source.has_demand else "randomTrips", "seed": self.seed,
                 "scale": round(self.scale, 4), "duration_s": self.duration_s, "warmup_s": self.warmup_s}
        if self.network:
            entry |= {"network": self.network, "heldout": self.heldout}
        if not self.source.has_demand and self.trip_density != RANDOM_TRIPS_DENSITY:
            entry["trip_density"] = round(self.trip_density, 2)
        if self.bike_density:
            entry["bike_density"] = round(self.bike_density, 2)
        if self.ped_density:  # absent without pedestrians: entries of earlier builds stay as they were
            entry |= {"ped_density": round(self.ped_density, 2), "sidewalk_km": round(self.sidewalk_km, 3)}
        if self.options:
            entry["options"] = dict(self.options)
        return entry | self.info


# ----------------------------------------------------------------------------- sources

def resolve_sources(paths: list[Path]) -> list[Source]:
    """Check every input exists and is a ``.sumocfg`` or ``.net.xml``; give each a unique name."""
    out: list[Source] = []
    used: set[str] = set()
    for p in paths:
        if not p.is_file():
            raise not_found(p)
        is_cfg = p.suffix == ".sumocfg"
        if not is_cfg and not p.name.endswith((".net.xml", ".net.xml.gz")):
            raise InputError(f"{p}: expected a .sumocfg or a .net.xml")
        has_demand, end, begin = False, None, 0.0
        if is_cfg:
            cfg = read_sumocfg(p)
            has_demand, end, begin = cfg.has_demand, cfg.end, cfg.begin or 0.0
        stem = p.name.split(".")[0]
        name = ds.safe_name(stem)
        if name in used:
            name = ds.safe_name(f"{p.parent.name}-{stem}")
        k = 2
        base = name
        while name in used:
            name, k = f"{base}-{k}", k + 1
        used.add(name)
        out.append(Source(name=name, path=p, is_config=is_cfg, has_demand=has_demand, end_s=end, begin_s=begin))
    return out


# ----------------------------------------------------------------------------- one run (in a task process)

def _random_trips(task: RunTask) -> list[Path]:
    """Seeded random trips over the run's duration, validated by duarouter into routes.

    Vehicles of the ``mix`` distribution on passenger roads; with ``bike_density`` also bicycles
    on the roads that allow them (a second trip set: they route over their own permissions).
    """
    from coster_sumo.infra import sumo_install

    work = task.work
    types = write_text(work / "vtypes.add.xml", task.vtypes)
    begin = task.source.begin_s
    sets = [("trips", "passenger", task.trip_density, "mix", "")]
    if task.bike_density > 0:
        sets.append(("bikes", "bicycle", task.bike_density, "bike", "bike"))
    out = []
    for stem, vclass, density, vtype, prefix in sets:
        routes = work / f"{stem}.rou.xml"
        cmd = [sys.executable, sumo_install.tool("randomTrips.py"), "-n", str(task.source.path.resolve()),
               "-o", str(work / f"{stem}.trips.xml"), "-r", str(routes), "-a", str(types),
               "-b", f"{begin:g}", "-e", f"{begin + task.duration_s:g}", "--seed", str(task.seed),
               "--insertion-density", f"{density:g}", "--fringe-factor", "5",
               "--min-distance", "150", "--random-depart", "--validate", "--edge-permission", vclass,
               "--trip-attributes", f'type="{vtype}" departLane="best" departSpeed="max"']
        if prefix:
            cmd += ["--prefix", prefix, "--vclass", vclass]
        run_tool(cmd, f"randomTrips ({vclass})", cwd=work)
        if not routes.exists():
            if prefix:
                continue  # no road allows bicycles: the run goes on without them
            raise RuntimeError("randomTrips wrote no routes")
        out.append(routes)
    return out


def _open_session(task: RunTask) -> Any:
    """The run's :class:`SumoSession` (not started): its configuration, or its net with its own
    demand or seeded random trips, plus its pedestrians' walks when it has any."""
    from coster_sumo.sim.session import SumoSession

    src = task.source
    options = {"--scale": f"{task.scale:.4f}", "--ignore-route-errors": "true"} | task.options
    begin = src.begin_s
    end = begin + task.duration_s
    walks: list[Path] = []
    if task.ped_density > 0 and not src.is_config:
        from coster_sumo.batch.pedestrians import pedestrian_trips

        walks = pedestrian_trips(task)
    if src.is_config:
        session = SumoSession(src.path, seed=task.seed, end=end, options=options)
    elif src.has_demand:
        session = SumoSession(net=src.path, routes=list(src.routes) + walks, additional=list(src.additional),
                              seed=task.seed, begin=begin, end=end, options=options)
    else:
        session = SumoSession(net=src.path, routes=_random_trips(task) + walks, additional=list(src.additional),
                              seed=task.seed, begin=begin, end=end, options=options)
    return session


def simulate_run(task: RunTask) -> RunOutcome:
    """Simulate, record in chunks, cut and write clips. Returns counts for the manifest."""
    from coster_sumo.formats.scene_file import save_scene
    from coster_sumo.sim.persons import PersonReader
    from coster_sumo.sim.record import record

    t_wall, t_cpu = time.perf_counter(), time.process_time()
    task.work.mkdir(parents=True, exist_ok=True)
    out_dir = task.clips_dir
    out_dir.mkdir(parents=True, exist_ok=True)
    session = _open_session(task)
    src, begin = task.source, task.source.begin_s
    end = begin + task.duration_s
    rng = np.random.default_rng([task.seed, zlib.crc32(task.run_id.encode())])
    sampler = Sampler() if task.stats else None
    persons = PersonReader() if task.ped_density > 0 else None
    after_step = sampler if persons is None else _chain(sampler, persons)
    clip_rows: list[tuple[float, ...]] = []
    clips = 0
    vehicles: set[str] = set()
    sim_end = begin
    with session:
        chunk_start = begin
        num_chunks = max(1, math.ceil(task.duration_s / CHUNK_S - 1e-9))
        for chunk in range(num_chunks):
            chunk_end = min(end, round(begin + (chunk + 1) * CHUNK_S, 6))
            scene = record(session, end=chunk_end, after_step=after_step)
            if persons is not None:
                scene = persons.merge(scene)
            scene = dataclasses.replace(scene, scenario_id=task.run_id, meta=scene.meta | {
                "run_id": task.run_id, "scale": task.scale, "seed": task.seed,
                "source": str(src.path)} | ({"network": task.network} if task.network else {}))
            sim_end = session.time
            vehicles.update(scene.tracks.ids[scene.tracks.object_type != ObjectType.PEDESTRIAN].tolist())
            budget = math.ceil((task.max_clips - clips) / (num_chunks - chunk))
            warmup = max(0.0, begin + task.warmup_s - chunk_start)
            if scene.num_steps >= ds.CLIP_STEPS and budget > 0 and warmup < chunk_end - chunk_start:
                picks = ds.plan_clips(scene, budget, rng, ds.ClipRules(task.targets_per_window, warmup_s=warmup))
                for start, target in picks:
                    t0 = float(scene.timestamps[start]) - begin
                    name = ds.clip_name(task.run_id, t0, str(scene.tracks.ids[target]))
                    clip = ds.clip_scene(scene, start, target, scenario_id=name)
                    save_scene(clip, out_dir / f"{name}.npz")
                    if sampler is not None:
                        clip_rows.append((*clip_summary(clip), *clip_vru_seconds(clip)))
                    clips += 1
            chunk_start = chunk_end
            if session.min_expected_number() == 0 or sim_end >= end - 1e-6:
                break
    if sampler is not None:
        stats = Path(task.dataset) / STATS_DIR / f"{task.run_id}.npz"
        stats.parent.mkdir(parents=True, exist_ok=True)
        clip_arr = np.array(clip_rows, np.float32).reshape(-1, 6)
        with atomic_path(stats) as tmp:
            arrays = sampler.arrays() | {"clip_agents": clip_arr[:, 0], "clip_median_speed": clip_arr[:, 1],
                                         "clip_speed_limit": clip_arr[:, 2], "clip_target_speed": clip_arr[:, 3],
                                         "clip_ped_s": clip_arr[:, 4], "clip_cyclist_s": clip_arr[:, 5]}
            np.savez_compressed(tmp, **arrays)  # type: ignore[arg-type]
    import resource

    children = resource.getrusage(resource.RUSAGE_CHILDREN)  # randomTrips, duarouter
    cpu = time.process_time() - t_cpu + children.ru_utime + children.ru_stime
    return RunOutcome(clips=clips, vehicles=len(vehicles), simulated_s=round(sim_end - begin, 3),
                      wall_s=round(time.perf_counter() - t_wall, 2), cpu_s=round(cpu, 2))


def _chain(*calls: Any) -> Any:
    """One ``after_step`` that calls each of ``calls`` (None ones left out) and never stops the run."""
    live = [c for c in calls if c is not None]

    def after_step(session: Any, states: Any) -> None:
        for c in live:
            c(session, states)

    return after_step


def run_task(payload: dict[str, Any]) -> RunOutcome:
    """Executor entry point: one :class:`RunTask` (``payload["run"]``)."""
    return simulate_run(payload["run"])


# ----------------------------------------------------------------------------- batches

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
    timeout_s: float = DEFAULT_TIMEOUT_S
    quiet: bool = False
    debug: bool = False


def plan_runs(cfg: SimulateConfig, sources: list[Source]) -> list[RunTask]:
    """Every (source, seed) run with its scale, duration and warm-up."""
    lo, hi = cfg.scale_range
    tasks = []
    for src in sources:
        duration = cfg.duration_s or src.end_s or DEFAULT_DURATION_S
        if cfg.duration_s is None and src.end_s is not None:
            duration = src.end_s - src.begin_s
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


@dataclass
class BatchResult:
    """What :func:`run_batch` did: runs planned / run now, failures (one line each), clips, wall time."""

    planned: int
    done_now: int
    failures: list[str]
    clips: int
    wall_s: float


def _same_plan(task: RunTask, entry: dict[str, Any]) -> bool:
    """Whether a recorded run was planned as ``task`` is (every planned manifest field equal)."""
    planned = json.loads(json.dumps(task.manifest_entry(), default=str))
    if "ped_density" in entry and "ped_density" not in planned:  # recorded with pedestrians, planned without
        return False
    return all(entry.get(k) == v for k, v in planned.items())


def _remove_outputs(dataset: Path, run_id: str) -> None:
    """Delete a run's clips (training or held-out) and statistics."""
    for folder in (ds.scenes_dir(dataset), ds.heldout_dir(dataset)):
        for p in folder.glob(f"{run_id}_*.npz") if folder.is_dir() else ():
            if p.name[len(run_id) + 1:][:1].isdigit():  # <run_id>_<start time>_<target>.npz
                p.unlink()
    (dataset / STATS_DIR / f"{run_id}.npz").unlink(missing_ok=True)


def run_batch(tasks: list[RunTask], dataset: Path, manifest: dict[str, Any], *, workers: int = 1,
              timeout_s: float = DEFAULT_TIMEOUT_S, quiet: bool = False, debug: bool = False,
              what: str = "simulate") -> BatchResult:
    """Run the ``tasks`` the manifest does not list as done, on the executor; the manifest is
    rewritten after every run (failed runs are listed as such and retried next time). A run the
    manifest lists as done but with another plan (seed, scale, demand, options...) is stale: its
    clips and statistics are removed and it runs again."""
    from tqdm import tqdm

    t_wall = time.perf_counter()
    recorded = {r["run_id"]: r for r in manifest["runs"] if r.get("status") == "ok"}
    todo, stale = [], []
    for t in tasks:
        entry = recorded.get(t.run_id)
        if entry is None:
            todo.append(t)
        elif not _same_plan(t, entry):  # planned differently since (another version): run it again
            todo.append(t)
            stale.append(t.run_id)
    for t in todo:  # stale runs, and what a run cut short (a crash, SIGKILL) left behind
        _remove_outputs(dataset, t.run_id)
    manifest["runs"] = [r for r in manifest["runs"] if r.get("status") == "ok" and r["run_id"] not in stale]
    ds.write_manifest(dataset, manifest)
    failures: list[str] = []
    clips = 0

    def on_done(task: Task, outcome: Outcome) -> list[Task]:
        nonlocal clips
        run: RunTask = task.payload["run"]
        entry = run.manifest_entry()
        if outcome.ok:
            done: RunOutcome = outcome.value
            entry |= done.to_json()
            clips += done.clips
            import shutil

            shutil.rmtree(run.work, ignore_errors=True)
        else:
            entry |= {"status": "failed", "error": outcome.reason}
            failures.append(f"{run.source.path} (seed {run.seed}): {outcome.reason}")
            msg = f"coster-sumo {what}: {failures[-1]}"
            if debug and outcome.detail:
                msg += "\n" + outcome.detail
            if quiet:
                print(msg, file=sys.stderr)
            else:
                tqdm.write(msg, file=sys.stderr)
        manifest["runs"].append(entry)
        ds.write_manifest(dataset, manifest)
        return []

    for run in todo:
        run.work.mkdir(parents=True, exist_ok=True)
    how = ExecutorSettings(workers, timeout=timeout_s, log_dir=dataset / WORK_DIR / "logs",
                           preload=("libsumo", "coster_sumo.sim.record"))
    execute([Task(key=t.run_id, fn=run_task, payload={"run": t}, kind="run") for t in todo], how,
            on_done=on_done, quiet=quiet, desc=what)
    logs = dataset / WORK_DIR / "logs"
    if logs.is_dir() and not failures:
        import shutil

        shutil.rmtree(logs, ignore_errors=True)
    work = dataset / WORK_DIR
    if work.is_dir() and not any(work.iterdir()):
        work.rmdir()
    return BatchResult(planned=len(tasks), done_now=len(todo), failures=failures, clips=clips,
                       wall_s=round(time.perf_counter() - t_wall, 2))


def run_simulate(cfg: SimulateConfig) -> SimulateSummary:
    """Run the batch; returns the summary (also written to ``DATASET/summary.json``)."""
    t_wall = time.perf_counter()
    sources = resolve_sources(cfg.sources)
    if not sources and not cfg.netgenerate:
        raise InputError("nothing to simulate: give .sumocfg / .net.xml files or --netgenerate K")
    if cfg.seeds < 1 or cfg.workers < 1 or cfg.clips_per_run < 0 or cfg.netgenerate < 0:
        raise InputError("--seeds and --workers must be >= 1, --clips-per-run and --netgenerate >= 0")
    if not (0.0 < cfg.scale_range[0] <= cfg.scale_range[1]):
        raise InputError(f"--scale-range must be 0 < LO <= HI, got {cfg.scale_range}")
    check_output(cfg.dataset, kind="dataset", inputs=[s.path for s in sources], reusable=True,
                 signature=ds.MANIFEST)
    cfg.dataset.mkdir(parents=True, exist_ok=True)
    with OutputLock(cfg.dataset, inside=True):
        if not (cfg.dataset / MARKER).exists():
            write_marker(cfg.dataset, "dataset")
        return _simulate_locked(cfg, sources, t_wall)


def _simulate_locked(cfg: SimulateConfig, sources: list[Source], t_wall: float) -> SimulateSummary:
    """:func:`run_simulate` once DATASET is checked and locked."""
    manifest = ds.read_manifest(cfg.dataset)
    failures: list[str] = []
    if cfg.netgenerate:
        gen_sources, gen_records, gen_errors = generate_nets(cfg.dataset, cfg.netgenerate, cfg.seed)
        sources += gen_sources
        known = {r["name"] for r in manifest.get("generated_nets", [])}
        manifest.setdefault("generated_nets", []).extend(r for r in gen_records if r["name"] not in known)
        failures += [f"netgenerate {e}" for e in gen_errors]
        for e in failures:
            print(f"coster-sumo simulate: {e}", file=sys.stderr)
    tasks = plan_runs(cfg, sources)
    result = run_batch(tasks, cfg.dataset, manifest, workers=cfg.workers, timeout_s=cfg.timeout_s,
                       quiet=cfg.quiet, debug=cfg.debug)
    failures += result.failures
    manifest = ds.read_manifest(cfg.dataset)
    counts = BatchCounts(runs_planned=result.planned, runs_done_now=result.done_now,
                         runs_failed_now=len(result.failures), clips_now=result.clips, failures=failures,
                         total_clips=manifest["counts"]["scenes"], simulated_hours=manifest["simulated_hours"],
                         wall_s=round(time.perf_counter() - t_wall, 2))
    config = {k: (str(v) if isinstance(v, Path) else v)
              for k, v in dataclasses.asdict(cfg).items() if k not in ("quiet", "debug")}
    summary = SimulateSummary(dataset=str(cfg.dataset), counts=counts,
                              config=config | {"sources": [str(p) for p in cfg.sources]})
    write_json(cfg.dataset / "summary.json", summary.to_json())
    return summary
