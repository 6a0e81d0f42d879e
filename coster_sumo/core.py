"""The generation core: from a scenario spec and a generation config to adversary plans.

Used by ``coster-sumo run``, ``regress``, ``eval scenarios`` and the Python API alike:

1. :func:`nominal_scene`: the nominal traffic at 10 Hz. A converted WOMD scene is its log
   (``scene.npz``, see :mod:`coster_sumo.formats.scene_folder`); any other configuration is
   simulated with libsumo and recorded with the spec's seed (the injection passes use the same);
2. :func:`choose_target`: the spec's target, else the SDC of a converted scene, else ``ego``;
3. :func:`plan_scenario`: the 2 Hz scene, the collision snapshot (a snapshot init of
   :data:`~coster_sumo.snapshot.SNAPSHOT_INITS` with a rule of
   :data:`~coster_sumo.snapshot.COLLISION_TIME_RULES`), the adversary plans (a rollout of
   :data:`~coster_sumo.rollout.methods.ROLLOUTS`), and the early-contact filter (no contact with
   the target or with another vehicle before t_col);
4. :func:`generate_variants`: up to K variants, drawing more snapshots when a rollout gives one
   trajectory per snapshot.

Injection of a plan is :func:`coster_sumo.sim.inject.inject_variant`.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo import weights
from coster_sumo.dataset import crop_scene
from coster_sumo.drivable import DrivableArea
from coster_sumo.errors import InputError, not_found
from coster_sumo.formats.scene_folder import converted_scene_file
from coster_sumo.formats.sumocfg import read_sumocfg
from coster_sumo.geometry import box_signed_distance, make_boxes
from coster_sumo.plan import AdversaryPlan
from coster_sumo.rollout.methods import ROLLOUTS
from coster_sumo.scene import Scene, load_scene, resample
from coster_sumo.sim.events import CONTACT_TOLERANCE_M
from coster_sumo.sim.hold import HeldStates
from coster_sumo.snapshot import COLLISION_TIME_RULES, MARGIN_END, SNAPSHOT_INITS, NoSnapshot
from coster_sumo.snapshot_state import CollisionSnapshot
from coster_sumo.spec import GenerationConfig, ScenarioSpec
from coster_sumo.targets import OFF_ROAD_CLASSES, config_demand

MAX_TARGET_LIFE_S = 3600.0  # [s] of the target's life a nominal pass records at most (then it stops)
DEFAULT_DURATION_S = 60.0  # [s] recorded when neither --end nor the configuration bounds the run

PRIOR_RATE_HZ = 2.0  # [1/s] the prior and the rollout work at 2 Hz
COLLISION_TIMES = 3  # collision times tried (best first, 2 s apart) before a scene is declared unusable
ATTEMPTS_PER_TIME = 5  # snapshot + rollout draws at one collision time before the next best is tried
STRICT_PER_TIME = 3  # of those, the first take only placements that close in on the target


@dataclass
class PlannedScenario:
    """The generation half of a run: snapshot and adversary plans for one target.

    Attributes:
        scene: the nominal scene at 10 Hz; scene_2hz: the same at 2 Hz.
        target_index: the target's agent index in both.
        snapshot: the collision snapshot.
        plans: one plan per kept variant (ids ``adversary0``, ``adversary1``, ...).
        samples_xy: (N, T, 2) [m] every oversampled trajectory (for the heatmap), or None.
        info: what the rollout reports (timings, clusters, dropped candidates).
    """

    scene: Scene
    scene_2hz: Scene
    target_index: int
    snapshot: CollisionSnapshot
    plans: list[AdversaryPlan]
    samples_xy: np.ndarray | None = None
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def dropped(self) -> list[str]:
        """One line per candidate that was generated or asked for and is not among :attr:`plans`,
        with its reason (``cluster 3: all 12 trajectories ...``, ``candidate 1: would hit the target
        at 20.1 s ...``)."""
        return [f"{_candidate_name(d['candidate'])}: {d['reason']}" for d in self.info.get("dropped", ())]


def _candidate_name(candidate: object) -> str:
    """``candidate 2`` for a rollout's index, the name itself for a cluster or an adversary id."""
    return f"candidate {candidate}" if isinstance(candidate, int) else str(candidate)


# ----------------------------------------------------------------------------- checks

def check_generation(gen: GenerationConfig) -> None:
    """Method names against the registries, counts, and the weights the methods need (exit 2 before work)."""
    for flag, value, registry in (("--init", gen.init, SNAPSHOT_INITS),
                                  ("--collision-time", gen.collision_time, COLLISION_TIME_RULES),
                                  ("--rollout", gen.rollout, ROLLOUTS)):
        if value not in registry:
            raise InputError(f"{flag} must be one of {', '.join(registry)}, not {value!r}")
    if gen.variants < 1:
        raise InputError(f"--variants must be >= 1, not {gen.variants}")
    if gen.samples < 1:
        raise InputError(f"--samples must be >= 1, not {gen.samples}")
    reason = missing_weights(gen)
    if reason:
        raise InputError(reason)


def missing_weights(gen: GenerationConfig) -> str | None:
    """Why the methods of ``gen`` cannot run with its models folder, or None."""
    needed = SNAPSHOT_INITS[gen.init].weights + ROLLOUTS[gen.rollout].weights
    return weights.missing_weights(needed, gen.models_dir)


# ----------------------------------------------------------------------------- nominal scene

def simulation_window(spec: ScenarioSpec) -> tuple[float, float]:
    """[begin, end] [s] of a SUMO configuration's run: the spec's, else the configuration's.

    Both are absolute simulation times as SUMO reads them (a configuration may begin at 57600 s);
    without any end the run lasts :data:`DEFAULT_DURATION_S`. An end not after the begin is one
    :class:`InputError` line.
    """
    cfg = read_sumocfg(spec.config)
    begin = spec.begin if spec.begin is not None else (cfg.begin or 0.0)
    end = spec.end if spec.end is not None else cfg.end
    if end is None:
        end = begin + DEFAULT_DURATION_S
    if end <= begin:
        raise InputError(f"{spec.config}: end {end:g} s is not after begin {begin:g} s (SUMO's end is an absolute "
                         "time; --duration gives a length from the begin)")
    return begin, end


def nominal_scene(spec: ScenarioSpec, *, traci: bool = False, hold: HeldStates | None = None,
                  additional: Sequence[Path] = (), progress: Callable[[float], None] | None = None,
                  more_targets: Sequence[str] = ()) -> tuple[Scene, bool]:
    """The nominal scene at 10 Hz and whether it is a converted WOMD scene (its log).

    A SUMO configuration is recorded around the target only (see :data:`SURROUNDINGS_RADIUS_M`),
    the target at every step, the vehicles around it at the models' 2 Hz and interpolated between
    (:class:`~coster_sumo.sim.record.Focus`: what the models read is exactly what SUMO did);
    with ``hold`` the pass leaves held copies of itself for the variants (:mod:`coster_sumo.sim.hold`);
    ``additional`` files are loaded as the variants' passes will load them (a planner's vType);
    ``progress`` is called with the simulation time [s] after every step; ``more_targets`` are
    recorded like the target (one pass for several targets: the union of their surroundings, up to
    the arrival of the last of them).
    """
    cfg = spec.config
    if not cfg.exists():
        raise not_found(cfg)
    log = converted_scene_file(cfg)
    if log is not None:
        return load_scene(log), True
    from coster_sumo.sim.record import SURROUNDINGS_RADIUS_M, Focus, record_config

    _, end = simulation_window(spec)
    target = spec.target or "ego"
    wanted = list(dict.fromkeys((target, *more_targets)))
    demand = config_demand(cfg)  # seconds, where a pass that finds no target takes minutes
    if demand is not None:
        classes = {v: demand.vclass(v) for v in wanted}  # None: not in the demand
        if all(c is None for c in classes.values()):
            where = "in its demand (route and additional files)"
            if spec.target is None and not more_targets:
                raise InputError(f"{cfg}: no vehicle 'ego' {where}; pick a target with --target, e.g. "
                                 f"{', '.join(demand.examples([]))}, or let --targets N choose")
            which = (f"target {wanted[0]!r} is" if len(wanted) == 1 else
                     "none of the targets " + ", ".join(map(repr, wanted)) + " is")
            raise InputError(f"{cfg}: {which} not {where}; candidates: {', '.join(demand.examples(wanted))}")
        if all(c in OFF_ROAD_CLASSES for c in classes.values()):  # the prior places road vehicles
            v, c = next(iter(classes.items()))
            raise InputError(f"{cfg}: target {v!r} is a {c} vehicle (vClass of its vType); COSTER places road "
                             "vehicles around a road vehicle: pick one with --target, or --targets N")
    # recording goes on a little after the target arrives: the collision-time search keeps the last
    # MARGIN_END steps of a scene free, and they must not eat into the target's own lifetime
    tail_s = (MARGIN_END + 1) / PRIOR_RATE_HZ
    extra: dict[str, Any] = {"additional": list(additional)} if additional else {}

    def after_step(session: Any, states: Any) -> bool:
        if progress is not None:
            progress(session.time)
        return hold.after_step(session, states) if hold is not None else False

    scene = record_config(cfg, seed=spec.seed, begin=spec.begin, end=end, traci=traci,
                          focus=Focus(target, SURROUNDINGS_RADIUS_M, tail_s=tail_s, surroundings_hz=PRIOR_RATE_HZ,
                                      more_targets=tuple(more_targets), max_life_s=MAX_TARGET_LIFE_S),
                          after_step=after_step, **extra)
    ids = scene.tracks.ids.tolist()
    present = [ids.index(v) for v in wanted if v in ids]
    if present:  # regions and the drivable area cover its (their) surroundings only
        # every recorded vehicle stays: SUMO found it within the radius (of the target's front, not
        # its centre), and dropping a few would copy every track array of the pass
        return crop_scene(scene, SURROUNDINGS_RADIUS_M, present[0], agent_radius_m=np.inf,
                          more_targets=present[1:]), False
    # no target ever ran: the focused pass kept who did (and for how long), for the error
    pass_window = scene.meta.get("pass_window_s")
    if pass_window is None:
        raise InputError(f"{cfg}: the simulation recorded no step in [{spec.begin}, {end}]")
    window = f"{pass_window[0]:.1f}-{pass_window[1]:.1f} s"
    raise missing_target(cfg, list(dict.fromkeys((spec.target, *more_targets))), window, scene.meta["ran_s"])


def choose_target(scene: Scene, requested: str | None, config: Any) -> int:
    """Index of the target: ``requested``, else the SDC of a converted scene, else ``ego``.

    Raises :class:`InputError` (naming ``config`` and candidate ids) when there is none, or when
    the target runs for fewer than two steps of the window.
    """
    ids = scene.tracks.ids.tolist()
    ts = scene.timestamps
    window = f"{float(ts[0]):.1f}-{float(ts[-1]):.1f} s" if len(ts) else "empty"
    if requested is None and scene.sdc_index >= 0:
        index = scene.sdc_index
    elif (requested or "ego") in ids:
        index = ids.index(requested or "ego")
    else:
        steps = scene.tracks.valid.sum(axis=1).tolist()
        raise missing_target(config, [requested], window, dict(zip(ids, steps, strict=True)))
    if scene.tracks.valid[index].sum() < 2:
        raise InputError(f"{config}: target {ids[index]!r} never departs in the window")
    return index


def missing_target(config: Any, requested: Sequence[str | None], window: str, ran: dict[str, float]) -> InputError:
    """The one-line error for targets that never run: ``requested`` (None: the default 'ego'), the
    window, and candidates from ``ran`` (every vehicle that ran, in order of appearance, with how
    long it ran): ids containing a requested name, else the longest-running ones."""
    if not ran:
        return InputError(f"{config}: no vehicle runs in the window ({window}) at all")
    if requested == [None]:
        longest = sorted(ran, key=lambda v: -ran[v])[:8]
        return InputError(f"{config}: no vehicle 'ego' runs in the window ({window}); pick a target with "
                          "--target, e.g. " + ", ".join(longest))
    names = [r or "ego" for r in requested]
    near = [v for v in ran if any(n.lower() in v.lower() for n in names)][:8] or list(ran)[:8]
    which = (f"target {names[0]!r} never runs" if len(names) == 1 else
             "none of the targets " + ", ".join(map(repr, names)) + " runs")
    return InputError(f"{config}: {which} in the window ({window}); candidates: {', '.join(near)}")


# ----------------------------------------------------------------------------- generation

def _checked_steps(plan: AdversaryPlan, times: np.ndarray, tolerance_s: float) -> np.ndarray:
    """(T,) bool: the scene steps from the plan's start to t_col - ``tolerance_s``, with half a step
    of margin against the log's timestamp jitter (the steps the contact filters look at)."""
    half_step = 0.5 * float(np.median(np.diff(times))) if len(times) > 1 else 0.0
    return (times >= plan.t_start - 1e-9) & (times < plan.t_col - tolerance_s - half_step)


def early_contact(plan: AdversaryPlan, scene: Scene, target: int, tolerance_s: float = 0.1) -> float | None:
    """Time [s] at which ``plan`` would overlap the target's nominal path before t_col - tolerance.

    Checked at the nominal scene's own rate (10 Hz) against the target's logged boxes; a variant
    that hits the target early is not the snapshot's collision and is not kept. The steps within
    ``tolerance_s`` of t_col are not checked, whatever the log's timestamp jitter (half a step of
    margin): with the default, touching one step early is allowed, two steps is not.
    """
    t = scene.tracks
    times = scene.timestamps
    sel = _checked_steps(plan, times, tolerance_s) & t.valid[target]
    if not sel.any():
        return None
    x, y, yaw, _ = plan.sample(times[sel])
    adv = make_boxes(x, y, yaw, plan.length, plan.width)
    tgt = make_boxes(t.x[target, sel], t.y[target, sel], t.heading[target, sel], t.length[target, sel],
                     t.width[target, sel])
    hit = box_signed_distance(adv, tgt) <= CONTACT_TOLERANCE_M
    return float(times[sel][np.argmax(hit)]) if hit.any() else None


def bystander_contact(plan: AdversaryPlan, scene: Scene, target: int, tolerance_s: float = 0.1
                      ) -> tuple[float, str] | None:
    """(time [s], vehicle id) of the first overlap of ``plan`` with a vehicle other than the target
    on its nominal path before t_col - tolerance, or None.

    An adversary that hits another vehicle on its way ends its run in that wreck instead of at the
    target (on a freeway: a 25 m/s car running into the queue ahead of it). The nominal paths are
    what the other vehicles would do without the adversary; in a simulated scene they may still
    brake for it, so this filter removes the plans that certainly hit someone else, not every one.
    Same window and tolerance as :func:`early_contact`.
    """
    t = scene.tracks
    others = np.flatnonzero(np.arange(t.num_agents) != target)
    times = scene.timestamps
    cols = np.flatnonzero(_checked_steps(plan, times, tolerance_s))
    if not len(cols) or not len(others):
        return None
    x, y, yaw, _ = plan.sample(times[cols])
    valid = t.valid[np.ix_(others, cols)]
    ox, oy = t.x[np.ix_(others, cols)], t.y[np.ix_(others, cols)]
    # only pairs whose centres are within reach of each other (half diagonals plus the tolerance)
    reach = 0.5 * (np.hypot(plan.length, plan.width) + np.hypot(t.length[np.ix_(others, cols)],
                                                                 t.width[np.ix_(others, cols)]))
    near = valid & (np.hypot(ox - x, oy - y) <= reach + CONTACT_TOLERANCE_M)
    if not near.any():
        return None
    a, s = np.nonzero(near)
    adv = make_boxes(x[s], y[s], yaw[s], plan.length, plan.width)
    rows, c = others[a], cols[s]
    oth = make_boxes(t.x[rows, c], t.y[rows, c], t.heading[rows, c], t.length[rows, c], t.width[rows, c])
    hit = box_signed_distance(adv, oth) <= CONTACT_TOLERANCE_M
    if not hit.any():
        return None
    first = np.flatnonzero(hit)[np.argmin(c[hit])]
    return float(times[c[first]]), str(t.ids[rows[first]])


SNAPSHOT_SEPARATION_STEPS = 4  # [2 Hz steps] the collision times of several snapshots lie 2 s apart or more


def _around(t_index: int) -> range:
    """The 2 Hz steps closer than :data:`SNAPSHOT_SEPARATION_STEPS` to ``t_index``."""
    return range(t_index - SNAPSHOT_SEPARATION_STEPS + 1, t_index + SNAPSHOT_SEPARATION_STEPS)


def generation_rng(seed: int, scene: Scene) -> np.random.Generator:
    """The random choices of one scene's generation: from the seed and the scene's id.

    Seeded by the seed alone, every scene of a batch run with one seed made the same choices: the
    "random" collision time fell on the same step of the window in 75 % of the 104 held-out scenes
    of ``eval scenarios`` (their windows have one length), so that ablation was a fixed step.
    """
    return np.random.default_rng([seed, int.from_bytes(hashlib.sha256(scene.scenario_id.encode()).digest()[:4], "big")])


def plan_scenario(scene: Scene, target: int, seed: int, gen: GenerationConfig,
                  drivable: DrivableArea, exclude: Collection[int] = (),
                  on_snapshot: Callable[[CollisionSnapshot], None] | None = None,
                  memo: dict[str, Any] | None = None) -> PlannedScenario:
    """Snapshot and adversary plans for ``target`` (one draw of the seeded generator).

    Plans that would hit the target, or another vehicle on its nominal path, before t_col are
    dropped; when none is left, a new snapshot is drawn (the generator moves on). At one collision
    time the first :data:`STRICT_PER_TIME` draws take only placements that close in on the target
    (:func:`coster_sumo.snapshot.closing`), the next ones also grazing ones; after
    :data:`ATTEMPTS_PER_TIME` draws, or as soon as it has no acceptable placement at all, the
    collision time is given up and the next best one at least 2 s away is tried (a target sweeping
    through a turn at the best one can leave no approach that does not touch it early). After
    :data:`COLLISION_TIMES` collision times: :class:`NoSnapshot`, naming each with its reason.
    ``exclude``: 2 Hz steps not to take as t_col. ``on_snapshot`` is called with every snapshot
    drawn, before its adversaries are generated (the variants' simulations can get ready meanwhile).
    ``memo``: a dict the caller keeps across draws for the same scene, target and ``gen`` (the 2 Hz
    scene and the prior's entropy curve are computed once in it).
    """
    rng = generation_rng(seed, scene)
    memo = {} if memo is None else memo
    if "low" not in memo:
        memo["low"] = resample(scene, PRIOR_RATE_HZ)
    low, init_memo = memo["low"], memo.setdefault("init", {})
    init, rollout = SNAPSHOT_INITS[gen.init], ROLLOUTS[gen.rollout]
    excluded = set(exclude)
    failed: dict[str, str] = {}  # "t_col 20.6 s" -> why its last draw failed

    def place(strict: bool) -> tuple[CollisionSnapshot, bool]:
        """A snapshot and whether it closes in; grazing when nothing closes in at the time."""
        try:
            return init.place(low, target, rng, drivable, gen.collision_time, seed, gen.models_dir, excluded,
                              strict=strict, memo=init_memo), strict
        except NoSnapshot as exc:
            if not strict or exc.t_index is None:
                raise
        return init.place(low, target, rng, drivable, gen.collision_time, seed, gen.models_dir, excluded,
                          strict=False, memo=init_memo), False

    def label(t_index: int) -> str:
        return f"t_col {float(low.timestamps[t_index]):.1f} s"

    draws = 0
    for _ in range(COLLISION_TIMES):
        here: int | None = None
        strict = True
        for k in range(ATTEMPTS_PER_TIME):
            draws += 1
            try:
                snap, strict = place(strict and k < STRICT_PER_TIME)
            except NoSnapshot as exc:
                if exc.t_index is None and not failed:
                    raise  # no collision time in the scene at all
                if exc.t_index is not None:
                    here = exc.t_index
                    failed[label(here)] = str(exc)
                break
            here = snap.t_index
            if on_snapshot is not None:
                on_snapshot(snap)
            plans, samples_xy, info = rollout.generate(low, target, snap, drivable, samples=gen.samples,
                                                       variants=gen.variants, seed=seed, models_dir=gen.models_dir)
            kept: list[AdversaryPlan] = []
            # a cluster of the rollout that gave no representative is a variant asked for and missing
            dropped: list[dict[str, Any]] = [{"candidate": f"cluster {r['cluster']}", "reason": r["reason"]}
                                             for r in info.get("rejected_clusters", ())]
            for i, plan in enumerate(plans):
                early = early_contact(plan, scene, target)
                other = bystander_contact(plan, scene, target) if early is None else None
                if early is not None:
                    dropped.append({"candidate": i, "reason": f"would hit the target at {early:.1f} s, before "
                                                              "t_col (on the target's nominal path)"})
                elif other is not None:
                    dropped.append({"candidate": i, "reason": f"would hit {other[1]} at {other[0]:.1f} s, before "
                                                              "t_col (on its nominal path)"})
                else:
                    kept.append(dataclasses.replace(plan, vehicle_id=f"adversary{len(kept)}"))
            if kept:
                failed.pop(label(here), None)
                info = {**info, "attempt": draws, "candidates": len(plans), "kept": len(kept), "dropped": dropped,
                        "collision_times_given_up": dict(failed)}
                return PlannedScenario(scene, low, target, snap, kept, samples_xy=samples_xy, info=info)
            failed[label(here)] = ("every trajectory hits the target or another vehicle before t_col" if plans
                                   else "no rollout stays on the road and clear of other vehicles")
        if here is None:
            break  # the window is used up
        excluded.update(_around(here))
    n = len(failed)
    raise NoSnapshot(f"no draw at {n} collision time{'s' if n != 1 else ''} gave a plan ("
                     + "; ".join(f"{k}: {v}" for k, v in failed.items()) + ")")


def plan_scenarios(scene: Scene, target: int, seed: int, gen: GenerationConfig, drivable: DrivableArea,
                   snapshots: int = 1, on_snapshot: Callable[[CollisionSnapshot], None] | None = None
                   ) -> list[PlannedScenario]:
    """Up to ``snapshots`` snapshots for one target, each with its own plans: the best collision time
    first, then the next best at least :data:`SNAPSHOT_SEPARATION_STEPS` away from those taken.

    The first equals :func:`plan_scenario` with the same seed; the others draw with derived seeds.
    Raises :class:`NoSnapshot` only when not even the first exists; fewer than asked is fine.
    """
    memo: dict[str, Any] = {}
    taken: list[PlannedScenario] = [plan_scenario(scene, target, seed, gen, drivable, on_snapshot=on_snapshot,
                                                  memo=memo)]
    excluded: set[int] = set()
    for j in range(1, snapshots):
        excluded.update(_around(taken[-1].snapshot.t_index))
        try:
            taken.append(plan_scenario(scene, target, derived_seed(seed, j), gen, drivable, exclude=excluded,
                                       on_snapshot=on_snapshot, memo=memo))
        except NoSnapshot:
            break
    offset = 0
    for p in taken:  # adversary ids unique across snapshots
        p.plans = [dataclasses.replace(plan, vehicle_id=f"adversary{offset + i}") for i, plan in enumerate(p.plans)]
        offset += len(p.plans)
    return taken


def derived_seed(seed: int, j: int) -> int:
    """The seed of extra draw ``j`` (j >= 1) of a scene: deterministic, far from seed + small ints."""
    return int.from_bytes(hashlib.sha1(f"{seed}/{j}".encode()).digest()[:4], "little")


@dataclass(frozen=True)
class Variant:
    """One generated variant: its plan, the snapshot it ends in, and the draw that made it."""

    plan: AdversaryPlan
    snapshot: CollisionSnapshot
    draw: int

    def to_dict(self) -> dict[str, Any]:
        return {"plan": self.plan.to_dict(), "snapshot": self.snapshot.to_dict(), "draw": self.draw}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Variant:
        return cls(AdversaryPlan.from_dict(d["plan"]), CollisionSnapshot.from_dict(d["snapshot"]), int(d["draw"]))


def generate_variants(scene: Scene, target: int, seed: int, gen: GenerationConfig, drivable: DrivableArea,
                      max_draws: int | None = None) -> tuple[list[Variant], dict[str, Any]]:
    """Up to ``gen.variants`` variants and an info dict.

    A rollout that gives K representatives per snapshot fills them in one draw. One that gives a
    single trajectory per snapshot (the constant-velocity baseline) draws again with derived seeds
    (a new snapshot each) up to K. Draw 0 uses ``seed`` itself, so its variants equal
    :func:`plan_scenario` with the same seed.
    """
    one_each = ROLLOUTS[gen.rollout].one_per_snapshot
    variants: list[Variant] = []
    infos: list[dict[str, Any]] = []
    reasons: list[str] = []
    max_draws = max_draws if max_draws is not None else 3 * gen.variants
    memo: dict[str, Any] = {}
    for j in range(max_draws):
        if len(variants) >= gen.variants:
            break
        draw_seed = seed if j == 0 else derived_seed(seed, j)
        try:
            planned = plan_scenario(scene, target, draw_seed, gen, drivable, memo=memo)
        except NoSnapshot as exc:
            reasons.append(f"draw {j}: {exc}")
            if not one_each:
                break  # the CVAE already tried its K; another seed rarely changes a scene without snapshot
            continue
        infos.append({k: v for k, v in planned.info.items() if k != "dropped"} | {"draw": j, "seed": draw_seed})
        for plan in planned.plans[:gen.variants - len(variants)]:
            plan = dataclasses.replace(plan, vehicle_id=f"adversary{len(variants)}")
            variants.append(Variant(plan, planned.snapshot, j))
        if not one_each:
            break  # the rollout's K representatives are the variants
    if not variants:
        raise NoSnapshot("; ".join(reasons[:3]) or "no variant")
    return variants, {"draws": infos, "rejected_draws": reasons}
