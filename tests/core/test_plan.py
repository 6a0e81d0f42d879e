from __future__ import annotations

import numpy as np
import pytest

from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.core.snapshot import AgentState


def _plan():
    # a left turn at about 8 m/s, knots every 0.5 s, ending in the snapshot state
    t = 10.0 + 0.5 * np.arange(7)
    ang = np.linspace(0.0, np.pi / 2, 7)
    r = 20.0
    knots = np.stack([r * np.sin(ang), r * (1 - np.cos(ang)), ang], axis=1)
    snap = AgentState(x=float(knots[-1, 0]), y=float(knots[-1, 1]), yaw=np.pi / 2, speed=8.0,
                      length=4.6, width=1.9)
    return AdversaryPlan.from_knots(t, knots, snap), knots


def test_plan_hits_knots_and_snapshot_exactly():
    plan, knots = _plan()
    x, y, yaw, speed = plan.sample(plan.times)
    np.testing.assert_allclose(x, knots[:, 0], atol=1e-9)
    np.testing.assert_allclose(y, knots[:, 1], atol=1e-9)
    np.testing.assert_allclose(yaw, knots[:, 2], atol=1e-9)
    assert speed[-1] == pytest.approx(8.0)


def test_plan_dense_sampling_is_smooth_and_continues_straight_after_t_col():
    plan, _ = _plan()
    t = np.arange(plan.t_start, plan.t_col + 1.0 + 1e-9, 0.1)
    x, y, yaw, speed = plan.sample(t)
    step = np.hypot(np.diff(x), np.diff(y))
    assert step.max() < 1.5  # < 15 m/s everywhere
    after = t > plan.t_col + 1e-9
    np.testing.assert_allclose(np.diff(x[after]), 0.0, atol=1e-9)
    np.testing.assert_allclose(np.diff(y[after]), 0.8, atol=1e-9)
    np.testing.assert_allclose(yaw[after], np.pi / 2)


def test_plan_json_round_trip(tmp_path):
    plan, _ = _plan()
    back = AdversaryPlan.load(plan.save(tmp_path / "p.json"))
    np.testing.assert_array_equal(back.x, plan.x)
    assert back.final_speed == plan.final_speed


def test_replaced_keeps_the_splines_only_while_the_knots_stay():
    plan, _ = _plan()
    t = np.arange(plan.t_start, plan.t_col + 1.0, 0.1)
    before = plan.sample(t)
    renamed = plan.replaced(vehicle_id="adversary7", road=np.array([[20.0, 20.0], [20.0, 60.0]]))
    assert renamed.vehicle_id == "adversary7" and renamed._splines is plan._splines  # built once
    inside = t <= plan.t_col
    for a, b in zip(before, renamed.sample(t), strict=True):
        np.testing.assert_array_equal(a[inside], b[inside])  # the road changes only what comes after t_col
    moved = plan.replaced(x=plan.x + 1.0)
    assert moved._splines is not plan._splines
    np.testing.assert_allclose(moved.sample(t)[0][inside], before[0][inside] + 1.0, atol=1e-9)
    fresh = AdversaryPlan.from_knots(plan.times, np.stack([plan.x, plan.y, plan.yaw], 1),
                                     AgentState(x=float(plan.x[-1]), y=float(plan.y[-1]), yaw=float(plan.yaw[-1]),
                                                speed=plan.final_speed, length=4.6, width=1.9))
    at_tcol = np.array([plan.t_col])
    assert fresh.sample(at_tcol)[3][0] == pytest.approx(8.0)  # the splines built, clamped to 8 m/s
    assert fresh.replaced(final_speed=3.0).sample(at_tcol)[3][0] == pytest.approx(3.0)  # rebuilt, not carried
