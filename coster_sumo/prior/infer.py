"""Prior checkpoints and batched prediction over the steps of a scene.

Checkpoint format (``torch.save`` of a plain dict, loadable with ``torch.load(weights_only=True)``):
``{"format": "coster-sumo-prior", "version": 1, "config": PriorConfig as dict, "state_dict": ...,
"metrics": dict, "meta": dict}``.

:func:`predict_scene` runs the prior on every step of a (2 Hz) scene at once, centred on the
target: one forward pass with the steps as the batch.

Scene adaptation (context mode): how busy a place is and which vehicles drive there depend on
the demand, which the map does not show, and a scene can be unlike any the prior was trained on
(real logs with parked cars hold four to five times as many vehicles near a vehicle as the
corpus' SUMO traffic; a gridlocked city with its own vehicle mix). The given traffic around tells:
:func:`fit_scene_adaptation` hides a seeded half of the visible regions as well, lets the prior
predict them, and compares with the vehicles that are there. It returns one logit offset for
presence (the predicted count of that half brought to the observed one, shrunk towards no offset
by :data:`DENSITY_PSEUDO_COUNT` vehicles per step) and one weight per speed and length class
(observed over predicted vehicles of the class, :data:`CLASS_PSEUDO_COUNT` added to both; speed
counted per token and step, length per distinct vehicle: :data:`CLASS_EVIDENCE`).
The offset is uniform over a scene's regions, so the order of the regions by presence stays the
same; counts, probabilities, speeds and sizes follow the scene (``docs/method.md``, "The prior
adapted to the scene's visible traffic").
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from coster_sumo.core.scene import Scene
from coster_sumo.errors import InputError, not_found
from coster_sumo.infra.atomic import atomic_path
from coster_sumo.prior.bins import ATTRIBUTES, AttributeBins
from coster_sumo.prior.data import ScenePriorData, at_prior_rate, prepare_scene, scene_tokens
from coster_sumo.prior.features import Tokens
from coster_sumo.prior.model import PriorConfig, TrafficPrior
from coster_sumo.prior.regions import Regions

CHECKPOINT_FORMAT = "coster-sumo-prior"
# Pseudo-counts added to both sides of an observed / predicted ratio (presence: per fitted step, since
# the same vehicles are seen at every step and the evidence grows more slowly than the count). Chosen on the
# validation clips of the training networks by the held-out score of the hidden disc (presence
# cross-entropy; log-likelihood of the true speed and length class), see docs/method.md.
DENSITY_PSEUDO_COUNT = 1.0
DENSITY_OFFSET_LIMIT = 8.0  # |logit offset| at most (a factor of about 3000 in the odds)
# What one unit of evidence is for a class weight. A speed changes from step to step, so every
# probed token counts (pseudo-count per class and per fitted step). A length does not: a vehicle
# seen at 19 steps is one vehicle of its class, so each distinct vehicle counts once, its
# appearances averaged (pseudo-count per class, in vehicles). Per vehicle, the validation clips'
# length log-loss is 1.4158 against 1.4350 per step (docs/method.md).
CLASS_EVIDENCE = {"speed": "step", "length": "vehicle"}
CLASS_PSEUDO_COUNT = {"speed": 0.1, "length": 1.0}  # per class, in CLASS_EVIDENCE's unit
ADAPTED_ATTRIBUTES = tuple(CLASS_PSEUDO_COUNT)  # the heads whose class mix each scene's traffic refits
CHECKPOINT_VERSION = 1


def save_prior(model: TrafficPrior, path: str | Path, metrics: dict | None = None, meta: dict | None = None,
               extra: dict | None = None) -> Path:
    """Write a checkpoint atomically (temporary name, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "config": model.config.to_dict(),
               "state_dict": model.state_dict(), "metrics": metrics or {}, "meta": meta or {}}
    payload.update(extra or {})
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return path


def read_checkpoint(path: str | Path) -> dict:
    """The raw checkpoint dict; :class:`InputError` (one line) when it is missing or not a prior."""
    path = Path(path)
    if not path.is_file():
        raise not_found(path, why="prior checkpoint: train one with `coster-sumo train prior`")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for corrupt files
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{path}: not a readable prior checkpoint ({first})") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
        raise InputError(f"{path}: not a coster-sumo prior checkpoint")
    if ckpt.get("version") != CHECKPOINT_VERSION:
        raise InputError(f"{path}: prior checkpoint version {ckpt.get('version')} is not supported")
    return ckpt


def width_table(model: TrafficPrior) -> np.ndarray | None:
    """The model's width bias per length class (L, W) as numpy, or None (independent heads)."""
    return None if model.width_table is None else model.width_table.detach().numpy().astype(np.float64)


def load_prior(path: str | Path) -> TrafficPrior:
    """The model of a checkpoint, in eval mode on the CPU."""
    ckpt = read_checkpoint(path)
    model = TrafficPrior(PriorConfig.from_dict(ckpt["config"]))
    try:
        model.load_state_dict(ckpt["state_dict"])
    except RuntimeError as exc:
        first = str(exc).splitlines()[0]
        raise InputError(f"{path}: weights do not match the stored config ({first})") from None
    return model.eval()


def _logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(np.asarray(p, np.float64), 1e-7, 1.0 - 1e-7)
    return np.log(p) - np.log1p(-p)


def _sigmoid(z: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * np.asarray(z, np.float64)))


def shift_presence(p: np.ndarray, offset: float) -> np.ndarray:
    """Presence probabilities ``p`` with ``offset`` added to their logits (float64)."""
    return _sigmoid(_logit(p) + offset)


def presence_offset(p: np.ndarray, observed: float, pseudo_count: float) -> float:
    """The logit offset that brings the predicted count ``sum(p)`` of some tokens to their
    ``observed`` count, shrunk towards 0 like a Gamma-Poisson rate: it solves
    ``sum(shift_presence(p, b)) = predicted * (observed + c) / (predicted + c)``, clipped to
    +-:data:`DENSITY_OFFSET_LIMIT`."""
    from scipy.optimize import brentq

    logits = _logit(p)
    predicted = float(_sigmoid(logits).sum())
    goal = predicted * (observed + pseudo_count) / (predicted + pseudo_count)

    def excess(b: float) -> float:
        return float(_sigmoid(logits + b).sum()) - goal

    lim = DENSITY_OFFSET_LIMIT
    if excess(-lim) >= 0.0:
        return -lim
    if excess(lim) <= 0.0:
        return lim
    return float(brentq(excess, -lim, lim, xtol=1e-6))


def class_weights(observed: np.ndarray, predicted: np.ndarray, pseudo_count: float | np.ndarray) -> np.ndarray:
    """(C,) weights ``(n + c) / (m + c)`` of the classes: ``observed`` vehicles per class (n) over the
    summed predicted probabilities of the class at those vehicles (m); ``c`` one number or one per
    class."""
    return (np.asarray(observed, np.float64) + pseudo_count) / (np.asarray(predicted, np.float64) + pseudo_count)


@dataclass(frozen=True)
class SceneAdaptation:
    """What a scene's visible traffic says about the prior's guesses for it (module docstring).

    Attributes:
        offset: logit offset added to every context-mode presence.
        class_weights: attribute (:data:`ADAPTED_ATTRIBUTES`) -> (C,) factor on its class
            probabilities (renormalised after).
        probed: visible tokens hidden to fit it; observed: the vehicles found in them.
    """

    offset: float = 0.0
    class_weights: dict[str, np.ndarray] = field(default_factory=dict)
    probed: int = 0
    observed: int = 0

    def apply(self, model: TrafficPrior, presence: np.ndarray, probs: dict[str, np.ndarray], where: np.ndarray
              ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """``presence`` (B, K) and ``probs`` adapted at the tokens ``where`` (B, K) (new arrays)."""
        if self.offset != 0.0:
            presence = np.array(presence, np.float32, copy=True)
            presence[where] = shift_presence(presence[where], self.offset)
        probs = dict(probs)
        for a, w in self.class_weights.items():
            if a not in probs:
                continue
            p = np.array(probs[a], copy=True)
            sub = p[where] * w.astype(np.float32)
            total = sub.sum(-1, keepdims=True)
            p[where] = np.where(total > 0, sub / np.maximum(total, 1e-30), p[where])
            probs[a] = p
        if "length" in self.class_weights and "width_logits" in probs and model.width_table is not None:
            width = np.array(probs["width"], copy=True)
            width[where] = _width_marginal(model.width_table.detach(), torch.from_numpy(probs["length"][where]),
                                           torch.from_numpy(probs["width_logits"][where])).numpy()
            probs["width"] = width
        return presence, probs


@dataclass(frozen=True)
class VisibleProbe:
    """The prior's guesses for a hidden half of the visible regions, and what is there.

    Attributes:
        presence: (P,) predicted presence of the probed tokens.
        observed: vehicles in them.
        class_counts: attribute -> (C,) vehicles per class among them (one per token and step).
        class_mass: attribute -> (C,) summed predicted class probabilities at those vehicles.
        steps: steps the probe covers (the per-step pseudo-counts scale with it).
        vehicle_counts, vehicle_mass: the same with every distinct vehicle counted once (its
            tokens' classes and predictions averaged over its appearances).
        vehicles: distinct vehicles in the probed tokens.
    """

    presence: np.ndarray
    observed: float
    class_counts: dict[str, np.ndarray]
    class_mass: dict[str, np.ndarray]
    steps: int
    vehicle_counts: dict[str, np.ndarray] = field(default_factory=dict)
    vehicle_mass: dict[str, np.ndarray] = field(default_factory=dict)
    vehicles: int = 0


def probe_visible_traffic(model: TrafficPrior, data: ScenePriorData, steps: np.ndarray, pose: np.ndarray,
                          tokens: Tokens, seed: int = 0) -> VisibleProbe | None:
    """Hide a seeded half of the visible ``tokens`` (context-mode tokens of ``steps`` / ``pose``
    (B, 3) in ``data``) as well, predict them, and compare with the vehicles there; None without
    visible regions (map mode, nothing around)."""
    visible = tokens.mask & ~tokens.query
    probe = visible & (np.random.default_rng([seed, 23]).random(visible.shape) < 0.5)
    if not probe.any():
        return None
    cfg = model.config
    probe_tokens = scene_tokens(data, np.asarray(steps, np.int64), np.asarray(pose, np.float64), cfg,
                                visible=visible & ~probe)
    p, probs = predict_tokens(model, probe_tokens, only_query=True, heads=ADAPTED_ATTRIBUTES)
    present = probe_tokens.present & probe
    agent, _, _ = data.occupancy.gather(np.asarray(steps, np.int64).reshape(-1, 1),
                                        np.maximum(probe_tokens.region_index, 0))
    ids, vehicle = np.unique(agent[present], return_inverse=True)
    share = 1.0 / np.bincount(vehicle)[vehicle]  # (N,) each token's part of its vehicle's one unit
    counts, mass, v_counts, v_mass = {}, {}, {}, {}
    for a in ADAPTED_ATTRIBUTES:
        num = probs[a].shape[-1]
        cls = probe_tokens.classes[..., ATTRIBUTES.index(a)][present]
        pa = probs[a][present].astype(np.float64)
        counts[a] = np.bincount(cls, minlength=num)[:num]
        mass[a] = pa.sum(0)
        v_counts[a] = np.bincount(cls, weights=share, minlength=num)[:num]
        v_mass[a] = (pa * share[:, None]).sum(0)
    return VisibleProbe(presence=p[probe], observed=float(present.sum()), class_counts=counts, class_mass=mass,
                        steps=len(np.asarray(steps).reshape(-1)), vehicle_counts=v_counts, vehicle_mass=v_mass,
                        vehicles=len(ids))


def probe_class_weights(probe: VisibleProbe, attribute: str, pseudo_count: float | np.ndarray, evidence: str
                        ) -> np.ndarray:
    """(C,) :func:`class_weights` of ``attribute`` from ``probe``, ``pseudo_count`` per class in the
    unit ``evidence``: "step" (every probed token; the pseudo-count is multiplied by the steps) or
    "vehicle" (every distinct vehicle once)."""
    if evidence == "step":
        return class_weights(probe.class_counts[attribute], probe.class_mass[attribute], pseudo_count * probe.steps)
    if evidence == "vehicle":
        return class_weights(probe.vehicle_counts[attribute], probe.vehicle_mass[attribute], pseudo_count)
    raise ValueError(f"evidence must be 'step' or 'vehicle', got {evidence!r}")


def fit_scene_adaptation(model: TrafficPrior, data: ScenePriorData, steps: np.ndarray, pose: np.ndarray,
                         tokens: Tokens, seed: int = 0) -> SceneAdaptation:
    """Fit the presence offset and the class weights on the scene's own visible traffic.

    :func:`probe_visible_traffic` on the context-mode ``tokens``, then presence: :func:`presence_offset`
    with c = :data:`DENSITY_PSEUDO_COUNT` x the number of steps; classes (speed, length):
    :func:`probe_class_weights` with :data:`CLASS_PSEUDO_COUNT` of the attribute in the unit of
    :data:`CLASS_EVIDENCE` (speed: per step, length: per distinct vehicle).
    No adaptation without visible regions (map mode, nothing around).
    """
    probe = probe_visible_traffic(model, data, steps, pose, tokens, seed)
    if probe is None:
        return SceneAdaptation()
    offset = presence_offset(probe.presence, probe.observed, DENSITY_PSEUDO_COUNT * probe.steps)
    weights = {a: probe_class_weights(probe, a, CLASS_PSEUDO_COUNT[a], CLASS_EVIDENCE[a]) for a in ADAPTED_ATTRIBUTES}
    return SceneAdaptation(offset=offset, class_weights=weights, probed=len(probe.presence),
                           observed=int(probe.observed))


@dataclass
class PriorPrediction:
    """Prior outputs for the target's neighbourhood at every step of a scene.

    Attributes:
        regions: the regions that ``region_index`` points into.
        steps: (T,) step indices into the scene that was predicted.
        region_index: (T, K) int64 region of each token, -1 padding.
        mask: (T, K) bool real tokens.
        query: (T, K) bool tokens that were predicted (hidden); others were given as context.
        observed_agent: (T, K) int64 agent the scene has in that region (-1 none), for reference.
        presence: (T, K) float32 presence probability (0 where not ``query``).
        probs: attribute name -> (T, K, num_classes) float32 probabilities (position: 1600 classes,
            ix * 40 + iy over the normalised region frame; heading relative to the region direction);
            zeros where not ``query``.
        bins: the discretisation (bin centres via ``bins.centres(name)``).
        width_table: (length classes, width classes) bias of the width logits per length class when
            the prior draws width given length (``probs["width"]`` is then the marginal and
            ``probs["width_logits"]`` the head's own logits); None for independent heads.
        adaptation: the scene adaptation applied to ``presence`` and ``probs`` (module docstring;
            none in map mode or when switched off).
    """

    regions: Regions
    steps: np.ndarray
    region_index: np.ndarray
    mask: np.ndarray
    query: np.ndarray
    observed_agent: np.ndarray
    presence: np.ndarray
    probs: dict[str, np.ndarray]
    bins: AttributeBins
    width_table: np.ndarray | None = None
    adaptation: SceneAdaptation = field(default_factory=SceneAdaptation)

    @property
    def density_offset(self) -> float:
        """The logit offset added to ``presence``."""
        return self.adaptation.offset

    def expected(self, attribute: str) -> np.ndarray:
        """(T, K) (position: (T, K, 2) normalised) expectation under the predicted distribution."""
        c = self.bins.centres(attribute)
        return np.asarray(self.probs[attribute] @ c)

    def sample(self, rng: np.random.Generator, t: np.ndarray, k: np.ndarray) -> dict[str, np.ndarray]:
        """Sample attributes of tokens (t, k) (arrays of equal shape S) from their categorical heads.

        Returns:
            name -> values (S,) ("position": (S, 2) normalised region frame, "heading" [rad] relative to
            the region direction, "speed" [m/s] drawn inside its bin (:meth:`AttributeBins.speed_in_bin`),
            "length"/"width" [m]), plus "world_xy" (S, 2) [m] and "world_heading" (S,) [rad].
        """
        t = np.asarray(t, np.int64).ravel()
        k = np.asarray(k, np.int64).ravel()
        classes = draw_classes({a: self.probs[a][t, k] for a in ATTRIBUTES}, rng, self.width_table,
                               self.probs["width_logits"][t, k] if self.width_table is not None else None)
        out = {a: self.bins.centres(a)[c] for a, c in classes.items()}
        out["speed"] = self.bins.speed_in_bin(classes["speed"], rng)
        ridx = self.region_index[t, k]
        out["world_xy"] = self.regions.from_normalised(out["position"], ridx)
        out["world_heading"] = self.regions.heading[ridx] + out["heading"]
        return out

    def position_log_prob(self, world_xy: np.ndarray, t: np.ndarray, k: np.ndarray) -> np.ndarray:
        """Log probability of the position class containing each world point (..., 2) in token (t, k)
        (...); -inf outside the region's rectangle."""
        ridx = self.region_index[t, k]
        loc = self.regions.to_region_frame(world_xy, ridx)
        h = self.regions.height[ridx]
        norm = np.stack([loc[..., 0] / self.regions.width, loc[..., 1] / h - 0.5], -1)
        inside = np.all(np.abs(norm) <= 0.5, axis=-1)
        cls = self.bins.position_class(norm)
        p = self.probs["position"][t, k, cls]
        with np.errstate(divide="ignore"):
            return np.where(inside, np.log(np.maximum(p, 0.0)), -np.inf)


def _categorical(p: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One class per row of probabilities (S, C) (rows need not be normalised)."""
    p = np.asarray(p, np.float64)
    cdf = np.cumsum(p, axis=-1)
    u = rng.random(len(p)) * cdf[:, -1]
    return np.minimum((cdf < u[:, None]).sum(axis=-1), p.shape[-1] - 1)


def draw_classes(rows: dict[str, np.ndarray], rng: np.random.Generator, width_table: np.ndarray | None = None,
                 width_logits: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """One class (S,) per attribute from per-token probabilities ``rows`` (attribute -> (S, C)), in
    the order of :data:`ATTRIBUTES`; with ``width_table`` and the width head's ``width_logits``
    (S, W), width is drawn given the length drawn for the same token."""
    out: dict[str, np.ndarray] = {}
    for a in ATTRIBUTES:
        if a == "width" and width_table is not None and width_logits is not None:
            z = np.asarray(width_logits, np.float64) + width_table[out["length"]]
            rows_a = np.exp(z - z.max(axis=-1, keepdims=True))
        else:
            rows_a = rows[a]
        out[a] = _categorical(rows_a, rng)
    return out


def _width_marginal(table: torch.Tensor, length_probs: torch.Tensor, width_logits: torch.Tensor,
                    chunk: int = 2048) -> torch.Tensor:
    """p(width) = sum over lengths of p(length) p(width | length): (N, L), (N, W) -> (N, W)."""
    out = []
    for i in range(0, len(width_logits), chunk):
        pw = torch.softmax(width_logits[i:i + chunk, None, :] + table[None], dim=-1)  # (n, L, W)
        out.append(torch.einsum("nl,nlw->nw", length_probs[i:i + chunk], pw))
    return torch.cat(out) if out else width_logits.new_zeros(width_logits.shape)


@torch.no_grad()
def predict_tokens(model: TrafficPrior, tokens: Tokens, only_query: bool = False,
                   heads: Collection[str] | None = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Presence probabilities (B, K) and attribute probabilities (B, K, C) of a token batch.

    A prior that draws width given length returns the marginal width distribution as "width" and
    the width head's own logits as "width_logits" (see :class:`PriorPrediction`).
    Padding is never computed (zeros there). ``only_query`` evaluates the heads on the query tokens
    only (the others get zeros too), which saves most of the cost when few tokens are hidden.
    ``heads``: the attributes to predict (default all); the position head alone has 1,600 classes.
    """
    mask = tokens.mask
    h = model.encode_packed(torch.from_numpy(tokens.map_features), torch.from_numpy(tokens.agent_features),
                            torch.from_numpy(mask))  # (N, 2D) real tokens only
    sel = (tokens.query & mask) if only_query else mask  # (B, K)
    hs = h[torch.from_numpy(sel[mask])]  # heads on the selected tokens only
    presence = np.zeros(mask.shape, np.float32)
    presence[sel] = torch.sigmoid(model.presence_head(hs)[..., 0]).numpy()
    probs = {}
    computed: dict[str, torch.Tensor] = {}  # probabilities per head (length comes before width)
    for a, head in model.heads.items():
        if heads is not None and a not in heads:
            continue
        v = head(hs)
        if a == "width" and model.width_table is not None:
            logits = np.zeros(mask.shape + (v.shape[-1],), np.float32)
            logits[sel] = v.numpy()
            probs["width_logits"] = logits
            pl = computed["length"] if "length" in computed else torch.softmax(model.heads["length"](hs), dim=-1)
            p = _width_marginal(model.width_table, pl, v)
        else:
            p = torch.softmax(v, dim=-1)
        computed[a] = p
        full = np.zeros(mask.shape + (v.shape[-1],), np.float32)
        full[sel] = p.numpy()
        probs[a] = full
    return presence, probs


def predict_scene(model: TrafficPrior, scene: Scene | ScenePriorData, target: int,
                  steps: np.ndarray | None = None, mode: str = "context",
                  pose: np.ndarray | None = None, heads: Collection[str] | None = None,
                  calibrate: bool | SceneAdaptation = True) -> PriorPrediction:
    """Run the prior around ``target`` at every step (one batched forward pass).

    Args:
        model: a loaded prior.
        scene: a scene (brought to 2 Hz first when finer) or its prepared data. A ``Scene`` needs
            ``target`` to be a vehicle index in its tracks.
        target: agent index of the target (neighbourhood centre).
        steps: (T,) steps of the 2 Hz scene (default all).
        mode: "context" (regions within the model's ``hide_radius`` of the target are predicted,
            the traffic outside is given) or "map" (every region predicted from map and signals
            only). Only the ``query`` tokens of the result carry predictions.
        pose: optional (T, 3) centre x, y, heading overriding the target's logged pose (needed where
            the target is invalid; such steps otherwise get no regions).
        heads: the attributes to predict (default all; :meth:`PriorPrediction.sample` needs all).
        calibrate: in "context" mode, adapt presence and the speed and length classes to the
            scene's visible traffic (True: :func:`fit_scene_adaptation` over these steps, module
            docstring); or the :class:`SceneAdaptation` to apply instead of fitting one here (e.g.
            one fitted over a longer stretch of the same scene). False: none.
    """
    cfg = model.config
    if isinstance(scene, Scene):
        scene2 = at_prior_rate(scene)
        tr = scene2.tracks
        st = np.arange(scene2.num_steps) if steps is None else np.asarray(steps, np.int64)
        if pose is None:
            pose = np.stack([tr.x[target, st], tr.y[target, st], tr.heading[target, st]], -1)
            ok = tr.valid[target, st]
        else:
            ok = np.ones(len(st), bool)
        # only the regions that some step's neighbourhood can reach (big SUMO maps stay cheap)
        data = prepare_scene(scene2, radius=cfg.radius, spacing=cfg.region_spacing, width=cfg.region_width,
                             crop=np.asarray(pose, np.float64)[ok, :2].reshape(-1, 2))
    else:
        data = scene
        st = np.arange(data.num_steps) if steps is None else np.asarray(steps, np.int64)
        if pose is None:
            rows = {(int(t), int(a)): i for i, (t, a) in enumerate(data.centres)}
            idx = np.array([rows.get((int(t), target), -1) for t in st])
            ok = idx >= 0
            pose = np.where(ok[:, None], data.centre_pose[np.maximum(idx, 0)], 0.0)
        else:
            ok = np.ones(len(st), bool)
    if mode not in ("context", "map"):
        raise ValueError(f"mode must be 'context' or 'map', got {mode!r}")
    pose = np.where(ok[:, None], pose, 1e12)  # far away: no regions at steps without a target
    tokens = scene_tokens(data, st, np.asarray(pose, np.float64), cfg, visible=mode, hide_radius=cfg.hide_radius)
    presence, probs = predict_tokens(model, tokens, only_query=True, heads=heads)
    fitted = SceneAdaptation()
    if calibrate is not False and mode == "context":
        fitted = (calibrate if isinstance(calibrate, SceneAdaptation)
                  else fit_scene_adaptation(model, data, st, np.asarray(pose, np.float64), tokens))
        presence, probs = fitted.apply(model, presence, probs, tokens.query & tokens.mask)
    agent, _, _ = data.occupancy.gather(st[:, None], np.maximum(tokens.region_index, 0))
    return PriorPrediction(regions=data.regions, steps=st, region_index=tokens.region_index, mask=tokens.mask,
                           query=tokens.query, observed_agent=np.where(tokens.mask, agent, -1),
                           presence=presence * tokens.mask, probs=probs, bins=cfg.bins(),
                           width_table=width_table(model), adaptation=fitted)
