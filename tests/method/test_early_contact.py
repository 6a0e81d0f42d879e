"""Which plans touch the target too early to be kept (method.filters.early_contact), on jittered log times."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.data import synthetic
from coster_sumo.method.filters import bystander_contact, early_contact

K_COL = 60  # t_col's step in the scene


def _scene_and_plan(gaps: dict[int, float], seed: int):
    """A parked adversary beside the target, which comes closer sideways; ``gaps`` [m] by steps before t_col."""
    scene = synthetic.two_lane_road()
    rng = np.random.default_rng(seed)
    times = scene.timestamps + rng.uniform(-2e-5, 2e-5, scene.num_steps)  # WOMD-like jitter
    tr = scene.tracks
    x0, y0, w_t = float(tr.x[0, 0]), float(tr.y[0, 0]), float(tr.width[0, 0])
    w_a = 2.0
    before = K_COL - np.arange(scene.num_steps)  # steps before t_col
    gap = np.array([gaps.get(int(b), 1.0 + 0.1 * abs(int(b))) for b in before])
    y_adv = y0 + 0.5 * (w_t + w_a)
    ys, xs, hs = tr.y.copy(), tr.x.copy(), tr.heading.copy()
    ys[0], xs[0], hs[0] = y0 - gap, x0, 0.0
    scene = dataclasses.replace(scene, timestamps=times, tracks=dataclasses.replace(tr, x=xs, y=ys, heading=hs))
    t_col = float(times[K_COL])
    knots = t_col - 0.5 * np.arange(10, -1, -1)
    n = len(knots)
    plan = AdversaryPlan(times=knots, x=np.full(n, x0), y=np.full(n, y_adv), yaw=np.zeros(n), final_speed=0.0,
                         length=float(tr.length[0, 0]), width=w_a)
    return scene, plan, times


@pytest.mark.parametrize("seed", range(6))
def test_touching_one_step_before_t_col_is_kept_two_steps_is_not(seed):
    scene, plan, _ = _scene_and_plan({0: 0.0, 1: 0.03, 2: 0.3}, seed)
    assert early_contact(plan, scene, 0) is None  # within one step (0.1 s) of t_col: allowed
    scene, plan, times = _scene_and_plan({0: 0.0, 1: 0.0, 2: 0.03}, seed)
    assert early_contact(plan, scene, 0) == pytest.approx(times[K_COL - 2])  # two steps early: dropped


def _plan_on(scene, agent: int, dy: float, every: int = 5, k_col: int = K_COL) -> AdversaryPlan:
    """A plan that follows ``agent``'s logged box (shifted ``dy`` m sideways) for 5 s up to step
    ``k_col``, with a knot every ``every`` steps of the 10 Hz scene."""
    tr, times = scene.tracks, scene.timestamps
    ks = k_col - every * np.arange(50 // every, -1, -1)
    return AdversaryPlan(times=times[ks], x=tr.x[agent, ks], y=tr.y[agent, ks] + dy, yaw=tr.heading[agent, ks],
                         final_speed=0.0, length=4.5, width=2.0)


def test_a_plan_through_another_vehicle_names_it_and_the_first_time():
    scene = synthetic.two_lane_road()
    left2 = list(scene.tracks.ids).index("left2")
    plan = _plan_on(scene, left2, dy=0.0)
    hit = bystander_contact(plan, scene, target=0)
    assert hit is not None
    assert hit == (pytest.approx(float(plan.times[0])), "left2")
    assert early_contact(plan, scene, 0) is None  # the target itself is never touched


def test_a_plan_clear_of_everyone_or_touching_only_at_t_col_is_kept():
    scene = synthetic.two_lane_road()
    left2 = list(scene.tracks.ids).index("left2")
    assert bystander_contact(_plan_on(scene, left2, dy=20.0), scene, target=0) is None
    # beside left2 (1 m of gap) until t_col, then on it: the last step is not checked, as for the target
    plan = _plan_on(scene, left2, dy=3.0, every=1)
    plan = dataclasses.replace(plan, y=np.where(np.arange(len(plan.y)) == len(plan.y) - 1,
                                                plan.y - 3.0, plan.y))
    assert bystander_contact(plan, scene, target=0) is None
    # the same vehicle as target: not a bystander
    assert bystander_contact(_plan_on(scene, left2, dy=0.0), scene, target=left2) is None
