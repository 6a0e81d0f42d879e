"""``coster-sumo regress``: planners on the same generated variants, each run isolated.

For each scene the variants are generated **once** (a task writing ``OUT/plans/<scene_key>.json``
and the nominal scene ``OUT/plans/<scene_key>.npz``), then every planner runs on the same variants
(:func:`coster_sumo.sim.inject.inject_variant`). One row per (scene, variant, planner) goes into a
Parquet dataset ``OUT/results/`` as one small part file per run, written atomically, so a rerun
skips what is done and never duplicates a row.
"""

from __future__ import annotations

import dataclasses
import json
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.avoidability.labels import escape_dict
from coster_sumo.batch.executor import GENERATION_TASK_MODULES, ExecutorSettings, Outcome, Task, execute, is_transient
from coster_sumo.batch.scene_plans import ScenePlans, read_plans
from coster_sumo.batch.shared_pass import PASS_FILE, SharedPasses, shared_nominal
from coster_sumo.batch.sources import (
    CONFIG_DIR,
    BatchOptions,
    config_dir,
    located,
    nominal_for,
    parse_sources,
    scene_key,
    slug,
    task_folders,
)
from coster_sumo.batch.store import ResultRow, ResultStore, result_row, row_outcome
from coster_sumo.batch.summaries import (
    PLANNER_RATES,
    GenerationFailure,
    PlannerSummary,
    RegressionRunOptions,
    RegressionSummary,
    RunCounts,
    RunFailure,
    SceneCounts,
    defect_rates,
)
from coster_sumo.core.spec import GenerationConfig, ScenarioSpec, check_avoidable, check_reaction_time
from coster_sumo.errors import InputError, NoSnapshot
from coster_sumo.formats.sumocfg import read_sumocfg
from coster_sumo.infra.atomic import write_json
from coster_sumo.infra.outdir import MARKER, OutputLock, check_output, staged_names, write_marker
from coster_sumo.infra.weights import WEIGHT_FILES
from coster_sumo.method.generation import Variant, check_generation
from coster_sumo.metrics import MetricSample, compute
from coster_sumo.sim.planners import check_planner

ESCAPE_PLANNER = "escape"  # the reference planner: the target drives the variant's proven escape (replay without one)


def generation_task(payload: dict[str, Any]) -> dict[str, Any]:
    """Task: nominal pass + variants of one scene -> ``plans/<scene_key>.json`` (+ the scene's .npz)."""
    from coster_sumo.formats.targets import choose_target
    from coster_sumo.geometry.drivable import DrivableArea
    from coster_sumo.method.generation import generate_variants

    t0 = time.perf_counter()
    spec = located(ScenarioSpec.from_dict(payload["spec"]), payload)
    plans_dir = Path(payload["plans_dir"])
    gen = GenerationConfig.from_dict(payload["generation"])
    if payload.get("models_dir"):  # where the weights are for this task (a private copy on a Ray worker)
        gen = dataclasses.replace(gen, models_dir=Path(payload["models_dir"]))
    if payload.get(PASS_FILE):  # a pass shared with the configuration's other targets (batch.shared_pass)
        scene, converted, scene_file = shared_nominal(spec, plans_dir, payload[PASS_FILE])
    else:
        scene, converted, scene_file = nominal_for(spec, plans_dir)
    target = choose_target(scene, spec.target, spec.config)
    drivable = DrivableArea.from_road_map(scene.road_map)
    t1 = time.perf_counter()
    variants, info = generate_variants(scene, target, spec.seed, gen, drivable)
    t2 = time.perf_counter()
    variants, labels, avoidable_only = label_variants(spec, scene, target, variants, gen, drivable, payload)
    doc = ScenePlans(scene_key=payload["scene_key"], status="ok", spec=spec.to_dict(), converted=converted,
                     scene_file=scene_file.name, target_id=str(scene.tracks.ids[target]),
                     end=float(scene.timestamps[-1]), generation=payload["generation"],
                     variants=tuple(v.to_dict() for v in variants), info=info,
                     avoidability=tuple(lab.summary() for lab in labels),
                     escapes=tuple(escape_dict(lab.escape) for lab in labels), avoidable_only=avoidable_only,
                     timings_s={"nominal": round(t1 - t0, 3), "generation": round(t2 - t1, 3),
                                "avoidability": round(time.perf_counter() - t2, 3)})
    write_json(plans_dir / f"{payload['scene_key']}.json", doc.to_json())
    return {"scene_key": payload["scene_key"], "variants": len(variants)}




def label_variants(spec: ScenarioSpec, scene: Any, target: int, variants: list[Variant], gen: GenerationConfig,
                   drivable: Any, payload: dict[str, Any]) -> tuple[list[Variant], list[Any], dict[str, int] | None]:
    """Every variant's avoidability with its escapes proven in SUMO (:mod:`coster_sumo.avoidability.labels`);
    with ``--avoidable only`` the unavoidable ones are replaced by variants of further draws (and
    the counts of variants tried, kept and extra draws are returned; None without)."""
    from coster_sumo.avoidability.labels import ProofSettings, label_plans
    from coster_sumo.method.generation import EXTRA_DRAWS, derived_seed, generate_variants

    reaction = float(payload.get("reaction_time", 1.0))

    def label(vs: list[Variant]) -> list[Any]:
        proof = ProofSettings(drivable, traffic=payload.get("traffic", "log"))  # a converted scene's agents react
        return label_plans(spec, scene, target, [v.plan for v in vs], proof, reaction_time_s=reaction)

    labels = label(variants)
    if payload.get("avoidable", "any") != "only":
        return variants, labels, None
    tried = len(variants)
    kept = [(v, lab) for v, lab in zip(variants, labels, strict=True) if lab.avoidable]
    draws = 0
    for j in range(1, EXTRA_DRAWS + 1):
        if len(kept) >= gen.variants:
            break
        draws += 1
        try:
            more, _ = generate_variants(scene, target, derived_seed(spec.seed, 100 + j), gen, drivable)
        except NoSnapshot:
            continue
        tried += len(more)
        kept += [(v, lab) for v, lab in zip(more, label(more), strict=True) if lab.avoidable]
    kept = kept[:gen.variants]
    out = [dataclasses.replace(v, plan=v.plan.replaced(vehicle_id=f"adversary{i}"))
           for i, (v, _) in enumerate(kept)]
    if not out:
        raise NoSnapshot(f"none of the {tried} variants was avoidable at a reaction time of {reaction:g} s "
                         "(--avoidable only)")
    return out, [lab for _, lab in kept], {"tried": tried, "kept": len(out), "extra_draws": draws}


def _target_path(res: Any, target_id: str, every: int = 5) -> list[list[float]]:
    t = res.scene.tracks
    if target_id not in set(t.ids.tolist()):
        return []
    a = t.index_of(target_id)
    steps = np.flatnonzero(t.valid[a])[::every]
    return [[round(float(t.x[a, s]), 2), round(float(t.y[a, s]), 2)] for s in steps]


def run_task(payload: dict[str, Any]) -> ResultRow:
    """Task: one planner on one variant of one scene -> a result row (``store.RESULT_FIELDS``)."""
    from coster_sumo.avoidability.labels import escape_replay, planner_outcome
    from coster_sumo.core.plan import HORIZON_AFTER_TCOL_S
    from coster_sumo.core.spec import InjectionSettings
    from coster_sumo.formats.scene_file import load_scene
    from coster_sumo.geometry.drivable import DrivableArea
    from coster_sumo.pipeline.outputs import variant_outcome
    from coster_sumo.sim.inject import inject_variant

    plans_dir = Path(payload["plans_dir"])
    doc = ScenePlans.from_json(json.loads((plans_dir / f"{payload['scene_key']}.json").read_text()))
    scene = load_scene(plans_dir / doc.scene_file)
    spec = located(ScenarioSpec.from_dict(doc.spec), payload)
    i = int(payload["variant"])
    variant = doc.variant(i)
    plan, t_col = variant.plan, variant.snapshot.time
    target_id = doc.target_id
    target = scene.tracks.index_of(target_id)
    drivable = DrivableArea.from_road_map(scene.road_map)
    label = doc.label(i)
    avoidable = None if label is None else bool(label["avoidable"])
    driver, how = None, InjectionSettings(payload["planner"], traffic=payload.get("traffic", "log"))
    if payload["planner"] == ESCAPE_PLANNER:  # the reference: the variant's own escape, where it has one
        esc, how = doc.escape(i), dataclasses.replace(how, planner="replay")
        length = float(np.median(scene.tracks.length[target][scene.tracks.valid[target]]))
        driver = escape_replay(esc, length) if esc else None
    with tempfile.TemporaryDirectory(prefix="coster-run-") as wd:
        res = inject_variant(spec, scene, target, plan, dataclasses.replace(how, workdir=Path(wd)), drivable=drivable,
                             driver=driver)
    rec = variant_outcome(i, plan, res, target_id, t_col, scene if plan.vclass != "passenger" else None)
    in_horizon = any(e.kind == "collision" and target_id in e.vehicles and e.time <= t_col + HORIZON_AFTER_TCOL_S + 1e-6
                     for e in res.events)
    target_any = any(e.kind == "collision" and target_id in e.vehicles for e in res.events)
    return result_row(payload, status="ok", reason="", collision=rec.collision or target_any,
                      adversary_contact=rec.collision,
                      target_other_collision=any(e.kind == "collision" and target_id in e.vehicles
                                                 and plan.vehicle_id not in e.vehicles for e in res.events),
                      target_off_road=bool(res.target_off_road), adversary_off_road=bool(rec.adversary_off_road),
                      route_completed=bool(res.route_completed), target_arrived=bool(res.target_arrived),
                      min_ttc=rec.min_ttc, contact_time=rec.collision_time,
                      contact_offset_s=rec.contact_offset_s, relative_speed=rec.relative_speed,
                      impact_angle=rec.impact_angle, sumo_reported_contact=rec.sumo_reported_contact,
                      t_col=t_col, sim_wall_time_s=float(res.wall_time_s),
                      target_path=json.dumps(_target_path(res, target_id)),
                      avoidable=avoidable, contact_in_horizon=in_horizon, adversary_class=rec.adversary_class,
                      contact_kind=None if label is None else label["contact_kind"],
                      outcome=planner_outcome(res.scene, target_id, plan, in_horizon, avoidable))


@dataclass(kw_only=True)
class RegressOptions(BatchOptions):
    """Everything ``coster-sumo regress`` takes (see its --help)."""

    planners: list[str]
    variants: int = GenerationConfig.variants  # the same default as run and the API
    duration: float | None = None  # [s] each scene's window from its begin (instead of end)
    init: str = "snapshot"
    rollout: str = "cvae"
    collision_time: str = "entropy"
    samples: int = 1000
    adversary: str = "vehicle"  # vehicle | cyclist | pedestrian | any (coster_sumo.method.vru)
    retry_failed: bool = False
    report: bool = True
    start_method: str | None = None
    reaction_time: float = 1.0  # [s] the avoidability labels' reaction time (coster_sumo.avoidability.labels)
    avoidable: str = "any"  # any | only
    traffic: str = "log"  # log | reactive: converted scenes' agents (coster_sumo.sim.reactive)
    more_targets: tuple[str, ...] = ()  # further targets of every scene with ``target`` (sharing its pass)
    targets: int | None = None  # choose this many targets per configuration, as run --targets N does


def check_planners(planners: Sequence[str]) -> None:
    """At least one planner, all distinct (also as file names), each one that exists."""
    if not planners:
        raise InputError("give at least one --planner")
    if len(set(planners)) != len(planners) or len({slug(p) for p in planners}) != len(planners):
        raise InputError(f"--planner values must be distinct: {', '.join(planners)}")
    for p in planners:
        if p != ESCAPE_PLANNER:
            check_planner(p)


def generation_task_for(key: str, spec: ScenarioSpec, plans_dir: Path, gen: dict[str, Any],
                        models_dir: Path | None, labels: dict[str, Any], pass_file: str | None = None) -> Task:
    """The task that generates one scene's variants; with the folders it reads (the configuration,
    a cached nominal scene, the weights given by ``--models``) named, so that it runs on a Ray worker
    without a disk shared with OUT. ``labels``: the avoidability settings (reaction time, any|only);
    ``pass_file``: the nominal pass it shares with other targets (in ``plans_dir``; None: its own)."""
    payload: dict[str, Any] = {"scene_key": key, "spec": spec.to_dict(), "plans_dir": str(plans_dir),
                               "generation": gen, CONFIG_DIR: config_dir(spec), **labels}
    folders = task_folders(spec, plans_dir=(pass_file or f"{scene_key(spec)}.npz",))
    if pass_file:
        payload[PASS_FILE] = pass_file
    if models_dir is not None:
        payload["models_dir"] = str(models_dir)
        folders["models_dir"] = WEIGHT_FILES
    return Task(f"plan__{key}", generation_task, payload, kind="plan", folders=folders)
def with_duration(spec: ScenarioSpec, duration: float) -> ScenarioSpec:
    """``spec`` ending ``duration`` [s] after its begin (its own, else its configuration's), as
    ``run --duration`` does; a source that names its own end keeps it."""
    if duration <= 0:
        raise InputError(f"--duration must be positive, not {duration:g}")
    if spec.end is not None:
        return spec
    begin = spec.begin if spec.begin is not None else (read_sumocfg(spec.config).begin or 0.0)
    return dataclasses.replace(spec, end=begin + duration)


def with_targets(specs: list[ScenarioSpec], target: str | None, more: Sequence[str],
                 n: int | None) -> list[ScenarioSpec]:
    """``specs`` with a scene for every further target: the ``more`` targets beside each scene of
    ``target``, or (``n``) the ``n`` targets :func:`~coster_sumo.formats.targets.choose_targets` picks for each
    scene without one, as ``run --targets N`` picks them. The targets of a configuration, window and
    seed share one nominal pass (:mod:`coster_sumo.batch.shared_pass`)."""
    from coster_sumo.formats.targets import choose_targets

    if n is not None and n < 1:
        raise InputError(f"--targets must be >= 1, not {n}")
    out: list[ScenarioSpec] = []
    chosen: dict[tuple[str, float | None, float | None], list[str]] = {}
    for s in specs:
        if n is not None and s.target is None:
            where = (str(s.config.resolve()), s.begin, s.end)
            if where not in chosen:
                chosen[where] = [c.vehicle_id for c in choose_targets(s.config, n, s.begin, s.end)]
            out += [dataclasses.replace(s, target=t) for t in chosen[where]]
        else:
            out.append(s)
            if more and s.target == target:
                out += [dataclasses.replace(s, target=t) for t in more if t != target]
    return list(dict.fromkeys(out))


def run_key(scene: str, variant: int, planner: str, traffic: str = "log") -> str:
    """The run's key in the result store (reactive traffic's runs apart from the log's)."""
    return f"{scene}__v{variant}__{slug(planner)}" + ("" if traffic == "log" else f"__{traffic}")


def regress(opts: RegressOptions) -> RegressionSummary:
    """Run the regression (module docstring); returns the summary (also OUT/summary.json)."""
    t_start = time.perf_counter()
    check_planners(opts.planners)
    check_avoidable(opts.avoidable)
    check_reaction_time(opts.reaction_time)
    if opts.traffic not in ("log", "reactive"):
        raise InputError(f"traffic must be log or reactive, not {opts.traffic!r}")
    generation = GenerationConfig(init=opts.init, collision_time=opts.collision_time, rollout=opts.rollout,
                                  samples=opts.samples, variants=opts.variants, adversary=opts.adversary,
                                  models_dir=opts.models_dir.resolve() if opts.models_dir else None)
    check_generation(generation)
    specs = parse_sources(opts.sources, seed=opts.seed, seeds=opts.seeds, begin=opts.begin, end=opts.end,
                          target=opts.target)
    if opts.duration is not None:
        specs = [with_duration(s, opts.duration) for s in specs]
    specs = with_targets(specs, opts.target, opts.more_targets, opts.targets)
    out = Path(opts.out)
    check_output(out, kind="regress", inputs=[Path(s.config) for s in specs], reusable=True,
                 signature="regress.json")
    out.mkdir(parents=True, exist_ok=True)
    with OutputLock(out, inside=True):
        if not (out / MARKER).exists():
            write_marker(out, "regress")
        return _regress_locked(opts, t_start, generation, specs, out)


def _regress_locked(opts: RegressOptions, t_start: float, generation: GenerationConfig,
                    specs: list[ScenarioSpec], out: Path) -> RegressionSummary:
    """:func:`regress` once OUT is checked and locked: leftovers of stopped batches removed, then the runs."""
    plans_dir, logs_dir = out / "plans", out / "logs"
    gen = generation.to_dict()
    keys = {scene_key(s, gen): s for s in specs}
    store = _start_folder(out, opts, keys)
    # failed runs are done, unless the failure was the machine's (timeout, memory, disk) or --retry-failed
    failed_runs = {r.run_key for r in store.read()
                   if not r.ok and (opts.retry_failed or is_transient(r.reason or ""))}
    done = store.keys() - failed_runs
    n_runs_expected = len(keys) * opts.variants * len(opts.planners)

    def run_tasks_for(key: str, doc: ScenePlans) -> list[Task]:
        return _run_tasks(key, keys[key], doc, opts.planners, done, plans_dir, opts.traffic)

    shared = SharedPasses(keys, plans_dir)  # the targets of a configuration, window and seed share its pass
    labels = {"reaction_time": opts.reaction_time, "avoidable": opts.avoidable, "traffic": opts.traffic}

    def generation_for(key: str) -> Task:
        return generation_task_for(key, keys[key], plans_dir, gen, generation.models_dir, labels,
                                   shared.pass_file(key))

    initial: list[Task] = []
    for key in keys:
        doc = read_plans(out / "plans" / f"{key}.json")
        retry = opts.retry_failed or is_transient(str(doc.reason if doc else "") or "")
        if doc is not None and (doc.ok or not retry):
            if doc.ok:
                initial.extend(run_tasks_for(key, doc))
        elif not shared.wait(key):
            initial.append(generation_for(key))
    initial += shared.tasks()

    def on_done(task: Task, outcome: Outcome) -> list[Task]:
        if task.kind == "pass":  # the shared pass is there: its scenes generate (or all fail with it)
            if outcome.ok:
                return [generation_for(k) for k in shared.released(task)]
            for k in shared.released(task):
                _failed_plans(plans_dir, k, outcome.reason, keys[k].to_dict(), gen)
            outcome.append_to_log(logs_dir / f"{task.key}.log")
            return []
        key = task.payload["scene_key"]
        if task.kind == "plan":
            if outcome.ok:
                doc = read_plans(out / "plans" / f"{key}.json")
                return run_tasks_for(key, doc) if doc else []
            _failed_plans(plans_dir, key, outcome.reason, task.payload["spec"], gen)
            outcome.append_to_log(logs_dir / f"{task.key}.log")
            return []
        if outcome.ok:
            row = dataclasses.replace(outcome.value, wall_time_s=round(outcome.wall_time_s, 3))
        else:
            outcome.append_to_log(logs_dir / f"{task.key}.log")
            row = result_row(task.payload, status="failed", reason=outcome.reason,
                             wall_time_s=round(outcome.wall_time_s, 3))
        store.write(row)
        return []

    generations = sum(t.key.startswith("plan__") for t in initial) + shared.waiting_scenes
    how = ExecutorSettings(opts.workers, opts.executor, opts.timeout, opts.start_method, ray_address=opts.ray_address,
                           log_dir=logs_dir if opts.executor == "local" else None, preload=GENERATION_TASK_MODULES)
    # the first tasks generate the scenes' variants (tens of seconds each, nothing else moves meanwhile)
    execute(initial, how, on_done=on_done, quiet=opts.quiet, expected_total=len(initial) + shared.waiting_scenes
            + n_runs_expected - len(done), desc=f"regress (first {generations} scene generation"
            f"{'s' if generations != 1 else ''})" if generations else "regress")
    return _write_summary(opts, out, keys, generation, store, t_start)


def _write_summary(opts: RegressOptions, out: Path, keys: dict[str, ScenarioSpec], generation: GenerationConfig,
                   store: ResultStore, t_start: float) -> RegressionSummary:
    """OUT/summary.json (and the report) of a finished batch; returns the summary."""
    summary = dataclasses.replace(
        summarize_regression(out, keys, opts.planners), wall_time_s=round(time.perf_counter() - t_start, 3),
        options=RegressionRunOptions(variants=generation.variants, workers=opts.workers, executor=opts.executor,
                                     timeout_s=opts.timeout, init=generation.init, rollout=generation.rollout,
                                     collision_time=generation.collision_time, samples=generation.samples,
                                     seed=opts.seed, adversary=generation.adversary))
    write_json(out / "summary.json", summary.to_json())  # before the report: a plotting failure loses no result
    if opts.report:
        from coster_sumo.batch.report import write_regression_report

        summary = dataclasses.replace(summary, report=tuple(write_regression_report(out, summary, store.read())))
        write_json(out / "summary.json", summary.to_json())
    return summary


def _start_folder(out: Path, opts: RegressOptions, keys: dict[str, ScenarioSpec]) -> ResultStore:
    """OUT ready for the runs: ``plans/``, no half-written file of a batch that was killed, and
    ``regress.json`` (the options and the scenes by key); returns the result store."""
    (out / "plans").mkdir(parents=True, exist_ok=True)
    for folder in (out / "plans", out / "results"):
        for leftover in staged_names(folder, (".tmp.npz", ".tmp.json", ".tmp.parquet")):
            leftover.unlink(missing_ok=True)
    store = ResultStore(out / "results")
    write_json(out / "regress.json", {"options": {k: (str(v) if isinstance(v, Path) else v)
                                                    for k, v in dataclasses.asdict(opts).items()},
                                        "scenes": {k: s.label() for k, s in keys.items()}})
    return store


def _run_tasks(key: str, spec: ScenarioSpec, doc: ScenePlans, planners: Sequence[str], done: set[str],
               plans_dir: Path, traffic: str = "log") -> list[Task]:
    """Every planner's run on every variant of the scene ``key`` that is not ``done`` yet."""
    tasks = []
    for i in range(len(doc.variants)):
        for p in planners:
            rk = run_key(key, i, p, traffic)
            if rk not in done:
                tasks.append(Task(rk, run_task, {"run_key": rk, "scene_key": key, "variant": i, "planner": p,
                                                 "traffic": traffic,
                                                 "plans_dir": str(plans_dir), "config": str(spec.config),
                                                 "seed": spec.seed, CONFIG_DIR: config_dir(spec)}, kind="run",
                                  folders=task_folders(spec, plans_dir=(f"{key}.json", doc.scene_file))))
    return tasks


def _failed_plans(plans_dir: Path, key: str, reason: str | None, spec: dict[str, Any], gen: dict[str, Any]) -> None:
    """A scene's plans file that says why it has no variants."""
    write_json(plans_dir / f"{key}.json", ScenePlans(scene_key=key, status="failed", reason=reason, spec=spec,
                                                     generation=gen).to_json())


# a planner's figures in summary.json: key -> the metric of coster_sumo.metrics.REGISTRY
REGRESS_RATES = {**PLANNER_RATES, "adversary_contact_rate": "CR"}
REGRESS_FIGURES = {"median_min_ttc_s": "median_min_ttc", "mean_relative_speed_mps": "mean_relative_speed"}


def summarize_regression(out: Path, keys: dict[str, ScenarioSpec], planners: Sequence[str]) -> RegressionSummary:
    """The summary of a regression over ``keys`` x ``planners`` (rows in OUT/results), less wall time and report."""
    rows = [r for r in ResultStore(out / "results").read() if r.scene_key in keys and r.planner in planners]
    from coster_sumo.avoidability.labels import labels_moved
    from coster_sumo.batch.by_class import defects_by_class

    scenes_failed, n_variants, n_avoidable, tried = [], 0, 0, 0
    labels: list[dict[str, Any]] = []
    for key, spec in keys.items():
        doc = read_plans(out / "plans" / f"{key}.json")
        if doc is not None and doc.ok:
            labels += [_moved_fields(a) for a in doc.avoidability]
            n_variants += len(doc.variants)
            n_avoidable += doc.avoidable_variants
            tried += doc.variants_tried
        else:
            scenes_failed.append(GenerationFailure(key, spec.label(), doc.reason if doc else "not generated"))
    failures = tuple(RunFailure(r.run_key, r.reason) for r in rows if not r.ok)
    return RegressionSummary(
        scenes=SceneCounts(len(keys), len(keys) - len(scenes_failed), tuple(scenes_failed)),
        variants=n_variants, avoidable_variants=n_avoidable, variants_tried=tried,
        runs=RunCounts(expected=n_variants * len(planners), recorded=len(rows), ok=len(rows) - len(failures),
                       failed=len(failures), failures=failures),
        planners={p: planner_summary([r for r in rows if r.planner == p]) for p in planners},
        labels_moved=labels_moved(labels), defects_by_class=defects_by_class(rows, planners))


def _moved_fields(label: Mapping[str, Any]) -> dict[str, Any]:
    """A stored label (``Avoidability.summary``) in the fields
    :func:`~coster_sumo.avoidability.labels.labels_moved` reads."""
    return {"blocked_tried": label.get("blocked_escapes_tried_in_sumo", 0),
            "blocked_cleared": label.get("blocked_escapes_cleared_in_sumo", 0),
            "flipped_by_reacting_traffic": label.get("flipped_by_reacting_traffic", False)}


def planner_summary(rows: Sequence[ResultRow]) -> PlannerSummary:
    """One planner's figures from its rows, from the metrics' registry (failed runs are not in them)."""
    ok = [row_outcome(r) for r in rows if r.ok]
    sample = MetricSample(tuple(ok))
    rates = {key: compute(name, sample) for key, name in REGRESS_RATES.items()}
    figures = {key: compute(name, sample).value for key, name in REGRESS_FIGURES.items()}
    return PlannerSummary(runs=len(rows), failed=len(rows) - len(ok), RCR=rates["RCR"], CR=rates["CR"],
                          ORR=rates["ORR"], adversary_contact_rate=rates["adversary_contact_rate"],
                          median_min_ttc_s=figures["median_min_ttc_s"],
                          mean_relative_speed_mps=figures["mean_relative_speed_mps"], defects=defect_rates(ok))


def regression_exit_code(summary: RegressionSummary) -> int:
    """0 when every scene generated and every run finished; 1 otherwise (docs/method.md, Contracts)."""
    return 1 if summary.scenes.failed or summary.runs.failed else 0
