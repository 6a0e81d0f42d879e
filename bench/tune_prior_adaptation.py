"""Choose the pseudo-counts of the prior's scene adaptation by held-out scores.

Usage: python bench/tune_prior_adaptation.py CORPUS [--every 2] [--checkpoint CKPT]
       python bench/tune_prior_adaptation.py --files SCENE... (held-out clips or WOMD files, to look)
The validation clips of CORPUS (every ``--every``-th), each centred as ``eval prior`` centres it.
Per clip the prior predicts the hidden disc in context mode (raw), and a seeded half of the
visible regions with that half hidden too, as :func:`coster_sumo.prior.infer.fit_scene_adaptation`
does. For each candidate pseudo-count (in total, per step fitted, or for the classes per distinct
vehicle of the probe) the script applies the adaptation and scores the hidden disc: presence
cross-entropy, and the log-loss of the true speed and length class of the disc's vehicles. Lower is
better; "none" is the raw model. Presence has no per-vehicle row (its evidence is the probed tokens,
empty or not). The "mixture" rows score the length classes mixed with the probe's own mix of
lengths instead of weighted (``(1 - s) p + s q``, q the probe's distinct vehicles' mix of length
classes, s = N / (N + c) for N of them; tried on 2026-11-25 and not kept, docs/method.md); speed and
presence have none. The "spread as predicted" rows give the classes ``c`` pseudo-vehicles in all,
shared out as the prior predicts them at the probe's vehicles (a Dirichlet prior centred on the
prediction: a class neither seen nor predicted is shrunk as evidence grows, where a pseudo-count per
class leaves it at 1; tried on 2026-11-26 and not kept, docs/method.md); speed is counted per step
there, length per vehicle, as shipped.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from coster_sumo.converters.read import iter_scenes

from coster_sumo.infra import weights
from coster_sumo.prior.bins import ATTRIBUTES
from coster_sumo.prior.data import at_prior_rate, load_prepared, prepare_scene, scene_tokens, split_files
from coster_sumo.prior.evaluate import evaluation_centres
from coster_sumo.prior.infer import (
    ADAPTED_ATTRIBUTES,
    CLASS_EVIDENCE,
    load_prior,
    predict_tokens,
    presence_offset,
    probe_class_weights,
    probe_visible_traffic,
    shift_presence,
)
from coster_sumo.prior.model import TrafficPrior

CANDIDATES = (0.1, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0)
MIX_CANDIDATES = (1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0)


def clip_record(model: TrafficPrior, data) -> dict | None:  # type: ignore[no-untyped-def]
    """What the scores need of one clip: the raw disc prediction, its truth, and the probe
    (None without centres or visible regions)."""
    cfg = model.config
    if len(data.centres) == 0:
        return None
    steps, poses = evaluation_centres(data, np.random.default_rng([0, 7]))
    ctx = scene_tokens(data, steps, poses, cfg, visible="context",
                       hide_radius=cfg.hide_radius)
    probe = probe_visible_traffic(model, data, steps, poses, ctx)
    if probe is None:
        return None
    q = ctx.query & ctx.mask
    p, probs = predict_tokens(model, ctx, only_query=True, heads=ADAPTED_ATTRIBUTES)
    hidden = ctx.present & q
    return {"probe": probe, "disc_presence": p[q], "disc_present": ctx.present[q],
            **{f"p_{a}": probs[a][hidden].astype(np.float64) for a in ADAPTED_ATTRIBUTES},
            **{f"c_{a}": ctx.classes[..., ATTRIBUTES.index(a)][hidden] for a in ADAPTED_ATTRIBUTES}}


def scores(records: list[dict], c: float | None, unit: str) -> dict[str, float]:
    """Presence cross-entropy and the speed / length log-losses of the disc for one pseudo-count
    (None: the raw model) in ``unit``: "total", "step" (times the steps fitted), "vehicle" (the
    classes' evidence counted per distinct vehicle; presence then as "step") or "mix" (the length
    classes mixed with the probe's own, ``c`` vehicles; speed and presence as the raw model) or
    "spread" (``c`` in all, shared out as predicted, in the shipped units of each class)."""
    bce, n_tok, n_veh = 0.0, 0, 0
    loss = dict.fromkeys(ADAPTED_ATTRIBUTES, 0.0)
    for r in records:
        probe = r["probe"]
        cc = None if c is None or unit == "mix" else c * (1 if unit == "total" else probe.steps)
        offset = 0.0 if cc is None else presence_offset(probe.presence, probe.observed, cc)
        p = np.clip(shift_presence(r["disc_presence"], offset), 1e-7, 1 - 1e-7)
        y = r["disc_present"]
        bce -= float(np.sum(y * np.log(p) + (~y) * np.log(1 - p)))
        n_tok += len(y)
        for a in ADAPTED_ATTRIBUTES:
            if unit == "mix" and a == "length" and c is not None:
                n = probe.vehicle_counts[a].sum()
                share, mix = (n / (n + c), probe.vehicle_counts[a] / n) if n > 0 else (0.0, 0.0)
                pa = (1.0 - share) * r[f"p_{a}"] + share * mix
                loss[a] -= float(np.sum(np.log(np.maximum(pa[np.arange(len(pa)), r[f"c_{a}"]], 1e-12))))
                continue
            if c is None or unit == "mix":
                w = 1.0
            elif unit == "total":
                w = probe_class_weights(probe, a, c / probe.steps, "step")
            elif unit == "spread":  # c in all, shared as the prior predicts, in the shipped unit
                m = probe.class_mass[a] if CLASS_EVIDENCE[a] == "step" else probe.vehicle_mass[a]
                w = probe_class_weights(probe, a, c * np.maximum(m / max(float(m.sum()), 1e-30), 1e-12),
                                        CLASS_EVIDENCE[a])
            else:
                w = probe_class_weights(probe, a, c, unit)
            pa = r[f"p_{a}"] * w
            pa /= np.maximum(pa.sum(-1, keepdims=True), 1e-30)
            loss[a] -= float(np.sum(np.log(np.maximum(pa[np.arange(len(pa)), r[f"c_{a}"]], 1e-12))))
        n_veh += len(r[f"c_{ADAPTED_ATTRIBUTES[0]}"])
    return {"presence": bce / max(n_tok, 1), **{a: v / max(n_veh, 1) for a, v in loss.items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("corpus", type=Path, nargs="?")
    ap.add_argument("--files", type=Path, nargs="*", default=[])
    ap.add_argument("--every", type=int, default=2, help="every N-th validation clip (%(default)s)")
    ap.add_argument("--checkpoint", type=Path, default=None, help="default: the shipped prior")
    args = ap.parse_args()
    torch.set_num_threads(1)
    model = load_prior(args.checkpoint or weights.weights_path(weights.PRIOR))
    radius = model.config.radius
    scenes = []
    if args.corpus is not None:
        _, val = split_files(args.corpus, 0.1)
        scenes += load_prepared(val[::args.every], radius)
    for f in args.files:
        scenes += [prepare_scene(at_prior_rate(s), radius=radius) for s in iter_scenes(f)]
    if not scenes:
        raise SystemExit("nothing to score: give CORPUS or --files")
    records = [r for r in (clip_record(model, d) for d in scenes) if r is not None]
    print(f"{len(records)} clips")
    print("| pseudo-count | presence cross-entropy | speed log-loss | length log-loss |")
    print("|---|---|---|---|")
    rows = [("none", None, "step")] + [(f"{c:g} {label}", c, unit) for unit, label in (
        ("total", "in total"), ("step", "per step"), ("vehicle", "per vehicle")) for c in CANDIDATES] + [
        (f"{c:g} vehicles, mixture", c, "mix") for c in MIX_CANDIDATES] + [
        (f"{c:g} in all, spread as predicted", c, "spread") for c in MIX_CANDIDATES]
    for label, c, unit in rows:
        s = scores(records, c, unit)
        presence = "-" if unit in ("vehicle", "mix", "spread") else f"{s['presence']:.5f}"
        speed = "-" if unit == "mix" else f"{s['speed']:.4f}"
        print(f"| {label} | {presence} | {speed} | {s['length']:.4f} |")


if __name__ == "__main__":
    main()
