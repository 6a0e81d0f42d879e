"""Oversampling, K-means, the motion vocabulary, rejection, baselines and the pipeline entry."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from coster_sumo.core.scene import resample
from coster_sumo.core.snapshot import AgentState, CollisionSnapshot
from coster_sumo.data import synthetic
from coster_sumo.errors import InputError
from coster_sumo.geometry.boxes import box_corners
from coster_sumo.infra import weights
from coster_sumo.rollout import sample as S
from coster_sumo.rollout import vocab as V
from coster_sumo.rollout.baselines import constant_lane_backward, constant_velocity_backward
from coster_sumo.rollout.checkpoint import save_checkpoint
from coster_sumo.rollout.model import RolloutConfig, RolloutCVAE
from coster_sumo.rollout.request import RolloutRequest

TINY = RolloutConfig(hidden=32, heads=4, latent=8, posterior_hidden=16, max_map_chunks=32, max_neighbors=8)


@pytest.fixture(autouse=True)
def one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def junction():
    return resample(synthetic.four_way_junction(), 2.0)


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return RolloutCVAE(TINY).eval()


def adversary_near_target(scene, t_index: int) -> AgentState:
    target = AgentState.from_tracks(scene.tracks, scene.sdc_index, t_index)
    return AgentState(target.x + 2.0, target.y + 4.6, target.yaw - 0.3, 7.0, 4.6, 1.9)


def test_samples_end_exactly_at_the_snapshot(junction, model):
    adv = adversary_near_target(junction, 14)
    trajs = S.sample_trajectories(model, junction, (adv, 14), n=50, seed=1)
    assert trajs.shape == (50, 11, 3)
    assert np.all(trajs[:, -1] == [adv.x, adv.y, adv.yaw])
    again = S.sample_trajectories(model, junction, (adv, 14), n=50, seed=1)
    assert np.array_equal(trajs, again)
    assert not np.array_equal(trajs, S.sample_trajectories(model, junction, (adv, 14), n=50, seed=2))


def test_horizon_is_shorter_when_the_collision_is_early(junction, model):
    adv = adversary_near_target(junction, 3)
    snap = CollisionSnapshot(scenario_id="x", target_id="sdc", t_index=3, time=1.5,
                             target=AgentState.from_tracks(junction.tracks, 0, 3), adversary=adv)
    trajs = S.sample_trajectories(model, junction, snap, n=4)
    assert trajs.shape == (4, 4, 3)
    np.testing.assert_array_equal(S.trajectory_times(junction, 3, 3), [0.0, 0.5, 1.0, 1.5])


def fan(offsets: list[float], length_m: float = 10.0, steps: int = 5) -> np.ndarray:
    """Straight trajectories from (-length, offset) to the origin, all ending in the same pose."""
    out = []
    for y0 in offsets:
        s = np.linspace(0.0, 1.0, steps)
        x, y = -length_m * (1 - s), y0 * (1 - s)
        yaw = np.full(steps, np.arctan2(-y0, length_m))
        yaw[-1] = 0.0
        out.append(np.stack([x, y, yaw], -1))
    return np.asarray(out)


def test_kmeans_is_deterministic_and_orders_members_by_distance():
    rng = np.random.default_rng(0)
    trajs = fan(list(rng.normal(0, 0.3, 40)) + list(rng.normal(6, 0.3, 25)) + list(rng.normal(-6, 0.3, 15)))
    a = S.cluster_trajectories(trajs, k=3, seed=0)
    b = S.cluster_trajectories(trajs, k=3, seed=0)
    assert [len(m) for m in a] == [40, 25, 15]  # largest cluster first
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    feats = S.cluster_features(trajs)
    for members in a:
        d = np.linalg.norm(feats[members] - feats[members].mean(0), axis=1)
        assert np.all(np.diff(d) >= -1e-12)  # closest to the centroid first


def test_kmeans_with_fewer_distinct_trajectories_than_clusters():
    trajs = fan([0.0] * 10 + [3.0] * 10)
    clusters = S.cluster_trajectories(trajs, k=5, seed=0)
    assert sorted(len(m) for m in clusters) == [10, 10]


@pytest.fixture(scope="module")
def vocab():
    scenes = [f() for f in synthetic.ALL.values()]
    trans = V.collect_transitions(scenes)
    rng = np.random.default_rng(0)
    # a little variety beyond constant-speed lane following
    extra = np.stack([rng.uniform(0, 12, 400), rng.normal(0, 0.3, 400), rng.normal(0, 0.1, 400)], -1)
    return V.build_vocab(np.concatenate([trans, extra]), size=48, seed=0)


def test_vocabulary_has_at_most_the_requested_tokens(vocab, tmp_path):
    assert 1 <= len(vocab) <= 48 and vocab.epsilon_m > 0
    loaded = V.MotionVocab.load(vocab.save(tmp_path / "v.npz"))
    assert np.array_equal(loaded.tokens, vocab.tokens) and loaded.epsilon_m == vocab.epsilon_m


def test_bad_vocabulary_file_is_an_input_error(tmp_path):
    p = tmp_path / "v.npz"
    p.write_bytes(b"nope")
    with pytest.raises(InputError, match="not a motion vocabulary"):
        V.MotionVocab.load(p)


def test_projection_keeps_the_snapshot_and_uses_tokens_only(vocab):
    rng = np.random.default_rng(1)
    trajs = fan([0.0, 1.5, -2.0], length_m=20.0, steps=11)
    trajs[..., :2] += rng.normal(0, 0.05, trajs[..., :2].shape)
    trajs[:, -1] = (1234.5, -87.25, 0.7)  # an arbitrary snapshot pose, far from the origin
    refined, err = V.project_backward(trajs, vocab, 4.6, 1.9)
    assert np.array_equal(refined[:, -1], trajs[:, -1])
    assert np.abs(refined[:, -1, :2] - trajs[:, -1, :2]).max() <= 1e-6
    steps = V.relative(refined[:, :-1], refined[:, 1:])  # (R, T-1, 3)
    dist = np.abs(steps[:, :, None, :] - vocab.tokens[None, None]).max(-1).min(-1)
    assert dist.max() < 1e-9  # every transition is a token
    assert err.shape == (3,) and np.all(err >= 0)


def test_projection_takes_the_token_of_the_smallest_mean_corner_error(vocab):
    """Each step back from the refined later pose, the token whose moved box has the smallest mean
    corner distance to the raw box (computed here the plain way, on the whole difference array)."""
    rng = np.random.default_rng(4)
    trajs = fan([0.0, 2.0], length_m=15.0, steps=6)
    trajs[..., :2] += rng.normal(0, 0.2, trajs[..., :2].shape)
    refined, err = V.project_backward(trajs, vocab, 4.6, 1.9)
    back = V.invert(vocab.tokens)
    token_c = box_corners(back[:, 0], back[:, 1], back[:, 2], 4.6, 1.9)  # (V, 4, 2)
    for r in range(len(trajs)):
        for k in range(trajs.shape[1] - 2, -1, -1):
            q = refined[r, k + 1]
            raw = box_corners(trajs[r, k, 0], trajs[r, k, 1], trajs[r, k, 2], 4.6, 1.9) - q[:2]  # (4, 2)
            c, s = np.cos(q[2]), np.sin(q[2])
            local = np.stack([c * raw[:, 0] + s * raw[:, 1], -s * raw[:, 0] + c * raw[:, 1]], -1)
            mean_err = np.sqrt(((token_c - local) ** 2).sum(-1)).mean(-1)  # (V,)
            np.testing.assert_allclose(refined[r, k], V.compose(q[None], back[[int(np.argmin(mean_err))]])[0],
                                       atol=1e-12)


def test_invert_and_compose_round_trip():
    rng = np.random.default_rng(2)
    pose = rng.normal(0, 3, (20, 3))
    delta = rng.normal(0, 1, (20, 3))
    back = V.compose(V.compose(pose, delta), V.invert(delta))
    np.testing.assert_allclose(back, pose, atol=1e-12)
    np.testing.assert_allclose(V.relative(pose, V.compose(pose, delta))[:, :2], delta[:, :2], atol=1e-12)


def obstacle(x: float, y: float, steps: int, at: int) -> S.OtherAgents:
    boxes = np.zeros((1, steps, 5))
    boxes[0, :] = (x, y, 0.0, 0.1, 0.1)
    valid = np.zeros((1, steps), bool)
    valid[0, at] = True
    return S.OtherAgents(boxes=boxes, valid=valid, ids=np.array(["obstacle"]))


def test_a_sample_that_hits_an_agent_before_t_col_does_not_represent_its_cluster():
    trajs = fan([0.0, 0.6, -0.7, 8.0, 8.4, 7.7])
    free = S.select_representatives(trajs, k=2, seed=0, size=(1.0, 0.2))
    hit = S.select_representatives(trajs, k=2, seed=0, size=(1.0, 0.2), others=obstacle(-10.0, 0.0, 5, 0))
    assert [r.rank for r in free] == [0, 0]
    first = next(r for r in free if abs(r.raw[0, 1]) < 1.0)
    assert first.raw[0, 1] == 0.0  # the member closest to the centroid
    instead = next(r for r in hit if abs(r.raw[0, 1]) < 1.0)
    assert instead.raw[0, 1] != 0.0 and len(hit) == 2  # its neighbour stands for the cluster
    # contact at t_col is the point: an obstacle at the last step does not reject
    at_tcol = S.select_representatives(trajs, k=2, seed=0, size=(1.0, 0.2), others=obstacle(0.0, 0.0, 5, 4))
    assert [r.rank for r in at_tcol] == [0, 0] and len(at_tcol) == 2


def test_clusters_are_made_of_usable_samples(vocab):
    """Three samples leave the road: K = 2 clusters of the three that stay on it, not one cluster of
    each kind of which one yields nothing."""
    trajs = fan([0.0, 0.6, -0.7, 8.0, 8.4, 7.7])

    def off_road(x, y, yaw, length, width):
        return y > 5.0

    reps = S.select_representatives(trajs, k=2, seed=0, vocab=vocab, drivable=off_road, size=(4.6, 1.9))
    assert len(reps) == 2 and all(r.refined for r in reps)
    assert len({r.sample_index for r in reps}) == 2 and {r.cluster_size for r in reps} == {1, 2}
    for r in reps:
        assert np.array_equal(r.poses[-1], trajs[r.sample_index, -1])
        assert np.all(r.poses[:, 1] <= 5.0)


def test_with_fewer_usable_samples_than_clusters_all_are_clustered(vocab):
    trajs = fan([0.0, 8.0, 8.4, 7.7])

    def off_road(x, y, yaw, length, width):
        return y > 5.0

    reps = S.select_representatives(trajs, k=2, seed=0, vocab=vocab, drivable=off_road, size=(4.6, 1.9))
    assert len(reps) == 1 and reps[0].sample_index == 0 and reps[0].cluster_size == 1


def test_constant_velocity_goes_straight_back():
    s = AgentState(10.0, 5.0, np.pi / 2, 4.0, 4.5, 1.9)
    out = constant_velocity_backward(s, np.array([-1.0, -0.5, 0.0]))
    np.testing.assert_allclose(out, [[10.0, 1.0, np.pi / 2], [10.0, 3.0, np.pi / 2], [10.0, 5.0, np.pi / 2]],
                               atol=1e-12)


@pytest.mark.parametrize("scene_fn, agent, t_index", [(synthetic.two_lane_road, "sdc", 14),
                                                     (synthetic.four_way_junction, "sdc", 18),
                                                     (synthetic.merge, "sdc", 16)])
def test_constant_lane_reconstructs_lane_following(scene_fn, agent, t_index):
    low = resample(scene_fn(), 2.0)
    a = low.tracks.index_of(agent)
    state = AgentState.from_tracks(low.tracks, a, t_index)
    rel = -0.5 * np.arange(10, -1, -1)
    out = constant_lane_backward(state, rel, low.road_map)
    truth = np.stack([low.tracks.x[a], low.tracks.y[a]], -1)[t_index - 10: t_index + 1]
    assert np.array_equal(out[-1], [state.x, state.y, state.yaw])
    assert np.linalg.norm(out[:, :2] - truth, axis=-1).max() < 0.5


def test_plan_variants_uses_the_models_folder(tmp_path, junction, vocab, model):
    with pytest.raises(InputError, match="train rollout"):
        S.plan_variants(RolloutRequest(junction, 0, None, None, samples=40, variants=3, seed=0,  # type: ignore[arg-type]
                                       models_dir=tmp_path))
    save_checkpoint(model, tmp_path / weights.ROLLOUT)
    vocab.save(tmp_path / weights.VOCAB)
    adv = adversary_near_target(junction, 14)
    snap = CollisionSnapshot(scenario_id="x", target_id="sdc", t_index=14, time=7.0,
                             target=AgentState.from_tracks(junction.tracks, 0, 14), adversary=adv)
    everyone = range(junction.tracks.num_agents)
    plans, xy, info = S.plan_variants(RolloutRequest(junction, 0, snap, None, samples=40, variants=3, seed=0,
                                                     models_dir=tmp_path), exclude=everyone)
    assert xy.shape == (40, 11, 2) and 1 <= len(plans) <= 3
    assert info["vocab_tokens"] == len(vocab) and len(info["representatives"]) == len(plans)
    for p in plans:
        assert (p.x[-1], p.y[-1], p.yaw[-1]) == (adv.x, adv.y, adv.yaw)
        assert p.times[-1] == 7.0 and len(p.times) == 11


def test_crossing_between_two_steps_counts_as_a_hit():
    """At 2 Hz two crossing cars can miss each other at both steps and overlap halfway between."""
    poses = np.zeros((1, 3, 3))
    poses[0, :, 0] = [0.0, 10.0, 20.0]  # along +x at 20 m/s
    boxes = np.zeros((1, 3, 5))
    boxes[0, :, 0] = 5.0
    boxes[0, :, 1] = [-5.0, 5.0, 15.0]  # along +y at 20 m/s, at (5, 0) 0.25 s after the first step
    boxes[0, :, 2] = np.pi / 2
    boxes[0, :, 3:] = (4.0, 1.8)
    crossing = S.OtherAgents(boxes=boxes, valid=np.ones((1, 3), bool), ids=np.array(["x"]))
    assert S._hits_others(crossing, poses, 4.0, 1.8).tolist() == [True]
    later = S.OtherAgents(boxes=boxes, valid=np.array([[True, False, True]]), ids=np.array(["x"]))
    assert S._hits_others(later, poses, 4.0, 1.8).tolist() == [False]  # not there at one end: not checked


def test_hits_others_equals_testing_every_pair():
    """The reach pre-filter only skips pairs that cannot overlap."""
    from coster_sumo.geometry.boxes import boxes_overlap, make_boxes

    rng = np.random.default_rng(5)
    poses = np.concatenate([rng.uniform(-150, 150, (300, 6, 2)), rng.uniform(-np.pi, np.pi, (300, 6, 1))], -1)
    boxes = np.concatenate([rng.uniform(-150, 150, (40, 6, 2)), rng.uniform(-np.pi, np.pi, (40, 6, 1)),
                            rng.uniform(1, 12, (40, 6, 1)), rng.uniform(0.5, 2.6, (40, 6, 1))], -1)
    others = S.OtherAgents(boxes=boxes, valid=rng.random((40, 6)) < 0.8, ids=np.arange(40).astype(str))
    got = S._hits_others(others, poses, 4.6, 1.9)
    dense, dboxes = S._with_midpoints(poses), S._with_midpoints(boxes)
    dvalid = np.repeat(others.valid, 2, axis=1)[:, :-1]
    dvalid[:, 1::2] = others.valid[:, :-1] & others.valid[:, 1:]
    mine = make_boxes(dense[..., 0], dense[..., 1], dense[..., 2], 4.6, 1.9)
    brute = (boxes_overlap(mine[:, None], dboxes[None]) & dvalid[None]).any(axis=(1, 2))
    assert got.tolist() == brute.tolist() and 0 < brute.sum() < len(brute)
