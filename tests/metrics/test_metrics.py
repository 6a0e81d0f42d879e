from __future__ import annotations

import math

import numpy as np
import pytest

from coster_sumo import metrics


def test_jsd_identical_is_zero_and_disjoint_is_ln2():
    h = np.array([1.0, 2.0, 3.0, 0.0])
    assert metrics.js_divergence(h, h) == pytest.approx(0.0, abs=1e-15)
    assert metrics.js_divergence(np.array([1.0, 0.0]), np.array([0.0, 1.0])) == pytest.approx(np.log(2))


def test_vdd_of_same_speeds_is_zero_and_of_far_speeds_is_ln2():
    rng = np.random.default_rng(0)
    v = rng.uniform(0, 30, 1000)
    assert metrics.velocity_distribution_divergence(v, v) == pytest.approx(0.0, abs=1e-12)
    assert metrics.velocity_distribution_divergence(np.full(10, 1.0), np.full(10, 40.0)) == pytest.approx(
        np.log(2))


def test_add_uses_200_bins_over_pm10():
    # 0.05 and 0.15 m/s^2 fall into different 0.1-wide bins -> disjoint
    assert metrics.acceleration_distribution_divergence(np.array([0.05]), np.array([0.15])) == pytest.approx(
        np.log(2))


@pytest.mark.parametrize(("adv", "angle"),
                         [((5, 0), 0.0), ((0, 3), 90.0), ((0, -3), -90.0), ((-5, 0), 180.0)])
def test_impact_angle_in_target_frame(adv, angle):
    assert metrics.impact_angle_deg(np.zeros(2), 0.0, np.asarray(adv, float)) == pytest.approx(angle)


def test_impact_angle_rotates_with_target():
    # target facing north: an adversary to the east is on its right
    assert metrics.impact_angle_deg(np.zeros(2), np.pi / 2, np.array([4.0, 0.0])) == pytest.approx(-90.0)


def test_cpd_of_symmetric_impacts():
    assert metrics.collision_position_diversity([90.0, -90.0]) == pytest.approx(90.0)
    assert metrics.collision_position_diversity([30.0, 30.0, 30.0]) == pytest.approx(0.0)
    # circular std sees 179 and -179 as 2 degrees apart, the linear std does not
    assert metrics.circular_std_deg([179.0, -179.0]) == pytest.approx(1.0, abs=0.01)
    assert metrics.collision_position_diversity([179.0, -179.0]) == pytest.approx(179.0)
    # identical impacts: exactly +0 (rounding put R a hair past 1 and printed "-0.0")
    for same in ([30.0] * 5, [-17.3] * 7, [123.4, 123.4]):
        assert math.copysign(1.0, metrics.circular_std_deg(same)) == 1.0
        assert metrics.circular_std_deg(same) == pytest.approx(0.0, abs=1e-6)


def test_csd_and_relative_speed():
    rel = metrics.relative_speed(np.array([[10.0, 0.0], [0.0, 0.0]]), np.array([[0.0, 0.0], [3.0, 4.0]]))
    np.testing.assert_allclose(rel, [10.0, 5.0])
    assert metrics.collision_speed_diversity(rel) == pytest.approx(2.5)


def test_rates():
    assert metrics.collision_rate([True, False, True, True]) == pytest.approx(0.75)
    assert metrics.off_road_rate([False, False]) == 0.0
    assert metrics.success_rate(4, 3) == pytest.approx(0.75)
    assert np.isnan(metrics.collision_rate([]))


def test_ade_fde_min_and_avg():
    truth = np.zeros((4, 2))
    pred = np.stack([np.zeros((4, 2)), np.ones((4, 2))])  # (2 samples, 4 steps, 2)
    mn_ade, mn_fde = metrics.min_ade_fde(pred, truth)
    av_ade, av_fde = metrics.avg_ade_fde(pred, truth)
    assert mn_ade == pytest.approx(0.0)
    assert mn_fde == pytest.approx(0.0)
    assert av_ade == pytest.approx(np.sqrt(2) / 2)
    assert av_fde == pytest.approx(np.sqrt(2) / 2)


def test_fde_uses_last_valid_step():
    truth = np.zeros((3, 2))
    pred = np.array([[[0.0, 0.0], [1.0, 0.0], [9.0, 0.0]]])
    _, fde = metrics.ade_fde(pred, truth, valid=np.array([True, True, False]))
    assert fde[0] == pytest.approx(1.0)


def test_mmd_zero_for_same_samples_positive_for_shifted():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(200, 2))
    assert metrics.mmd(x, x) == pytest.approx(0.0, abs=1e-12)
    assert metrics.mmd(x, x + 3.0) > 0.3


def test_registry_has_all_seven_scenario_metrics():
    assert {"SUR", "CR", "ORR", "VDD", "ADD", "CSD", "CPD"} <= set(metrics.REGISTRY)


def test_circular_range_wraps_at_180():
    from coster_sumo.metrics import circular_range_deg

    assert circular_range_deg([-180.0, 180.0, -180.0]) == 0.0
    assert circular_range_deg([-180.0, 90.0, 180.0]) == pytest.approx(90.0)
    assert circular_range_deg([170.0, -170.0]) == pytest.approx(20.0)
    assert circular_range_deg([0.0, 90.0, 180.0, 270.0]) == pytest.approx(270.0)
    assert circular_range_deg([12.0]) == 0.0


def test_scene_bootstrap_interval_holds_the_value_and_narrows_with_more_scenes():
    rng = np.random.default_rng(1)
    few = [rng.normal(0, 10, 5) for _ in range(10)]
    many = [rng.normal(0, 10, 5) for _ in range(400)]
    v, lo, hi = metrics.scene_bootstrap(metrics.collision_speed_diversity, few)
    assert v == pytest.approx(np.concatenate(few).std()) and lo <= v <= hi
    v2, lo2, hi2 = metrics.scene_bootstrap(metrics.collision_speed_diversity, many)
    assert lo2 <= 10 <= hi2 and hi2 - lo2 < (hi - lo) / 2
    # the same draws: the same interval
    assert metrics.scene_bootstrap(metrics.collision_speed_diversity, few) == (v, lo, hi)


def test_paired_scene_bootstrap_separates_a_real_difference_from_none():
    rng = np.random.default_rng(2)
    a = [rng.normal(0, 20, 5) for _ in range(200)]
    wider = [x * 2 for x in a]
    same = [x + rng.normal(0, 0.1, x.shape) for x in a]
    d, lo, hi = metrics.scene_bootstrap(metrics.collision_position_diversity, wider, a)
    assert d > 0 and lo > 0  # twice the spread on every scene: settled
    d, lo, hi = metrics.scene_bootstrap(metrics.collision_position_diversity, same, a)
    assert lo < 0 < hi  # the same contacts: not settled either way
    with pytest.raises(ValueError, match="same scenes"):
        metrics.scene_bootstrap(metrics.collision_position_diversity, a, a[:-1])
    v, lo, hi = metrics.scene_bootstrap(metrics.collision_position_diversity, [])
    assert math.isnan(v) and math.isnan(lo)


def test_paired_diversity_compares_coster_on_shared_scenes_only():
    from coster_sumo.batch.eval_metrics import avoidability_summary, paired_diversity
    from coster_sumo.batch.evaluate import GENERATOR_METHODS
    from coster_sumo.batch.generator_summary import EvalSummary, GeneratorResult, GeneratorTable
    from coster_sumo.batch.report import diversity_section
    from coster_sumo.metrics import MetricValue

    per_scene = {"COSTER": {"s1": ([1.0, 2.0], [10.0, 20.0]), "s2": ([5.0], [-90.0]), "s3": ([3.0], [0.0])},
                 "COSTER t_col=last": {"s1": ([1.0], [0.0]), "s2": ([1.0], [0.0])}}
    paired = paired_diversity(per_scene)
    entry = paired["COSTER - COSTER t_col=last"]
    assert entry.scenes == 2  # s3: only COSTER generated for it
    assert entry.CSD[0] == pytest.approx(np.std([1.0, 2.0, 5.0]) - 0.0)
    assert entry.CPD[0] == pytest.approx(np.std([10.0, 20.0, -90.0]))
    assert paired_diversity({"other": per_scene["COSTER"]}) == {}
    coster = GeneratorResult(
        method=GENERATOR_METHODS[0], scenes=3, variants=4, failed_tasks=(), SUR=MetricValue(1.0), CR=MetricValue(1.0),
        ORR=MetricValue(0.0), VDD=None, ADD=None, CSD=MetricValue(1.0, 0.5, 1.5), CPD=MetricValue(2.0, 1.0, 3.0),
        CPD_circular=MetricValue(3.0, float("nan"), 4.0), generation_s_per_variant=None,
        avoidability=avoidability_summary([]), relative_speeds=(), impact_angles=(), VDD_tcol=None,
        VDD_tcol_floor=None, size_in_class=None)
    summary = EvalSummary(scenes={}, planner="replay", variants=4, samples=1,
                          methods=GeneratorTable({"COSTER": coster}, paired=paired))
    md = "\n".join(diversity_section(summary))
    assert "| COSTER | 1.00 [0.50, 1.50] | 2.0 [1.0, 3.0] | 3.0 |" in md
    assert "| COSTER - COSTER t_col=last | 2 |" in md
