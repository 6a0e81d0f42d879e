"""Rollout inputs: the t_rev frame, neighbours per step, map chunks, reverse targets."""

from __future__ import annotations

import numpy as np
import pytest

from coster_sumo.core.scene import resample
from coster_sumo.data import synthetic
from coster_sumo.errors import InputError
from coster_sumo.rollout import data as D
from coster_sumo.rollout.model import RolloutConfig

CFG = RolloutConfig()


@pytest.fixture(scope="module")
def road():
    low = resample(synthetic.two_lane_road(), 2.0)
    return low, D.build_cache(low, CFG)


def test_neighbours_are_in_the_t_rev_frame_and_exclude_the_vehicle(road):
    low, cache = road
    tr = low.tracks
    sdc, lead = tr.index_of("sdc"), tr.index_of("lead")
    ctx = D.agent_context(cache, sdc, 12, 10, CFG)
    assert ctx.nbr.shape == (11, CFG.max_neighbors, D.NBR_FEATURES)
    valid = ctx.nbr[0][ctx.nbr_mask[0]]
    assert len(valid) == tr.num_agents - 1  # everyone but the sdc itself
    # the lead vehicle drives 25 m ahead in the same lane: +x, y ~ 0, same heading
    gap = (tr.x[lead, 12] - tr.x[sdc, 12]) / CFG.pos_scale_m
    hit = np.flatnonzero(np.isclose(valid[:, 0], gap, atol=1e-5))
    assert len(hit) == 1
    assert abs(valid[hit[0], 1]) < 1e-5 and valid[hit[0], 4] == pytest.approx(1.0)


def test_neighbours_follow_the_scene_backwards_in_time(road):
    low, cache = road
    tr = low.tracks
    sdc, lead = tr.index_of("sdc"), tr.index_of("lead")
    ctx = D.agent_context(cache, sdc, 12, 10, CFG)
    for k in (0, 5, 10):
        gap_x = (tr.x[lead, 12 - k] - tr.x[sdc, 12]) / CFG.pos_scale_m  # origin stays at t_rev
        assert np.any(np.isclose(ctx.nbr[k, :, 0], gap_x, atol=1e-5) & ctx.nbr_mask[k])


def test_map_chunks_cover_the_road_in_the_local_frame(road):
    _, cache = road
    ctx = D.agent_context(cache, 0, 12, 10, CFG)
    assert ctx.map_mask.any()
    ys = ctx.map_pos[ctx.map_mask][:, [1, 3]] * CFG.pos_scale_m
    assert np.all(np.abs(ys) < 4.0)  # both lanes: 0 m and 3.7 m to the left
    xs = ctx.map_pos[ctx.map_mask][:, [0, 2]] * CFG.pos_scale_m
    assert np.all(np.abs(xs) <= CFG.map_radius_m + CFG.lane_spacing_m * CFG.chunk_vectors)
    assert ctx.map_vec.shape == (CFG.max_map_chunks, CFG.chunk_vectors, D.MAP_VEC_FEATURES)


def test_reverse_targets_of_a_constant_speed_vehicle(road):
    low, _ = road
    sdc = low.tracks.index_of("sdc")
    traj, mask = D.reverse_targets(low, sdc, 12, 10)
    assert mask.all()
    np.testing.assert_allclose(traj[:, 0], -10.0 * 0.5 * np.arange(1, 11), atol=1e-3)  # 10 m/s
    np.testing.assert_allclose(traj[:, 1:], 0.0, atol=1e-4)


def test_short_or_gappy_pasts_are_masked():
    low = resample(synthetic.four_way_junction(), 2.0)
    late = low.tracks.index_of("late")  # valid only from 2 s on (2 Hz step 4)
    traj, mask = D.reverse_targets(low, late, 7, 10)
    assert mask.tolist() == [True] * 3 + [False] * 7
    assert np.all(traj[~mask] == 0)
    ex = D.enumerate_examples(low, CFG, full_only=True)
    assert all(h == 10 and t >= 10 for _, t, h in ex)
    assert (late, 12, 10) not in ex


def test_horizon_before_the_scene_start_is_an_error(road):
    _, cache = road
    with pytest.raises(InputError):
        D.agent_context(cache, 0, 3, 10, CFG)


def test_a_10hz_scene_is_refused():
    with pytest.raises(InputError, match="2 Hz"):
        D.build_cache(synthetic.merge(), CFG)


def test_batches_pad_horizons_and_neighbours():
    ex = D.build_examples([synthetic.four_way_junction()], CFG)
    short = np.flatnonzero(ex.index[:, 3] < 10)[:3]
    full = np.flatnonzero(ex.index[:, 3] == 10)[:2]
    b = ex.batch(np.concatenate([short, full]), CFG)
    assert b["nbr"].shape[:2] == (5, 11) and b["traj"].shape == (5, 10, 3)
    assert not b["step_mask"][0, ex.index[short[0], 3]:].any()
