"""The rollout CVAE: factored attention, shapes, the w/o-DSA flag, overfitting, checkpoints."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from coster_sumo.core.scene import resample
from coster_sumo.data import synthetic
from coster_sumo.errors import InputError
from coster_sumo.rollout import data as D
from coster_sumo.rollout.checkpoint import load_model, save_checkpoint
from coster_sumo.rollout.model import RelativeAttention, RolloutConfig, RolloutCVAE, best_of_error, true_displacements


@pytest.fixture(autouse=True)
def one_thread():
    """Small tensors: one thread is fastest, and on a shared machine two can be 30x slower."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


TINY = dict(hidden=32, heads=4, latent=8, posterior_hidden=16, max_map_chunks=32, max_neighbors=8)


def tiny_config(**kw) -> RolloutConfig:
    return RolloutConfig(**{**TINY, **kw})


def batch_of(scene_fn, cfg: RolloutConfig, rows=None):
    ex = D.build_examples([scene_fn()], cfg, full_only=True)
    rows = np.arange(len(ex)) if rows is None else rows
    t = D.to_tensors(ex.batch(rows, cfg))
    traj, mask = t.pop("traj"), t.pop("step_mask")
    t.pop("origin")
    return t, traj, mask


def test_relative_attention_equals_explicit_per_sample_keys():
    torch.manual_seed(0)
    c, s, m, d, heads, r = 2, 5, 7, 16, 4, 4
    att = RelativeAttention(d, heads, r)
    base, rel = torch.randn(c, m, d), torch.randn(c, m, r)
    query, sample = torch.randn(c, s, d), torch.randn(c, s, r)
    mask = torch.rand(c, s, m) > 0.3
    mask[0, 0] = False  # a sample with nothing to attend to gives zeros
    keys, values = att.keys_values(base, rel)
    got = att(query, keys, values, sample, mask)
    # the textbook version: keys and values of (item - sample) features, built per sample
    kv = att.kv(base)[:, None] + att.kv_rel(rel[:, None] - sample[:, :, None])  # (C, S, M, 2D)
    k, v = kv.chunk(2, -1)
    q = att.q(query)
    dh = d // heads
    qh, kh, vh = (x.reshape(*x.shape[:-1], heads, dh) for x in (q, k, v))
    scores = torch.einsum("cshd,csmhd->cshm", qh, kh) / math.sqrt(dh)
    scores = scores.masked_fill(~mask[:, :, None], float("-inf"))
    w = torch.nan_to_num(torch.softmax(scores, -1))
    want = torch.einsum("cshm,csmhd->cshd", w, vh).reshape(c, s, d)
    assert torch.allclose(got, want, atol=1e-5)
    assert torch.all(got[0, 0] == 0)


@pytest.mark.parametrize("use_dsa", [True, False])
def test_shapes_training_and_sampling(use_dsa):
    cfg = tiny_config(use_dsa=use_dsa)
    ctx, traj, mask = batch_of(synthetic.four_way_junction, cfg)
    model = RolloutCVAE(cfg)
    out = model(ctx, traj, mask)
    c = traj.shape[0]
    assert out.poses.shape == (c, 1, cfg.max_horizon, 3)
    assert out.loss is not None and out.loss.ndim == 0 and torch.isfinite(out.loss)
    out.loss.backward()
    assert all(p.grad is not None for p in model.parameters() if p.requires_grad)
    samples = model.sample(ctx, 7, generator=torch.Generator().manual_seed(0))
    assert samples.shape == (c, 7, cfg.max_horizon, 3)


def test_horizon_adapts_to_the_context():
    cfg = tiny_config()
    low = resample(synthetic.two_lane_road(), 2.0)
    cache = D.build_cache(low, cfg)
    ctx = D.agent_context(cache, 0, 4, 4, cfg)  # t_rev at step 4: only 4 steps back
    arrays = D.stack_contexts([ctx])
    arrays.pop("origin")
    poses = RolloutCVAE(cfg).sample(D.to_tensors(arrays), 3)
    assert poses.shape == (1, 3, 4, 3)


def test_sampling_is_deterministic_per_seed():
    cfg = tiny_config()
    ctx, _, _ = batch_of(synthetic.merge, cfg)
    torch.manual_seed(0)
    model = RolloutCVAE(cfg)
    a = model.sample(ctx, 4, generator=torch.Generator().manual_seed(3))
    b = model.sample(ctx, 4, generator=torch.Generator().manual_seed(3))
    c = model.sample(ctx, 4, generator=torch.Generator().manual_seed(4))
    assert torch.equal(a, b) and not torch.equal(a, c)


def test_without_dsa_only_the_t_rev_neighbours_matter():
    torch.manual_seed(0)
    cfg = tiny_config()
    ctx, _, _ = batch_of(synthetic.two_lane_road, cfg, rows=np.arange(2))
    dsa = RolloutCVAE(cfg)
    no_dsa = RolloutCVAE(tiny_config(use_dsa=False))
    no_dsa.load_state_dict(dsa.state_dict())  # same weights: the flag alone changes the computation
    moved = dict(ctx)
    nbr = ctx["nbr"].clone()
    nbr[:, 1:, :, :2] += 0.3  # neighbours 6 m elsewhere at every step before t_rev
    moved["nbr"] = nbr

    def run(model, c):
        return model.sample(c, 3, generator=torch.Generator().manual_seed(0))

    assert not torch.allclose(run(dsa, ctx), run(no_dsa, ctx))
    assert not torch.allclose(run(dsa, ctx), run(dsa, moved))
    assert torch.equal(run(no_dsa, ctx), run(no_dsa, moved))


def test_true_displacements_compose_back_to_the_poses():
    traj = torch.tensor([[[-5.0, 0.2, 0.1], [-9.0, 1.0, 0.3], [-12.0, 2.5, 0.6]]])
    d = true_displacements(traj)
    x = y = yaw = torch.zeros(1)
    for k in range(3):
        c, s = torch.cos(yaw), torch.sin(yaw)
        x, y = x + c * d[0, k, 0] - s * d[0, k, 1], y + s * d[0, k, 0] + c * d[0, k, 1]
        yaw = yaw + d[0, k, 2]
        assert torch.allclose(torch.stack([x, y, yaw], -1)[0], traj[0, k], atol=1e-5)


def test_overfits_a_tiny_batch():
    torch.manual_seed(0)
    cfg = tiny_config()
    ctx, traj, mask = batch_of(synthetic.four_way_junction, cfg, rows=np.arange(4))
    model = RolloutCVAE(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    first = None
    for _ in range(60):
        out = model(ctx, traj, mask)
        assert out.loss is not None
        first = float(out.loss.detach()) if first is None else first
        opt.zero_grad()
        out.loss.backward()
        opt.step()
    assert out.loss is not None and float(out.loss.detach()) < 0.05 * first
    err = (out.poses[:, 0, :, :2] - traj[..., :2]).norm(dim=-1)[mask]
    assert float(err.detach().mean()) < 0.5  # [m] posterior reconstruction of the training batch


def test_best_of_error_by_hand():
    # one context, two samples, three steps of which the first two are valid
    traj = torch.zeros(1, 3, 3)
    poses = torch.zeros(1, 2, 3, 3)
    poses[0, 0, :, 0] = torch.tensor([3.0, 4.0, 100.0])  # errors 3, 4 (the third step is invalid)
    poses[0, 1, :, 1] = torch.tensor([1.0, 6.0, 0.0])  # errors 1, 6
    mask = torch.tensor([[True, True, False]])
    # sample 0: mean 3.5 + last valid 4 = 7.5; sample 1: 3.5 + 6 = 9.5
    assert best_of_error(poses, traj, mask).tolist() == [7.5]


def test_best_of_term_joins_the_training_loss_only():
    cfg = tiny_config()
    ctx, traj, mask = batch_of(synthetic.four_way_junction, cfg, rows=np.arange(4))
    torch.manual_seed(0)
    plain = RolloutCVAE(cfg)
    best = RolloutCVAE(tiny_config(best_of=3, best_of_weight=2.0))
    best.load_state_dict(plain.state_dict())
    torch.manual_seed(1)
    lp = plain(ctx, traj, mask).loss
    torch.manual_seed(1)
    lb = best(ctx, traj, mask).loss
    assert lp is not None and lb is not None
    # the same ELBO draw (the posterior noise comes first), then a positive best-of term
    assert float(lb.detach()) > float(lp) + 1e-3
    lb.backward()
    assert all(p.grad is not None for p in best.parameters() if p.requires_grad)
    best.eval()
    torch.manual_seed(1)
    assert float(best(ctx, traj, mask).loss) == pytest.approx(float(lp), rel=1e-6)
    # a default config stores no best-of keys: checkpoints and their config dicts stay as they were
    assert "best_of" not in cfg.to_dict() and best.cfg.to_dict()["best_of"] == 3


def test_checkpoint_round_trip(tmp_path):
    torch.manual_seed(0)
    cfg = tiny_config(use_dsa=False)
    model = RolloutCVAE(cfg)
    path = save_checkpoint(model, tmp_path / "r.pt", meta={"epochs": 1})
    loaded = load_model(path)
    assert loaded.cfg == cfg and not loaded.training
    for k, v in model.state_dict().items():
        assert torch.equal(v, loaded.state_dict()[k])


def _one_line(exc: pytest.ExceptionInfo) -> str:
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


@pytest.mark.parametrize("case", ["missing", "garbage", "other_format", "unknown_key", "wrong_shape", "pickle"])
def test_bad_or_mismatched_checkpoint_is_one_clear_error(tmp_path, case):
    path = tmp_path / "bad.pt"
    cfg = tiny_config()
    good = {"format": "coster-sumo-rollout", "version": 1, "config": cfg.to_dict(),
            "state_dict": RolloutCVAE(cfg).state_dict(), "meta": {}}
    if case == "garbage":
        path.write_bytes(b"not a checkpoint at all")
    elif case == "other_format":
        torch.save({"format": "coster-sumo-prior", "state_dict": {}}, path)
    elif case == "unknown_key":
        torch.save({**good, "config": {**cfg.to_dict(), "future_option": 1}}, path)
    elif case == "wrong_shape":
        torch.save({**good, "config": tiny_config(hidden=48).to_dict()}, path)
    elif case == "pickle":
        torch.save({**good, "meta": {"obj": object}}, path)  # needs unpickling code: refused
    with pytest.raises(InputError) as exc:
        load_model(path)
    assert str(path) in _one_line(exc)
