from __future__ import annotations

import numpy as np
import pytest

from coster_sumo import synthetic
from coster_sumo.drivable import DrivableArea
from coster_sumo.sim.events import EventDetector, VehicleStates


def _states(rows):
    ids, x, y, yaw, v = zip(*rows, strict=True)
    n = len(ids)
    return VehicleStates(ids=np.asarray(ids), x=np.asarray(x, float), y=np.asarray(y, float),
                         yaw=np.asarray(yaw, float), speed=np.asarray(v, float),
                         length=np.full(n, 4.0), width=np.full(n, 2.0),
                         vclass=np.full(n, "passenger"), type_id=np.full(n, "car"))


def test_t_bone_is_one_event_with_side_impact_angle():
    det = EventDetector("ego", "adv", drivable=None)
    # adversary coming from the ego's left, heading south, overlapping ego's left side
    far = _states([("ego", 0, 0, 0, 10), ("adv", 0, 5, -np.pi / 2, 8), ("x", 50, 0, 0, 5)])
    near = _states([("ego", 0, 0, 0, 10), ("adv", 0, 2.5, -np.pi / 2, 8), ("x", 50, 0, 0, 5)])
    assert det.check(0.0, far) == []
    ev = det.check(0.1, near)
    assert len(ev) == 1
    e = ev[0]
    assert e.kind == "collision" and e.vehicles == ["ego", "adv"]
    assert e.impact_angle == pytest.approx(90.0)
    assert e.relative_speed == pytest.approx(np.hypot(10, 8))
    # still overlapping: no new event; separated then overlapping again: a new one
    assert det.check(0.2, near) == []
    det.check(0.3, far)
    assert len(det.check(0.4, near)) == 1


def test_collision_with_bystander_is_logged():
    det = EventDetector("ego", "adv", drivable=None)
    ev = det.check(0.0, _states([("ego", 0, 0, 0, 1), ("adv", 30, 0, 0, 8), ("x", 33, 0, np.pi, 5)]))
    assert [e.vehicles for e in ev] == [["adv", "x"]]
    assert ev[0].impact_angle == pytest.approx(0.0)


def test_off_road_and_sumo_collision_events():
    scene = synthetic.two_lane_road()
    x0, y0 = scene.road_map.lanes.centerline[0][20]
    det = EventDetector("ego", "adv", DrivableArea.from_road_map(scene.road_map))
    s = _states([("ego", x0, y0, 0, 10), ("adv", x0 + 20, y0 - 8, 0, 5)])
    ev = det.check(1.0, s, sumo_collisions=[{"collider": "adv", "victim": "ego", "type": "collision"}])
    kinds = sorted(e.kind for e in ev)
    assert kinds == ["off_road", "sumo_collision"]
    assert det.first("off_road", "adv") is not None
    assert det.first("off_road", "ego") is None
