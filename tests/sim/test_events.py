from __future__ import annotations

import numpy as np
import pytest

from coster_sumo.data import synthetic
from coster_sumo.geometry.drivable import DrivableArea
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


def test_sat_gap_bounds_the_exact_distance_and_agrees_on_overlap():
    from coster_sumo.geometry.boxes import box_signed_distance, make_boxes
    from coster_sumo.sim.events import _sat_gap

    rng = np.random.default_rng(3)
    n = 2000
    a = make_boxes(0.0, 0.0, rng.uniform(-np.pi, np.pi, n), rng.uniform(3, 6, n), rng.uniform(1.5, 2.5, n))
    b = make_boxes(rng.uniform(-7, 7, n), rng.uniform(-7, 7, n), rng.uniform(-np.pi, np.pi, n),
                   rng.uniform(3, 12, n), rng.uniform(1.5, 2.6, n))
    exact = box_signed_distance(a, b)
    def box(row: np.ndarray) -> tuple[float, float, float, float, float]:
        x, y, yaw, length, width = map(float, row)
        return x, y, yaw, length, width

    gap = np.array([_sat_gap(box(a[k]), box(b[k])) for k in range(n)])
    assert ((gap <= 0) == (exact <= 0)).all()  # SAT: overlap exactly when no axis separates
    sep = exact > 0
    assert (gap[sep] <= exact[sep] + 1e-9).all()  # an axis gap never exceeds the Euclidean gap
    assert np.allclose(gap[~sep], exact[~sep])  # penetration depth = the smallest overlap


def test_batched_off_road_matches_per_step():
    scene = synthetic.two_lane_road()
    drivable = DrivableArea.from_road_map(scene.road_map)
    x0, y0 = scene.road_map.lanes.centerline[0][20]
    lateral = [0, 0, -8, -8, 0, -8, -8, -8, 0, 0]  # the adversary leaves the road twice
    steps = [_states([("ego", x0 + k, y0, 0, 10), ("adv", x0 + 20 + k, y0 + dy, 0, 5)])
             for k, dy in enumerate(lateral)]
    now = EventDetector("ego", "adv", drivable)
    batched = EventDetector("ego", "adv", drivable, batch=4)
    for k, s in enumerate(steps):
        now.check(0.1 * k, s)
        batched.check(0.1 * k, s)
    batched.flush()
    times = [round(e.time, 3) for e in now.events]
    assert [e.kind for e in now.events] == ["off_road", "off_road"] and times == [0.2, 0.5]
    assert [(e.kind, round(e.time, 3), e.vehicles) for e in batched.events] == \
        [(e.kind, round(e.time, 3), e.vehicles) for e in now.events]


def test_batched_detector_finds_the_same_events_as_per_step():
    rng = np.random.default_rng(7)
    scene = synthetic.two_lane_road()
    drivable = DrivableArea.from_road_map(scene.road_map)
    x0, y0 = scene.road_map.lanes.centerline[0][20]
    names = ["ego", "adv", "a", "b"]
    pos = np.array([[x0, y0], [x0 + 6, y0 + 3], [x0 - 5, y0], [x0 + 4, y0 - 3]], float)
    steps = []
    for _k in range(60):
        pos += rng.normal(0, 1.2, pos.shape)
        present = rng.random(4) > 0.1  # vehicles (the references too) miss some steps
        steps.append(_states([(n, p[0], p[1], rng.uniform(-0.3, 0.3), 5.0)
                              for n, p, ok in zip(names, pos, present, strict=True) if ok]))
    ref = EventDetector("ego", "adv", drivable)
    batched = EventDetector("ego", "adv", drivable, batch=7)
    for k, s in enumerate(steps):
        ref.check(0.1 * k, s)
        batched.check(0.1 * k, s)
    batched.flush()

    def key(d: EventDetector) -> list:
        return sorted((e.kind, round(e.time, 3), tuple(e.vehicles)) for e in d.events)

    assert len(ref.events) >= 5 and {"collision", "off_road"} <= {e.kind for e in ref.events}
    assert key(batched) == key(ref)


def test_batched_target_contact_episodes_split_on_separation_and_absence():
    near, far = ("a", 3.0, 0.5, 0, 5), ("a", 30.0, 0.5, 0, 5)
    ego = ("ego", 0.0, 0.0, 0, 5)
    seq = [[ego, far], [ego, near], [ego, near], [ego, far], [ego, near], [ego, near], [near], [ego, near]]
    for batch in (1, 3, 100):
        det = EventDetector("ego", "adv", None, batch=batch)
        for k, rows in enumerate(seq):
            det.check(0.1 * k, _states(rows))
        det.flush()
        assert [round(e.time, 3) for e in det.events] == [0.1, 0.4, 0.7], batch


def _random_walk(seed: int, steps: int = 60) -> list[VehicleStates]:
    rng = np.random.default_rng(seed)
    scene = synthetic.two_lane_road()
    x0, y0 = scene.road_map.lanes.centerline[0][20]
    names = ["ego", "adv", "a", "b"]
    pos = np.array([[x0, y0], [x0 + 6, y0 + 3], [x0 - 5, y0], [x0 + 4, y0 - 3]], float)
    out = []
    for _k in range(steps):
        pos += rng.normal(0, 1.2, pos.shape)
        present = rng.random(4) > 0.1
        out.append(_states([(n, p[0], p[1], rng.uniform(-0.3, 0.3), 5.0)
                            for n, p, ok in zip(names, pos, present, strict=True) if ok]))
    return out


@pytest.mark.parametrize("seed", [7, 11, 12])
def test_settled_adversary_is_checked_in_batches_with_the_same_events(seed):
    steps = _random_walk(seed)
    drivable = DrivableArea.from_road_map(synthetic.two_lane_road().road_map)
    ref = EventDetector("ego", "adv", drivable)
    settled = EventDetector("ego", "adv", drivable, batch=7)
    for k, s in enumerate(steps):
        ref.check(0.1 * k, s)
        settled.check(0.1 * k, s)
        if k == 20:
            settled.settle_adversary()  # from step 21 on its contacts are batched
    settled.flush()

    def key(d: EventDetector) -> list:
        return sorted((e.kind, round(e.time, 3), tuple(e.vehicles)) for e in d.events)

    late = [e for e in ref.events if e.kind == "collision" and "adv" in e.vehicles and e.time > 2.05]
    assert late, "the walk should bring the adversary into contact after it settles"
    assert key(settled) == key(ref)


def test_contact_going_on_when_the_adversary_settles_is_not_a_new_event():
    ego, touching, apart = ("ego", 0.0, 0.0, 0, 0), ("adv", 4.0, 0.0, 0, 0), ("adv", 20.0, 0.0, 0, 0)
    seq = [[ego, apart], [ego, touching], [ego, touching], [ego, touching], [ego, apart], [ego, touching]]
    det = EventDetector("ego", "adv", None, batch=50)
    for k, rows in enumerate(seq):
        new = det.check(0.1 * k, _states(rows))
        if k == 1:
            assert [e.vehicles for e in new] == [["ego", "adv"]]  # reported live, at once
            det.settle_adversary()
    det.flush()
    assert [round(e.time, 3) for e in det.events] == [0.1, 0.5]


def test_parked_vehicle_keeps_its_off_road_state_across_batches_and_absence():
    scene = synthetic.two_lane_road()
    drivable = DrivableArea.from_road_map(scene.road_map)
    x0, y0 = scene.road_map.lanes.centerline[0][20]
    ego = ("ego", x0, y0, 0, 0)
    parked_off, on_road = ("adv", x0 + 20, y0 - 8, 0, 0), ("adv", x0 + 20, y0, 0, 0)
    seq = [[ego, parked_off]] * 10 + [[ego]] * 2 + [[ego, parked_off]] * 4 + [[ego, on_road]] * 4 + \
        [[ego, parked_off]] * 3
    for batch in (1, 3, 100):
        det = EventDetector("ego", "adv", drivable, batch=batch)
        for k, rows in enumerate(seq):
            det.check(0.1 * k, _states(rows))
        det.flush()
        off = [e for e in det.events if e.kind == "off_road"]
        assert [(round(e.time, 3), e.vehicles) for e in off] == [(0.0, ["adv"]), (1.2, ["adv"]), (2.0, ["adv"])], batch
        assert all(e.detail["area_outside_m2"] == pytest.approx(8.0) for e in off)


def test_row_hint_follows_a_vehicle_as_others_come_and_go():
    from coster_sumo.sim.events import _find

    ids = ["a", "c", "ego", "x"]
    assert _find(ids, "ego", 2) == 2
    assert _find(["a", "b", "c", "ego", "x"], "ego", 2) == 3  # "b" departed: one row down
    assert _find(["c", "ego", "x"], "ego", 2) == 1  # "a" arrived: one row up
    assert _find(["ego"], "ego", 7) == 0  # a stale hint falls back to a scan
    assert _find(ids, "adv", 1) == -1 and _find([], "ego", 0) == -1
