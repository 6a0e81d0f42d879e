"""``coster-sumo train rollout``, ``coster-sumo train vocab`` and ``coster-sumo eval rollout``."""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import sys
import time
from pathlib import Path
from typing import Any

from coster_sumo.errors import InputError, not_found
from coster_sumo.infra.atomic import write_json
from coster_sumo.rollout.config import AGENT_CLASSES, CLASS_SCALES, VEHICLE_CLASS, RolloutConfig

DEFAULT_CHECKPOINT = "models/rollout.pt"
DEFAULT_CHECKPOINT_NO_DSA = "models/rollout_nodsa.pt"
DEFAULT_VOCAB = "models/vocab.npz"


def register(cli) -> None:  # type: ignore[no-untyped-def]
    _register_train(cli)
    _register_vocab(cli)
    _register_eval(cli)


def _register_train(cli) -> None:  # type: ignore[no-untyped-def]
    """``coster-sumo train rollout``."""
    train = cli.training(
        "rollout", help="train the time-reversed CVAE rollout on a dataset of scenes",
        description="Train the rollout CVAE on DATASET/scenes/*.npz (2 Hz, held-out split by file name). "
                    "Writes the checkpoint to OUTPUT after every epoch, metrics to OUTPUT with .json and a "
                    "training state to OUTPUT.state: rerun the same command to resume.",
        out=DEFAULT_CHECKPOINT, what="checkpoint")
    train.add_argument("--agent-class", choices=tuple(AGENT_CLASSES), default="vehicle",
                       help="whose tracks to learn (their object type): one model per class; the class is "
                            "stored in the checkpoint, and sets the output scales (%(default)s)")
    train.add_argument("--disp-scale", type=float, nargs=3, default=None, metavar=("DX", "DY", "DYAW"),
                       help="scale of the decoder's correction of the constant-velocity step [m, m, rad] "
                            "(default: the --init checkpoint's, else the class's: "
                            "coster_sumo.rollout.config.CLASS_SCALES)")
    train.add_argument("--recon-sigma", type=float, nargs=3, default=None, metavar=("DX", "DY", "DYAW"),
                       help="sigma of the reconstruction term [m, m, rad] (default: the --init checkpoint's, "
                            "else the class's)")
    train.add_argument("--best-of", type=int, default=0, metavar="K",
                       help="add the best of K prior samples' error to the loss (minADE / minFDE's own "
                            "measure; 0: the plain ELBO, %(default)s)")
    train.add_argument("--best-of-weight", type=float, default=1.0, metavar="W",
                       help="weight of the best-of-K term per metre (%(default)s)")
    train.add_argument("--no-dsa", action="store_true",
                       help="the w/o-DSA ablation: neighbours only as they were at t_rev")
    train.add_argument("--no-map-steps", action="store_true", help="attend to the map only for the first state")
    train.add_argument("--epochs", type=int, default=20)
    train.add_argument("--batch-size", type=int, default=256,
                       help="contexts per step (%(default)s; the previous recipe: 64 with --lr 5e-4 --warmup-steps 0)")
    train.add_argument("--lr", type=float, default=1e-3,
                       help="AdamW learning rate after the warm-up (%(default)s = 5e-4 x sqrt(256 / 64))")
    train.add_argument("--warmup-steps", type=int, default=50,
                       help="linear learning-rate warm-up over the first optimiser steps (%(default)s; 0: none)")
    train.add_argument("--lr-drop-epoch", type=int, default=0,
                       help="from this epoch on (1-based) train at --lr x --lr-drop-factor (0: never); a "
                            "finished run resumes with a drop after its last epoch (--epochs more)")
    train.add_argument("--lr-drop-factor", type=float, default=0.1,
                       help="the learning rate from --lr-drop-epoch on is --lr times this, in (0, 1] (%(default)s)")
    train.add_argument("--seed", type=int, default=0)
    train.add_argument("--hidden", type=int, default=256, help="model width (%(default)s)")
    train.add_argument("--heads", type=int, default=8, help="attention heads (%(default)s)")
    train.add_argument("--latent", type=int, default=32, help="per-step latent size (%(default)s)")
    train.add_argument("--kl-weight", type=float, default=1.0, help="weight of the KL term (1 = ELBO)")
    train.add_argument("--neighbor-radius", type=float, default=RolloutConfig.neighbor_radius_m, metavar="M",
                       help="dynamic surrounding attention sees the neighbours within M metres of the sample "
                            f"at every step (%(default)s; at most the {RolloutConfig.neighbor_select_radius_m:g} m "
                            "within which they are kept)")
    train.add_argument("--examples-per-epoch", type=int, default=20_000,
                       help="a fresh seeded subset of the training examples each epoch (0 = all; %(default)s)")
    train.add_argument("--val-fraction", type=float, default=0.1)
    train.add_argument("--max-val-examples", type=int, default=500,
                       help="held-out examples scored per epoch (%(default)s: enough for a run's trend, too few to "
                            "compare two runs by a few percent: use eval rollout --max-examples 10000 for that)")
    train.add_argument("--threads", type=int, default=1,
                       help="torch threads (default 1: measured as fast as 2 on the 2-core development machine, "
                            "and the same on every machine; 0: one per core; the same seed and thread count give "
                            "the same weights)")
    train.add_argument("--precision", choices=("fp32", "bf16"), default="fp32",
                       help="bf16: the training forward pass under CPU autocast to bfloat16 (weights and "
                            "optimiser in float32); about 3x the examples/s on CPUs with AVX-512 BF16 or AMX, "
                            "several times slower on CPUs without (a warning says so) (%(default)s)")
    train.add_argument("--device", default="cpu",
                       help="cpu (default), cuda, cuda:N, or auto (a GPU when torch sees one): where the model "
                            "trains; checkpoints are written for the CPU either way")
    train.add_argument("--cache-dir", default=None,
                       help="where the per-corpus feature cache lives (default DATASET/.cache)")
    train.add_argument("--no-cache", action="store_true",
                       help="build the inputs of every batch from the scenes (slow; no files written)")
    train.add_argument("--init", default=None, metavar="CHECKPOINT",
                       help="start from this rollout checkpoint's weights (same model settings, except "
                            "--neighbor-radius and --kl-weight) with a fresh optimiser: continue a finished run "
                            "whose training state is gone, or fine-tune the shipped weights on your own traffic")
    train.add_argument("--restart", action="store_true", help="ignore an existing training state")
    train.set_defaults(func=run_train)


def _register_vocab(cli) -> None:  # type: ignore[no-untyped-def]
    """``coster-sumo train vocab``."""
    vocab = cli.training(
        "vocab", help="build the motion vocabulary (k-disks over 0.5 s transitions)",
        description="Collect every 2 Hz transition (dx, dy, dyaw) of the vehicles of DATASET (training split) "
                    "and cover them with about SIZE tokens by k-disks on the mean box-corner error. Writes "
                    "OUTPUT (.npz) and OUTPUT with .json (coverage).",
        out=DEFAULT_VOCAB, what="vocabulary")
    vocab.add_argument("--size", type=int, default=384, help="number of tokens (%(default)s)")
    vocab.add_argument("--seed", type=int, default=0)
    vocab.add_argument("--max-transitions", type=int, default=50_000,
                       help="seeded subset of transitions used by k-disks (%(default)s)")
    vocab.add_argument("--val-fraction", type=float, default=0.1)
    vocab.set_defaults(func=run_vocab)


def _register_eval(cli) -> None:  # type: ignore[no-untyped-def]
    """``coster-sumo eval rollout``."""
    ev = cli.group("eval", help="evaluate a model").add_parser(
        "rollout", help="minADE/minFDE of the CVAE (with and w/o DSA) vs constant velocity / constant lane",
        description="Reconstruct the 5 s past of every vehicle with a full 5 s past, at every 2 Hz step (or the "
                    "last one, --t-rev last), with "
                    "constant velocity, constant lane and the CVAE checkpoints; report minADE/minFDE over "
                    "--samples samples, avgADE/avgFDE and the inference time per trajectory. --data takes a "
                    "dataset folder (its held-out split unless --split all) or scene files (.npz, WOMD "
                    ".tfrecord, ScenarioNet .pkl).")
    ev.add_argument("--data", required=True, nargs="+", help="dataset folder or scene file(s)")
    ev.add_argument("--agent-class", choices=tuple(AGENT_CLASSES), default="vehicle",
                    help="whose tracks to reconstruct; a checkpoint of another class is refused (%(default)s)")
    ev.add_argument("--checkpoint", default=None,
                    help=f"CVAE with DSA (default {DEFAULT_CHECKPOINT} when it exists; for pedestrians and "
                         "cyclists models/rollout_CLASS.pt)")
    ev.add_argument("--checkpoint-no-dsa", default=None,
                    help=f"CVAE without DSA (default {DEFAULT_CHECKPOINT_NO_DSA} when it exists; for pedestrians "
                         "and cyclists models/rollout_CLASS_nodsa.pt)")
    ev.add_argument("--split", choices=("val", "all"), default="val",
                    help="which scenes of a dataset folder to evaluate (%(default)s)")
    ev.add_argument("--val-fraction", type=float, default=0.1)
    ev.add_argument("--t-rev", choices=("all", "last"), default="all",
                    help="reconstruct from every 2 Hz step with a full 5 s past, or only from each scene's "
                         "last step (%(default)s)")
    ev.add_argument("--samples", type=int, default=5, help="samples per vehicle for minADE/minFDE (%(default)s)")
    ev.add_argument("--max-examples", type=int, default=0, help="score a seeded subset (0 = all)")
    ev.add_argument("--batch-size", type=int, default=64)
    ev.add_argument("--seed", type=int, default=0)
    ev.add_argument("--threads", type=int, default=1, help="torch threads (%(default)s)")
    ev.add_argument("--device", default="cpu",
                    help="cpu (default), cuda, cuda:N or auto: where the CVAEs sample (the same draws: the noise "
                         "is seeded on the CPU)")
    ev.add_argument("-o", "--out", "--json", dest="out", required=True, metavar="JSON",
                    help="where to write the results (JSON)")
    ev.set_defaults(func=run_eval)


def _command() -> str:
    return "coster-sumo " + shlex.join(sys.argv[1:]) if sys.argv else ""


def _write_json(path: Path, obj: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, obj)


def _output_scales(args: argparse.Namespace) -> dict[str, tuple[float, float, float]]:
    """``disp_scale`` and ``recon_sigma`` of a training run: ``--disp-scale`` / ``--recon-sigma`` when
    given, else those of the ``--init`` checkpoint (its weights mean corrections at its scales: a
    pedestrian model fine-tuned from the vehicle model keeps the vehicle's), else the class's."""
    scales = dict(CLASS_SCALES[args.agent_class])
    if args.init is not None and (args.disp_scale is None or args.recon_sigma is None):
        from coster_sumo.rollout.checkpoint import load_model

        init_cfg = load_model(args.init).cfg
        scales = {"disp_scale": init_cfg.disp_scale, "recon_sigma": init_cfg.recon_sigma}
    for name in ("disp_scale", "recon_sigma"):
        given = getattr(args, name)
        if given is not None:
            if min(given) <= 0.0:
                raise InputError(f"--{name.replace('_', '-')} must be three values above 0, not {given}")
            scales[name] = (float(given[0]), float(given[1]), float(given[2]))
    return scales


def run_train(args: argparse.Namespace) -> int:
    if "torch" not in sys.modules:  # OpenMP reads this when torch loads
        # on a machine shared with other jobs, threads spinning at OpenMP barriers while their
        # sibling is descheduled made two-thread steps 4-5x slower than one thread; waiting
        # passively costs little when the machine is idle
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    from coster_sumo.rollout.train import TrainConfig, train_rollout

    if args.epochs < 1 or args.batch_size < 1 or args.warmup_steps < 0 or args.threads < 0 or args.lr_drop_epoch < 0:
        raise InputError("--epochs and --batch-size must be at least 1, --warmup-steps, --threads and "
                         "--lr-drop-epoch at least 0")
    if not 0.0 < args.lr_drop_factor <= 1.0:
        raise InputError(f"--lr-drop-factor must be in (0, 1], not {args.lr_drop_factor}")
    scales = _output_scales(args)
    cfg = RolloutConfig(hidden=args.hidden, heads=args.heads, latent=args.latent, use_dsa=not args.no_dsa,
                        map_every_step=not args.no_map_steps, kl_weight=args.kl_weight,
                        neighbor_radius_m=args.neighbor_radius, agent_class=args.agent_class,
                        disp_scale=scales["disp_scale"], recon_sigma=scales["recon_sigma"],
                        best_of=args.best_of, best_of_weight=args.best_of_weight)
    tcfg = TrainConfig(epochs=args.epochs, batch_size=args.batch_size, lr=args.lr, seed=args.seed,
                       val_fraction=args.val_fraction, examples_per_epoch=args.examples_per_epoch,
                       max_val_examples=args.max_val_examples, threads=args.threads,
                       warmup_steps=args.warmup_steps, lr_drop_epoch=args.lr_drop_epoch,
                       lr_drop_factor=args.lr_drop_factor, precision=args.precision)
    t0 = time.perf_counter()
    metrics = train_rollout(args.data, args.out, cfg, tcfg, resume=not args.restart, quiet=args.quiet,
                            command=_command(), cache=not args.no_cache, cache_dir=args.cache_dir,
                            init=args.init, device=args.device)
    if not args.quiet:
        final = metrics.get("final", {})
        shown = ", ".join(f"{k} {final[k]:.3f}" for k in ("val_minADE", "val_minFDE", "val_loss") if k in final)
        print(f"wrote {args.out} ({shown or 'no held-out scenes'}; {time.perf_counter() - t0:.0f} s)",
              file=sys.stderr)
    return 0


def run_vocab(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from coster_sumo.formats.scene_file import load_scene
    from coster_sumo.rollout.train import split_scene_files
    from coster_sumo.rollout.vocab import build_vocab, collect_transitions

    if args.size < 1:
        raise InputError("--size must be at least 1")
    train_files, _ = split_scene_files(args.data, args.val_fraction, args.seed)
    t0 = time.perf_counter()
    scenes = (load_scene(p) for p in tqdm(train_files, desc="transitions", disable=args.quiet, leave=False))
    transitions = collect_transitions(scenes)
    vocab = build_vocab(transitions, size=args.size, seed=args.seed, max_points=args.max_transitions)
    meta = dict(vocab.meta)
    meta.update({"data": str(Path(args.data).resolve()), "scenes": len(train_files), "command": _command()})
    from dataclasses import replace

    vocab = replace(vocab, meta=meta)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    vocab.save(out)
    report = {"format": "coster-sumo-vocab-metrics", "tokens": len(vocab), "epsilon_m": vocab.epsilon_m,
              "box_m": [vocab.length, vocab.width], **meta, "wall_time_s": time.perf_counter() - t0,
              "units": {"errors": "m, mean box-corner distance"}}
    _write_json(out.with_suffix(".json"), report)
    if not args.quiet:
        print(f"wrote {out}: {len(vocab)} tokens, epsilon {vocab.epsilon_m:.3f} m, mean coverage error "
              f"{meta['coverage_mean_error_m']:.3f} m ({len(transitions)} transitions)", file=sys.stderr)
    return 0


def _eval_scenes(args: argparse.Namespace) -> list:  # type: ignore[type-arg]
    from coster_sumo.converters.read import iter_scenes
    from coster_sumo.data.dataset import list_scenes, split
    from coster_sumo.formats.scene_file import load_scene

    scenes = []
    for src in args.data:
        p = Path(src)
        if p.is_dir():
            files = list_scenes(p)
            if args.split == "val":
                _, files = split(files, args.val_fraction, seed=0)
            scenes += [load_scene(f) for f in files]
        elif p.is_file():
            scenes += list(iter_scenes(p))
        else:
            raise not_found(p, "file or folder")
    return scenes


def default_checkpoints(agent_class: str) -> tuple[str, str]:
    """The checkpoints ``eval rollout`` reads when none is given: (with DSA, without DSA)."""
    if agent_class == VEHICLE_CLASS:
        return DEFAULT_CHECKPOINT, DEFAULT_CHECKPOINT_NO_DSA
    return f"models/rollout_{agent_class}.pt", f"models/rollout_{agent_class}_nodsa.pt"


def _eval_models(args: argparse.Namespace, device: Any) -> tuple[dict[str, Any], dict[str, str], dict[str, str]]:
    """The models ``eval rollout`` scores, the ones it skips and why, and the checkpoint of each."""
    from coster_sumo.rollout.checkpoint import load_model, require_class

    models, skipped = {}, {}
    dsa, nodsa = default_checkpoints(args.agent_class)
    for name, given, default in (("cvae_no_dsa", args.checkpoint_no_dsa, nodsa), ("cvae_dsa", args.checkpoint, dsa)):
        path = given if given is not None else default if Path(default).is_file() else None
        if path is None:
            skipped[name] = f"no checkpoint ({default} not found)"
            continue
        models[name] = require_class(load_model(path), args.agent_class, path).to(device)
    return models, skipped, {"cvae_dsa": args.checkpoint or dsa, "cvae_no_dsa": args.checkpoint_no_dsa or nodsa}


def run_eval(args: argparse.Namespace) -> int:
    import dataclasses

    import torch

    from coster_sumo.infra.devices import training_device
    from coster_sumo.rollout.data import build_examples
    from coster_sumo.rollout.evaluate import LANE_NEIGHBOUR_ALONG_M, evaluate_rollout

    if args.threads > 0:
        torch.set_num_threads(args.threads)
    device = training_device(args.device)
    models, skipped, checkpoints = _eval_models(args, device)
    scenes = _eval_scenes(args)
    if not scenes:
        raise InputError("no scenes to evaluate (an empty held-out split? try --split all)")
    # the scene caches depend on how lanes are cut into chunks: one setting for all models
    cfg = next(iter(models.values())).cfg if models else RolloutConfig()
    for name, m in models.items():
        if (m.cfg.lane_spacing_m, m.cfg.chunk_vectors) != (cfg.lane_spacing_m, cfg.chunk_vectors):
            raise InputError(f"{name}: its map chunking differs from the other checkpoint's; evaluate them apart")
    cfg = dataclasses.replace(cfg, agent_class=args.agent_class)
    examples = build_examples(scenes, cfg, full_only=True, t_indices=[-1] if args.t_rev == "last" else None)
    t0 = time.perf_counter()
    result = evaluate_rollout(examples, models, horizon=10, num_samples=args.samples, seed=args.seed,
                              batch_size=args.batch_size, max_examples=args.max_examples,
                              agent_class=args.agent_class)
    report = {"format": "coster-sumo-rollout-eval", "data": [str(d) for d in args.data], "split": args.split,
              "t_rev": args.t_rev, "agent_class": args.agent_class,
              "scenes": len(scenes), **result.to_json(), "skipped": skipped, "checkpoints": checkpoints,
              "seed": args.seed, "threads": torch.get_num_threads(), "torch": torch.__version__,
              "machine": platform.machine(), "wall_time_s": time.perf_counter() - t0, "command": _command(),
              "units": {"ADE/FDE": "m", "time_per_trajectory_s": "s (CPU wall time)"}}
    _write_json(Path(args.out), report)
    if not args.quiet:
        for name, scores in result.methods.items():
            e = scores.errors
            print(f"{name:18s} minADE {e.min_ade:.3f} minFDE {e.min_fde:.3f} avgADE {e.avg_ade:.3f} "
                  f"avgFDE {e.avg_fde:.3f} m, {1e3 * scores.time_per_trajectory_s:.2f} ms/traj", file=sys.stderr)
        dsa, nodsa = result.methods.get("cvae_dsa"), result.methods.get("cvae_no_dsa")
        if dsa and nodsa:  # where the neighbours are: what DSA has to attend to
            for title, groups_dsa, groups_nodsa in (
                    ("neighbours", dsa.by_neighbours, nodsa.by_neighbours),
                    (f"lane neighbour within {LANE_NEIGHBOUR_ALONG_M:g} m:", dsa.by_lane_neighbour,
                     nodsa.by_lane_neighbour)):
                for a, b in zip(groups_dsa or (), groups_nodsa or (), strict=True):
                    print(f"{title} {a.label:>4s} ({a.contexts} vehicles): minFDE DSA {a.min_fde:.3f}, "
                          f"no DSA {b.min_fde:.3f} m, DSA better by {100 * (1 - a.min_fde / b.min_fde):+.1f} %",
                          file=sys.stderr)
    return 0
