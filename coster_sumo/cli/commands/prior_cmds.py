"""``coster-sumo train prior`` and ``coster-sumo eval prior``."""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from coster_sumo.errors import InputError, not_found
from coster_sumo.infra.atomic import write_json

if TYPE_CHECKING:
    from coster_sumo.prior.records import MethodMmd, PriorEvaluation

DEFAULT_CHECKPOINT = "models/prior.pt"


def _subset(files: list[Path], n: int | None, seed: int) -> list[Path]:
    """At most ``n`` of ``files``, drawn at random (seeded) so that a subset spans the whole dataset
    (file names sort by source network), kept in sorted order."""
    if n is None or n >= len(files):
        return files
    import numpy as np

    keep = np.random.default_rng(seed).choice(len(files), size=max(n, 0), replace=False)
    return [files[i] for i in sorted(keep)]


def register(cli) -> None:  # type: ignore[no-untyped-def]
    train = cli.training(
        "prior", help="train the regional traffic prior on a dataset of scenes",
        description="Train the traffic prior on DATASET/scenes/*.npz (held-out split by file name). "
                    "Writes the best held-out checkpoint to OUTPUT, metrics to OUTPUT with .json, and a "
                    "resumable training state to OUTPUT.state (rerun the same command to resume).",
        out=DEFAULT_CHECKPOINT, what="checkpoint")
    train.add_argument("--epochs", type=int, default=20)
    train.add_argument("--batch-size", type=int, default=32)
    train.add_argument("--lr", type=float, default=1e-3)
    train.add_argument("--seed", type=int, default=0)
    train.add_argument("--threads", type=int, default=1, help="torch threads (1: bitwise reproducible)")
    train.add_argument("--device", default="cpu",
                       help="cpu (default), cuda, cuda:N, or auto (a GPU when torch sees one): where the model "
                            "trains; the checkpoint is written for the CPU either way")
    train.add_argument("--hidden", type=int, default=128, help="token width")
    train.add_argument("--blocks", type=int, default=5, help="context-gating blocks")
    train.add_argument("--val-fraction", type=float, default=0.1)
    train.add_argument("--max-scenes", type=int, default=None,
                       help="use at most this many training scenes (a seeded random subset)")
    train.add_argument("--state", default=None, help="training state file (default OUTPUT.state)")
    train.add_argument("--restart", action="store_true", help="ignore an existing training state")
    train.set_defaults(func=run_train)

    ev = cli.group("eval", help="evaluate a model").add_parser(
        "prior", help="MMD and presence calibration of the prior vs baselines",
        description="Evaluate a prior checkpoint on held-out scenes: MMD per attribute against ground "
                    "truth for the model, a mean-value and a Gaussian-mixture baseline (fitted on the "
                    "training split), presence calibration. --data takes a dataset folder (its held-out "
                    "split) or scene files (.npz, WOMD .tfrecord, ScenarioNet .pkl).")
    ev.add_argument("--data", required=True, nargs="+", help="dataset folder or scene file(s)")
    ev.add_argument("--checkpoint", default=DEFAULT_CHECKPOINT, help="prior checkpoint (%(default)s)")
    ev.add_argument("--train-data", default=None,
                    help="dataset whose training split fits the baselines (default: --data when it is a "
                         "dataset folder; otherwise no baselines)")
    ev.add_argument("--split", choices=("val", "all"), default="val",
                    help="which scenes of a dataset folder to evaluate (%(default)s)")
    ev.add_argument("--val-fraction", type=float, default=0.1)
    ev.add_argument("--max-scenes", type=int, default=None,
                    help="evaluate at most this many scenes (a seeded random subset)")
    ev.add_argument("--baseline-scenes", type=int, default=400,
                    help="fit the baselines on at most this many training scenes (%(default)s)")
    ev.add_argument("--seed", type=int, default=0)
    ev.add_argument("--mmd", choices=("biased", "unbiased"), default="biased",
                    help="MMD estimator: biased (with the kernel's diagonal; favours methods that draw more "
                         "agents when a scene has few) or unbiased (scored on the scenes where every method "
                         "has two samples) (%(default)s)")
    ev.add_argument("--threads", type=int, default=1, help="torch threads (%(default)s)")
    ev.add_argument("-o", "--out", "--json", dest="out", required=True, metavar="JSON",
                    help="where to write the results (JSON)")
    ev.set_defaults(func=run_eval)


def _log(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    return None if args.quiet else (lambda msg: print(msg, file=sys.stderr))


def run_train(args: argparse.Namespace) -> int:
    from coster_sumo.infra.devices import training_device
    from coster_sumo.prior.data import load_prepared, split_files
    from coster_sumo.prior.model import PriorConfig
    from coster_sumo.prior.train import TrainConfig, train_prior

    if args.epochs < 1 or args.batch_size < 1:
        raise InputError("--epochs and --batch-size must be at least 1")
    training_device(args.device)  # one that is not there fails before the scenes load
    train_files, val_files = split_files(args.data, args.val_fraction)
    train_files = _subset(train_files, args.max_scenes, args.seed)
    if not train_files:
        raise InputError(f"{args.data}: no training scenes after the held-out split")
    progress = not args.quiet
    mcfg = PriorConfig(hidden=args.hidden, num_blocks=args.blocks, head_hidden=args.hidden)
    tcfg = TrainConfig(epochs=args.epochs, batch_size=args.batch_size, lr=args.lr, seed=args.seed,
                       threads=args.threads)
    t0 = time.perf_counter()
    train = load_prepared(train_files, radius=mcfg.radius, progress=progress)
    val = load_prepared(val_files, radius=mcfg.radius, progress=progress)
    meta = {"data": str(args.data), "command": "coster-sumo " + shlex.join(sys.argv[1:]) if sys.argv else "",
            "train_files": len(train_files), "val_files": len(val_files)}
    metrics = train_prior(train, val, args.out, mcfg, tcfg, state_path=args.state, resume=not args.restart,
                          progress=progress, meta=meta, log=_log(args), device=args.device)
    if not args.quiet:
        print(f"wrote {args.out} (best epoch {metrics.best_epoch}, score {metrics.best_score:.4f}, "
              f"{time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return 0


def run_eval(args: argparse.Namespace) -> int:
    import torch

    from coster_sumo.prior.data import at_prior_rate, load_prepared, prepare_scene, split_files
    from coster_sumo.prior.evaluate import evaluate_prior, fit_baselines
    from coster_sumo.prior.infer import load_prior

    torch.set_num_threads(max(1, args.threads))
    model = load_prior(args.checkpoint)
    radius = model.config.radius
    progress = not args.quiet
    inputs = [Path(d) for d in args.data]
    scenes = []
    dataset_dir = None
    for path in inputs:
        if path.is_dir():
            train_files, val_files = split_files(path, args.val_fraction)
            files = val_files if args.split == "val" else train_files + val_files
            scenes += load_prepared(_subset(files, args.max_scenes, args.seed), radius, progress)
            dataset_dir = dataset_dir or path
        elif path.is_file():
            from coster_sumo.converters.read import iter_scenes

            for scene in iter_scenes(path):
                scenes.append(prepare_scene(at_prior_rate(scene), radius=radius))
        else:
            raise not_found(path, "file or folder")
    if args.max_scenes:
        scenes = scenes[: args.max_scenes]
    if not scenes:
        raise InputError(f"{' '.join(args.data)}: no scenes to evaluate")
    train_src = Path(args.train_data) if args.train_data else dataset_dir
    baselines = []
    if train_src is not None:
        train_files, _ = split_files(train_src, args.val_fraction)
        train_files = _subset(train_files, args.baseline_scenes, args.seed)
        baselines = fit_baselines(model, load_prepared(train_files, radius, progress), seed=args.seed)
    result = evaluate_prior(model, scenes, baselines, seed=args.seed, progress=progress, mmd_estimator=args.mmd)
    report = result.to_json() | {"checkpoint": str(args.checkpoint), "data": [str(d) for d in args.data],
                                 "baselines_fitted_on": str(train_src) if train_src else None, "seed": args.seed,
                                 "split": args.split}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json(out, report, indent=2)
    if not args.quiet:
        _print_evaluation(result)
        print(f"wrote {out}", file=sys.stderr)
    return 0


def _mmd_line(m: MethodMmd) -> str:
    return " ".join(f"{a}={m.values[a]:.4f}" if m.values[a] is not None else f"{a}=n/a"
                    for a in ("position", "heading", "speed", "size"))


def _print_evaluation(result: PriorEvaluation) -> None:
    """The evaluation's headline numbers, on stderr."""
    for name, m in result.scores.mmd.items():
        print(f"{name:>10}: MMD {_mmd_line(m)} ({m.scenes} scenes)", file=sys.stderr)
    for name, m in result.scores.mmd_hidden_disc.items():
        print(f"{name:>10}: MMD in the hidden disc (context mode) {_mmd_line(m)} ({m.scenes} scenes)", file=sys.stderr)
    a, h = result.scores.agents_per_scene, result.scores.agents_in_hidden_disc
    print("agents per scene (map mode): " + " ".join(f"{k}={v:.1f}" for k, v in a.items())
          + f"; in the hidden disc (context mode): ground_truth={h['ground_truth']:.1f} "
          f"prior={h['prior_context_expected']:.1f} (without the density offset "
          f"{h['prior_context_raw_expected']:.1f})", file=sys.stderr)
    w = result.without_centre_agent
    for name, m in w.mmd_hidden_disc.items():
        print(f"{name:>10}: MMD in the hidden disc without the centre agent {_mmd_line(m)} ({m.scenes} scenes)",
              file=sys.stderr)
    hw = w.agents_in_hidden_disc
    print(f"in the hidden disc without the centre agent: ground_truth={hw['ground_truth']:.1f} "
          f"prior={hw['prior_context_expected']:.1f}", file=sys.stderr)
    pm = result.presence.get("prior_map")
    if pm is not None and pm.ece is not None:
        auc = pm.auc if pm.auc is not None else float("nan")
        print(f"presence (map mode): ECE {pm.ece:.4f} AUC {auc:.3f}", file=sys.stderr)
    pc, pr = result.presence.get("prior_context"), result.presence.get("prior_context_raw")
    if pc is not None and pr is not None and pc.ece is not None and pr.ece is not None:
        print(f"presence (context mode): ECE {pc.ece:.4f} (without the density offset {pr.ece:.4f})",
              file=sys.stderr)
