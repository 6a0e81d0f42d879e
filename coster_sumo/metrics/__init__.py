"""Scenario and model metrics, one function each, with one registry.

Conventions (docs/method.md, Reference figures (metric conventions)): Jensen-Shannon divergence with the
natural log (maximum ln 2); speed histograms over 0-50 m/s in 100 bins; acceleration histograms
over -10..10 m/s^2 in 200 bins; MMD with one Gaussian kernel whose bandwidth is the mean pairwise
squared distance of the pooled samples, biased estimate; impact angle = atan2 of the adversary's
position in the target frame; relative speed = |v_target - v_adv| (vector difference).

Every function takes plain numpy arrays, usable from scripts, notebooks and tests alike. The figures
the commands report come from :data:`REGISTRY` (:mod:`.base`): each :class:`Metric` computes one
:class:`MetricValue` of one :class:`MetricSample` (a :class:`RunOutcome` per variant driven, and more).
One module per family: :mod:`.rates`, :mod:`.distributions`, :mod:`.impacts` (scenario metrics, each
with its ``METRICS``) and :mod:`.trajectories` (the models' displacement errors and MMD). This module
registers the families' metrics in the order the reports list them and hands their names on.
"""

from __future__ import annotations

from coster_sumo.metrics import distributions, impacts, rates
from coster_sumo.metrics.base import (
    REGISTRY,
    Metric,
    MetricSample,
    MetricValue,
    RunOutcome,
    compute,
    register_metric,
)
from coster_sumo.metrics.distributions import (
    ACCEL_BINS,
    FLOOR_DRAWS,
    SPEED_BINS,
    acceleration_distribution_divergence,
    js_divergence,
    speeds_and_accels,
    velocity_distribution_divergence,
)
from coster_sumo.metrics.impacts import (
    BOOTSTRAP_DRAWS,
    circular_range_deg,
    circular_std_deg,
    collision_position_diversity,
    collision_speed_diversity,
    impact_angle_deg,
    relative_speed,
    scene_bootstrap,
)
from coster_sumo.metrics.rates import (
    WILSON_Z,
    collision_rate,
    off_road_rate,
    rate_value,
    rate_with_ci,
    route_completion_rate,
    success_rate,
    wilson_interval,
)
from coster_sumo.metrics.trajectories import ade_fde, avg_ade_fde, min_ade_fde, mmd

# the order the reports list the figures in (summary.json, regress and eval scenarios reports)
REPORT_ORDER = ("SUR", "CR", "ORR", "CR_target", "ORR_target", "RCR", "defect_rate", "unavoidable_contact_rate",
                "VDD", "ADD", "CSD", "CPD", "CPD_circular", "impact_angle_spread", "median_min_ttc",
                "mean_relative_speed", "VDD_tcol", "VDD_tcol_floor", "size_in_class")

if not REGISTRY:  # a reload of this module registers nothing twice
    _families = {m.name: m for family in (rates, distributions, impacts) for m in family.METRICS}
    for _name in REPORT_ORDER:
        register_metric(_families.pop(_name))
    assert not _families, f"metrics missing from REPORT_ORDER: {sorted(_families)}"

__all__ = [
    "ACCEL_BINS", "BOOTSTRAP_DRAWS", "FLOOR_DRAWS", "REGISTRY", "REPORT_ORDER", "SPEED_BINS", "WILSON_Z", "Metric",
    "MetricSample", "MetricValue", "RunOutcome", "acceleration_distribution_divergence", "ade_fde", "avg_ade_fde",
    "circular_range_deg", "circular_std_deg", "collision_position_diversity", "collision_rate",
    "collision_speed_diversity", "compute", "impact_angle_deg", "js_divergence", "min_ade_fde", "mmd",
    "off_road_rate", "rate_value", "rate_with_ci", "register_metric", "relative_speed", "route_completion_rate",
    "scene_bootstrap", "speeds_and_accels", "success_rate", "velocity_distribution_divergence", "wilson_interval",
]
