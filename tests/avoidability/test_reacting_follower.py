"""No unavoidable label on an untested escape: a target that brakes for a stopped vehicle with a
follower close behind is kinematically blocked (the follower, moving as in the nominal pass, drives
into it), but in SUMO the follower brakes too, so the label is avoidable (docs/method.md step 8)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from coster_sumo.avoidability import search
from coster_sumo.avoidability.labels import ProofSettings, label_line, label_plans, label_record, labels_moved
from coster_sumo.batch.nets import run_tool
from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.core.spec import ScenarioSpec
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.infra import sumo_install
from coster_sumo.pipeline.scenario import nominal_scene

pytestmark = pytest.mark.sumo
SPEED = 15.0  # [m/s] target and follower
GAP_S = 1.3  # [s] the follower's time gap behind the target


def _one_lane_road(tmp_path: Path) -> Path:
    """A straight one-lane road 800 m long; the target departs at 200 m, its follower GAP_S behind."""
    (tmp_path / "r.nod.xml").write_text('<nodes><node id="a" x="0" y="0"/><node id="b" x="800" y="0"/></nodes>\n')
    (tmp_path / "r.edg.xml").write_text('<edges><edge id="e" from="a" to="b" numLanes="1" speed="15"/></edges>\n')
    run_tool([sumo_install.binary("netconvert"), "--node-files", str(tmp_path / "r.nod.xml"), "--edge-files",
              str(tmp_path / "r.edg.xml"), "--output-file", str(tmp_path / "r.net.xml")], "netconvert")
    follower_pos = 200.0 - 5.0 - GAP_S * SPEED
    (tmp_path / "r.rou.xml").write_text(
        '<routes><vType id="car" length="5" minGap="2.5" maxSpeed="20" sigma="0"/>'
        '<route id="r" edges="e"/>'
        f'<vehicle id="ego" type="car" route="r" depart="0" departPos="200" departSpeed="{SPEED}"/>'
        f'<vehicle id="follower" type="car" route="r" depart="0" departPos="{follower_pos}" '
        f'departSpeed="{SPEED}"/></routes>\n')
    cfg = tmp_path / "r.sumocfg"
    cfg.write_text('<configuration><input><net-file value="r.net.xml"/><route-files value="r.rou.xml"/></input>'
                   '<time><begin value="0"/><end value="30"/></time></configuration>\n')
    return cfg


def test_a_braking_target_blocked_only_by_its_follower_is_avoidable(tmp_path):
    cfg = _one_lane_road(tmp_path)
    spec = ScenarioSpec(cfg, seed=1, end=30.0)
    scene, _ = nominal_scene(spec)
    tr = scene.tracks
    target = tr.index_of("ego")
    drivable = DrivableArea.from_road_map(scene.road_map)
    # a stopped car in the target's lane where the target would be at t_col = 12 s, there from 7 s
    k = int(np.argmin(np.abs(scene.timestamps - 12.0)))
    x_col = float(tr.x[target, k]) + 5.0
    y = float(tr.y[target, k])
    times = np.arange(7.0, 12.01, 0.5)
    plan = AdversaryPlan(times=times, x=np.full(len(times), x_col), y=np.full(len(times), y),
                         yaw=np.zeros(len(times)), final_speed=0.0, length=5.0, width=1.8)
    blind = search.assess(scene, target, plan, drivable)  # the follower as recorded, reacting to nothing
    assert not blind.avoidable and not blind.blocked
    [lab] = label_plans(spec, scene, target, [plan], ProofSettings(drivable))
    tried = [e for e in lab.blocked if e.proven is not None]
    assert tried and all(e.blocked_by == ("follower",) for e in tried)
    assert lab.avoidable and lab.escape is not None and lab.escape.proven
    assert lab.escape.blocked_by == ("follower",) and lab.flipped_by_reacting_traffic
    assert "follower" in label_line(lab)
    moved = labels_moved([label_record(lab)])
    assert moved["labels_flipped_by_reacting_traffic"] == {"count": 1, "share": 1.0}
    assert moved["blocked_escapes_cleared_in_sumo"] >= 1


def test_sumo_drives_an_adversary_that_missed_once_the_horizon_has_passed(tmp_path):
    """A slow adversary ahead of the target in its lane, never touched: it keeps to the lane at its
    speed up to the labels' horizon, then SUMO's driver takes it over (it speeds up to the road's
    limit, stays on the road, and the target's driver follows it without contact)."""
    from coster_sumo.core.plan import HORIZON_AFTER_TCOL_S
    from coster_sumo.geometry.road_follow import follow_road
    from coster_sumo.sim.inject import PassSettings, run_injection
    from coster_sumo.sim.planners import make_planner

    cfg = _one_lane_road(tmp_path)
    scene, _ = nominal_scene(ScenarioSpec(cfg, seed=1, end=30.0))
    tr = scene.tracks
    k = int(np.argmin(np.abs(scene.timestamps - 6.0)))
    x0, y = float(tr.x[tr.index_of("ego"), k]) + 60.0, float(tr.y[tr.index_of("ego"), k])
    times = np.arange(6.0, 10.01, 0.5)  # t_col 10 s, 60-100 m ahead of the target at 8 m/s
    plan = follow_road(AdversaryPlan(times=times, x=x0 + 8.0 * (times - 6.0), y=np.full(len(times), y),
                                     yaw=np.zeros(len(times)), final_speed=8.0, length=5.0, width=1.8),
                       scene.road_map)
    assert plan.road is not None
    res = run_injection(cfg, "ego", plan, make_planner("sumo"),
                        PassSettings(end=22.0, drivable=DrivableArea.from_road_map(scene.road_map)), seed=1,
                        workdir=tmp_path)
    assert res.contact is None
    assert not [e for e in res.events if plan.vehicle_id in e.vehicles]  # no contact, never off the road
    ts, a = res.scene.timestamps, res.scene.tracks.index_of(plan.vehicle_id)
    speed = np.hypot(res.scene.tracks.vx[a], res.scene.tracks.vy[a])
    horizon = (ts > plan.t_col + 0.05) & (ts <= plan.t_col + HORIZON_AFTER_TCOL_S)
    assert np.allclose(speed[horizon], 8.0, atol=0.05)  # its plan: the lane at its speed
    late = res.scene.tracks.valid[a] & (ts >= plan.t_col + HORIZON_AFTER_TCOL_S + 5.0)
    assert late.any() and speed[late].max() > 12.0  # SUMO's driver: up to the 15 m/s limit
