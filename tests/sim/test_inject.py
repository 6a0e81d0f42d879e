"""One injection pass: the adversary becomes a wreck at its first contact, with or without detection."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from coster_sumo.core.spec import GenerationConfig, ScenarioSpec
from coster_sumo.formats.targets import choose_target
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.method.generation import plan_scenario
from coster_sumo.pipeline.scenario import nominal_scene
from coster_sumo.sim.inject import PassSettings, run_injection
from coster_sumo.sim.inject import nominal_replay as replay_planner_for
from coster_sumo.sim.planners import make_planner

REPO = Path(__file__).resolve().parents[2]
CFG = REPO / "networks/intersection/intersection.sumocfg"
pytestmark = pytest.mark.sumo


def _planned(tmp_path: Path, end: float, seed: int):
    """The intersection's nominal scene, its target, drivable area and a constant-velocity plan."""
    spec = ScenarioSpec(CFG, seed=seed, end=end)
    scene, _ = nominal_scene(spec)
    target = choose_target(scene, None, CFG)
    drivable = DrivableArea.from_road_map(scene.road_map)
    gen = GenerationConfig(init="random", rollout="cv")
    return scene, target, drivable, plan_scenario(scene, target, seed, gen, drivable).plans[0]


def test_pass_without_detection_told_the_contact_time_plays_out_the_same(tmp_path):
    scene, target, drivable, plan = _planned(tmp_path, 50, seed=1)
    tid = str(scene.tracks.ids[target])

    def run(detect: bool, freeze_at: float | None = None):
        return run_injection(CFG, tid, plan, make_planner("sumo"),
                             PassSettings(end=50.0, drivable=drivable, detect_events=detect, freeze_at=freeze_at),
                             seed=1, workdir=tmp_path)

    detected = run(True)
    first = next(e for e in detected.events if e.kind == "collision" and plan.vehicle_id in e.vehicles)
    tr = detected.scene.tracks
    a = tr.index_of(plan.vehicle_id)
    after = detected.scene.timestamps > first.time + 1e-6
    assert after.sum() > 10 and tr.valid[a, after].all()
    assert np.ptp(tr.x[a, after]) < 1e-6 and np.ptp(tr.y[a, after]) < 1e-6  # a wreck: it stays put
    assert np.allclose(tr.x[a, after], first.positions[first.vehicles.index(plan.vehicle_id)][0], atol=1e-6)

    blind = run(False, freeze_at=first.time)
    assert blind.events == []
    assert list(blind.scene.tracks.ids) == list(tr.ids)
    for field in ("x", "y", "heading"):
        assert np.allclose(getattr(blind.scene.tracks, field), getattr(tr, field), atol=1e-6), field
    free = run(False)  # not told: it drives on through the contact
    assert not np.allclose(free.scene.tracks.x[free.scene.tracks.index_of(plan.vehicle_id)][after],
                           tr.x[a, after], atol=1e-3)


def test_traci_pass_finds_the_same_events_as_libsumo(tmp_path):
    scene, target, drivable, plan = _planned(tmp_path, 45, seed=3)
    runs = [run_injection(CFG, str(scene.tracks.ids[target]), plan, replay_planner_for(scene, target),
                          PassSettings(end=45.0, drivable=drivable), seed=3, traci=traci, workdir=tmp_path)
            for traci in (False, True)]
    events = [[(e.kind, round(e.time, 3), e.vehicles) for e in r.events] for r in runs]
    assert runs[0].contact is not None and events[0]
    assert events[0] == events[1]


def test_a_pass_whose_adversary_hits_another_vehicle_ends_after_t_col(tmp_path):
    """The adversary touches a vehicle that is not the pass's target: it stays there, and the pass
    ends ``post_contact_s`` after t_col instead of simulating to the end with a wreck on the road."""
    scene, target, drivable, plan = _planned(tmp_path, 50, seed=1)
    hit = str(scene.tracks.ids[target])
    tr = scene.tracks
    k0, k1 = (int(np.argmin(np.abs(scene.timestamps - t))) for t in (plan.t_start, plan.t_col + 3.0))
    others = [i for i in range(len(tr.ids)) if i != target and tr.valid[i, k0:k1 + 1].all()]
    assert others, "no other vehicle lives from the plan's start to 3 s after t_col"
    bystander = str(tr.ids[others[0]])
    res = run_injection(CFG, bystander, plan, make_planner("sumo"),
                        PassSettings(end=50.0, drivable=drivable, post_contact_s=2.0), seed=1, workdir=tmp_path)
    first = next(e for e in res.events if e.kind == "collision" and plan.vehicle_id in e.vehicles)
    assert hit in first.vehicles and res.contact is None
    last = float(res.scene.timestamps[-1])
    assert abs(last - (max(first.time, plan.t_col) + 2.0)) <= 0.1 + 1e-6, (last, first.time, plan.t_col)
