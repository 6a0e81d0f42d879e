"""The adversaries' states at t_col against nominal traffic of the same lane type (eval scenarios)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from coster_sumo.batch.eval_metrics import snapshot_state_metrics
from coster_sumo.batch.evaluate import nominal_speeds_by_lane_type
from coster_sumo.batch.generator_summary import VariantRecord
from coster_sumo.data.synthetic import two_lane_road
from coster_sumo.metrics import SPEED_BINS


def _hist(speeds):
    return np.histogram(speeds, bins=SPEED_BINS)[0]


def _rec(speed, lane_type="FREEWAY", length=4.5, width=1.9, snapshot=None):
    return VariantRecord(adversary_speed=speed, adversary_length=length, adversary_width=width,
                         adversary_lane_type=lane_type, snapshot=snapshot)


def test_each_adversary_is_compared_with_traffic_on_its_own_lane_type():
    nominal = {"FREEWAY": _hist(np.full(100, 30.2)), "SURFACE_STREET": _hist(np.full(100, 10.2))}
    same = snapshot_state_metrics([_rec(30.2), _rec(10.2, "SURFACE_STREET")], nominal)
    assert same["VDD_tcol"] == pytest.approx(0.0, abs=1e-12)
    assert same["adversaries_by_lane_type"] == {"FREEWAY": 1, "SURFACE_STREET": 1}
    swapped = snapshot_state_metrics([_rec(10.2), _rec(30.2, "SURFACE_STREET")], nominal)
    assert swapped["VDD_tcol"] == pytest.approx(math.log(2))  # right speeds, wrong roads: disjoint
    stopped = snapshot_state_metrics([_rec(0.0), _rec(30.2)], nominal)
    assert 0.0 < stopped["VDD_tcol"] < math.log(2)


def test_sizes_outside_every_vehicle_class_are_counted():
    m = snapshot_state_metrics([_rec(5.0), _rec(5.0, length=2.1, width=2.05), _rec(5.0, length=12.0, width=2.55)],
                               {"FREEWAY": _hist([5.0])})
    assert m["size_in_class"] == pytest.approx(2 / 3)


def test_nothing_recorded_gives_none():
    assert snapshot_state_metrics([VariantRecord(collision=True)], {}) == {"VDD_tcol": None, "VDD_tcol_floor": None,
                                                                "size_in_class": None,
                                                                "adversaries_by_lane_type": {}}


def test_the_floor_is_what_the_nominal_traffic_itself_scores_with_as_few_adversaries():
    rng = np.random.default_rng(1)
    traffic = rng.uniform(0, 30, 20000)
    nominal = {"SURFACE_STREET": _hist(traffic)}
    drawn = rng.uniform(0, 30, 2000)  # adversaries with the traffic's own speeds
    few = snapshot_state_metrics([_rec(v, "SURFACE_STREET") for v in drawn[:20]], nominal)
    many = snapshot_state_metrics([_rec(v, "SURFACE_STREET") for v in drawn], nominal)
    # speeds drawn from the traffic itself: VDD is near its floor, and both shrink with more adversaries
    for m in (few, many):
        assert 0.5 < m["VDD_tcol"] / m["VDD_tcol_floor"] < 2.0
    assert many["VDD_tcol_floor"] < 0.1 * few["VDD_tcol_floor"]
    stopped = snapshot_state_metrics([_rec(0.0, "SURFACE_STREET")] * 2000, nominal)  # 2000 snapshots
    assert stopped["VDD_tcol"] > 10 * stopped["VDD_tcol_floor"]
    # 20 snapshots with 5 variants each are 20 draws, not 100: the floor is that of 20
    repeated = snapshot_state_metrics([_rec(v, "SURFACE_STREET", snapshot=f"scene{i // 5}")
                                       for i, v in enumerate(np.repeat(drawn[:20], 5))], nominal)
    hundred = snapshot_state_metrics([_rec(v, "SURFACE_STREET") for v in drawn[:100]], nominal)
    assert repeated["VDD_tcol_floor"] > 2 * hundred["VDD_tcol_floor"]
    assert repeated["VDD_tcol_floor"] == pytest.approx(few["VDD_tcol_floor"], rel=0.2)


def test_nominal_speeds_are_split_by_the_nearest_lanes_type():
    scene = two_lane_road()
    hists = nominal_speeds_by_lane_type(scene)
    assert set(hists) == {"SURFACE_STREET"}  # the synthetic road is a surface street
    assert sum(hists["SURFACE_STREET"]) == int(scene.tracks.valid[:, ::5].sum())  # every vehicle at 2 Hz


def test_a_vru_adversary_is_compared_with_its_own_class_of_the_raw_scenes():
    """eval scenarios --adversary pedestrian|cyclist: VDD, ADD and VDD at t_col against the raw scenes'
    agents of that class, not every agent; a scene without them adds no counts."""
    from coster_sumo.batch.evaluate import NominalTraffic
    from coster_sumo.batch.generator_summary import ScenePart
    from coster_sumo.core.scene import ObjectType
    from coster_sumo.data.synthetic import four_way_junction, with_vulnerable_road_users

    walker = {"speed_hist": [0, 7] + [0] * 98, "accel_hist": [1] * 200, "speed_hist_by_lane_type": {"CROSS": [2] * 100}}
    with_walkers = ScenePart("ok", speed_hist=[5] * 100, accel_hist=[3] * 200,
                             speed_hist_by_lane_type={"SURFACE_STREET": [4] * 100}, by_class={"pedestrian": walker})
    read_back = ScenePart.from_json(dataclasses.asdict(with_walkers))
    assert read_back == with_walkers
    cars_only = dataclasses.replace(with_walkers, by_class={})
    vehicles, walkers = NominalTraffic(), NominalTraffic()
    for key, part in (("a", read_back), ("b", cars_only)):
        vehicles.add(key, part)
        walkers.add(key, part, "pedestrian")
    assert vehicles.speed_hist.tolist() == [10] * 100 and walkers.speed_hist.tolist() == walker["speed_hist"]
    assert walkers.accel_hist.tolist() == [1] * 200 and set(walkers.speed_hist_by_lane_type) == {"CROSS"}
    assert walkers.scenes == vehicles.scenes == ["a", "b"]
    # the scene's pedestrians at 2 Hz, by the lane type nearest each
    scene = with_vulnerable_road_users(four_way_junction())
    per_type = nominal_speeds_by_lane_type(scene, ObjectType.PEDESTRIAN)
    assert sum(sum(h) for h in per_type.values()) == 2 * len(np.arange(0, scene.timestamps[-1] + 1e-9, 0.5))
