"""Vehicle sizes the prior samples on held-out networks: pairs no training vehicle has, and the
most common size.

Usage: python bench/prior_samples.py CORPUS [--checkpoint CKPT] [--scenes N] [--train-scenes M]
Per held-out network (``CORPUS/heldout``, file names ``<network>_r<run>_...``): every third clip,
the first N (default 20); every region of every step sampled in map mode, as ``eval prior`` does.
A sampled (length bin, width bin) pair is *unseen* when no vehicle of M training clips (default
200, a seeded subset of the training split) falls into that pair of bins.
"""

from __future__ import annotations

import argparse
import re
from collections import Counter
from pathlib import Path

import numpy as np

from coster_sumo.cli.commands.prior_cmds import _subset
from coster_sumo.infra import weights
from coster_sumo.prior.data import batch_tokens, epoch_samples, load_prepared, scene_tokens, split_files
from coster_sumo.prior.evaluate import _sample_model, evaluation_centres
from coster_sumo.prior.infer import load_prior, predict_tokens, width_table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("corpus", type=Path)
    ap.add_argument("--checkpoint", type=Path, default=None, help="default: the shipped prior")
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--train-scenes", type=int, default=200)
    args = ap.parse_args()
    model = load_prior(args.checkpoint or weights.weights_path(weights.PRIOR))
    cfg, bins, table = model.config, model.config.bins(), width_table(model)
    train_files, _ = split_files(args.corpus, 0.1)
    train = load_prepared(_subset(train_files, args.train_scenes, 0), cfg.radius)
    seen = np.zeros((cfg.length_bins, cfg.width_bins), bool)
    samples = epoch_samples(train, np.random.default_rng([0, 0]), 1)
    for i in range(0, len(samples), 256):
        tok = batch_tokens(train, samples[i:i + 256], cfg, visible="map")
        c = tok.classes[tok.mask & tok.present]
        seen[c[:, 3], c[:, 4]] = True
    by_net: dict[str, list[Path]] = {}
    for p in sorted((args.corpus / "heldout").glob("*.npz")):
        m = re.match(r"(.+?)_r\d+_", p.name)
        by_net.setdefault(m.group(1) if m else p.stem, []).append(p)
    print("| network | sampled vehicles | unseen size pairs | most common size [m] (share) |")
    print("|---|---|---|---|")
    for net, files in by_net.items():
        rng = np.random.default_rng(0)
        total, unseen, sizes = 0, 0, Counter()
        for data in load_prepared(files[::3][: args.scenes], cfg.radius):
            steps, poses = evaluation_centres(data, rng)
            tok = scene_tokens(data, steps, poses, cfg, visible="map")
            presence, probs = predict_tokens(model, tok)
            _, vals = _sample_model(presence, probs, tok.mask, bins, rng, table)
            lc, wc = bins.length_class(vals[:, 4]), bins.width_class(vals[:, 5])
            total += len(vals)
            unseen += int((~seen[lc, wc]).sum())
            sizes.update(zip(np.round(vals[:, 4], 2).tolist(), np.round(vals[:, 5], 2).tolist(), strict=True))
        (length, width), n = sizes.most_common(1)[0] if sizes else ((0.0, 0.0), 0)
        print(f"| {net} | {total} | {unseen / max(total, 1):.3f} | {length:.2f} x {width:.2f} "
              f"({n / max(total, 1):.2f}) |")


if __name__ == "__main__":
    main()
