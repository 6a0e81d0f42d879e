"""``coster-sumo run``: the data flow of DESIGN.md, from a SUMO configuration to logged variants.

1. nominal pass: converted WOMD scenes use their log (``scene.npz`` beside the ``.sumocfg``); any
   other configuration is simulated with libsumo and recorded (same seed as the injection passes);
2. 2 Hz scene; collision time and snapshot (prior, or the random-offset baseline);
3. adversary trajectories backwards from the snapshot (CVAE oversampling + K-means + motion
   vocabulary, or the constant-velocity baseline), representatives kept as variants;
4. one injection pass per variant from a fresh start with the same seed;
5. outputs (see :func:`write_outputs` and the README).
"""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.drivable import DrivableArea
from coster_sumo.errors import InputError
from coster_sumo.geometry import box_signed_distance, make_boxes
from coster_sumo.planners import LoggedPlanner, Planner, ReplayPlanner, make_planner
from coster_sumo.scene import CollisionSnapshot, Scene, load_scene, resample
from coster_sumo.sim.events import CONTACT_TOLERANCE_M
from coster_sumo.sim.inject import InjectionResult, StepActor, run_injection
from coster_sumo.sim.plan import AdversaryPlan
from coster_sumo.snapshot import NoSnapshot, prior_snapshot, random_snapshot

DEFAULT_DURATION_S = 60.0  # [s] recorded when neither --end nor the configuration bounds the run
ROLLOUT_HORIZON_STEPS = 10  # [2 Hz steps] 5 s
PRIOR_RATE_HZ = 2.0


@dataclass
class RunOptions:
    """Everything ``coster-sumo run`` takes (see ``coster-sumo run --help``)."""

    config: Path
    out: Path
    target: str | None = None
    planner: str | None = None
    samples: int = 1000
    variants: int = 5
    collision_time: str = "entropy"
    init: str = "snapshot"
    begin: float | None = None
    end: float | None = None
    seed: int = 0
    traci: bool = False
    rollout: str = "cvae"  # "cvae" | "cv" (constant velocity)
    render: bool = True
    quiet: bool = False
    models_dir: Path | None = None


@dataclass
class PlannedScenario:
    """The generation half of a run: snapshot and adversary plans for one target."""

    scene: Scene  # nominal, 10 Hz
    scene_2hz: Scene
    target_index: int
    snapshot: CollisionSnapshot
    plans: list[AdversaryPlan]
    samples_xy: np.ndarray | None = None  # (N, T, 2) all oversampled trajectories, for the heatmap
    info: dict[str, Any] = field(default_factory=dict)


# ----------------------------------------------------------------------------- inputs

def converted_scene_file(config: Path) -> Path | None:
    """``scene.npz`` of a converted WOMD scene, if ``config`` is one."""
    p = config.parent / "scene.npz"
    return p if p.exists() else None


def sumocfg_end(config: Path) -> float | None:
    """The ``<end value=...>`` of a .sumocfg, if any."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.parse(config).getroot()
    except (ET.ParseError, OSError) as exc:
        raise InputError(f"{config}: not a readable SUMO configuration ({exc})") from None
    for el in root.iter("end"):
        with_value = el.get("value")
        if with_value is not None:
            return float(with_value)
    return None


def choose_target(scene: Scene, requested: str | None, config: Path) -> int:
    """Index of the target: ``requested``, else the SDC of a converted scene, else ``ego``."""
    ids = scene.tracks.ids.tolist()
    ts = scene.timestamps
    window = f"{float(ts[0]):.1f}-{float(ts[-1]):.1f} s" if len(ts) else "empty"
    if requested is None:
        if scene.sdc_index >= 0:
            return scene.sdc_index
        if "ego" in ids:
            return ids.index("ego")
        long_lived = np.argsort(-scene.tracks.valid.sum(axis=1))[:8]
        raise InputError(f"{config}: no vehicle 'ego' runs in the window ({window}); pick a target with "
                         "--target, e.g. "
                         + ", ".join(ids[i] for i in long_lived))
    if requested not in ids:
        near = [i for i in ids if requested.lower() in i.lower()][:8] or ids[:8]
        raise InputError(f"{config}: target {requested!r} never runs in the window ({window}); "
                         f"candidates: {', '.join(near)}")
    return ids.index(requested)


def nominal_scene(opts: RunOptions) -> tuple[Scene, bool]:
    """The nominal scene at 10 Hz and whether it is a converted WOMD scene (replayed log)."""
    cfg = opts.config
    if not cfg.exists():
        raise InputError(f"{cfg}: no such SUMO configuration")
    conv = converted_scene_file(cfg)
    if conv is not None:
        return load_scene(conv), True
    from coster_sumo.sim.record import record_config

    end = opts.end if opts.end is not None else sumocfg_end(cfg)
    if end is None:
        end = (opts.begin or 0.0) + DEFAULT_DURATION_S
    scene = record_config(cfg, seed=opts.seed, begin=opts.begin, end=end, traci=opts.traci)
    if scene.num_steps == 0:
        raise InputError(f"{cfg}: the simulation recorded no step in [{opts.begin}, {end}]")
    return scene, False


# ----------------------------------------------------------------------------- generation

def constant_velocity_plan(snapshot: CollisionSnapshot, scene_2hz: Scene, horizon: int) -> AdversaryPlan:
    """Backward constant-velocity extrapolation from the snapshot (the CV baseline trajectory)."""
    t = scene_2hz.timestamps
    h = min(horizon, snapshot.t_index)
    times = t[snapshot.t_index - h: snapshot.t_index + 1]
    adv = snapshot.adversary
    back = (times - times[-1])[:, None] * adv.velocity[None, :]  # (h+1, 2), <= 0 s before t_col
    traj = np.column_stack([adv.x + back[:, 0], adv.y + back[:, 1], np.full(len(times), adv.yaw)])
    return AdversaryPlan.from_knots(times, traj, adv)


def early_contact(plan: AdversaryPlan, scene: Scene, target: int, tolerance_s: float = 0.1) -> float | None:
    """Time [s] at which ``plan`` would overlap the target's nominal path before t_col - tolerance.

    Checked at the nominal scene's own rate (10 Hz) against the target's logged boxes; a variant
    that hits the target early is not the snapshot's collision and is not kept. The steps within
    ``tolerance_s`` of t_col are not checked, whatever the log's timestamp jitter (half a step of
    margin): with the default, touching one step early is allowed, two steps is not.
    """
    t = scene.tracks
    times = scene.timestamps
    half_step = 0.5 * float(np.median(np.diff(times))) if len(times) > 1 else 0.0
    sel = (times >= plan.t_start - 1e-9) & (times < plan.t_col - tolerance_s - half_step) & t.valid[target]
    if not sel.any():
        return None
    x, y, yaw, _ = plan.sample(times[sel])
    adv = make_boxes(x, y, yaw, plan.length, plan.width)
    tgt = make_boxes(t.x[target, sel], t.y[target, sel], t.heading[target, sel], t.length[target, sel],
                     t.width[target, sel])
    hit = box_signed_distance(adv, tgt) <= CONTACT_TOLERANCE_M
    return float(times[sel][np.argmax(hit)]) if hit.any() else None


SNAPSHOT_ATTEMPTS = 5  # snapshot + rollout attempts before a scene is declared unusable


def plan_scenario(scene: Scene, target: int, opts: RunOptions, drivable: DrivableArea) -> PlannedScenario:
    """Snapshot and adversary plans (steps 2-3).

    Plans that would hit the target before t_col are dropped; when none is left, a new snapshot
    is drawn (the seeded generator moves on), up to :data:`SNAPSHOT_ATTEMPTS` times.
    """
    rng = np.random.default_rng(opts.seed)
    low = resample(scene, PRIOR_RATE_HZ)
    model = None
    reasons: list[str] = []
    for _attempt in range(SNAPSHOT_ATTEMPTS):
        if opts.init == "random":
            snap = random_snapshot(low, target, rng, drivable, collision_time=opts.collision_time,
                                   seed=opts.seed)
        else:
            if model is None:
                from coster_sumo.models import model_path
                from coster_sumo.snapshot import DEFAULT_PRIOR

                weights = model_path(DEFAULT_PRIOR, opts.models_dir)  # a missing file is reported first
                from coster_sumo.prior.infer import load_prior

                model = load_prior(weights)
            snap = prior_snapshot(low, target, rng, drivable, collision_time=opts.collision_time,
                                  seed=opts.seed, model=model)
        samples_xy = None
        if opts.rollout == "cv":
            plans = [constant_velocity_plan(snap, low, ROLLOUT_HORIZON_STEPS)]
            info: dict[str, Any] = {"rollout": "constant_velocity"}
        else:
            from coster_sumo.rollout.sample import plan_variants

            plans, samples_xy, info = plan_variants(low, target, snap, drivable, n=opts.samples,
                                                    k=opts.variants, seed=opts.seed, models_dir=opts.models_dir)
        kept: list[AdversaryPlan] = []
        dropped: list[dict[str, Any]] = []
        for i, plan in enumerate(plans):
            early = early_contact(plan, scene, target)
            if early is None:
                kept.append(dataclasses.replace(plan, vehicle_id=f"adversary{len(kept)}"))
            else:
                dropped.append({"candidate": i, "reason": f"hits the target at {early:.1f} s, before t_col"})
        if kept:
            info = {**info, "attempt": _attempt + 1, "candidates": len(plans), "kept": len(kept),
                    "dropped": dropped}
            return PlannedScenario(scene, low, target, snap, kept, samples_xy=samples_xy, info=info)
        reasons.append(f"t_col {snap.time:.1f} s: every trajectory hits the target before t_col")
    raise NoSnapshot(f"{SNAPSHOT_ATTEMPTS} attempts failed ({reasons[-1]})")


# ----------------------------------------------------------------------------- injection

def replay_planner_for(scene: Scene, target: int) -> ReplayPlanner:
    t = scene.tracks
    return ReplayPlanner(scene.timestamps, t.x[target], t.y[target], t.heading[target],
                         t.speed[target], t.valid[target], float(np.median(t.length[target][t.valid[target]])))


def log_actors(config: Path, scene: Scene, exclude: set[str]) -> tuple[StepActor, ...]:
    """Actors replaying a converted scene's log (all agents except ``exclude``)."""
    from coster_sumo.sim.replay import LogReplayer

    return (LogReplayer.for_config(config, scene, exclude=exclude),)


def inject_variants(planned: PlannedScenario, opts: RunOptions, converted: bool, drivable: DrivableArea,
                    workdir: Path) -> list[InjectionResult]:
    scene, target = planned.scene, planned.target_index
    target_id = str(scene.tracks.ids[target])
    planner_spec = opts.planner or ("replay" if converted else "sumo")
    end = float(scene.timestamps[-1]) + 1e-9
    results = []
    if converted and planner_spec != "replay":
        # the converted net has no routes for logged agents, so SUMO cannot take the target over
        raise InputError(f"{opts.config}: converted WOMD scenes support --planner replay only "
                         f"(got {planner_spec!r}); run the planner on a SUMO configuration with routes")
    for plan in planned.plans:
        if converted:  # the log drives everyone, the target included
            planner: Planner = LoggedPlanner()
            actors = log_actors(opts.config, scene, exclude=set())
        else:
            planner = make_planner(planner_spec, replay_planner_for(scene, target))
            actors = ()
        results.append(run_injection(opts.config, target_id, plan, planner, seed=opts.seed, end=end,
                                     begin=opts.begin, drivable=drivable, actors=actors, traci=opts.traci,
                                     workdir=workdir))
    return results


# ----------------------------------------------------------------------------- outputs

def write_outputs(staging: Path, opts: RunOptions, planned: PlannedScenario, results: list[InjectionResult],
                  timings: dict[str, float]) -> dict[str, Any]:
    """Write everything into ``staging`` (renamed to OUTDIR by the caller)."""
    from coster_sumo.outputs import write_run_outputs

    return write_run_outputs(staging, opts, planned, results, timings)


def run(opts: RunOptions) -> dict[str, Any]:
    """Run the whole pipeline; returns the summary (also written to OUTDIR/summary.json)."""
    for name, value, allowed in (("--collision-time", opts.collision_time, ("entropy", "last", "random")),
                                 ("--init", opts.init, ("snapshot", "random")),
                                 ("--rollout", opts.rollout, ("cvae", "cv"))):
        if value not in allowed:
            raise InputError(f"{name} must be one of {', '.join(allowed)}, not {value!r}")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    scene, converted = nominal_scene(opts)
    timings["nominal_s"] = time.perf_counter() - t0
    target = choose_target(scene, opts.target, opts.config)
    if scene.tracks.valid[target].sum() < 2:
        raise InputError(f"{opts.config}: target {str(scene.tracks.ids[target])!r} never departs in the window")
    t0 = time.perf_counter()
    drivable = DrivableArea.from_road_map(scene.road_map)
    try:
        planned = plan_scenario(scene, target, opts, drivable)
    except NoSnapshot as exc:
        raise InputError(f"{opts.config}: no collision snapshot for target "
                          f"{str(scene.tracks.ids[target])!r}: {exc}") from None
    timings["generation_s"] = time.perf_counter() - t0
    opts.out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{opts.out.name}.", dir=opts.out.parent))
    try:
        t0 = time.perf_counter()
        results = inject_variants(planned, opts, converted, drivable, staging)
        timings["injection_s"] = time.perf_counter() - t0
        summary = write_outputs(staging, opts, planned, results, timings)
        if opts.out.exists():
            shutil.rmtree(opts.out)
        staging.replace(opts.out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return summary


def options_to_json(opts: RunOptions) -> dict[str, Any]:
    d = dataclasses.asdict(opts)
    return {k: (str(v) if isinstance(v, Path) else v) for k, v in d.items()}
