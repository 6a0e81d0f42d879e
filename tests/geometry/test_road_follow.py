"""An adversary that missed its contact drives on along its lane (coster_sumo.geometry.road_follow), and the
search and the SUMO pass sample the same continuation (AdversaryPlan.sample)."""

from __future__ import annotations

import numpy as np

from coster_sumo.core.plan import HORIZON_AFTER_TCOL_S, AdversaryPlan
from coster_sumo.data import synthetic
from coster_sumo.geometry.boxes import project_points
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.geometry.road_follow import follow_road

ORIGIN = (1234.567, -9876.543)  # synthetic.merge's default


def _ramp_plan(before_merge_m: float, speed: float = 12.0) -> AdversaryPlan:
    """An adversary on the 45-degree on-ramp of synthetic.merge, ``before_merge_m`` before the
    merge point at t_col = 5 s, at constant ``speed``."""
    mid = np.array([ORIGIN[0] + 125.0, ORIGIN[1]])
    yaw = np.pi / 4
    d = np.array([np.cos(yaw), np.sin(yaw)])
    times = np.arange(0.0, 5.01, 0.5)
    back = speed * (5.0 - times) + before_merge_m
    pts = mid[None] - back[:, None] * d
    return AdversaryPlan(times=times, x=pts[:, 0], y=pts[:, 1], yaw=np.full(len(times), yaw), final_speed=speed,
                         length=4.5, width=1.9)


def test_a_missed_adversary_on_a_ramp_follows_the_road_where_constant_velocity_leaves_it():
    scene = synthetic.merge()
    drivable = DrivableArea.from_road_map(scene.road_map)
    plan = _ramp_plan(8.0)
    on_road = follow_road(plan, scene.road_map)
    assert on_road.road is not None
    t = plan.t_col + np.arange(0.1, HORIZON_AFTER_TCOL_S + 5.0, 0.1)
    for p, stays in ((on_road, True), (plan, False)):
        x, y, yaw, v = p.sample(t)
        off = drivable.off_road(x, y, yaw, np.asarray(p.length), np.asarray(p.width))
        assert (not off.any()) is stays
        assert np.allclose(v, plan.final_speed)
    # it starts where the plan ends, with the plan's heading, and ends on the main road's centreline
    x, y, yaw, _ = on_road.sample(np.array([plan.t_col, plan.t_col + 0.1]))
    assert np.hypot(x[0] - plan.x[-1], y[0] - plan.y[-1]) < 1e-6
    assert abs(yaw[1] - plan.yaw[-1]) < np.radians(8.0)
    x, y, _, _ = on_road.sample(np.array([plan.t_col + HORIZON_AFTER_TCOL_S + 3.0]))
    main = scene.road_map.lanes.centerline[1]  # main_out
    _, lateral, _ = project_points(np.array([x[0], y[0]]), main)
    assert abs(float(lateral)) < 0.05
    # both the search and a SUMO pass read the plan from its dict (batches): the continuation survives
    again = AdversaryPlan.from_dict(on_road.to_dict())
    assert np.allclose(np.stack(again.sample(t)), np.stack(on_road.sample(t)), atol=1e-2)


def test_an_adversary_off_every_lane_keeps_the_constant_velocity_run_on():
    scene = synthetic.merge()
    plan = _ramp_plan(8.0)
    far = AdversaryPlan(times=plan.times, x=plan.x + 500.0, y=plan.y + 500.0, yaw=plan.yaw,
                        final_speed=plan.final_speed, length=plan.length, width=plan.width)
    assert follow_road(far, scene.road_map).road is None


def test_an_adversary_at_its_lane_s_very_end_goes_on_along_the_successor():
    # t_col exactly where the on-ramp's centreline ends (a real held-out fkk_in clip raised IndexError)
    scene = synthetic.merge()
    ramp_end = scene.road_map.lanes.centerline[2][-1]
    plan = _ramp_plan(0.0)
    plan = AdversaryPlan(times=plan.times, x=plan.x + (ramp_end[0] - plan.x[-1]), y=plan.y + (ramp_end[1] - plan.y[-1]),
                         yaw=plan.yaw, final_speed=plan.final_speed, length=plan.length, width=plan.width)
    on_road = follow_road(plan, scene.road_map)
    assert on_road.road is not None
    x, y, _, _ = on_road.sample(np.array([plan.t_col + HORIZON_AFTER_TCOL_S]))
    _, lateral, _ = project_points(np.array([x[0], y[0]]), scene.road_map.lanes.centerline[1])
    assert abs(float(lateral)) < 0.5
