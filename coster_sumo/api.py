"""Python API: plan adversaries for a SUMO configuration, then drive them in your own loop.

Example (also in the README, and run by tests/test_api.py)::

    from coster_sumo.api import AdversaryController, SumoSession, plan_adversaries

    planned = plan_adversaries("networks/intersection/intersection.sumocfg", seed=0, variants=3)
    plan = planned.plans[0]                      # 2 Hz knots ending in the collision snapshot
    adversary = AdversaryController(plan)
    with SumoSession("networks/intersection/intersection.sumocfg", seed=0) as sim:
        while sim.time < plan.t_col + 2.0:
            adversary.before_step(sim, round(sim.time + sim.step_length, 9))  # every step
            sim.step()
            # ... your planner / logging here: sim.vehicle_states(), sim.api (libsumo or TraCI) ...

For an external ``sumo`` or ``sumo-gui`` you started yourself with ``--remote-port P``, use
``SumoSession(port=P)``: the session attaches over TraCI and the same loop works.
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path
from typing import Any

from coster_sumo.avoidability.labels import ProofSettings, label_plans
from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.core.spec import GenerationConfig, LabelOptions, ScenarioSpec
from coster_sumo.errors import InputError
from coster_sumo.formats.targets import choose_target
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.method.generation import DrawMemo, PlannedScenario, check_generation, label_and_keep, plan_scenarios
from coster_sumo.pipeline.scenario import nominal_scene
from coster_sumo.sim.inject import AdversaryController, inject_variant, run_injection
from coster_sumo.sim.session import SumoSession

__all__ = ["AdversaryController", "AdversaryPlan", "GenerationConfig", "LabelOptions", "PlannedScenario",
           "ScenarioSpec", "SumoSession", "inject_variant", "plan_adversaries", "run_injection"]


def plan_adversaries(config: str | Path, target: str | None = None, *, seed: int = 0, begin: float | None = None,
                     end: float | None = None, generation: GenerationConfig | None = None,
                     labels: LabelOptions | None = None, **settings: Any) -> PlannedScenario:
    """Nominal pass, collision snapshot and adversary plans for ``target`` (see ``coster-sumo run``).

    Returns the :class:`~coster_sumo.method.generation.PlannedScenario`: ``.snapshot`` and ``.plans`` (one
    :class:`~coster_sumo.core.plan.AdversaryPlan` per kept variant, sim times in seconds). Inject one
    with :func:`~coster_sumo.sim.inject.inject_variant` or drive it in your own loop.

    Fewer plans than ``variants`` is possible (a cluster of the oversampled trajectories had no
    member that stays on the road, a candidate would hit the target or another vehicle before
    t_col): ``.dropped`` then holds one line per missing candidate with its reason, and a
    :class:`UserWarning` says the same.
    Every plan is labelled (docs/method.md step 8; escapes proven in SUMO from the begin):
    ``.info["avoidability"]`` maps each plan's ``vehicle_id`` to its label (``avoidable`` at
    ``reaction_time`` [s], the escapes, the last moment to act, the kind of contact). With
    ``avoidable="only"`` the unavoidable plans are dropped and replaced by plans of up to three
    further draws (their own collision snapshots: each label carries its ``t_col``);
    ``.info["avoidable_only"]`` says how many were tried.

    How the plans are made and labelled: ``generation`` (a :class:`GenerationConfig`: ``init``,
    ``collision_time``, ``rollout``, ``samples``, ``variants``, ``models_dir``) and ``labels`` (a
    :class:`~coster_sumo.core.spec.LabelOptions`: ``reaction_time``, ``avoidable``), their defaults
    ``coster-sumo run``'s; any of their fields may also be given as a keyword (``variants=3``,
    ``avoidable="only"``) and replaces that field. A bad or unknown one is one :class:`InputError`
    line before any work. ``adversary`` (a field of :class:`GenerationConfig`): vehicle (default),
    cyclist, pedestrian or any (``coster-sumo run --adversary``); each plan's ``vclass`` and the
    snapshot's ``adversary_class`` say the class drawn.
    """
    spec = ScenarioSpec(Path(config), seed=seed, begin=begin, end=end, target=target)
    gen, wanted = _settings(generation or GenerationConfig(), labels or LabelOptions(), settings)
    variants = gen.variants
    check_generation(gen)  # the method names and their weights, before the nominal pass
    scene, _ = nominal_scene(spec)
    index = choose_target(scene, target, spec.config)
    drivable = DrivableArea.from_road_map(scene.road_map)
    shared = DrawMemo.of(scene)  # what every draw for this target computes once
    planned = plan_scenarios(scene, index, seed, gen, drivable, shared)[0]  # one snapshot: the first draw

    def label(plans: list[AdversaryPlan]) -> list[Any]:
        return label_plans(spec, scene, index, plans, ProofSettings(drivable), reaction_time_s=wanted.reaction_time)

    kept, by_plan, tried = label_and_keep([planned], label, wanted, variants, seed=seed, gen=gen, drivable=drivable,
                                          memo=shared)
    if tried is not None:
        planned.plans = [p for q in kept for p in q.plans]  # may be empty: none was avoidable
        planned.info["avoidable_only"] = tried.to_json()
    planned.info["avoidability"] = {p.vehicle_id: by_plan[p.vehicle_id].summary() for p in planned.plans}
    if len(planned.plans) < variants:
        warnings.warn(f"{config}: {len(planned.plans)} of {variants} variants; "
                      + "; ".join(planned.dropped or ["the rollout gave fewer representatives"]), stacklevel=2)
    return planned


def _settings(gen: GenerationConfig, wanted: LabelOptions, settings: dict[str, Any]
              ) -> tuple[GenerationConfig, LabelOptions]:
    """``gen`` and ``wanted`` with the fields that ``settings`` name replaced (each checks itself)."""
    gen_fields = {f.name for f in dataclasses.fields(GenerationConfig)}
    label_fields = {f.name for f in dataclasses.fields(LabelOptions)}
    unknown = sorted(set(settings) - gen_fields - label_fields)
    if unknown:
        raise InputError(f"plan_adversaries: unknown setting {unknown[0]!r} (the settings are "
                         f"{', '.join(sorted(gen_fields | label_fields))})")
    if settings.get("models_dir") is not None:
        settings = {**settings, "models_dir": Path(settings["models_dir"])}
    gen = dataclasses.replace(gen, **{k: v for k, v in settings.items() if k in gen_fields})
    return gen, dataclasses.replace(wanted, **{k: v for k, v in settings.items() if k in label_fields})
