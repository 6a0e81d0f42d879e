"""The traffic prior network: region tokens -> multi-context gating -> independent heads.

Architecture (TrafficGen / MultiPath++ style multi-context gating, MCG):
- token_k = MLP(map part) + MLP(observed-agent part) (see :mod:`coster_sumo.prior.features`);
- the initial context vector c is the masked max-pool of the tokens;
- each of ``num_blocks`` context-gating blocks computes s'_k = s_k + MLP_s(LN(s_k)) * sigmoid(MLP_c(c))
  (every element gated by the one global context) and c' = masked max-pool of s'; the next block
  receives the running mean of all block outputs so far (for s and for c);
- heads are independent MLPs on [s_k, c]: presence (1 logit), position (40 x 40), heading (144),
  speed (1 + 60), length (60), width (40); with ``width_given_length`` the width logits get a
  learned bias per length class (a 60 x 40 table), so a sample's width is drawn given its length:
  p(w | l, token) = softmax(head_w(token) + table[l]). Independent length and width heads made
  vehicles nobody drives (a motorcycle's length with a car's width), most of the samples on some
  held-out networks (models/prior.md).

Loss (per batch): over the query tokens Q (hidden, real regions),
``sum_Q [BCE(presence) + present * (CE_pos + CE_heading + CE_speed + CE_length + CE_width)] / |Q|``,
label smoothing ``label_smoothing`` (0.1) on heading, length and width.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import torch
import torch.nn.functional as F
from torch import nn

from coster_sumo.prior.bins import ATTRIBUTES, AttributeBins
from coster_sumo.prior.features import AGENT_FEATURES, MAP_FEATURES
from coster_sumo.prior.regions import MAX_REGIONS, NEIGHBOURHOOD_RADIUS, REGION_SPACING, REGION_WIDTH

SMOOTHED = ("heading", "length", "width")
LENGTH = ATTRIBUTES.index("length")


@dataclass
class PriorConfig:
    """Everything needed to rebuild the network and its inputs (stored in checkpoints as a dict)."""

    hidden: int = 128
    num_blocks: int = 5
    head_hidden: int = 128
    label_smoothing: float = 0.1
    # inputs
    map_features: int = MAP_FEATURES
    agent_features: int = AGENT_FEATURES
    region_spacing: float = REGION_SPACING  # [m]
    region_width: float = REGION_WIDTH  # [m]
    radius: float = NEIGHBOURHOOD_RADIUS  # [m]
    max_regions: int = MAX_REGIONS
    hide_radius: float = 15.0  # [m] inference "context" mode: regions this close to the target are hidden
    # discretisation (see coster_sumo.prior.bins)
    position_bins: int = 40
    heading_bins: int = 144
    heading_range_rad: float = 0.7853981633974483  # pi / 4
    speed_bins: int = 60
    stopped_speed: float = 0.5
    max_speed: float = 45.0
    length_bins: int = 60
    max_length: float = 15.0
    width_bins: int = 40
    max_width: float = 4.0
    width_given_length: bool = True

    def bins(self) -> AttributeBins:
        names = {f.name for f in fields(AttributeBins)}
        return AttributeBins(**{k: v for k, v in asdict(self).items() if k in names})

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> PriorConfig:
        known = {f.name for f in fields(cls)}
        legacy = {"width_given_length": False}  # stored configs from before the field existed
        return cls(**{**legacy, **{k: v for k, v in d.items() if k in known}})


def _mlp(dims: list[int], last_plain: bool = True) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(dims) - 1):
        layers.append(nn.Linear(dims[i], dims[i + 1]))
        if i < len(dims) - 2 or not last_plain:
            layers += [nn.LayerNorm(dims[i + 1]), nn.ReLU()]
    return nn.Sequential(*layers)


def segment_max(x: torch.Tensor, segment: torch.Tensor, num_segments: int) -> torch.Tensor:
    """(N, D) packed tokens, (N,) int64 sample of each -> (num_segments, D) max per sample
    (0 for a sample without tokens)."""
    out = x.new_zeros(num_segments, x.shape[-1])
    return out.scatter_reduce(0, segment[:, None].expand_as(x), x, reduce="amax", include_self=False)


class ContextGating(nn.Module):
    """One context-gating block: gate every token element by the global context, pool a new context.

    ``s' = s + MLP_s(LN(s)) * sigmoid(MLP_c(c))``, ``c' = max-pool of s'`` over the sample's tokens.
    The residual and the sigmoid gate (instead of a plain product of two MLP outputs) keep a deep
    stack trainable: with the plain product, 5 stacked blocks could not even overfit a 3-sample
    batch in 200 steps. Tokens are packed (no padding): ``segment`` names each token's sample.
    """

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(dim)
        self.token_mlp = _mlp([dim, dim, dim])
        self.context_mlp = _mlp([dim, dim, dim])

    def forward(self, s: torch.Tensor, c: torch.Tensor, segment: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        gate = torch.sigmoid(self.context_mlp(c))  # (B, D)
        s = s + self.token_mlp(self.norm(s)) * gate[segment]  # (N, D)
        return s, segment_max(s, segment, c.shape[0])  # (N, D), (B, D)


class MultiContextGating(nn.Module):
    """Stacked context-gating blocks with a running mean of the block outputs."""

    def __init__(self, dim: int, num_blocks: int) -> None:
        super().__init__()
        self.blocks = nn.ModuleList([ContextGating(dim) for _ in range(num_blocks)])

    def forward(self, s: torch.Tensor, c: torch.Tensor, segment: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        s_sum, c_sum = torch.zeros_like(s), torch.zeros_like(c)
        for i, block in enumerate(self.blocks):
            s_new, c_new = block(s, c, segment)
            s_sum, c_sum = s_sum + s_new, c_sum + c_new
            s, c = s_sum / (i + 1), c_sum / (i + 1)  # running mean
        return s, c


@dataclass
class PriorOutput:
    """Logits per token: presence (B, K); attribute logits (B, K, num_classes) by attribute name.
    With ``width_given_length`` the width entry is the head's own part: the logits of a given
    length class add ``width_table[length class]`` (:meth:`TrafficPrior.attribute_logits`)."""

    presence: torch.Tensor
    attributes: dict[str, torch.Tensor]


class TrafficPrior(nn.Module):
    """Predicts presence and attribute distributions of the query regions."""

    def __init__(self, config: PriorConfig) -> None:
        super().__init__()
        self.config = config
        d = config.hidden
        self.map_proj = _mlp([config.map_features, d, d])
        self.agent_proj = _mlp([config.agent_features, d, d])
        self.mcg = MultiContextGating(d, config.num_blocks)
        n_cls = config.bins().num_classes()
        self.presence_head = _mlp([2 * d, config.head_hidden, 1])
        self.heads = nn.ModuleDict({a: _mlp([2 * d, config.head_hidden, n_cls[a]]) for a in ATTRIBUTES})
        self.width_table = (nn.Parameter(torch.zeros(n_cls["length"], n_cls["width"]))
                            if config.width_given_length else None)

    def attribute_logits(self, h: torch.Tensor, attribute: str, length_class: torch.Tensor | None = None
                         ) -> torch.Tensor:
        """Logits (..., C) of one head on token features (..., 2D); the width head also takes the
        length class (...) int64 when the model draws width given length."""
        logits = self.heads[attribute](h)
        if attribute == "width" and self.width_table is not None:
            if length_class is None:
                raise ValueError("this prior draws width given length: pass the length class")
            logits = logits + self.width_table[length_class]
        return logits

    def encode_packed(self, map_features: torch.Tensor, agent_features: torch.Tensor, mask: torch.Tensor
                      ) -> torch.Tensor:
        """(B, K, Fm), (B, K, Fa), (B, K) bool -> (N, 2D) features [s_k, c] of the N real tokens,
        in ``mask`` order (row-major); padding is never computed."""
        segment = mask.nonzero()[:, 0]  # (N,) sample of each real token
        mf = map_features[mask][:, : self.config.map_features]  # older checkpoints read fewer map features
        tokens = self.map_proj(mf) + self.agent_proj(agent_features[mask])  # (N, D)
        s, c = self.mcg(tokens, segment_max(tokens, segment, mask.shape[0]), segment)
        return torch.cat([s, c[segment]], dim=-1)  # (N, 2D)

    def encode(self, map_features: torch.Tensor, agent_features: torch.Tensor, mask: torch.Tensor
               ) -> torch.Tensor:
        """(B, K, Fm), (B, K, Fa), (B, K) bool -> (B, K, 2D) per-token features (zeros at padding)."""
        h = self.encode_packed(map_features, agent_features, mask)
        out = h.new_zeros(mask.shape + (h.shape[-1],))
        out[mask] = h
        return out

    def decode(self, h: torch.Tensor) -> PriorOutput:
        """Per-token features (..., 2D) -> logits of every head."""
        return PriorOutput(presence=self.presence_head(h)[..., 0],
                           attributes={a: head(h) for a, head in self.heads.items()})

    def forward(self, map_features: torch.Tensor, agent_features: torch.Tensor, mask: torch.Tensor,
                query: torch.Tensor | None = None, present: torch.Tensor | None = None,
                classes: torch.Tensor | None = None) -> tuple[PriorOutput | None, torch.Tensor | None]:
        """Logits for all tokens, or, when targets are given, only the loss.

        Args:
            map_features: (B, K, Fm); agent_features: (B, K, Fa); mask: (B, K) bool real tokens.
            query: (B, K) bool tokens to predict (loss); present: (B, K) bool; classes: (B, K, 5) int64.

        Returns:
            (output, None) without targets; (None, loss) with targets (heads are evaluated only on
            the query tokens, the attribute heads only where present).
        """
        if query is None or present is None or classes is None:
            return self.decode(self.encode(map_features, agent_features, mask)), None
        h = self.encode_packed(map_features, agent_features, mask)  # (N, 2D)
        return None, self.loss(h, query[mask], present[mask], classes[mask])

    def loss(self, h: torch.Tensor, query: torch.Tensor, present: torch.Tensor, classes: torch.Tensor
             ) -> torch.Tensor:
        """Mean over query tokens of BCE(presence) + present * sum of attribute cross-entropies.

        ``h`` (..., 2D) token features with ``query``, ``present`` (...) bool and ``classes`` (..., 5)
        of the same leading shape (packed (N,) or padded (B, K) with padding excluded from ``query``).
        """
        hq = h[query]  # (Q, 2D)
        n = max(int(hq.shape[0]), 1)
        pq = present[query]
        total = F.binary_cross_entropy_with_logits(self.presence_head(hq)[:, 0], pq.float(), reduction="sum")
        hp = hq[pq]  # (P, 2D)
        cp = classes[query][pq]  # (P, 5)
        for i, a in enumerate(ATTRIBUTES):
            smoothing = self.config.label_smoothing if a in SMOOTHED else 0.0
            total = total + F.cross_entropy(self.attribute_logits(hp, a, cp[:, LENGTH]), cp[:, i], reduction="sum",
                                            label_smoothing=smoothing)
        return total / n

    def attribute_losses(self, h: torch.Tensor, query: torch.Tensor, present: torch.Tensor,
                         classes: torch.Tensor) -> dict[str, torch.Tensor]:
        """Per-head summed losses and counts (for metrics): presence BCE over Q, attribute CE
        (without label smoothing) over present query tokens."""
        hq = h[query]
        pq = present[query]
        out = {"presence": F.binary_cross_entropy_with_logits(self.presence_head(hq)[:, 0], pq.float(),
                                                              reduction="sum"),
               "num_query": torch.tensor(float(hq.shape[0])), "num_present": pq.sum().float()}
        hp, cp = hq[pq], classes[query][pq]
        for i, a in enumerate(ATTRIBUTES):
            out[a] = F.cross_entropy(self.attribute_logits(hp, a, cp[:, LENGTH]), cp[:, i], reduction="sum")
        return out
