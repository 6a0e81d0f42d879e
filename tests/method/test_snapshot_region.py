"""The adversary is drawn from a region around the target, never from the region the target fills."""

from __future__ import annotations

import numpy as np

from coster_sumo.core.scene import resample
from coster_sumo.errors import NoSnapshot
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.method.snapshot import PlacementRequest, PriorMemo, prior_snapshot


def test_the_adversary_never_comes_from_the_targets_own_region(synthetic_scene):
    # the region under the target is the most likely occupied one (a vehicle is there), so taking
    # the highest presence in the ellipse used to pick it and copy the target's own motion
    low = resample(synthetic_scene, 2.0)
    target = low.sdc_index if low.sdc_index >= 0 else 0
    drivable = DrivableArea.from_road_map(low.road_map)
    memo = PriorMemo()
    placed = 0
    for seed in range(4):
        try:
            request = PlacementRequest(low, target, np.random.default_rng(seed), drivable, "entropy", seed, memo=memo)
            snap = prior_snapshot(request)
        except NoSnapshot:
            continue
        placed += 1
        occupant = memo.data.occupancy.gather(np.array([snap.t_index]), np.array([snap.region_id]))[0]
        assert int(occupant[0]) != target, f"seed {seed}: region {snap.region_id} is the target's own"
    assert placed > 0
