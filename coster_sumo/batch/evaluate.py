"""``coster-sumo eval scenarios``: scenario generators compared with the scenario metrics.

Every generator of :data:`GENERATOR_METHODS` runs on every scene of the sources (same executor and
scene sources as ``regress``); each variant is injected with the one injection path
(:func:`coster_sumo.sim.inject.inject_variant`) and the seven metrics are aggregated per method.
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.batch import sources
from coster_sumo.batch.eval_metrics import (
    adversaries_by_lane_type,
    avoidability_summary,
    paired_diversity,
    record_outcome,
)
from coster_sumo.batch.executor import GENERATION_TASK_MODULES, ExecutorSettings, Outcome, Task, execute, is_transient
from coster_sumo.batch.generator_summary import (
    EvalSummary,
    GeneratorEntry,
    GeneratorMethod,
    GeneratorResult,
    GeneratorTable,
    MethodPart,
    SceneFailure,
    ScenePart,
    SkippedGenerator,
    VariantRecord,
    read_method_part,
    read_scene_part,
)
from coster_sumo.batch.shared_pass import PASS_FILE, SharedPasses, shared_nominal
from coster_sumo.batch.sources import scene_key
from coster_sumo.core.scene import ObjectType, resample
from coster_sumo.core.spec import GenerationConfig, InjectionSettings, ScenarioSpec
from coster_sumo.errors import InputError
from coster_sumo.infra.atomic import write_json
from coster_sumo.infra.outdir import MARKER, OutputLock, check_output, staged_names, write_marker
from coster_sumo.infra.weights import WEIGHT_FILES, weights_digest
from coster_sumo.method.generation import missing_weights
from coster_sumo.method.vru.classes import VRU_CLASSES
from coster_sumo.metrics import (
    MetricSample,
    compute,
)
from coster_sumo.sim.planners import check_planner

GENERATOR_METHODS: tuple[GeneratorMethod, ...] = (
    GeneratorMethod("COSTER", "snapshot", "cvae", "entropy"),
    GeneratorMethod("Random+CVAE", "random", "cvae", "entropy"),
    GeneratorMethod("Snapshot+CV", "snapshot", "cv", "entropy"),
    GeneratorMethod("Random+CV", "random", "cv", "last", group="baseline"),
    GeneratorMethod("COSTER t_col=last", "snapshot", "cvae", "last", group="ablation"),
    GeneratorMethod("COSTER t_col=random", "snapshot", "cvae", "random", group="ablation"),
)


@dataclass(kw_only=True)
class EvalOptions(sources.BatchOptions):
    """Everything ``coster-sumo eval scenarios`` takes."""

    methods: list[str] | None = None  # names of GENERATOR_METHODS (default: all)
    planner: str = "replay"
    traffic: str = "log"  # log | reactive: converted scenes' agents in the labels' proofs and the injections
    variants: int = 5
    samples: int = 1000
    adversary: str = "vehicle"  # vehicle | cyclist | pedestrian | any (coster_sumo.method.vru)


def _hist(values: np.ndarray, bins: np.ndarray, lo: float, hi: float) -> list[int]:
    return np.histogram(np.clip(values, lo, hi), bins=bins)[0].astype(int).tolist()


def scene_task(payload: dict[str, Any]) -> dict[str, Any]:
    """Eval task: nominal pass of one scene (cached .npz) and its speed/acceleration histograms."""
    from coster_sumo.formats.targets import choose_target
    from coster_sumo.metrics import ACCEL_BINS, SPEED_BINS, speeds_and_accels

    spec = sources.located(ScenarioSpec.from_dict(payload["spec"]), payload)
    if payload.get(PASS_FILE):  # a pass shared with the configuration's other targets (batch.shared_pass)
        scene, _, path = shared_nominal(spec, Path(payload["scenes_dir"]), payload[PASS_FILE])
    else:
        scene, _, path = sources.nominal_for(spec, Path(payload["scenes_dir"]))
    choose_target(scene, spec.target, spec.config)
    t = scene.tracks
    v, a = speeds_and_accels(t.xy, t.valid, scene.dt)
    low = resample(scene, 2.0)
    by_class = {}  # the reference of a pedestrian or cyclist adversary: the scene's agents of its class
    for name, vru in VRU_CLASSES.items():
        mine = t.object_type == vru.object_type
        if mine.any():
            cv, ca = speeds_and_accels(t.xy[mine], t.valid[mine], scene.dt)
            by_class[name] = {"speed_hist": _hist(cv, SPEED_BINS, 0, 50), "accel_hist": _hist(ca, ACCEL_BINS, -10, 10),
                              "speed_hist_by_lane_type": speeds_by_lane_type(low, vru.object_type)}
    return {"scene_file": path.name, "speed_hist": _hist(v, SPEED_BINS, 0, 50),
            "accel_hist": _hist(a, ACCEL_BINS, -10, 10),
            "speed_hist_by_lane_type": speeds_by_lane_type(low), "by_class": by_class}


def nominal_speeds_by_lane_type(scene: Any, object_type: int = ObjectType.VEHICLE) -> dict[str, list[int]]:
    """:func:`speeds_by_lane_type` of ``scene`` resampled to 2 Hz."""
    return speeds_by_lane_type(resample(scene, 2.0), object_type)


def speeds_by_lane_type(low: Any, object_type: int = ObjectType.VEHICLE) -> dict[str, list[int]]:
    """Speed histograms (:data:`~coster_sumo.metrics.SPEED_BINS`) of the 2 Hz scene ``low``'s agents
    of ``object_type`` (vehicles by default), one per :class:`~coster_sumo.core.scene.LaneType` name
    of the lane nearest to each: the reference the adversaries' speeds at t_col are compared with,
    lane type by lane type."""
    from coster_sumo.core.scene import LaneType
    from coster_sumo.metrics import SPEED_BINS

    t = low.tracks
    ok = t.valid & (t.object_type == object_type)[:, None]
    speed = np.hypot(t.vx[ok], t.vy[ok])
    kind = low.road_map.lane_type_at(np.stack([t.x[ok], t.y[ok]], -1))
    return {LaneType(k).name: _hist(speed[kind == k], SPEED_BINS, 0, 50) for k in np.unique(kind).tolist()}


def method_task(payload: dict[str, Any]) -> dict[str, Any]:
    """Eval task: one generator on one scene; every variant injected; per-variant records + histograms."""
    from coster_sumo.core.scene import LaneType
    from coster_sumo.errors import NoSnapshot
    from coster_sumo.formats.scene_file import load_scene
    from coster_sumo.formats.targets import choose_target
    from coster_sumo.geometry.drivable import DrivableArea
    from coster_sumo.method.generation import generate_variants, missing_weights
    from coster_sumo.metrics import ACCEL_BINS, SPEED_BINS, speeds_and_accels
    from coster_sumo.sim.inject import inject_variant

    spec = sources.located(ScenarioSpec.from_dict(payload["spec"]), payload)
    scenes_dir = Path(payload["scenes_dir"])
    scene = load_scene(scenes_dir / payload["scene_file"])
    target = choose_target(scene, spec.target, spec.config)
    drivable = DrivableArea.from_road_map(scene.road_map)
    m = payload["method"]
    gen = GenerationConfig(init=m["init"], rollout=m["rollout"], collision_time=m["collision_time"],
                           variants=payload["variants"], samples=payload["samples"],
                           adversary=m.get("adversary", "vehicle"),
                           models_dir=Path(payload["models_dir"]) if payload.get("models_dir") else None)
    reason = missing_weights(gen)
    if reason:
        return {"status": "skipped", "reason": reason}
    t0 = time.perf_counter()
    try:
        variants, _ = generate_variants(scene, target, spec.seed, gen, drivable)
    except NoSnapshot as exc:
        return {"status": "no_scenario", "reason": str(exc), "generation_s": time.perf_counter() - t0,
                "records": []}
    gen_s = time.perf_counter() - t0
    from coster_sumo.avoidability.labels import ProofSettings, label_plans, label_record

    t1 = time.perf_counter()
    traffic = payload.get("traffic", "log")
    labels = label_plans(spec, scene, target, [v.plan for v in variants], ProofSettings(drivable, traffic=traffic))
    avoid_s = time.perf_counter() - t1
    records = []
    speeds, accels = [], []
    lane_types = scene.road_map.lane_type_at(np.array([[v.snapshot.adversary.x, v.snapshot.adversary.y]
                                                       for v in variants]))
    for i, v in enumerate(variants):
        plan = v.plan
        with tempfile.TemporaryDirectory(prefix="coster-eval-") as wd:
            how = InjectionSettings(payload["planner"], workdir=Path(wd), traffic=traffic)
            res = inject_variant(spec, scene, target, plan, how, drivable=drivable)
        c = res.contact
        adv = v.snapshot.adversary
        label = label_record(labels[i])
        records.append(VariantRecord(
            variant=i, collision=c is not None, adversary_off_road=_off(plan, res, scene),
            relative_speed=c.relative_speed if c else None, impact_angle=c.impact_angle if c else None,
            t_col=v.snapshot.time, adversary_speed=adv.speed, adversary_length=adv.length, adversary_width=adv.width,
            adversary_lane_type=LaneType(int(lane_types[i])).name, avoidable=label.pop("avoidable"),
            extra={**label, "adversary_class": v.snapshot.adversary_class}))
        tr = res.scene.tracks
        if plan.vehicle_id in set(tr.ids.tolist()):
            a = tr.index_of(plan.vehicle_id)
            stop = min(c.time if c else plan.t_col, plan.t_col)
            window = (res.scene.timestamps >= plan.t_start - 1e-6) & (res.scene.timestamps <= stop + 1e-6)
            sv, sa = speeds_and_accels(tr.xy_of(slice(a, a + 1)), (tr.valid[a] & window)[None], res.scene.dt)
            speeds.append(sv)
            accels.append(sa)
    sv = np.concatenate(speeds) if speeds else np.zeros(0)
    sa = np.concatenate(accels) if accels else np.zeros(0)
    return {"status": "ok", "records": [r.to_json() for r in records], "generation_s": gen_s, "avoidability_s": avoid_s,
            "speed_hist": _hist(sv, SPEED_BINS, 0, 50), "accel_hist": _hist(sa, ACCEL_BINS, -10, 10)}


def _off(plan: Any, res: Any, scene: Any) -> bool:
    """The adversary left the drivable area (a vehicle) or its class's area (a pedestrian or cyclist)."""
    from coster_sumo.method.vru.areas import off_class_area

    return bool(res.adversary_off_road) if plan.vclass == "passenger" else off_class_area(plan, scene)


def _scene_task_for(key: str, spec: ScenarioSpec, scenes_dir: Path, pass_file: str | None) -> Task:
    """The task of one scene's nominal pass (``pass_file``: the pass it shares, in ``scenes_dir``)."""
    payload: dict[str, Any] = {"spec": spec.to_dict(), "scenes_dir": str(scenes_dir), "scene_key": key,
                               sources.CONFIG_DIR: sources.config_dir(spec)}
    if pass_file:
        payload[PASS_FILE] = pass_file
    return Task(f"{key}__scene", scene_task, payload, kind="scene",
                folders=sources.task_folders(spec, scenes_dir=(pass_file or f"{key}.npz",)))


def evaluate_generators(opts: EvalOptions) -> EvalSummary:
    """``coster-sumo eval scenarios``: every generator on every scene; metrics table (JSON, Markdown, PNG)."""
    t_start = time.perf_counter()
    names = opts.methods or [m.name for m in GENERATOR_METHODS]
    by_name = {m.name: m for m in GENERATOR_METHODS}
    unknown = [n for n in names if n not in by_name]
    if unknown:
        raise InputError(f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(by_name)}")
    methods = [by_name[n] for n in names]
    check_planner(opts.planner)
    if opts.traffic not in ("log", "reactive"):
        raise InputError(f"traffic must be log or reactive, not {opts.traffic!r}")
    specs = sources.parse_sources(opts.sources, seed=opts.seed, seeds=opts.seeds, begin=opts.begin, end=opts.end,
                          target=opts.target)
    out = Path(opts.out)
    check_output(out, kind="eval-scenarios", inputs=[Path(s.config) for s in specs], reusable=True)
    out.mkdir(parents=True, exist_ok=True)
    with OutputLock(out, inside=True):
        if not (out / MARKER).exists():
            write_marker(out, "eval-scenarios")
        return _evaluate_locked(opts, t_start, methods, specs, out)


def part_key(scene: str, method: str, variants: int, weights: str, adversary: str = "vehicle",
             traffic: str = "log") -> str:
    """The file stem of one method's part on one scene (the weights by their contents: other
    weights are another part, the same weights by another path the same one; a VRU adversary's and
    reactive traffic's parts apart)."""
    tail = ("" if adversary == "vehicle" else f"__{adversary}") + ("" if traffic == "log" else f"__{traffic}")
    return f"{scene}__{sources.slug(method)}__k{variants}__w{weights[:8]}{tail}"


def _done(part: ScenePart | MethodPart | None) -> bool:
    """A part written by an earlier batch that counts: ok, or failed for a reason of the input's."""
    return part is not None and (part.status != "failed" or not is_transient(part.reason or ""))


def _missing_weights(methods: Sequence[GeneratorMethod], models_dir: Path | None) -> dict[str, str]:
    """Method name -> why it is skipped: the weights it needs are missing."""
    reasons = {m.name: missing_weights(GenerationConfig(init=m.init, rollout=m.rollout, models_dir=models_dir))
               for m in methods}
    return {name: reason for name, reason in reasons.items() if reason}


def _evaluate_locked(opts: EvalOptions, t_start: float, methods: list[GeneratorMethod], specs: list[ScenarioSpec],
                     out: Path) -> EvalSummary:
    """:func:`evaluate_generators` once OUT is checked and locked."""
    scenes_dir, parts_dir = out / "scenes", out / "parts"
    parts_dir.mkdir(parents=True, exist_ok=True)
    scenes_dir.mkdir(parents=True, exist_ok=True)
    for folder in (scenes_dir, parts_dir):  # half-written files of a batch that was killed
        for leftover in staged_names(folder, (".tmp.npz", ".tmp.json")):
            leftover.unlink(missing_ok=True)
    weights = weights_digest(opts.models_dir)
    skipped = _missing_weights(methods, opts.models_dir)
    active = [m for m in methods if m.name not in skipped]
    keys = {scene_key(s): s for s in specs}

    def method_tasks(key: str, scene_file: str) -> list[Task]:
        tasks = []
        for m in active:
            pk = part_key(key, m.name, opts.variants, weights, opts.adversary, opts.traffic)
            if _done(read_method_part(parts_dir / f"{pk}.json")):
                continue
            folders = sources.task_folders(keys[key], scenes_dir=(scene_file,))
            if opts.models_dir:
                folders["models_dir"] = WEIGHT_FILES
            tasks.append(Task(pk, method_task, {
                "part_key": pk, "scene_key": key, "spec": keys[key].to_dict(), "scene_file": scene_file,
                "scenes_dir": str(scenes_dir), "method": {**dataclasses.asdict(m), "adversary": opts.adversary},
                "variants": opts.variants, "samples": opts.samples, "planner": opts.planner, "traffic": opts.traffic,
                sources.CONFIG_DIR: sources.config_dir(keys[key]),
                "models_dir": str(opts.models_dir.resolve()) if opts.models_dir else None}, kind="method",
                folders=folders))
        return tasks

    shared = SharedPasses(keys, scenes_dir)  # the targets of a configuration, window and seed share its pass
    initial = []
    for key in keys:
        sp = read_scene_part(parts_dir / f"{key}__scene.json")
        if sp is not None and sp.ok:
            initial.extend(method_tasks(key, sp.scene_file))
        elif not _done(sp) and not shared.wait(key):
            initial.append(_scene_task_for(key, keys[key], scenes_dir, shared.pass_file(key)))
    initial += shared.tasks()

    def on_done(task: Task, outcome: Outcome) -> list[Task]:
        if task.kind == "pass":  # the shared pass is there: its scenes go on (or all fail with it)
            for k in [] if outcome.ok else shared.released(task):
                write_json(parts_dir / f"{k}__scene.json", {"status": "failed", "reason": outcome.reason})
            return [_scene_task_for(k, keys[k], scenes_dir, shared.pass_file(k))
                    for k in shared.released(task)] if outcome.ok else []
        key = task.payload["scene_key"]
        if opts.executor == "local":
            outcome.append_to_log(out / "logs" / f"{task.key}.log")
        if task.kind == "scene":
            doc = {"status": "ok", **outcome.value} if outcome.ok else {"status": "failed", "reason": outcome.reason}
            write_json(parts_dir / f"{key}__scene.json", doc)
            return method_tasks(key, doc["scene_file"]) if outcome.ok else []
        doc = outcome.value if outcome.ok else {"status": "failed", "reason": outcome.reason}
        write_json(parts_dir / f"{task.payload['part_key']}.json",
                     {**doc, "method": task.payload["method"]["name"], "scene_key": key})
        return []

    # what is left: a resumed batch's bar counts the tasks still to run, not those done before
    todo = sum(1 + len(active) if t.kind == "scene" else 1 for t in initial) + shared.waiting_scenes * (1 + len(active))
    if not opts.quiet and todo < len(keys) * (1 + len(active)):
        print(f"resuming {out}: {len(keys) * (1 + len(active)) - todo} of {len(keys) * (1 + len(active))} tasks "
              "done before", flush=True)
    how = ExecutorSettings(opts.workers, opts.executor, opts.timeout, ray_address=opts.ray_address,
                           log_dir=out / "logs" if opts.executor == "local" else None, preload=GENERATION_TASK_MODULES)
    execute(initial, how, on_done=on_done, quiet=opts.quiet, desc="eval scenarios", expected_total=todo)
    table = aggregate_generator_metrics(parts_dir, keys, methods, skipped, opts.variants, weights, opts.adversary,
                                        opts.traffic)
    summary = EvalSummary(scenes={k: s.label() for k, s in keys.items()}, planner=opts.planner,
                          variants=opts.variants, samples=opts.samples, methods=table, adversary=opts.adversary,
                          traffic=opts.traffic,
                          wall_time_s=round(time.perf_counter() - t_start, 3))
    write_json(out / "summary.json", summary.to_json())
    from coster_sumo.batch.report import write_generator_report

    summary = dataclasses.replace(summary, report=tuple(write_generator_report(out, summary)))
    write_json(out / "summary.json", summary.to_json())
    return summary


def aggregate_generator_metrics(parts_dir: Path, keys: dict[str, ScenarioSpec], methods: Sequence[GeneratorMethod],
                                skipped: dict[str, str], variants: int, weights: str,
                                adversary: str = "vehicle", traffic: str = "log") -> GeneratorTable:
    """Per method: SUR, CR, ORR (with Wilson intervals), VDD, ADD, CSD, CPD, circular CPD (with 95 %
    intervals from resampling scenes); ``paired``: COSTER's diversities minus each other method's on
    the same scenes (:func:`paired_diversity`)."""
    nominal = NominalTraffic()
    failed_scenes = []
    for key in keys:
        sp = read_scene_part(parts_dir / f"{key}__scene.json")
        if sp is None or not sp.ok:
            failed_scenes.append(SceneFailure(key, sp.reason if sp is not None else "not run"))
            continue
        nominal.add(key, sp, adversary)
    per_scene: dict[str, dict[str, tuple[list[float | None], list[float | None]]]] = {}  # method -> scene -> contacts
    table: dict[str, GeneratorEntry] = {}
    for m in methods:
        if m.name in skipped:
            table[m.name] = SkippedGenerator(m, skipped[m.name])
            continue
        loaded = [read_method_part(parts_dir / f"{part_key(k, m.name, variants, weights, adversary, traffic)}.json")
                  for k in nominal.scenes]
        parts = [p for p in loaded if p is not None]
        skip = [p for p in parts if p.status == "skipped"]
        if parts and len(skip) == len(parts):
            table[m.name] = SkippedGenerator(m, str(skip[0].reason))
            continue
        table[m.name], sample = generator_result(m, parts, nominal)
        per_scene[m.name] = {p.scene_key: ([o.relative_speed for o in sample.contacts if o.scene == p.scene_key],
                                           [o.impact_angle for o in sample.contacts if o.scene == p.scene_key])
                             for p in parts if p.status == "ok"}
    return GeneratorTable(table, tuple(failed_scenes), paired_diversity(per_scene))


@dataclass
class NominalTraffic:
    """The scenes that ran their nominal pass, and the sums of their speed and acceleration
    histograms: (100,) over :data:`~coster_sumo.metrics.SPEED_BINS`, (200,) over
    :data:`~coster_sumo.metrics.ACCEL_BINS`, and per lane type name (100,) (None: no scene yet)."""

    scenes: list[str] = field(default_factory=list)
    speed_hist: np.ndarray | None = None
    accel_hist: np.ndarray | None = None
    speed_hist_by_lane_type: dict[str, np.ndarray] = field(default_factory=dict)

    def add(self, key: str, part: ScenePart, adversary: str = "vehicle") -> None:
        """A scene's part (:func:`scene_task`) added; for a pedestrian or cyclist ``adversary`` the
        histograms of the scene's agents of that class (none: the scene adds no counts)."""
        self.scenes.append(key)
        if adversary in VRU_CLASSES:
            mine = part.by_class.get(adversary)
            if mine is None:
                return
            part = dataclasses.replace(part, speed_hist=mine["speed_hist"], accel_hist=mine["accel_hist"],
                                       speed_hist_by_lane_type=mine["speed_hist_by_lane_type"])
        v, a = np.asarray(part.speed_hist), np.asarray(part.accel_hist)
        self.speed_hist = v if self.speed_hist is None else np.add(self.speed_hist, part.speed_hist)
        self.accel_hist = a if self.accel_hist is None else np.add(self.accel_hist, part.accel_hist)
        for kind, hist in part.speed_hist_by_lane_type.items():
            self.speed_hist_by_lane_type[kind] = self.speed_hist_by_lane_type.get(kind, 0) + np.asarray(hist)


def generator_result(m: GeneratorMethod, parts: Sequence[MethodPart], nominal: NominalTraffic
                     ) -> tuple[GeneratorResult, MetricSample]:
    """One method's entry from its parts (:func:`method_task`) on the scenes of ``nominal``, and the
    sample its metrics were computed on."""
    ok = [p for p in parts if p.status == "ok"]
    # a scene's variants share a snapshot: name it, so the VDD at t_col floor counts it once
    keyed = [(p.scene_key, dataclasses.replace(r, snapshot=f"{p.scene_key}@{r.t_col}")) for p in ok for r in p.records]
    records = [r for _, r in keyed]
    sample = MetricSample(
        tuple(record_outcome(r, key) for key, r in keyed),
        scenes=tuple(nominal.scenes), nominal_speed_hist=nominal.speed_hist, nominal_accel_hist=nominal.accel_hist,
        generated_speed_hist=np.sum([p.speed_hist for p in ok], axis=0) if records else None,
        generated_accel_hist=np.sum([p.accel_hist for p in ok], axis=0) if records else None,
        nominal_speed_hist_by_lane_type=nominal.speed_hist_by_lane_type)
    values = {name: compute(name, sample) for name in GENERATOR_METRICS}
    gen_time = [(p.generation_s or 0.0) / len(p.records) for p in ok if p.records]
    result = GeneratorResult(
        method=m, scenes=len(nominal.scenes), variants=len(records),
        failed_tasks=tuple(SceneFailure(p.scene_key, p.reason) for p in parts if p.status == "failed"),
        SUR=values["SUR"], CR=values["CR"], ORR=values["ORR"], VDD=values["VDD"].value, ADD=values["ADD"].value,
        CSD=values["CSD"], CPD=values["CPD"], CPD_circular=values["CPD_circular"],
        generation_s_per_variant=float(np.mean(gen_time)) if gen_time else None,
        avoidability=avoidability_summary(records),
        relative_speeds=tuple(o.relative_speed for o in sample.contacts),
        impact_angles=tuple(o.impact_angle for o in sample.contacts),
        VDD_tcol=values["VDD_tcol"].value, VDD_tcol_floor=values["VDD_tcol_floor"].value,
        size_in_class=values["size_in_class"].value, adversaries_by_lane_type=adversaries_by_lane_type(sample))
    return result, sample


# eval scenarios' figures per method: the metrics of coster_sumo.metrics.REGISTRY by name
GENERATOR_METRICS = ("SUR", "CR", "ORR", "VDD", "ADD", "CSD", "CPD", "CPD_circular", "VDD_tcol", "VDD_tcol_floor",
                     "size_in_class")
def eval_exit_code(summary: EvalSummary) -> int:
    """0 when every scene ran its nominal pass and every generator's task finished; 1 otherwise."""
    t = summary.methods
    return 1 if t.failed_scenes or any(m.failed_tasks for m in t.ran.values()) else 0
