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
