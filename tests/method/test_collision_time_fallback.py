"""When the best collision time gives no usable plan, the next best one (2 s away) is tried."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from coster_sumo.core.spec import GenerationConfig
from coster_sumo.data.synthetic import two_lane_road
from coster_sumo.errors import NoSnapshot
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.method import snapshot as placement
from coster_sumo.method.collision_time import COLLISION_TIMES, SNAPSHOT_SEPARATION_STEPS
from coster_sumo.method.generation import plan_scenario
from coster_sumo.method.snapshot import ATTEMPTS_PER_TIME, SNAPSHOT_INITS
from coster_sumo.rollout.methods import ROLLOUTS

GEN = GenerationConfig(init="random", rollout="cv", collision_time="last")


@pytest.fixture(scope="module")
def road():
    scene = two_lane_road()
    return scene, scene.sdc_index, DrivableArea.from_road_map(scene.road_map)


def _record_places(monkeypatch, fail_at: set[int] | None = None):
    """Wrap the random init: record every (t_col, strict) drawn; fail at the steps of ``fail_at``."""
    drawn: list[tuple[int, bool]] = []
    base = SNAPSHOT_INITS["random"]

    def place(request):
        snap = base.place(request)
        drawn.append((snap.t_index, request.strict))
        if fail_at is not None and snap.t_index in fail_at:
            raise NoSnapshot("test: no placement here", t_index=snap.t_index)
        return snap

    monkeypatch.setitem(SNAPSHOT_INITS, "random", dataclasses.replace(base, place=place))
    return drawn


def test_a_collision_time_without_placement_gives_way_to_the_next_best(road, monkeypatch):
    scene, target, drivable = road
    first = plan_scenario(scene, target, 0, GEN, drivable)  # "last": the last step of the window
    drawn = _record_places(monkeypatch, fail_at={first.snapshot.t_index})
    planned = plan_scenario(scene, target, 0, GEN, drivable)
    t0 = first.snapshot.t_index
    assert planned.snapshot.t_index <= t0 - SNAPSHOT_SEPARATION_STEPS  # the next "last" step, 2 s earlier
    given_up = planned.info["collision_times_given_up"]  # (a time may also fail by chance: random init)
    assert f"t_col {first.snapshot.time:.1f} s" in given_up
    assert f"t_col {planned.snapshot.time:.1f} s" not in given_up
    # one strict and one grazing draw at that time (nothing at all there), then the next time
    at_t0 = [i for i, (t, _) in enumerate(drawn) if t == t0]
    assert [drawn[i] for i in at_t0] == [(t0, True), (t0, False)] and at_t0[1] == at_t0[0] + 1
    assert drawn[at_t0[1] + 1][0] != t0


def test_draws_whose_rollouts_all_hit_early_move_on_after_attempts_per_time(road, monkeypatch):
    scene, target, drivable = road
    drawn = _record_places(monkeypatch)
    calls = {"n": 0}
    cv = ROLLOUTS["cv"]

    def generate(request):  # the first ATTEMPTS_PER_TIME rollouts return nothing usable
        calls["n"] += 1
        plans, xy, info = cv.generate(request)
        return (plans if calls["n"] > ATTEMPTS_PER_TIME else []), xy, info

    monkeypatch.setitem(ROLLOUTS, "cv", dataclasses.replace(cv, generate=generate))
    planned = plan_scenario(scene, target, 0, GEN, drivable)
    times = [t for t, _ in drawn]
    assert len(set(times[:ATTEMPTS_PER_TIME])) == 1 and times[ATTEMPTS_PER_TIME] < times[0]
    assert [s for _, s in drawn[:ATTEMPTS_PER_TIME]] == [True] * placement.STRICT_PER_TIME + [False] * (
        ATTEMPTS_PER_TIME - placement.STRICT_PER_TIME)  # closing-in placements first, then grazing ones
    assert planned.info["attempt"] == ATTEMPTS_PER_TIME + 1 and planned.snapshot.t_index == times[-1]


def test_no_usable_time_at_all_names_each_one_tried(road, monkeypatch):
    scene, target, drivable = road
    window = np.arange(scene.num_steps)
    drawn = _record_places(monkeypatch, fail_at=set(window.tolist()))
    with pytest.raises(NoSnapshot, match=rf"no draw at {COLLISION_TIMES} collision times gave a plan "
                                         r"\(t_col [\d.]+ s: test: no placement here; t_col"):
        plan_scenario(scene, target, 0, GEN, drivable)
    times = sorted({t for t, _ in drawn})
    assert len(times) == COLLISION_TIMES and np.all(np.diff(times) >= SNAPSHOT_SEPARATION_STEPS)


def test_scenes_run_with_one_seed_draw_different_random_collision_times(road):
    """The generator's random choices depend on the scene too: one seed, different scenes, different draws."""
    scene, target, drivable = road
    gen = dataclasses.replace(GEN, collision_time="random")
    drawn = []
    for k in range(6):
        renamed = dataclasses.replace(scene, scenario_id=f"scene_{k}")
        first = plan_scenario(renamed, target, 0, gen, drivable)
        again = plan_scenario(renamed, target, 0, gen, drivable)
        assert first.snapshot.t_index == again.snapshot.t_index  # still reproducible per scene and seed
        drawn.append(first.snapshot.t_index)
    assert len(set(drawn)) > 1, drawn
