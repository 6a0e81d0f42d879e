"""Pedestrian and cyclist adversaries without SUMO: the class limits, the class's area, the snapshot
and the kinematic time-reversed rollout on synthetic scenes built in code."""

from __future__ import annotations

import numpy as np
import pytest

from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.core.scene import resample
from coster_sumo.core.snapshot import AgentState
from coster_sumo.core.spec import GenerationConfig
from coster_sumo.data import synthetic
from coster_sumo.errors import InputError
from coster_sumo.geometry.boxes import box_signed_distance, make_boxes
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.method.generation import DrawMemo, plan_scenarios
from coster_sumo.method.snapshot import PlacementRequest
from coster_sumo.method.vru.areas import ClassArea
from coster_sumo.method.vru.classes import CYCLIST, PEDESTRIAN, VRU_CLASSES, Kinematics, check_adversary, within_limits
from coster_sumo.method.vru.rollout import plan_kinematics, plan_within_limits, sample_backwards, vru_rollout
from coster_sumo.method.vru.snapshot import vru_snapshot
from coster_sumo.rollout.request import RolloutRequest

LANE_WIDTH = synthetic.LANE_WIDTH


@pytest.mark.parametrize("bad", ["car", "Pedestrian", ""])
def test_bad_adversary_is_one_input_error(bad: str) -> None:
    with pytest.raises(InputError, match="--adversary must be one of vehicle, cyclist, pedestrian, any"):
        check_adversary(bad)
    with pytest.raises(InputError, match="--adversary"):
        GenerationConfig(adversary=bad)


def test_vehicle_plans_serialise_as_before() -> None:
    """A vehicle plan's JSON has no class key (plan.json of vehicle runs unchanged); a VRU plan's has."""
    times = np.array([0.0, 0.5, 1.0])
    state = AgentState(2.0, 0.0, 0.0, 2.0, 0.5, 0.5)
    vehicle = AdversaryPlan.from_knots(times, np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]), state)
    walker = AdversaryPlan.from_knots(times, np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]), state, vclass="pedestrian")
    assert "vclass" not in vehicle.to_dict()
    assert AdversaryPlan.from_dict(walker.to_dict()).vclass == "pedestrian"
    assert GenerationConfig().adversary == "vehicle"


@pytest.mark.parametrize("cls", [PEDESTRIAN, CYCLIST], ids=lambda c: c.name)
def test_speeds_drawn_within_the_class_range(cls) -> None:
    v = cls.draw_speed(np.random.default_rng(0), 5000)
    assert v.min() >= cls.walk_min and v.max() <= cls.fast_max
    usual = v[v <= cls.walk_max]
    assert abs(float(np.median(usual)) - cls.walk_mean) < 0.2  # the usual speed centres on the class's mean


@pytest.mark.parametrize("cls", [PEDESTRIAN, CYCLIST], ids=lambda c: c.name)
def test_backward_samples_end_in_the_state_and_keep_the_limits(cls) -> None:
    knots = sample_backwards(cls, 10.0, 5.0, 0.3, cls.walk_mean, 10, 300, np.random.default_rng(1))
    assert knots.shape == (300, 11, 3)
    np.testing.assert_allclose(knots[:, -1], np.broadcast_to([10.0, 5.0, 0.3], (300, 3)))
    kin = Kinematics.of(knots[..., :2], knots[..., 2], 0.5)
    assert kin.speed.max() <= cls.fast_max + 0.05
    # 2 Hz differences of 0.1 s integration stay inside the class's acceleration limits
    assert kin.accel.max() <= cls.max_accel + 0.1 and kin.accel.min() >= -cls.max_decel - 0.1
    if cls is CYCLIST:  # a bicycle: its turn rate is bounded by speed / min radius
        assert np.abs(kin.yaw_rate).max() <= cls.fast_max / cls.min_turn_radius + 1e-6


def test_within_limits_rejects_a_sprinting_pedestrian() -> None:
    t = np.arange(11) * 0.5
    walk = np.stack([1.4 * t, 0 * t], -1)[None]
    sprint = np.stack([6.0 * t, 0 * t], -1)[None]
    yaw = np.zeros((1, 11))
    assert within_limits(PEDESTRIAN, Kinematics.of(walk, yaw, 0.5))[0]
    assert not within_limits(PEDESTRIAN, Kinematics.of(sprint, yaw, 0.5))[0]


def test_class_areas_on_a_two_lane_road() -> None:
    """Road surface: both classes; 2 m beside it: a pedestrian's verge, not a cyclist's; 6 m: neither."""
    scene = synthetic.two_lane_road()
    drivable = DrivableArea.from_road_map(scene.road_map)
    ped = ClassArea.build(PEDESTRIAN, scene.road_map, drivable)
    cyc = ClassArea.build(CYCLIST, scene.road_map, drivable)
    ox, oy = -7785.0, -6683.0
    pts = np.array([[ox + 100, oy], [ox + 100, oy - LANE_WIDTH / 2 - 2.0], [ox + 100, oy - LANE_WIDTH / 2 - 6.0]])
    assert ped.contains(pts).tolist() == [True, True, False]
    assert cyc.contains(pts).tolist() == [True, False, False]
    assert ped.edge_distance(pts[1:2])[0] == pytest.approx(2.0, abs=0.05)
    assert ped.off_area(pts[None]).tolist() == [True]


@pytest.mark.parametrize("name", ["pedestrian", "cyclist"])
def test_snapshot_touches_the_target_inside_the_class_area(name: str) -> None:
    scene = synthetic.four_way_junction()
    low = resample(scene, 2.0)
    drivable = DrivableArea.from_road_map(scene.road_map)
    cls = VRU_CLASSES[name]
    area = ClassArea.build(cls, scene.road_map, drivable)
    req = PlacementRequest(low, scene.sdc_index, np.random.default_rng(3), drivable, "last", seed=3)
    snap = vru_snapshot(req, cls, area, use_prior=False, init_method="random")
    a, t = snap.adversary, snap.target
    assert snap.adversary_class == name and (a.length, a.width) == (cls.length, cls.width)
    gap = box_signed_distance(make_boxes(a.x, a.y, a.yaw, a.length, a.width), make_boxes(t.x, t.y, t.yaw, t.length,
                                                                                         t.width))
    assert abs(float(gap)) < 0.05  # in contact
    assert area.contains(np.array([[a.x, a.y]]))[0]
    assert cls.walk_min <= a.speed <= cls.fast_max
    plans, samples, info = vru_rollout(RolloutRequest(low, scene.sdc_index, snap, drivable, samples=200, variants=3,
                                                      seed=3), cls, area)
    assert plans and len(plans) <= 3 and samples is not None
    for p in plans:
        assert p.vclass == cls.vclass and p.t_col == pytest.approx(snap.time)
        assert (p.x[-1], p.y[-1]) == (a.x, a.y)
        assert plan_within_limits(p, cls)
        assert not area.off_area(np.stack([p.x, p.y], -1)[None])[0]
        assert plan_kinematics(p).speed.max() <= cls.fast_max + 0.05


@pytest.mark.parametrize("adversary", ["pedestrian", "cyclist", "any"])
def test_generation_draws_the_class_asked_for(adversary: str) -> None:
    scene = synthetic.four_way_junction()
    drivable = DrivableArea.from_road_map(scene.road_map)
    gen = GenerationConfig(init="random", rollout="cv", samples=100, variants=2, adversary=adversary)
    planned = plan_scenarios(scene, scene.sdc_index, 0, gen, drivable, DrawMemo.of(scene))[0]
    wanted = {"pedestrian": {"pedestrian"}, "cyclist": {"cyclist"}, "any": {"vehicle", "pedestrian", "cyclist"}}
    assert planned.snapshot.adversary_class in wanted[adversary]
    vclass = {"vehicle": "passenger", "pedestrian": "pedestrian", "cyclist": "bicycle"}[
        planned.snapshot.adversary_class]
    assert planned.plans and all(p.vclass == vclass for p in planned.plans)
    if vclass != "passenger":
        assert all(p.road is None for p in planned.plans)  # a missed VRU walks / rides straight on, no lane


def test_any_takes_the_classes_in_the_shares_they_travel_near_the_target() -> None:
    from coster_sumo.method.vru.methods import ANY_CLASSES, ANY_FLOOR, class_shares

    cars_only = synthetic.four_way_junction()
    shares = dict(zip(ANY_CLASSES, class_shares(cars_only, cars_only.sdc_index), strict=True))
    assert shares == pytest.approx({"vehicle": 1.0 - 2 * ANY_FLOOR, "cyclist": ANY_FLOOR, "pedestrian": ANY_FLOOR})
    scene = synthetic.with_vulnerable_road_users(cars_only)  # two walkers and a rider beside the SDC's path
    shares = dict(zip(ANY_CLASSES, class_shares(scene, scene.sdc_index), strict=True))
    import shapely

    tr = scene.tracks
    me = scene.sdc_index
    path = shapely.LineString(np.stack([tr.x[me, tr.valid[me]], tr.y[me, tr.valid[me]]], -1))
    kind = {2: "pedestrian", 3: "cyclist"}
    steps = dict.fromkeys(ANY_CLASSES, 0)
    for a in range(tr.num_agents):
        for k in np.flatnonzero(tr.valid[a]) if a != me else ():
            if path.distance(shapely.Point(tr.x[a, k], tr.y[a, k])) <= 30.0:
                steps[kind.get(int(tr.object_type[a]), "vehicle")] += 1
    total = sum(steps.values())
    assert steps["pedestrian"] > 0 and steps["cyclist"] > 0
    assert shares == pytest.approx({c: ANY_FLOOR + (1 - 3 * ANY_FLOOR) * steps[c] / total for c in ANY_CLASSES})
    assert sum(shares.values()) == pytest.approx(1.0)
    drivable = DrivableArea.from_road_map(scene.road_map)
    gen = GenerationConfig(init="random", rollout="cv", samples=100, variants=1, adversary="any")
    seen = [plan_scenarios(scene, scene.sdc_index, seed, gen, drivable, DrawMemo.of(scene))[0].snapshot.adversary_class
            for seed in range(10)]
    assert set(seen) == {"vehicle", "pedestrian", "cyclist"}, seen


def test_eval_parts_of_a_vru_adversary_are_keyed_apart_and_vehicle_keys_unchanged() -> None:
    from coster_sumo.batch.evaluate import part_key

    assert part_key("s", "COSTER", 5, "abcdef0123") == "s__COSTER__k5__wabcdef01"
    assert part_key("s", "COSTER", 5, "abcdef0123", "cyclist") == "s__COSTER__k5__wabcdef01__cyclist"


def test_defect_rate_per_class_splits_the_rows() -> None:
    from coster_sumo.batch.by_class import class_table, defects_by_class
    from coster_sumo.batch.store import ResultRow

    def row(i: int, cls: str | None, hit: bool) -> ResultRow:
        return ResultRow(run_key=f"r{i}", scene_key="s", variant=i, planner="p", status="ok", collision=hit,
                         adversary_contact=hit, avoidable=True, contact_in_horizon=hit, adversary_class=cls,
                         target_off_road=False, adversary_off_road=False, route_completed=not hit)

    rows = [row(0, "pedestrian", True), row(1, "pedestrian", False), row(2, None, True), row(3, "cyclist", False)]
    per = defects_by_class(rows, ["p"])["p"]
    assert sorted(per) == ["cyclist", "pedestrian", "vehicle"]  # a row without a class is a vehicle's
    assert per["pedestrian"]["defect_rate"]["k"] == 1 and per["pedestrian"]["defect_rate"]["n"] == 2
    assert per["cyclist"]["defect_rate"]["k"] == 0 and per["vehicle"]["defect_rate"]["k"] == 1
    head, table = class_table({"p": per})
    assert [r[1] for r in table] == ["cyclist", "pedestrian", "vehicle"] and table[1][3].startswith("50.0 %")
