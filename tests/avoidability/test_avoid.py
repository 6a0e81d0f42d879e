"""Avoidability labels on hand-built scenes: what no escape can avoid, and what braking or a lane
change does avoid (coster_sumo.avoidability.search)."""

from __future__ import annotations

import numpy as np
import pytest

from coster_sumo.avoidability import evasion, search
from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.core.scene import Scene, SignalStates
from coster_sumo.data import synthetic
from coster_sumo.geometry.boxes import box_signed_distance, make_boxes
from coster_sumo.geometry.drivable import DrivableArea

STEPS = 140  # 14 s at 10 Hz
T_COL = 8.0  # [s]
LENGTH, WIDTH = 4.5, 1.9  # [m] every vehicle (synthetic._tracks)


def straight_road(lanes: int, agents: list[tuple[str, int, float, float]], end_x: float = 600.0) -> Scene:
    """A one-way road along +x to ``end_x`` [m] with ``lanes`` lanes (lane 0 on the right) and vehicles
    at constant speed: (id, lane, x at t=0 [m], speed [m/s]); the first one is the target."""
    b = synthetic._MapBuilder()
    ids = [b.lane(synthetic._line((-100.0, k * synthetic.LANE_WIDTH), (end_x, k * synthetic.LANE_WIDTH)))
           for k in range(lanes)]
    for right, left in zip(ids, ids[1:], strict=False):
        b.neighbours(left, right)
    road = b.build()
    t = np.arange(STEPS) * synthetic.DT
    tracks = synthetic._tracks([(name, x0 + v * t, np.full(STEPS, lane * synthetic.LANE_WIDTH), np.zeros(STEPS), v)
                                for name, lane, x0, v in agents], steps=STEPS)
    return Scene(scenario_id="straight", timestamps=np.round(t, 6), tracks=tracks, road_map=road,
                 signals=SignalStates.empty(STEPS), sdc_index=0, source="synthetic").validate()


def straight_plan(x_col: float, y_col: float, yaw: float, speed: float, horizon_s: float = 5.0) -> AdversaryPlan:
    """An adversary at constant ``speed`` along ``yaw`` reaching (x_col, y_col) at T_COL (2 Hz knots)."""
    knots = T_COL - 0.5 * np.arange(int(horizon_s / 0.5), -1, -1)
    back = speed * (T_COL - knots)
    return AdversaryPlan(times=knots, x=x_col - back * np.cos(yaw), y=y_col - back * np.sin(yaw),
                         yaw=np.full(len(knots), yaw), final_speed=speed, length=LENGTH, width=WIDTH)


def _assess(scene: Scene, plan: AdversaryPlan) -> evasion.Avoidability:
    return search.assess(scene, 0, plan, DrivableArea.from_road_map(scene.road_map))


def test_an_adversary_from_behind_faster_than_any_acceleration_is_unavoidable_on_one_lane():
    scene = straight_road(1, [("ego", 0, 0.0, 10.0)])
    x_t = 10.0 * T_COL
    plan = straight_plan(x_t - LENGTH, 0.0, 0.0, 30.0)  # its front touches the target's back at t_col
    res = _assess(scene, plan)
    assert res.contact_kind == "rear_end_by_adversary"
    assert not res.avoidable
    assert not any(res.avoidable_at(r) for r in search.REACTION_TIMES_S)
    assert res.escape is None


def test_a_crossing_vehicle_appearing_inside_the_stopping_distance_is_unavoidable():
    scene = straight_road(1, [("ego", 0, 0.0, 15.0)])
    x_t = 15.0 * T_COL
    # it crosses from the right at 10 m/s and appears 1.0 s before t_col, touching the target's
    # front right corner: 15 m from the target's front when it appears, inside any stopping distance
    plan = straight_plan(x_t + 0.5 * LENGTH + 0.5 * WIDTH - 0.2, -(0.5 * WIDTH + 0.5 * LENGTH), np.pi / 2, 10.0,
                         horizon_s=1.0)
    res = _assess(scene, plan)
    assert res.contact_kind == "crossing"
    assert res.t_threat == pytest.approx(plan.t_start)
    assert not res.avoidable_at(0.5)


def test_a_stopped_vehicle_ahead_is_avoidable_by_braking():
    scene = straight_road(1, [("ego", 0, 0.0, 15.0)])
    plan = straight_plan(15.0 * T_COL + LENGTH, 0.0, 0.0, 0.0)  # stands 5 s in the target's lane
    res = _assess(scene, plan)
    assert res.contact_kind == "into_vehicle_ahead"
    assert res.avoidable and res.avoidable_at(0.5)
    e = res.escape
    assert e is not None and e.manoeuvre.longitudinal == "brake" and e.manoeuvre.lateral_m == 0.0
    assert e.t_act >= res.t_threat + evasion.DEFAULT_REACTION_S - 1e-6
    assert e.clearance_m >= search.MIN_CLEARANCE_M
    assert e.peak_decel <= evasion.CLASS_LIMITS["passenger"].emergency_decel + 1e-6
    assert res.last_moment_s is not None and res.last_moment_s > 0.5
    # the escape really keeps clear of the adversary's boxes, step by step
    ax, ay, ayaw, _ = plan.sample(e.times)
    gap = box_signed_distance(make_boxes(e.x, e.y, e.yaw, LENGTH, WIDTH), make_boxes(ax, ay, ayaw, LENGTH, WIDTH))
    assert gap.min() >= search.MIN_CLEARANCE_M - 1e-6


def test_an_adversary_from_behind_is_avoidable_by_a_lane_change_when_the_next_lane_is_free():
    scene = straight_road(2, [("ego", 0, 0.0, 10.0)])
    plan = straight_plan(10.0 * T_COL - LENGTH, 0.0, 0.0, 25.0)
    res = _assess(scene, plan)
    assert res.contact_kind == "rear_end_by_adversary"
    assert res.avoidable
    e = res.escape
    assert e is not None and e.manoeuvre.lateral_m > 0  # to the left: the only other lane
    assert e.peak_lateral_accel <= evasion.CLASS_LIMITS["passenger"].emergency_decel + 1e-6


def test_the_same_lane_change_is_blocked_by_a_vehicle_in_the_next_lane():
    # a car beside the target for the whole time closes the left lane
    scene = straight_road(2, [("ego", 0, 0.0, 10.0), ("beside", 1, 0.0, 10.0)])
    plan = straight_plan(10.0 * T_COL - LENGTH, 0.0, 0.0, 25.0)
    res = _assess(scene, plan)
    assert not res.avoidable


def test_braking_into_a_follower_does_not_count_as_an_escape():
    # stopped car ahead, and a car close behind that keeps its speed: braking hard is hit from behind
    scene = straight_road(1, [("ego", 0, 0.0, 15.0), ("follower", 0, -LENGTH - 3.0, 15.0)])
    plan = straight_plan(15.0 * T_COL + LENGTH, 0.0, 0.0, 0.0)
    res = _assess(scene, plan)
    assert not res.avoidable


@pytest.mark.parametrize(("yaw", "offset", "kind"), [
    (np.pi, (LENGTH, 0.0), "head_on"),
    (np.pi / 2, (0.0, -3.0), "crossing"),
    (0.0, (0.0, WIDTH), "side_swipe"),
    (0.0, (LENGTH, 0.0), "into_vehicle_ahead"),
    (0.0, (-LENGTH, 0.0), "rear_end_by_adversary"),
])
def test_contact_kinds(yaw, offset, kind):
    target = evasion.Motion(0.0, 0.0, 0.0, 10.0, LENGTH, WIDTH)
    assert evasion.contact_kind(target, evasion.Motion(offset[0], offset[1], yaw, 5.0, LENGTH, WIDTH)) == kind


def test_braking_profiles_are_jerk_limited_and_stop_at_zero():
    v, a = evasion.speed_profiles(10.0, 0.0, np.array([-9.0, 2.6]), 60, v_cap=12.0)
    moving = v[0, 1:] > 0  # at a standstill the braking simply ends
    assert np.all(np.abs(np.diff(a[0]))[moving] <= evasion.JERK_MPS3 * evasion.DT_S + 1e-9)
    assert v[0].min() == 0.0 and v[0, -1] == 0.0 and a[0].min() >= -9.0 - 1e-9
    assert v[1].max() == pytest.approx(12.0)


def test_plans_of_one_time_grid_share_their_candidates_and_get_the_labels_they_get_alone(monkeypatch):
    # three adversaries appearing at 3 s with t_col 8 s (one grid): ahead, from behind, beside; the
    # road ends 150 m on, so speeding up leaves it when done early enough (road checks differ by moment)
    from coster_sumo.avoidability import candidates

    scene = straight_road(2, [("ego", 0, 0.0, 12.0)], end_x=150.0)
    plans = [straight_plan(12.0 * T_COL + LENGTH, 0.0, 0.0, 0.0), straight_plan(12.0 * T_COL - LENGTH, 0.0, 0.0, 25.0),
             straight_plan(12.0 * T_COL, WIDTH, 0.0, 11.0)]
    drivable = DrivableArea.from_road_map(scene.road_map)
    alone = [search.assess(scene, 0, p, drivable, reactive_others=True) for p in plans]
    built: list[int] = []
    rows = candidates.candidate_rows
    monkeypatch.setattr(candidates, "candidate_rows", lambda ctx, k: built.extend(k.tolist()) or rows(ctx, k))
    shared: dict = {}
    together = [search.assess(scene, 0, p, drivable, reactive_others=True, shared=shared) for p in plans[::-1]][::-1]
    assert len(shared) == 1 and len(built) == len(set(built))  # each moment's candidates built once
    # exact equality on any x86-64 CPU: a moment's candidates are elementwise numpy (ufuncs whose
    # SIMD loops treat a vector's tail with masked loads, the same algorithm for every element) and
    # gradients along each row's own time axis, so which other moments share the batch changes no bit
    for a, b in zip(alone, together, strict=True):
        assert a.summary() == b.summary()
        for ea, eb in zip([*a.escapes.values(), *a.blocked], [*b.escapes.values(), *b.blocked], strict=True):
            assert (ea is None) == (eb is None)
            if ea is not None:
                np.testing.assert_array_equal(np.stack([ea.x, ea.y, ea.yaw, ea.speed]),
                                              np.stack([eb.x, eb.y, eb.yaw, eb.speed]))
    assert {a.avoidable for a in alone} == {True, False}  # not one answer for all
    # the road checks the grid keeps (from every plan's search) are those of their own moments and
    # manoeuvres: asked again for every pair at once, they agree with a fresh context's
    (ctx,) = shared.values()
    ks = np.array(sorted(ctx.rows))
    fresh = candidates.SearchContext.build(scene, 0, plans[0].t_start, plans[0].t_col, drivable)
    kk, mm = (a.ravel() for a in np.meshgrid(np.arange(len(ks)), np.arange(len(ctx.man)), indexing="ij"))
    checks = []
    for c in (ctx, fresh):
        pos, yaw, _, after, *_ = c.rows_of(ks)
        checks.append(search._RoadCheck(c, ks, pos, yaw, after)(kk, mm))
    np.testing.assert_array_equal(checks[0], checks[1])
    by_moment = checks[1].reshape(len(ks), len(ctx.man))
    # some manoeuvre is on the road when done at one moment and off it at another
    assert ctx.road_known and (by_moment.any(0) & ~by_moment.all(0)).any()
