"""Evaluation of the prior against ground truth and two baselines.

Samples: every step of every evaluated scene (at 2 Hz), centred on the scene's target
(``sdc_index``) where it is a valid vehicle, otherwise on a random valid vehicle of that step
(seeded). All regions of a neighbourhood are hidden ("map" mode: map and signals only), so the
model and the baselines generate the whole neighbourhood's traffic from the same information.

Generation: per region, presence ~ Bernoulli(p); for present ones every attribute is drawn from
its categorical head and decoded to its bin centre. Ground truth: the agents assigned to the
regions, with their exact attributes.

MMD (per attribute, per scene, then averaged over scenes where both sets are non-empty): samples
are pooled over the scene's steps, in the centre agent's frame: position (x, y) [m], heading as
(cos, sin) of the heading relative to the centre, speed [m/s], size (length, width) [m]. One
Gaussian kernel exp(-|a - b|^2 / h) with h = mean pairwise squared distance of the pooled samples;
biased estimate mean(K_xx) + mean(K_yy) - 2 mean(K_xy) by default. Its diagonal terms add about
1/n + 1/m, so with a few samples per scene a method that draws more agents scores lower whatever
they look like. ``mmd_estimator="unbiased"`` leaves the diagonals out (the U-statistic) and scores
a scene only where the truth and every method have at least two samples, so that all methods are
averaged over the same scenes.

MMD in the hidden disc (``mmd_hidden_disc``): the same four MMDs over the regions "context" mode
predicts (within the hide radius of the centre agent, the traffic beyond it given), the prior's
draws against the agents that were there; the baselines draw those regions from their map
buckets, as in map mode (they have no way to see the traffic around). This is the use the
snapshot makes of the prior.

Agents per scene: generated (Bernoulli draws of every region's presence) against the ground truth,
in "map" mode for the model and the baselines; and, for the model in "context" mode (the traffic
beyond the hide radius given, as the snapshot uses it), the agents drawn in the hidden disc
against those that were there (``agents_in_hidden_disc``). Map mode has only the map and the
signals: how busy a network is depends on its demand, which no map shows; the context count says
whether the prior reads that from the traffic around. Context mode is scored as the pipeline uses
it, adapted to the scene's visible traffic (:func:`coster_sumo.prior.infer.fit_scene_adaptation`
over all its evaluated steps: a presence offset and speed and length class weights); the raw
model's numbers are kept beside them (``prior_raw`` in ``mmd_hidden_disc``,
``prior_context_raw_expected``, presence ``prior_context_raw``; the offsets in ``density_offset``).

Without the centre agent (``without_centre_agent``): the same MMDs and counts with the centre
agent's own region left out of the truth and of every method's draws. The centre agent sits in the
middle of its neighbourhood at every step, where any model that knows the frame puts a vehicle;
in the corpus' clips it is about half of the agents a neighbourhood holds, and more than half of
the hidden disc's. These numbers say how well the other vehicles are predicted.

Presence calibration: reliability over 10 equal-width probability bins (count, mean predicted,
observed frequency), expected calibration error, BCE, Brier score and ROC AUC, for the model in
"map" mode, the model in "context" mode (only the tokens it predicts), and the bucket rates of the
baselines.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from coster_sumo.prior.baselines import GMMBaseline, MeanValueBaseline
from coster_sumo.prior.bins import ATTRIBUTES, AttributeBins
from coster_sumo.prior.data import ScenePriorData, batch_tokens, epoch_samples, scene_tokens
from coster_sumo.prior.features import Tokens, centre_frame_attributes, token_buckets
from coster_sumo.prior.infer import (
    DENSITY_OFFSET_LIMIT,
    draw_classes,
    fit_scene_adaptation,
    predict_tokens,
    width_table,
)
from coster_sumo.prior.model import TrafficPrior
from coster_sumo.prior.records import (
    Calibration,
    DensityOffset,
    MethodMmd,
    PriorEvaluation,
    ReliabilityBin,
    TrafficScores,
)
from coster_sumo.prior.train import evaluate_loss

MMD_ATTRIBUTES = ("position", "heading", "speed", "size")


def mmd(x: np.ndarray, y: np.ndarray, unbiased: bool = False) -> float:
    """MMD^2 of samples x (n, d) and y (m, d), one Gaussian kernel, bandwidth = mean pairwise
    squared distance of the pooled samples (over distinct pairs); biased (V-statistic) or, with
    ``unbiased``, without the diagonal terms (needs n, m >= 2; can be below 0)."""
    x = np.asarray(x, np.float64).reshape(len(x), -1)
    y = np.asarray(y, np.float64).reshape(len(y), -1)
    z = np.concatenate([x, y])
    sq = np.sum(z * z, axis=1)
    d2 = np.maximum(sq[:, None] + sq[None, :] - 2.0 * z @ z.T, 0.0)
    n = len(z)
    bw = d2.sum() / max(n * (n - 1), 1)
    k = np.exp(-d2 / bw) if bw > 0 else np.ones_like(d2)
    nx = len(x)
    if unbiased:
        ny = len(y)
        if nx < 2 or ny < 2:
            raise ValueError("the unbiased MMD needs at least two samples on each side")
        kxx, kyy = k[:nx, :nx], k[nx:, nx:]
        return float((kxx.sum() - np.trace(kxx)) / (nx * (nx - 1)) + (kyy.sum() - np.trace(kyy)) / (ny * (ny - 1))
                     - 2.0 * k[:nx, nx:].mean())
    return float(k[:nx, :nx].mean() + k[nx:, nx:].mean() - 2.0 * k[:nx, nx:].mean())


def reliability(p: np.ndarray, y: np.ndarray, num_bins: int = 10) -> Calibration:
    """Calibration of probabilities ``p`` (n,) against outcomes ``y`` (n,) bool."""
    p = np.asarray(p, np.float64)
    y = np.asarray(y, bool)
    if len(p) == 0:
        return Calibration(count=0)
    which = np.minimum((p * num_bins).astype(np.int64), num_bins - 1)
    table, ece = [], 0.0
    for b in range(num_bins):
        sel = which == b
        n = int(sel.sum())
        if n:
            mean_predicted, observed = float(p[sel].mean()), float(y[sel].mean())
            ece += n / len(p) * abs(mean_predicted - observed)
            table.append(ReliabilityBin(b / num_bins, (b + 1) / num_bins, n, mean_predicted, observed))
        else:
            table.append(ReliabilityBin(b / num_bins, (b + 1) / num_bins, n))
    eps = 1e-7
    pc = np.clip(p, eps, 1 - eps)
    auc = None
    if 0 < y.sum() < len(y):
        from sklearn.metrics import roc_auc_score

        auc = float(roc_auc_score(y, p))
    return Calibration(count=int(len(p)), ece=ece, bce=float(-np.mean(y * np.log(pc) + (~y) * np.log(1 - pc))),
                       brier=float(np.mean((p - y) ** 2)), rate_observed=float(y.mean()),
                       rate_predicted=float(p.mean()), bins=tuple(table), auc=auc)


def centre_rows(data: ScenePriorData, rng: np.random.Generator) -> np.ndarray:
    """(T,) rows of ``data.centres``, one per step: the target where valid, else a random valid vehicle."""
    chosen = []
    for t in np.unique(data.centres[:, 0]):
        rows = np.flatnonzero(data.centres[:, 0] == t)
        sdc = rows[data.centres[rows, 1] == data.sdc_index]
        chosen.append(int(sdc[0] if len(sdc) else rng.choice(rows)))
    return np.asarray(chosen, np.int64)


def evaluation_centres(data: ScenePriorData, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Steps (T,) and centre poses (T, 3) of :func:`centre_rows`."""
    rows = centre_rows(data, rng)
    return data.centres[rows, 0].astype(np.int64), data.centre_pose[rows].astype(np.float64).reshape(-1, 3)


def _not_centre(data: ScenePriorData, tok: Tokens, steps: np.ndarray, centre_agent: np.ndarray) -> np.ndarray:
    """Flat bool over ``tok``'s tokens: False where the centre agent itself is (its own region)."""
    agent, _, _ = data.occupancy.gather(steps[:, None], np.maximum(tok.region_index, 0))
    return ~((agent == centre_agent[:, None]) & tok.mask).ravel()


def _score_draws(tok: Tokens, truth_sel: np.ndarray, draws: dict[str, tuple[np.ndarray, np.ndarray]],
                 out: dict[str, dict[str, list[float]]], radius: float, width: float,
                 keep: np.ndarray | None = None, unbiased: bool = False) -> None:
    """Append each method's per-scene MMDs (draws: name -> (flat indices, (n, 6) values)) against
    the agents at ``truth_sel``; ``keep``: a flat bool of the tokens to score (default all).
    Biased: every method with a draw is scored; unbiased: all or none (module docstring)."""
    if keep is not None:
        truth_sel = truth_sel[keep[truth_sel]]
        draws = {name: (sel[keep[sel]], vals[keep[sel]]) for name, (sel, vals) in draws.items()}
    least = 2 if unbiased else 1
    if len(truth_sel) < least or (unbiased and any(len(sel) < least for sel, _ in draws.values())):
        return
    truth = _mmd_features(tok, truth_sel, tok.values.reshape(-1, 6)[truth_sel].astype(np.float64), radius, width)
    for name, (sel, vals) in draws.items():
        if len(sel) >= least:
            feats = _mmd_features(tok, sel, vals, radius, width)
            for a in MMD_ATTRIBUTES:
                out[name][a].append(mmd(feats[a], truth[a], unbiased))


def _mmd_features(tok: Tokens, sel: np.ndarray, values: np.ndarray, radius: float, width: float
                  ) -> dict[str, np.ndarray]:
    """Per-attribute MMD features of the tokens ``sel`` (n,) flat indices with attributes (n, 6)."""
    mf = tok.map_features.reshape(-1, tok.map_features.shape[-1])[sel]
    pos, head = centre_frame_attributes(mf, values[:, :2], values[:, 2], radius, width)
    return {"position": pos, "heading": np.stack([np.cos(head), np.sin(head)], -1),
            "speed": values[:, 3:4], "size": values[:, 4:6]}


def _sample_model(presence: np.ndarray, probs: dict[str, np.ndarray], mask: np.ndarray, bins: AttributeBins,
                  rng: np.random.Generator, table: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices of generated agents and their (n, 6) attributes (bin centres); ``table``: the
    model's width bias per length class (:func:`coster_sumo.prior.infer.width_table`)."""
    gen = (rng.random(presence.shape) < presence) & mask
    sel = np.flatnonzero(gen.ravel())
    vals = np.zeros((len(sel), 6))

    def rows(name: str) -> np.ndarray:
        return probs[name].reshape(-1, probs[name].shape[-1])[sel]

    classes = draw_classes({a: rows(a) for a in ATTRIBUTES}, rng, table,
                           rows("width_logits") if table is not None else None)
    for a in ATTRIBUTES:
        c = bins.centres(a)[classes[a]]
        if a == "position":
            vals[:, 0:2] = c
        else:
            vals[:, 2 + ATTRIBUTES.index(a) - 1] = c
    return sel, vals


def fit_baselines(model: TrafficPrior, train: Sequence[ScenePriorData], seed: int = 0
                  ) -> list[MeanValueBaseline | GMMBaseline]:
    """Fit both baselines on one epoch of the model's training samples (all regions, map mode)."""
    cfg = model.config
    samples = epoch_samples(train, np.random.default_rng([seed, 0]), 1)
    buckets, present, values = [], [], []
    for i in range(0, len(samples), 256):
        tok = batch_tokens(train, samples[i:i + 256], cfg, visible="map")
        m = tok.mask
        buckets.append(token_buckets(tok.map_features)[m])
        present.append(tok.present[m])
        values.append(tok.values[m].astype(np.float64))
    b, p, v = np.concatenate(buckets), np.concatenate(present), np.concatenate(values)
    return [MeanValueBaseline().fit(b, p, v), GMMBaseline(cfg.bins(), seed=seed).fit(b, p, v)]


_Scores = dict[str, dict[str, list[float]]]  # method -> attribute -> per-scene MMDs


def _per_method(methods: Sequence[str]) -> _Scores:
    return {m: {a: [] for a in MMD_ATTRIBUTES} for m in methods}


@dataclass
class _Tallies:
    """The per-scene numbers :func:`evaluate_prior` collects, scene by scene: MMDs, agent counts
    and presence predictions with what was there; ``*_others``: the same without the centre
    agent's own region."""

    per_scene: _Scores
    per_scene_disc: _Scores
    per_scene_others: _Scores
    per_scene_disc_others: _Scores
    counts: dict[str, list[int]]
    counts_others: dict[str, list[int]]
    hidden: dict[str, list[float]]
    hidden_others: dict[str, list[float]]
    offsets: list[float]
    cal: dict[str, tuple[list[np.ndarray], list[np.ndarray]]]

    @classmethod
    def empty(cls, methods: list[str]) -> _Tallies:
        counts: dict[str, list[int]] = {m: [] for m in ["ground_truth", *methods]}
        return cls(
            per_scene=_per_method(methods), per_scene_disc=_per_method([*methods, "prior_raw"]),
            per_scene_others=_per_method(methods), per_scene_disc_others=_per_method([*methods, "prior_raw"]),
            counts=counts, counts_others={m: [] for m in counts},
            hidden={"ground_truth": [], "prior_context": [], "prior_context_expected": [],
                    "prior_context_raw_expected": []},
            hidden_others={"ground_truth": [], "prior_context_expected": [], "prior_context_raw_expected": []},
            offsets=[],
            cal={k: ([], []) for k in ("prior_map", "prior_context", "prior_context_raw", "bucket_rate")})


@dataclass(frozen=True)
class _Evaluation:
    """What scoring every scene reads: the model with its bins and width table, the baselines,
    the estimator and the two random streams (``hidden_rng`` draws the hidden disc, so that the
    other draws stay as they were before it existed)."""

    model: TrafficPrior
    bins: AttributeBins
    table: np.ndarray | None
    baselines: Sequence[MeanValueBaseline | GMMBaseline]
    unbiased: bool
    rng: np.random.Generator
    hidden_rng: np.random.Generator


@dataclass(frozen=True)
class _Centres:
    """The evaluated steps of one scene: ``steps`` (n,), centre agent (n,) and pose (n, 3)."""

    data: ScenePriorData
    steps: np.ndarray
    centre_agent: np.ndarray
    poses: np.ndarray


def _score_map_mode(ev: _Evaluation, c: _Centres, t: _Tallies) -> None:
    """Every region hidden: the model's and the baselines' draws against the ground truth."""
    cfg = ev.model.config
    tok = scene_tokens(c.data, c.steps, c.poses, cfg, visible="map")
    mask = tok.mask
    flat_mask = mask.ravel()
    gt_sel = np.flatnonzero((tok.present & mask).ravel())
    t.counts["ground_truth"].append(len(gt_sel))
    others = _not_centre(c.data, tok, c.steps, c.centre_agent)
    t.counts_others["ground_truth"].append(int(others[gt_sel].sum()))
    presence, probs = predict_tokens(ev.model, tok)
    t.cal["prior_map"][0].append(presence[mask])
    t.cal["prior_map"][1].append(tok.present[mask])
    generated: dict[str, tuple[np.ndarray, np.ndarray]] = {
        "prior": _sample_model(presence, probs, mask, ev.bins, ev.rng, ev.table)}
    buckets = token_buckets(tok.map_features).ravel()
    for b in ev.baselines:
        p = b.presence(buckets)
        sel = np.flatnonzero((ev.rng.random(len(p)) < p) & flat_mask)
        generated[b.name] = (sel, b.sample_values(buckets[sel], ev.rng))
    if ev.baselines:
        t.cal["bucket_rate"][0].append(ev.baselines[0].presence(buckets[flat_mask]))
        t.cal["bucket_rate"][1].append(tok.present.ravel()[flat_mask])
    for name, (sel, _) in generated.items():
        t.counts[name].append(len(sel))
        t.counts_others[name].append(int(others[sel].sum()))
    _score_draws(tok, gt_sel, generated, t.per_scene, cfg.radius, cfg.region_width, None, ev.unbiased)
    _score_draws(tok, gt_sel, generated, t.per_scene_others, cfg.radius, cfg.region_width, others, ev.unbiased)


def _score_hidden_disc(ev: _Evaluation, c: _Centres, t: _Tallies) -> None:
    """The traffic beyond the hide radius given: the prior (raw and adapted to the scene) sees it,
    the baselines only their map buckets; draws in the hidden disc against what was there."""
    cfg = ev.model.config
    ctx = scene_tokens(c.data, c.steps, c.poses, cfg, visible="context", hide_radius=cfg.hide_radius)
    p_raw, probs_raw = predict_tokens(ev.model, ctx)
    q = ctx.query & ctx.mask
    adaptation = fit_scene_adaptation(ev.model, c.data, c.steps, c.poses, ctx)
    t.offsets.append(adaptation.offset)
    p_ctx, probs_ctx = adaptation.apply(ev.model, p_raw, probs_raw, q)
    t.cal["prior_context_raw"][0].append(p_raw[q])
    t.cal["prior_context_raw"][1].append(ctx.present[q])
    t.cal["prior_context"][0].append(p_ctx[q])
    t.cal["prior_context"][1].append(ctx.present[q])
    disc: dict[str, tuple[np.ndarray, np.ndarray]] = {
        "prior": _sample_model(np.where(q, p_ctx, 0.0), probs_ctx, q, ev.bins, ev.hidden_rng, ev.table)}
    q_flat, ctx_buckets = q.ravel(), token_buckets(ctx.map_features).ravel()
    for b in ev.baselines:
        p = b.presence(ctx_buckets)
        sel = np.flatnonzero((ev.hidden_rng.random(len(p)) < p) & q_flat)
        disc[b.name] = (sel, b.sample_values(ctx_buckets[sel], ev.hidden_rng))
    disc["prior_raw"] = _sample_model(np.where(q, p_raw, 0.0), probs_raw, q, ev.bins, ev.hidden_rng, ev.table)
    truth_sel = np.flatnonzero((ctx.present & q).ravel())
    t.hidden["ground_truth"].append(len(truth_sel))
    t.hidden["prior_context"].append(len(disc["prior"][0]))
    t.hidden["prior_context_expected"].append(float(p_ctx[q].sum()))  # the mean of that draw
    t.hidden["prior_context_raw_expected"].append(float(p_raw[q].sum()))
    _score_draws(ctx, truth_sel, disc, t.per_scene_disc, cfg.radius, cfg.region_width, None, ev.unbiased)
    # the same without the centre agent's own region (about half of what the disc holds)
    others_ctx = _not_centre(c.data, ctx, c.steps, c.centre_agent)
    q_others = q & others_ctx.reshape(q.shape)
    t.hidden_others["ground_truth"].append(int(others_ctx[truth_sel].sum()))
    t.hidden_others["prior_context_expected"].append(float(p_ctx[q_others].sum()))
    t.hidden_others["prior_context_raw_expected"].append(float(p_raw[q_others].sum()))
    _score_draws(ctx, truth_sel, disc, t.per_scene_disc_others, cfg.radius, cfg.region_width, others_ctx,
                 ev.unbiased)


def _summary(per_method: _Scores) -> dict[str, MethodMmd]:
    return {name: MethodMmd({a: (float(np.mean(v)) if v else None) for a, v in per.items()},
                            scenes=len(per["position"])) for name, per in per_method.items()}


def _mean_counts(counts: dict[str, list[int]] | dict[str, list[float]]) -> dict[str, float]:
    return {name: float(np.mean(c)) if c else 0.0 for name, c in counts.items()}


def _results(t: _Tallies, mmd_estimator: str) -> PriorEvaluation:
    """The evaluation's numbers from the per-scene tallies (but for the held-out losses)."""
    offset = None
    if t.offsets:
        o = np.asarray(t.offsets)
        offset = DensityOffset(mean=float(o.mean()), min=float(o.min()), max=float(o.max()),
                               at_limit=int(np.sum(np.abs(o) >= DENSITY_OFFSET_LIMIT - 1e-9)))
    return PriorEvaluation(
        num_scenes=len(t.counts["ground_truth"]), mmd_estimator=mmd_estimator,
        scores=TrafficScores(mmd=_summary(t.per_scene), mmd_hidden_disc=_summary(t.per_scene_disc),
                             agents_per_scene=_mean_counts(t.counts), agents_in_hidden_disc=_mean_counts(t.hidden)),
        presence={name: reliability(np.concatenate(ps), np.concatenate(ys)) for name, (ps, ys) in t.cal.items() if ps},
        without_centre_agent=TrafficScores(
            mmd=_summary(t.per_scene_others), mmd_hidden_disc=_summary(t.per_scene_disc_others),
            agents_per_scene=_mean_counts(t.counts_others), agents_in_hidden_disc=_mean_counts(t.hidden_others)),
        density_offset=offset)


def evaluate_prior(model: TrafficPrior, scenes: Sequence[ScenePriorData],
                   baselines: Sequence[MeanValueBaseline | GMMBaseline] = (), seed: int = 0,
                   progress: bool = False, mmd_estimator: str = "biased") -> PriorEvaluation:
    """MMD of generated vs ground-truth traffic, presence calibration and held-out losses;
    ``mmd_estimator``: "biased" or "unbiased" (module docstring)."""
    if mmd_estimator not in ("biased", "unbiased"):
        raise ValueError(f"mmd_estimator must be 'biased' or 'unbiased', got {mmd_estimator!r}")
    cfg = model.config
    ev = _Evaluation(model, cfg.bins(), width_table(model), baselines, mmd_estimator == "unbiased",
                     rng=np.random.default_rng([seed, 7]),
                     hidden_rng=np.random.default_rng([seed, 11]))  # its own stream: the others stay as they were
    tallies = _Tallies.empty(["prior", *[b.name for b in baselines]])
    it: Sequence[ScenePriorData] = scenes
    if progress:
        from tqdm import tqdm

        it = tqdm(scenes, desc="evaluating", unit="scene")  # type: ignore[assignment]
    for data in it:
        if len(data.centres) == 0:
            continue
        rows = centre_rows(data, ev.rng)
        centres = _Centres(data, data.centres[rows, 0].astype(np.int64), data.centres[rows, 1],
                           data.centre_pose[rows].astype(np.float64).reshape(-1, 3))
        _score_map_mode(ev, centres, tallies)
        _score_hidden_disc(ev, centres, tallies)
    result = _results(tallies, mmd_estimator)
    samples = epoch_samples(scenes, np.random.default_rng([seed, 10**6 + 1]), 1)
    if len(samples):
        result = replace(result, heldout_loss={
            mode: evaluate_loss(model, scenes, samples, 64, seed, visible=mode) for mode in ("map", "context")})
    return result
