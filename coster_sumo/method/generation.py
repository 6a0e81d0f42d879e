"""Generation (docs/method.md steps 3-6 together): from a nominal scene, its target and a generation
config to adversary plans. ``coster-sumo run``, ``regress``, ``eval scenarios``, the scenario sets of
the environment and the Python API all draw through :func:`draw_scenarios`:

1. :func:`plan_scenario`, one draw: the 2 Hz scene, the collision snapshot (a snapshot init of
   :data:`~coster_sumo.method.snapshot.SNAPSHOT_INITS` with a rule of
   :data:`~coster_sumo.method.collision_time.COLLISION_TIME_RULES`), the adversary plans (a rollout
   of :data:`~coster_sumo.rollout.methods.ROLLOUTS`), and the filters of candidates
   (:mod:`coster_sumo.method.filters`); the next collision time when one gives no plan;
2. :func:`draw_scenarios`, the one loop of draws (the seed, then derived seeds) sharing what a
   scene computes once;
3. :func:`plan_scenarios` (``run``: up to N snapshots, collision times 2 s apart, each with its
   variants) and :func:`generate_variants` (``regress``, ``eval scenarios``: up to K variants, more
   draws when a rollout gives one trajectory per snapshot) stop that loop each their own way.

The nominal scene and the target come from :mod:`coster_sumo.pipeline.scenario`; injection of a plan is
:func:`coster_sumo.sim.inject.inject_variant`.
"""

from __future__ import annotations

import hashlib
import itertools
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from coster_sumo.avoidability.evasion import Avoidability
from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.core.results import AvoidableOnly
from coster_sumo.core.scene import Scene, resample
from coster_sumo.core.snapshot import CollisionSnapshot
from coster_sumo.core.spec import GenerationConfig, LabelOptions
from coster_sumo.errors import InputError, NoSnapshot
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.geometry.road_follow import follow_road
from coster_sumo.infra import weights
from coster_sumo.method.collision_time import COLLISION_TIME_RULES, COLLISION_TIMES, PRIOR_RATE_HZ, around
from coster_sumo.method.filters import keep_clear_plans
from coster_sumo.method.snapshot import (
    ATTEMPTS_PER_TIME,
    SNAPSHOT_INITS,
    STRICT_PER_TIME,
    PlacementRequest,
    PriorMemo,
    place_closing_first,
)
from coster_sumo.rollout.methods import ROLLOUTS
from coster_sumo.rollout.request import RolloutRequest


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
    """Method names against the registries and the weights the methods need (exit 2 before work; the
    counts are checked when ``gen`` is made)."""
    for flag, value, registry in (("--init", gen.init, SNAPSHOT_INITS),
                                  ("--collision-time", gen.collision_time, COLLISION_TIME_RULES),
                                  ("--rollout", gen.rollout, ROLLOUTS)):
        if value not in registry:
            raise InputError(f"{flag} must be one of {', '.join(registry)}, not {value!r}")
    reason = missing_weights(gen)
    if reason:
        raise InputError(reason)


def missing_weights(gen: GenerationConfig) -> str | None:
    """Why the methods of ``gen`` cannot run with its models folder, or None."""
    needed = SNAPSHOT_INITS[gen.init].weights + ROLLOUTS[gen.rollout].weights
    return weights.missing_weights(needed, gen.models_dir)


def generation_rng(seed: int, scene: Scene) -> np.random.Generator:
    """The random choices of one scene's generation: from the seed and the scene's id.

    Seeded by the seed alone, every scene of a batch run with one seed made the same choices: the
    "random" collision time fell on the same step of the window in 75 % of the 104 held-out scenes
    of ``eval scenarios`` (their windows have one length), so that ablation was a fixed step.
    """
    return np.random.default_rng([seed, int.from_bytes(hashlib.sha256(scene.scenario_id.encode()).digest()[:4], "big")])


@dataclass
class DrawMemo:
    """What the draws for one scene, target and generation config share (the draws of
    :func:`draw_scenarios`, and the further draws of :func:`keep_avoidable`):
    the scene at the models' 2 Hz and what the prior computes once (:class:`PriorMemo`).

    The 2 Hz scene comes with the memo: a run resamples its nominal scene once for all its targets
    (:class:`coster_sumo.pipeline.scenario.NominalPass`); :meth:`of` resamples a scene.
    """

    low: Scene
    prior: PriorMemo = field(default_factory=PriorMemo)
    areas: dict[str, Any] = field(default_factory=dict)  # VRU areas, a target's `any` shares (method.vru.methods)

    @classmethod
    def of(cls, scene: Scene) -> DrawMemo:
        """A fresh memo for draws on ``scene`` (10 Hz): its 2 Hz scene made here."""
        return cls(resample(scene, PRIOR_RATE_HZ))


class _Draws:
    """The draws of one :func:`plan_scenario`: the seeded generator, the 2 Hz steps not to take as
    t_col, the collision times given up (label -> why its last draw failed) and the draws made."""

    def __init__(self, scene: Scene, target: int, seed: int, gen: GenerationConfig, drivable: DrivableArea,
                 memo: DrawMemo, exclude: Collection[int],
                 on_snapshot: Callable[[CollisionSnapshot], None] | None) -> None:
        self.scene, self.low, self.target, self.seed, self.gen = scene, memo.low, target, seed, gen
        self.drivable, self.on_snapshot, self.init_memo = drivable, on_snapshot, memo.prior
        self.rng = generation_rng(seed, scene)
        self.init, self.rollout = SNAPSHOT_INITS[gen.init], ROLLOUTS[gen.rollout]
        self.areas = memo.areas
        self.excluded = set(exclude)
        self.failed: dict[str, str] = {}  # "t_col 20.6 s" -> why its last draw failed
        self.count = 0

    def label(self, t_index: int) -> str:
        return f"t_col {float(self.low.timestamps[t_index]):.1f} s"

    def at_one_time(self) -> tuple[PlannedScenario | None, int | None]:
        """Up to :data:`ATTEMPTS_PER_TIME` draws at the best collision time left: the plans of the
        first that gives any, and the 2 Hz step of that time (None: no collision time is left)."""
        here: int | None = None
        strict = True
        for k in range(ATTEMPTS_PER_TIME):
            self.count += 1
            if self.gen.adversary != "vehicle":  # the class's own placement and rollout (coster_sumo.method.vru)
                self.init, self.rollout = self.class_methods()
            try:
                snap, strict = place_closing_first(self.init, PlacementRequest(
                    self.low, self.target, self.rng, self.drivable, self.gen.collision_time, self.seed,
                    self.gen.models_dir, self.excluded, strict=strict and k < STRICT_PER_TIME, memo=self.init_memo))
            except NoSnapshot as exc:
                if exc.t_index is None and not self.failed:
                    raise  # no collision time in the scene at all
                if exc.t_index is not None:
                    here = exc.t_index
                    self.failed[self.label(here)] = str(exc)
                break
            here = snap.t_index
            planned = self.plans_of(snap)
            if planned is not None:
                return planned, here
        return None, here

    def class_methods(self) -> tuple[Any, Any]:
        """The snapshot init and rollout of this draw's adversary class (``any``: drawn now)."""
        from coster_sumo.method.vru.methods import class_area, class_shares, draw_class, methods_for

        shares = None
        if self.gen.adversary == "any":
            shares = self.areas.get(f"any shares {self.target}")
            if shares is None:
                shares = self.areas[f"any shares {self.target}"] = class_shares(self.low, self.target)
        name = draw_class(self.gen.adversary, self.rng, shares)
        area = None if name == "vehicle" else class_area(name, self.scene.road_map, self.drivable, self.areas)
        return methods_for(name, self.gen.init, self.gen.rollout, area)

    def plans_of(self, snap: CollisionSnapshot) -> PlannedScenario | None:
        """The rollout from ``snap`` and the plans the filters keep; None (and the time's reason
        recorded) when they keep none."""
        if self.on_snapshot is not None:
            self.on_snapshot(snap)
        gen = self.gen
        plans, samples_xy, info = self.rollout.generate(RolloutRequest(
            self.low, self.target, snap, self.drivable, samples=gen.samples, variants=gen.variants, seed=self.seed,
            models_dir=gen.models_dir))
        # a cluster of the rollout that gave no representative is a variant asked for and missing
        dropped: list[dict[str, Any]] = [{"candidate": f"cluster {r['cluster']}", "reason": r["reason"]}
                                         for r in info.get("rejected_clusters", ())]
        kept, filtered = keep_clear_plans(plans, self.scene, self.target)
        if snap.adversary_class != "vehicle":  # a VRU squeezes past vehicles: a clearance too
            from coster_sumo.method.vru.rollout import keep_vru_clear

            kept, more = keep_vru_clear(kept, self.scene, self.target)
            filtered += more
        # after t_col a missed adversary keeps to its lane: the search and every pass see that
        kept = [follow_road(p, self.scene.road_map) if p.vclass == "passenger" else p for p in kept]
        dropped += filtered
        if kept:
            self.failed.pop(self.label(snap.t_index), None)
            info = {**info, "attempt": self.count, "candidates": len(plans), "kept": len(kept), "dropped": dropped,
                    "collision_times_given_up": dict(self.failed)}
            return PlannedScenario(self.scene, self.low, self.target, snap, kept, samples_xy=samples_xy, info=info)
        self.failed[self.label(snap.t_index)] = (
            "every trajectory hits the target or another vehicle before t_col" if plans
            else f"no rollout stays on the {_surface(snap)} and clear of other vehicles")
        return None


def _surface(snap: CollisionSnapshot) -> str:
    """Where the adversary of ``snap`` must stay: the road, or its class's area."""
    return {"pedestrian": "walkable area", "cyclist": "rideable area"}.get(snap.adversary_class, "road")


def plan_scenario(scene: Scene, target: int, seed: int, gen: GenerationConfig,
                  drivable: DrivableArea, exclude: Collection[int] = (),
                  on_snapshot: Callable[[CollisionSnapshot], None] | None = None,
                  memo: DrawMemo | None = None) -> PlannedScenario:
    """Snapshot and adversary plans for ``target`` (one draw of the seeded generator).

    Plans that would hit the target, or another vehicle on its nominal path, before t_col are
    dropped; when none is left, a new snapshot is drawn (the generator moves on). At one collision
    time the first :data:`~coster_sumo.method.snapshot.STRICT_PER_TIME` draws take only placements
    that close in on the target (:func:`coster_sumo.method.snapshot.closing`), the next ones also
    grazing ones; after :data:`~coster_sumo.method.snapshot.ATTEMPTS_PER_TIME` draws, or as soon as
    it has no acceptable placement at all, the collision time is given up and the next best one at
    least 2 s away is tried (a target sweeping through a turn at the best one can leave no approach
    that does not touch it early). After :data:`~coster_sumo.method.collision_time.COLLISION_TIMES`
    collision times: :class:`NoSnapshot`, naming each with its reason.
    ``exclude``: 2 Hz steps not to take as t_col. ``on_snapshot`` is called with every snapshot
    drawn, before its adversaries are generated (the variants' simulations can get ready meanwhile).
    ``memo``: kept by the caller across draws for the same scene, target and ``gen`` (the 2 Hz
    scene and the prior's curves are computed once in it, :class:`DrawMemo`); None: a fresh one.
    """
    return _plan(scene, target, seed, gen, drivable, DrawMemo.of(scene) if memo is None else memo, exclude,
                 on_snapshot)


def _plan(scene: Scene, target: int, seed: int, gen: GenerationConfig, drivable: DrivableArea, memo: DrawMemo,
          exclude: Collection[int] = (), on_snapshot: Callable[[CollisionSnapshot], None] | None = None
          ) -> PlannedScenario:
    """:func:`plan_scenario` with its memo."""
    draws = _Draws(scene, target, seed, gen, drivable, memo, exclude, on_snapshot)
    for _ in range(COLLISION_TIMES):
        planned, here = draws.at_one_time()
        if planned is not None:
            return planned
        if here is None:
            break  # the window is used up
        draws.excluded.update(around(here))
    n = len(draws.failed)
    raise NoSnapshot(f"no draw at {n} collision time{'s' if n != 1 else ''} gave a plan ("
                     + "; ".join(f"{k}: {v}" for k, v in draws.failed.items()) + ")")


def draw_scenarios(scene: Scene, target: int, seed: int, gen: GenerationConfig, drivable: DrivableArea,
                   memo: DrawMemo, apart: bool = False,
                   on_snapshot: Callable[[CollisionSnapshot], None] | None = None
                   ) -> Iterator[tuple[int, int, PlannedScenario | NoSnapshot]]:
    """The one loop of generation: draw ``j`` = 0, 1, ... of :func:`plan_scenario` with ``seed``
    itself, then :func:`derived_seed` (``seed``, j), all sharing one memo (the 2 Hz scene, the
    regions, the entropy curve are computed once per scene and target).

    Yields (j, the draw's seed, its :class:`PlannedScenario` or the :class:`NoSnapshot` it raised);
    a draw is made only when the caller asks for the next one, so the caller bounds the draws
    (``itertools.islice``); the sequence itself does not end. With ``apart`` no draw takes a
    collision time closer than 2 s to one taken before (several snapshots of one scene). ``memo``:
    that memo (:meth:`DrawMemo.of` the scene), which the caller keeps when it draws again later for
    the same scene, target and ``gen`` (:func:`keep_avoidable`).
    """
    excluded: set[int] = set()
    for j in itertools.count():
        draw_seed = seed if j == 0 else derived_seed(seed, j)
        try:
            planned = _plan(scene, target, draw_seed, gen, drivable, memo, exclude=excluded, on_snapshot=on_snapshot)
        except NoSnapshot as exc:
            yield j, draw_seed, exc
            continue
        if apart:
            excluded.update(around(planned.snapshot.t_index))
        yield j, draw_seed, planned


def plan_scenarios(scene: Scene, target: int, seed: int, gen: GenerationConfig, drivable: DrivableArea,
                   memo: DrawMemo, snapshots: int = 1,
                   on_snapshot: Callable[[CollisionSnapshot], None] | None = None) -> list[PlannedScenario]:
    """Up to ``snapshots`` snapshots for one target, each with its own plans: the best collision time
    first, then the next best at least 2 s away from those taken.

    The first equals :func:`plan_scenario` with the same seed; the others draw with derived seeds.
    Raises :class:`NoSnapshot` only when not even the first exists; fewer than asked is fine.
    ``memo``: see :func:`draw_scenarios`.
    """
    taken: list[PlannedScenario] = []
    draws = draw_scenarios(scene, target, seed, gen, drivable, memo, apart=True, on_snapshot=on_snapshot)
    for j, _, drawn in itertools.islice(draws, snapshots):
        if isinstance(drawn, NoSnapshot):
            if j == 0:
                raise drawn
            break
        taken.append(drawn)
    offset = 0
    for p in taken:  # adversary ids unique across snapshots
        p.plans = [plan.replaced(vehicle_id=f"adversary{offset + i}") for i, plan in enumerate(p.plans)]
        offset += len(p.plans)
    return taken


def further_draw(scene: Scene, target: int, seed: int, gen: GenerationConfig, drivable: DrivableArea,
                 j: int, memo: DrawMemo) -> PlannedScenario | None:
    """Draw ``j`` of the further draws that replace unavoidable variants (``--avoidable only``):
    seeds far from those of :func:`draw_scenarios`; None when it has no snapshot. ``memo``: the
    first draws' (:func:`draw_scenarios`): the prior's curves over the target's life are not
    computed again."""
    try:
        return _plan(scene, target, derived_seed(seed, 100 + j), gen, drivable, memo)
    except NoSnapshot:
        return None


EXTRA_DRAWS = 3  # further snapshots drawn to replace unavoidable variants under --avoidable only


# labels the plans it is given (the avoidability labels, proven in SUMO: coster_sumo.avoidability.labels)
Label = Callable[[list[AdversaryPlan]], list[Avoidability]]


def label_and_keep(planned: list[PlannedScenario], label: Label, wanted: LabelOptions, variants: int, *,
                   seed: int, gen: GenerationConfig, drivable: DrivableArea, memo: DrawMemo
                   ) -> tuple[list[PlannedScenario], dict[str, Avoidability], AvoidableOnly | None]:
    """Label every plan of ``planned`` with ``label``; with ``wanted.avoidable == "only"`` keep the
    avoidable ones, up to ``variants``, drawing again for the others (:func:`keep_avoidable`).

    Returns the scenarios kept (``planned`` itself without ``only``), every label by adversary id (the
    dropped ones too) and, with ``only``, what was tried (None without).
    """
    plans = [pl for p in planned for pl in p.plans]
    labels = dict(zip((pl.vehicle_id for pl in plans), label(plans), strict=True))
    if wanted.avoidable != "only":
        return planned, labels, None
    kept, tried = keep_avoidable(planned, labels, label, variants, seed=seed, gen=gen, drivable=drivable,
                                 memo=memo)
    return kept, labels, tried


def keep_avoidable(planned: list[PlannedScenario], labels: dict[str, Avoidability], label: Label, wanted: int, *,
                   seed: int, gen: GenerationConfig, drivable: DrivableArea, memo: DrawMemo
                   ) -> tuple[list[PlannedScenario], AvoidableOnly]:
    """``--avoidable only``: drop the unavoidable plans of ``planned`` (``labels`` by adversary id,
    of the scene and target of ``planned``) and replace them by plans of :func:`further_draw` (with
    ``seed``, ``gen``, ``drivable``) until ``wanted`` are avoidable or :data:`EXTRA_DRAWS` more draws
    are spent. ``label(plans)`` gives the labels of a further draw's plans (``labels`` gains them).
    ``memo``: the one :func:`plan_scenarios` drew ``planned`` with.

    Returns the kept scenarios (at least one, maybe without plans) and what was tried.
    """
    tried = sum(len(p.plans) for p in planned)
    for p in planned:
        p.plans = [pl for pl in p.plans if labels[pl.vehicle_id].avoidable]
    kept = sum(len(p.plans) for p in planned)
    draws = 0
    for j in range(1, EXTRA_DRAWS + 1):
        if kept >= wanted:
            break
        extra = further_draw(planned[0].scene, planned[0].target_index, seed, gen, drivable, j, memo)
        draws += 1
        if extra is None:
            continue
        ids = [f"adversary{tried + i}" for i in range(len(extra.plans))]
        extra.plans = [pl.replaced(vehicle_id=v) for pl, v in zip(extra.plans, ids, strict=True)]
        tried += len(extra.plans)
        for pl, lab in zip(extra.plans, label(extra.plans), strict=True):
            labels[pl.vehicle_id] = lab
        extra.plans = [pl for pl in extra.plans if labels[pl.vehicle_id].avoidable][:wanted - kept]
        kept += len(extra.plans)
        if extra.plans:
            planned.append(extra)
    planned = [p for p in planned if p.plans] or planned[:1]
    return planned, AvoidableOnly(tried=tried, kept=kept, extra_draws=draws)


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
    if gen.variants > 0:
        draws = draw_scenarios(scene, target, seed, gen, drivable, DrawMemo.of(scene))
        for j, draw_seed, planned in itertools.islice(draws, max_draws):
            if isinstance(planned, NoSnapshot):
                reasons.append(f"draw {j}: {planned}")
                if not one_each:
                    break  # the CVAE already tried its K; another seed rarely changes a scene without snapshot
                continue
            infos.append({k: v for k, v in planned.info.items() if k != "dropped"} | {"draw": j, "seed": draw_seed})
            for plan in planned.plans[:gen.variants - len(variants)]:
                plan = plan.replaced(vehicle_id=f"adversary{len(variants)}")
                variants.append(Variant(plan, planned.snapshot, j))
            if not one_each or len(variants) >= gen.variants:
                break  # the rollout's K representatives are the variants, or K are there
    if not variants:
        raise NoSnapshot("; ".join(reasons[:3]) or "no variant")
    return variants, {"draws": infos, "rejected_draws": reasons}
