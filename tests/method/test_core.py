"""The generation core: method registries, checks before work, variants from one scene."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from coster_sumo.cli.command_line import build_parser
from coster_sumo.core.scene import resample
from coster_sumo.core.spec import GenerationConfig
from coster_sumo.errors import InputError
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.method.collision_time import COLLISION_TIME_RULES, choose_collision_time
from coster_sumo.method.generation import check_generation, generate_variants, missing_weights, plan_scenario
from coster_sumo.method.snapshot import SNAPSHOT_INITS
from coster_sumo.rollout.methods import ROLLOUTS
from coster_sumo.sim.planners import PLANNERS, check_planner

BASELINES = GenerationConfig(init="random", rollout="cv", collision_time="last")


def _choices(argv: list[str], flag: str) -> tuple[str, ...]:
    parser = build_parser()
    sub = parser._subparsers._group_actions[0].choices[argv[0]]  # type: ignore[union-attr]
    action = next(a for a in sub._actions if flag in a.option_strings)
    return tuple(action.choices)


@pytest.mark.parametrize("command", ["run", "regress"])
def test_cli_choices_are_the_registries(command):
    assert _choices([command], "--init") == tuple(SNAPSHOT_INITS)
    assert _choices([command], "--collision-time") == tuple(COLLISION_TIME_RULES)
    assert _choices([command], "--rollout") == tuple(ROLLOUTS)


def test_a_new_collision_time_rule_is_one_function_and_one_line(monkeypatch):
    monkeypatch.setitem(COLLISION_TIME_RULES, "first", lambda request: int(request.window[0]))
    assert choose_collision_time(np.array([4, 5, 6]), "first", np.random.default_rng(0)) == 4
    check_generation(GenerationConfig(init="random", rollout="cv", collision_time="first"))


def test_an_unknown_collision_time_rule_is_one_input_error_line():
    with pytest.raises(InputError, match="unknown collision-time method 'soon'; use one of entropy, last, random"):
        choose_collision_time(np.array([4, 5, 6]), "soon", np.random.default_rng(0))


@pytest.mark.parametrize(("field", "value", "flag"), [("init", "prior", "--init"), ("rollout", "gan", "--rollout"),
                                                      ("collision_time", "soon", "--collision-time")])
def test_unknown_methods_are_refused_before_work(field, value, flag):
    with pytest.raises(InputError, match=flag):
        check_generation(GenerationConfig(**{**BASELINES.__dict__, field: value}))


def test_missing_weights_name_the_file_and_the_training_command(tmp_path):
    reason = missing_weights(GenerationConfig(models_dir=tmp_path))
    assert reason is not None and str(tmp_path / "prior.pt") in reason and "train prior" in reason
    assert missing_weights(GenerationConfig(init="random", rollout="cv", models_dir=tmp_path)) is None


def test_planner_registry_and_module_planners():
    assert set(PLANNERS) == {"replay", "sumo", "policy"}
    check_planner("sumo:IDM")
    check_planner("misbehaving_planners:Hang")
    for bad in ("sumo:NoSuchModel", "teleport", "no_such_module:Planner"):
        with pytest.raises(InputError):
            check_planner(bad)


def test_constant_velocity_draws_one_snapshot_per_variant(synthetic_scene):
    scene = synthetic_scene
    if scene.sdc_index < 0:
        pytest.skip("no target in this synthetic scene")
    drivable = DrivableArea.from_road_map(scene.road_map)
    try:
        variants, info = generate_variants(scene, scene.sdc_index, 0, GenerationConfig(init="random", rollout="cv",
                                                                                        variants=3), drivable)
    except Exception as exc:  # noqa: BLE001 - a synthetic scene may have no room for an adversary
        pytest.skip(f"no snapshot: {exc}")
    assert [v.plan.vehicle_id for v in variants] == [f"adversary{i}" for i in range(len(variants))]
    assert len({v.draw for v in variants}) == len(variants)  # one draw (snapshot) each
    first = plan_scenario(scene, scene.sdc_index, 0, GenerationConfig(init="random", rollout="cv"), drivable)
    assert np.array_equal(first.plans[0].x, variants[0].plan.x)  # draw 0 is the run with the same seed
    assert resample(scene, 2.0).num_steps == first.scene_2hz.num_steps


def test_variants_round_trip_through_json(synthetic_scene, tmp_path: Path):
    from coster_sumo.method.generation import Variant

    scene = synthetic_scene
    if scene.sdc_index < 0:
        pytest.skip("no target in this synthetic scene")
    try:
        (v, *_), _ = generate_variants(scene, scene.sdc_index, 1, GenerationConfig(init="random", rollout="cv",
                                                                                   variants=1),
                                       DrivableArea.from_road_map(scene.road_map))
    except Exception as exc:  # noqa: BLE001
        pytest.skip(f"no snapshot: {exc}")
    back = Variant.from_dict(v.to_dict())
    assert np.array_equal(back.plan.times, v.plan.times) and back.snapshot.time == v.snapshot.time


def test_further_draws_reuse_the_first_draws_prior_curves(synthetic_scene, monkeypatch):
    """--avoidable only draws again for the same target: with the first draws' memo the prior's
    curves over the target's life are not computed again (16.4 s -> 0.9 s per further draw on A10KW),
    and the draw is the one it would be alone."""
    from coster_sumo.errors import NoSnapshot
    from coster_sumo.method import snapshot
    from coster_sumo.method.generation import DrawMemo, further_draw, plan_scenarios

    scene = synthetic_scene
    if scene.sdc_index < 0:
        pytest.skip("no target in this synthetic scene")
    drivable, gen = DrivableArea.from_road_map(scene.road_map), GenerationConfig()
    curves = []
    real = snapshot.entropy_search  # the curve over the window (every step of a short one)
    monkeypatch.setattr(snapshot, "entropy_search", lambda *a, **k: curves.append(1) or real(*a, **k))
    shared = DrawMemo.of(scene)
    try:
        plan_scenarios(scene, scene.sdc_index, 0, gen, drivable, shared)
    except NoSnapshot as exc:
        pytest.skip(f"no snapshot: {exc}")
    assert len(curves) == 1
    again = further_draw(scene, scene.sdc_index, 0, gen, drivable, 1, shared)
    assert len(curves) == 1  # the shared memo had it
    alone = further_draw(scene, scene.sdc_index, 0, gen, drivable, 1, DrawMemo.of(scene))
    assert len(curves) == 2
    assert (again is None) == (alone is None)
    if again is not None and alone is not None:
        assert again.snapshot.time == alone.snapshot.time
        assert [p.vehicle_id for p in again.plans] == [p.vehicle_id for p in alone.plans]
        for a, b in zip(again.plans, alone.plans, strict=True):
            assert np.array_equal(a.x, b.x) and np.array_equal(a.y, b.y)
