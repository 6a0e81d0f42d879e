"""The time-reversed CVAE (docs/method.md step 5): :class:`RolloutConfig` and :class:`RolloutCVAE`.

Inputs are contexts built by :mod:`coster_sumo.rollout.data` (the reconstructed vehicle's frame at
t_rev); tensors carry two leading axes, contexts ``C`` (agents, scenes) and samples ``S`` per
context, so that training (C = batch, S = 1), evaluation (C = agents, S = 5) and oversampling one
snapshot (C = 1, S = 1000) run the same batched code without Python loops over samples.

Architecture:

- **first hidden state** ``h0``: the state embedding, joined to a cross-attention from it to the map
  chunks (PointNet-style polyline encoder) and to the neighbours at t_rev;
- **each reverse step** ``k = 1..H``: conditional prior ``p(z_k | h)``; during training the
  posterior ``q(z_k | g_k, h)``, ``g_k`` the output at step k of a GRU run from the far end of the
  true reverse segment back to step k (it summarises steps k..H); the decoder maps ``(h, z_k)`` to
  the reverse displacement ``(dx, dy, dyaw)`` in the body frame of the current pose, as a
  correction to a constant-velocity step (an untrained decoder continues the current motion);
- **dynamic surrounding attention (DSA)**: at every step, attention from ``h`` (plus the new state
  embedding) to the neighbours at that step, with keys and values from their positions and
  velocities relative to the sample's new pose; joined (summed: the parts end in free linear maps,
  so this is as expressive as a concatenation at a third of the cost) to the new state embedding and a
  per-step map attention (``map_every_step``), it updates ``h`` through a GRU cell. ``use_dsa=False`` (the
  "w/o DSA" ablation) feeds the t_rev neighbour attention at every step instead: neighbours are
  seen only as they were at t_rev.

Cost (docs/method.md, "Where the rollout's time goes"): keys and values are linear in
``(item - sample)`` features, so the item part is projected once per context (map: once; neighbours:
once per step, all steps before the loop) and the sample part drops out of the softmax and is
subtracted once from the weighted values (:class:`RelativeAttention`); no ``(S, items, D)`` tensor
is ever built. The map encoder and the key/value projections run on real map chunks and
neighbour slots only (:func:`packed`; padding is masked anyway), which about halves the cost of a
training step; the forward pass gives the same numbers as computing them for every slot.

Loss: the negative ELBO averaged over valid steps: Gaussian reconstruction of the displacement
(fixed ``recon_sigma``) plus ``kl_weight`` times the per-step KL(q || p); with ``best_of`` K, plus
the best of K prior samples' errors (:func:`best_of_error`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from coster_sumo.rollout.config import RolloutConfig
from coster_sumo.rollout.data import (
    MAP_ATTR_FEATURES,
    MAP_POS_FEATURES,
    MAP_VEC_FEATURES,
    NBR_FEATURES,
    REL_FEATURES,
    ROLLOUT_HZ,
    STATE_FEATURES,
)

DT = 1.0 / ROLLOUT_HZ  # [s]
STEP_FEATURES = 9  # x, y, cos, sin, vx, vy, normalised correction (3)
POSTERIOR_FEATURES = 7  # x, y, cos, sin, displacement / POSTERIOR_DISP_SCALE (3)
POSTERIOR_DISP_SCALE = (5.0, 0.5, 0.1)  # [m, m, rad]
_MASKED = -1e9


def mlp(d_in: int, d_hidden: int, d_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(d_in, d_hidden), nn.ReLU(), nn.Linear(d_hidden, d_out))


class RelativeAttention(nn.Module):
    """Multi-head attention from per-sample queries to items shared by all samples of a context.

    An item's key and value are ``W base_j + U (rel_j - s)``: ``base_j`` (D) an item embedding,
    ``rel_j`` (R) its relative features (position, velocity) and ``s`` (R) the same features of
    the sample. ``U s`` is constant over items: it drops out of the softmax and, since the weights
    sum to one, is subtracted once from the weighted values. :meth:`keys_values` runs once per
    context (per step for neighbours, before the loop); :meth:`forward` costs two (S x items)
    matrix products per head.
    """

    def __init__(self, dim: int, heads: int, rel_dim: int) -> None:
        super().__init__()
        self.dim, self.heads = dim, heads
        self.q = nn.Linear(dim, dim)
        self.kv = nn.Linear(dim, 2 * dim)
        self.kv_rel = nn.Linear(rel_dim, 2 * dim, bias=False)

    def project(self, base: Tensor, rel: Tensor) -> tuple[Tensor, Tensor]:
        """base (..., D), rel (..., R) -> flat keys and values (..., D) each: ``kv(base) + kv_rel(rel)``
        computed per half (no chunking, whose gradient would be a concatenation), with the same
        products and sums as the whole, so that sampling gives the same numbers as before."""
        d = self.dim
        w, w_rel, b = self.kv.weight, self.kv_rel.weight, self.kv.bias
        return (F.linear(base, w[:d], b[:d]) + F.linear(rel, w_rel[:d]),
                F.linear(base, w[d:], b[d:]) + F.linear(rel, w_rel[d:]))

    def keys_values(self, base: Tensor, rel: Tensor) -> tuple[Tensor, Tensor]:
        """base (..., M, D), rel (..., M, R) -> keys (..., heads, dh, M), values (..., heads, M, dh)."""
        return self.split(*self.project(base, rel))

    def split(self, k: Tensor, v: Tensor) -> tuple[Tensor, Tensor]:
        """Flat keys and values (..., M, D) from :meth:`project` -> keys (..., heads, dh, M), values
        (..., heads, M, dh)."""
        lead, m = k.shape[:-2], k.shape[-2]
        dh = self.dim // self.heads
        keys = k.reshape(*lead, m, self.heads, dh).permute(*range(len(lead)), -2, -1, -3)
        values = v.reshape(*lead, m, self.heads, dh).transpose(-3, -2)
        return keys, values

    def forward(self, query: Tensor, keys: Tensor, values: Tensor, sample_rel: Tensor, mask: Tensor) -> Tensor:
        """Attend.

        Args:
            query: (C, S, D) per-sample queries.
            keys: (C, heads, dh, M); values: (C, heads, M, dh) from :meth:`keys_values`.
            sample_rel: (C, S, R) the sample's relative features.
            mask: (C, S, M) or (C, 1, M) bool, True = attend.

        Returns:
            (C, S, D) the heads' weighted values, concatenated; zero where a sample has no item to
            attend to. There is no output projection: every caller feeds the result to a linear layer
            (the GRU cell's input weights, an MLP), which absorbs it.
        """
        c, s, d = query.shape
        dh = d // self.heads
        q = (self.q(query) * (1.0 / math.sqrt(dh))).view(c, s, self.heads, dh).transpose(1, 2)  # (C, h, S, dh)
        scores = torch.matmul(q, keys)  # (C, h, S, M)
        if mask.shape[1] == 1:  # one mask for all samples: an additive bias is cheaper than a fill
            bias = torch.zeros(mask.shape, dtype=scores.dtype, device=scores.device).masked_fill(~mask, _MASKED)
            scores.add_(bias[:, None])
        else:
            scores.masked_fill_(~mask[:, None], _MASKED)
        attn = torch.softmax(scores, dim=-1)
        o = torch.matmul(attn, values).transpose(1, 2).reshape(c, s, d)  # (C, S, D)
        o = o - F.linear(sample_rel, self.kv_rel.weight[d:])  # the sample's share of every value
        any_item = mask.any(dim=-1, keepdim=True).to(o.dtype)  # (C, S or 1, 1)
        return o * any_item


class MapEncoder(nn.Module):
    """PointNet-style chunk encoder: per-vector MLP, max-pool over the chunk, MLP with attributes."""

    def __init__(self, dim: int) -> None:
        super().__init__()
        half = dim // 2
        self.vec = mlp(MAP_VEC_FEATURES, half, half)
        self.chunk = mlp(half + MAP_ATTR_FEATURES, dim, dim)

    def forward(self, map_vec: Tensor, vec_mask: Tensor, attr: Tensor) -> Tensor:
        """map_vec (C, M, P, 6), vec_mask (C, M, P), attr (C, M, 9) -> (C, M, D)."""
        v = self.vec(map_vec).masked_fill(~vec_mask[..., None], _MASKED)  # (C, M, P, D/2)
        pooled = v.max(dim=-2).values
        pooled = torch.where(vec_mask.any(-1, keepdim=True), pooled, torch.zeros_like(pooled))
        return self.chunk(torch.cat([pooled, attr], dim=-1))


@dataclass
class Encoded:
    """Everything computed once per context before the step loop.

    Attributes:
        h0: (C, D) first hidden state.
        map_kv: keys (C, h, dh, M), values (C, h, M, dh) of the per-step map attention (or None).
        map_mask: (C, 1, M) bool.
        nbr_kv: per step k = 0..H, keys (C, h, dh, N) and values (C, h, N, dh) (None without DSA).
        nbr_xy: (C, H+1, N, 2) [pos_scale] neighbour positions; nbr_mask: (C, H+1, N).
        static_nbr: (C, D) neighbour attention at t_rev (the w/o-DSA input at every step).
        speed: (C,) [m/s] speed at t_rev.
    """

    h0: Tensor
    map_kv: tuple[Tensor, Tensor] | None
    map_mask: Tensor
    nbr_kv: tuple[tuple[Tensor, ...], tuple[Tensor, ...]] | None
    nbr_xy: Tensor
    nbr_mask: Tensor
    static_nbr: Tensor
    speed: Tensor


@dataclass
class RolloutOutput:
    """Result of :meth:`RolloutCVAE.forward`.

    Attributes:
        poses: (C, S, H, 3) x, y [m], yaw [rad] at reverse steps 1..H in the t_rev frame.
        loss: scalar negative ELBO per valid step (None without targets); recon, kl: its parts.
    """

    poses: Tensor
    loss: Tensor | None = None
    recon: Tensor | None = None
    kl: Tensor | None = None


def _gaussian_kl(mu_q: Tensor, lv_q: Tensor, mu_p: Tensor, lv_p: Tensor) -> Tensor:
    """KL(N(mu_q, exp lv_q) || N(mu_p, exp lv_p)) summed over the last axis."""
    return 0.5 * (lv_p - lv_q + (lv_q.exp() + (mu_q - mu_p) ** 2) / lv_p.exp() - 1.0).sum(-1)


def best_of_error(poses: Tensor, traj: Tensor, step_mask: Tensor) -> Tensor:
    """(C,) the smallest over S samples of (mean distance over the valid steps + distance at the last
    valid step) [m], for sampled ``poses`` (C, S, H, 3), true ``traj`` (C, H, 3), ``step_mask`` (C, H)
    (valid steps form a prefix)."""
    gap = (poses[..., :2] - traj[:, None, :, :2]).norm(dim=-1)  # (C, S, H)
    m = step_mask[:, None, :].to(gap.dtype)
    n = step_mask.sum(-1).clamp(min=1)  # (C,)
    ade = (gap * m).sum(-1) / n[:, None]
    fde = gap.gather(-1, (n - 1)[:, None, None].expand(-1, gap.shape[1], 1)).squeeze(-1)
    return (ade + fde).min(dim=1).values


def true_displacements(traj: Tensor) -> Tensor:
    """(C, H, 3) true poses at reverse steps 1..H -> (C, H, 3) displacements, each in the body frame
    of the previous pose (pose 0 is the origin)."""
    prev = torch.cat([torch.zeros_like(traj[:, :1]), traj[:, :-1]], dim=1)
    dxy = traj[..., :2] - prev[..., :2]
    c, s = torch.cos(prev[..., 2]), torch.sin(prev[..., 2])
    dx = c * dxy[..., 0] + s * dxy[..., 1]
    dy = -s * dxy[..., 0] + c * dxy[..., 1]
    dyaw = torch.atan2(torch.sin(traj[..., 2] - prev[..., 2]), torch.cos(traj[..., 2] - prev[..., 2]))
    return torch.stack([dx, dy, dyaw], dim=-1)


def _used_prefix(mask: Tensor, dim: int) -> int:
    """1 + the last index along ``dim`` where any entry of ``mask`` is True (0 if none)."""
    other = tuple(i for i in range(mask.dim()) if i != dim % mask.dim())
    used = mask.any(dim=other) if other else mask
    idx = torch.nonzero(used)
    return int(idx.max()) + 1 if len(idx) else 0


def trim_padding(ctx: dict[str, Tensor]) -> dict[str, Tensor]:
    """Drop map chunks and neighbour slots that are padding in every context (fewer items to
    attend to at every step; the result is the same)."""
    out = dict(ctx)
    m = max(1, _used_prefix(ctx["map_mask"], 1))
    for k in ("map_vec", "map_vec_mask", "map_attr", "map_pos", "map_mask"):
        out[k] = ctx[k][:, :m]
    n = max(1, _used_prefix(ctx["nbr_mask"], 2))
    out["nbr"] = ctx["nbr"][:, :, :n]
    out["nbr_mask"] = ctx["nbr_mask"][:, :, :n]
    return out


def packed(mask: Tensor, fn: Callable[..., tuple[Tensor, ...]], *inputs: Tensor) -> list[Tensor]:
    """``fn`` applied to the rows of ``inputs`` (each ``(*mask.shape, ...)``) where ``mask`` is True
    only; each of its outputs (rows, width) scattered back into zeros ``(*mask.shape, width)``:
    padding items cost nothing. Every caller masks the padding rows afterwards, so what they hold
    does not matter."""
    idx = mask.reshape(-1).nonzero().squeeze(1)
    rows = [x.reshape(mask.numel(), *x.shape[mask.dim():])[idx] for x in inputs]
    return [out.new_zeros(mask.numel(), out.shape[-1]).index_copy_(0, idx, out).view(*mask.shape, out.shape[-1])
            for out in fn(*rows)]


class RolloutCVAE(nn.Module):
    """The time-reversed CVAE with dynamic surrounding attention (see the module docstring)."""

    disp_scale: Tensor  # (3,) buffers, see __init__
    recon_sigma: Tensor

    def __init__(self, cfg: RolloutConfig) -> None:
        super().__init__()
        self.cfg = cfg
        d, z = cfg.hidden, cfg.latent
        self.state_enc = mlp(STATE_FEATURES, d, d)
        self.map_enc = MapEncoder(d)
        self.map_attn0 = RelativeAttention(d, cfg.heads, MAP_POS_FEATURES)
        self.nbr_enc = mlp(NBR_FEATURES, d, d)
        self.nbr_attn = RelativeAttention(d, cfg.heads, REL_FEATURES)
        self.h0_net = mlp(3 * d, d, d)
        self.map_attn = RelativeAttention(d, cfg.heads, MAP_POS_FEATURES) if cfg.map_every_step else None
        self.step_enc = nn.Linear(STEP_FEATURES, d)  # the GRU that follows supplies the non-linearity
        self.cell = nn.GRUCell(d, d)
        self.prior = mlp(d, d // 2, 2 * z)
        self.post_rnn = nn.GRU(POSTERIOR_FEATURES, cfg.posterior_hidden, batch_first=True)
        self.posterior = mlp(d + cfg.posterior_hidden, d, 2 * z)
        self.decoder = mlp(d + z, d // 2, 3)
        self.register_buffer("disp_scale", torch.tensor(cfg.disp_scale, dtype=torch.float32), persistent=False)
        self.register_buffer("recon_sigma", torch.tensor(cfg.recon_sigma, dtype=torch.float32), persistent=False)

    # ------------------------------------------------------------------ encoding

    @property
    def device(self) -> torch.device:
        """Where the weights are (the inputs go there too)."""
        return self.disp_scale.device

    def encode(self, ctx: dict[str, Tensor]) -> Encoded:
        """Map embedding, neighbour keys/values for every step and ``h0`` (once per context)."""
        cfg = self.cfg
        ctx = trim_padding(ctx)
        state = ctx["state"]  # (C, 4)
        c = state.shape[0]
        speed = state[:, 0] * cfg.vel_scale_mps
        s_emb = self.state_enc(state)  # (C, D)
        # map chunks: the encoder and the keys/values of both map attentions on real chunks only
        map_attns = [self.map_attn0] + ([self.map_attn] if self.map_attn is not None else [])

        def chunk_kv(vec: Tensor, vec_mask: Tensor, attr: Tensor, pos: Tensor) -> tuple[Tensor, ...]:
            chunks = self.map_enc(vec, vec_mask, attr)  # (K, D)
            return tuple(t for a in map_attns for t in a.project(chunks, pos))

        # (C, M, D) keys and values of each map attention
        map_all = packed(ctx["map_mask"], chunk_kv, ctx["map_vec"], ctx["map_vec_mask"], ctx["map_attr"],
                         ctx["map_pos"])
        map_mask = ctx["map_mask"][:, None, :]  # (C, 1, M)
        mk, mv = self.map_attn0.split(map_all[0], map_all[1])
        origin_rel = state.new_zeros(c, 1, MAP_POS_FEATURES)
        m0 = self.map_attn0(s_emb[:, None], mk, mv, origin_rel, map_mask)[:, 0]  # (C, D)
        nbr, nbr_mask = ctx["nbr"], ctx["nbr_mask"]  # (C, H+1, N, 12), (C, H+1, N)
        nbr_xy = nbr[..., :2]
        steps = nbr if cfg.use_dsa else nbr[:, :1]  # without DSA only t_rev is ever attended
        steps_mask = nbr_mask if cfg.use_dsa else nbr_mask[:, :1]
        # step-major (H+1, C, N, D) keys and values, real neighbour slots only; then one contiguous
        # slice per step (indexing the stacked tensor at every step would cost a full-size zero
        # gradient each)
        nbr_all = packed(steps_mask.transpose(0, 1),
                         lambda x: self.nbr_attn.project(self.nbr_enc(x), x[:, :REL_FEATURES]), steps.transpose(0, 1))
        nk, nv = self.nbr_attn.split(nbr_all[0], nbr_all[1])
        nk_steps, nv_steps = nk.contiguous().unbind(0), nv.contiguous().unbind(0)
        # the neighbours at t_rev, seen from the origin with the t_rev velocity
        rel0 = torch.stack([torch.zeros_like(speed), torch.zeros_like(speed), speed / cfg.vel_scale_mps,
                            torch.zeros_like(speed)], -1)[:, None]  # (C, 1, 4)
        near0 = nbr_mask[:, 0] & (nbr_xy[:, 0].norm(dim=-1) * cfg.pos_scale_m <= cfg.neighbor_radius_m)
        static = self.nbr_attn(s_emb[:, None], nk_steps[0], nv_steps[0], rel0, near0[:, None])[:, 0]  # (C, D)
        h0 = self.h0_net(torch.cat([s_emb, m0, static], dim=-1))
        map_kv = None
        if self.map_attn is not None:  # used at every step: contiguous once, not copied per step
            keys, values = self.map_attn.split(map_all[2], map_all[3])
            map_kv = (keys.contiguous(), values.contiguous())
        nbr_kv = (nk_steps, nv_steps) if cfg.use_dsa else None
        return Encoded(h0=h0, map_kv=map_kv, map_mask=map_mask, nbr_kv=nbr_kv,
                       nbr_xy=nbr_xy, nbr_mask=nbr_mask, static_nbr=static, speed=speed)

    def posterior_summary(self, traj: Tensor, disp: Tensor) -> Tensor:
        """g: (C, H, Dg), g_k summarising the true reverse segment from step k to H."""
        cfg = self.cfg
        feats = torch.cat([traj[..., :2] / cfg.pos_scale_m, torch.cos(traj[..., 2:]), torch.sin(traj[..., 2:]),
                           disp / disp.new_tensor(POSTERIOR_DISP_SCALE)], dim=-1)  # (C, H, 7)
        out, _ = self.post_rnn(feats.flip(1))
        return out.flip(1)

    # ------------------------------------------------------------------ decoding

    def rollout(self, enc: Encoded, num_samples: int, eps: Tensor, g: Tensor | None = None,
                temperature: float = 1.0) -> tuple[Tensor, Tensor, Tensor | None]:
        """Unroll H reverse steps for S samples per context.

        Args:
            enc: from :meth:`encode`.
            num_samples: S.
            eps: (H, C, S, Z) standard normal noise of the latents.
            g: (C, H, Dg) posterior summaries (training) or None (sampling from the prior).
            temperature: scales the prior's standard deviation when sampling.

        Returns:
            poses (C, S, H, 3), displacements (C, S, H, 3) [m, m, rad], KL per step (C, S, H) or None.

        The decoder predicts a correction to a constant-velocity step: the displacement is
        ``(-v dt, 0, 0) + disp_scale * output`` with ``v`` the speed of the previous step (at t_rev
        the snapshot's speed), so that an untrained decoder already continues the current motion.
        """
        cfg = self.cfg
        c, d = enc.h0.shape
        s = num_samples
        horizon = eps.shape[0]
        h = enc.h0[:, None, :].expand(c, s, d)  # (C, S, D)
        # the pose is integrated in float32 whatever the layers compute in (bfloat16 under autocast
        # has 8 bits of mantissa: 0.5 m steps at 100 m), and so are the latent statistics and the KL
        x = h.new_zeros(c, s, dtype=torch.float32)
        y = h.new_zeros(c, s, dtype=torch.float32)
        yaw = h.new_zeros(c, s, dtype=torch.float32)
        vx = enc.speed[:, None].expand(c, s).float()
        v_long = vx  # [m/s] forward speed along the body axis, for the constant-velocity step
        vy = h.new_zeros(c, s, dtype=torch.float32)
        static = enc.static_nbr[:, None, :].expand(c, s, d)
        poses, disps, kls = [], [], []
        g_steps = g.unbind(1) if g is not None else None
        nbr_k, nbr_v = enc.nbr_kv if enc.nbr_kv is not None else (None, None)
        for k in range(horizon):
            mu_p, lv_p = self.prior(h).float().chunk(2, dim=-1)
            lv_p = lv_p.clamp(-8.0, 8.0)
            if g_steps is not None:
                gk = g_steps[k][:, None, :].expand(c, s, g_steps[k].shape[-1])
                mu_q, lv_q = self.posterior(torch.cat([h, gk], dim=-1)).float().chunk(2, dim=-1)
                lv_q = lv_q.clamp(-8.0, 8.0)
                z = mu_q + torch.exp(0.5 * lv_q) * eps[k]
                kls.append(_gaussian_kl(mu_q, lv_q, mu_p, lv_p))
            else:
                z = mu_p + temperature * torch.exp(0.5 * lv_p) * eps[k]
            dn = self.decoder(torch.cat([h, z.to(h.dtype)], dim=-1)).float()  # (C, S, 3) normalised
            dsp = dn * self.disp_scale
            dsp = torch.cat([dsp[..., :1] - v_long[..., None] * DT, dsp[..., 1:]], dim=-1)
            v_long = -dsp[..., 0] / DT
            cy, sy = torch.cos(yaw), torch.sin(yaw)
            nx = x + cy * dsp[..., 0] - sy * dsp[..., 1]
            ny = y + sy * dsp[..., 0] + cy * dsp[..., 1]
            yaw = yaw + dsp[..., 2]
            vx, vy = (x - nx) / DT, (y - ny) / DT  # forward-in-time velocity at the new pose
            x, y = nx, ny
            poses.append(torch.stack([x, y, yaw], dim=-1))
            disps.append(dsp)
            px, py = x / cfg.pos_scale_m, y / cfg.pos_scale_m
            pvx, pvy = vx / cfg.vel_scale_mps, vy / cfg.vel_scale_mps
            e = self.step_enc(torch.cat([torch.stack([px, py, torch.cos(yaw), torch.sin(yaw), pvx, pvy], -1), dn],
                                        dim=-1))  # (C, S, D)
            query = h + e
            if nbr_k is not None and nbr_v is not None:
                nk, nv = nbr_k[k + 1], nbr_v[k + 1]
                sxy = torch.stack([px, py], -1)  # (C, S, 2)
                gap = torch.cdist(sxy, enc.nbr_xy[:, k + 1]) * cfg.pos_scale_m  # (C, S, N)
                mask = enc.nbr_mask[:, k + 1, None, :] & (gap <= cfg.neighbor_radius_m)
                a_n = self.nbr_attn(query, nk, nv, torch.stack([px, py, pvx, pvy], -1), mask)
            else:
                a_n = static
            # joined by a sum: the GRU's input weights act on it linearly, as they would on the
            # concatenation, at a third of the cost (the parts' last layers are free linear maps)
            joined = e + a_n
            if self.map_attn is not None and enc.map_kv is not None:
                rel = torch.stack([px, py, px, py], -1)
                joined = joined + self.map_attn(query, enc.map_kv[0], enc.map_kv[1], rel, enc.map_mask)
            h = self.cell(joined.reshape(c * s, d), h.reshape(c * s, d)).view(c, s, d)
        kl = torch.stack(kls, dim=-1) if kls else None
        return torch.stack(poses, dim=2), torch.stack(disps, dim=2), kl

    # ------------------------------------------------------------------ API

    def forward(self, ctx: dict[str, Tensor], traj: Tensor | None = None, step_mask: Tensor | None = None,
                num_samples: int = 1, generator: torch.Generator | None = None,
                temperature: float = 1.0) -> RolloutOutput:
        """With ``traj`` (C, H, 3) and ``step_mask`` (C, H): posterior rollout and the loss.
        Without: ``num_samples`` prior samples per context (horizon = ``ctx["nbr"].shape[1] - 1``)."""
        enc = self.encode(ctx)
        c = enc.h0.shape[0]
        horizon = ctx["nbr"].shape[1] - 1 if traj is None else traj.shape[1]
        # drawn on the generator's device (a seeded CPU generator gives the same noise wherever the
        # model runs), then moved to the model's
        eps = torch.randn(horizon, c, num_samples, self.cfg.latent, generator=generator,
                          device=generator.device if generator is not None else enc.h0.device,
                          dtype=torch.float32).to(enc.h0.device)
        if traj is None:
            poses, _, _ = self.rollout(enc, num_samples, eps, temperature=temperature)
            return RolloutOutput(poses=poses)
        if step_mask is None:
            step_mask = torch.ones(traj.shape[:2], dtype=torch.bool, device=traj.device)
        disp = true_displacements(traj)  # (C, H, 3)
        g = self.posterior_summary(traj, disp)
        poses, dsp, kl = self.rollout(enc, num_samples, eps, g=g)
        assert kl is not None
        err = (dsp - disp[:, None]) / self.recon_sigma  # (C, S, H, 3)
        recon = 0.5 * (err**2).sum(-1)  # (C, S, H)
        kl_pen = kl.clamp(min=self.cfg.free_nats) if self.cfg.free_nats > 0 else kl
        w = step_mask[:, None, :].to(recon.dtype).expand_as(recon)
        denom = w.sum().clamp(min=1.0)
        rec = (recon * w).sum() / denom
        kl_mean = (kl * w).sum() / denom
        loss = ((recon + self.cfg.kl_weight * kl_pen) * w).sum() / denom
        if self.training and self.cfg.best_of > 0:
            eps_p = torch.randn(horizon, c, self.cfg.best_of, self.cfg.latent, device=enc.h0.device)
            prior_poses, _, _ = self.rollout(enc, self.cfg.best_of, eps_p)
            loss = loss + self.cfg.best_of_weight * best_of_error(prior_poses, traj, step_mask).mean()
        return RolloutOutput(poses=poses, loss=loss, recon=rec.detach(), kl=kl_mean.detach())

    @torch.inference_mode()
    def sample(self, ctx: dict[str, Tensor], num_samples: int, generator: torch.Generator | None = None,
               temperature: float = 1.0) -> Tensor:
        """(C, S, H, 3) prior samples in each context's t_rev frame (reverse steps 1..H)."""
        return self.forward(ctx, num_samples=num_samples, generator=generator, temperature=temperature).poses
