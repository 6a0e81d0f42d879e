"""``coster-sumo eval scenarios SOURCES...``: COSTER against its baselines and the collision-time ablation."""

from __future__ import annotations

import argparse
from pathlib import Path

from coster_sumo.cli.commands.regress import add_scene_source_arguments
from coster_sumo.core.spec import ADVERSARY_CHOICES


def register(cli) -> None:  # type: ignore[no-untyped-def]
    from coster_sumo.batch.evaluate import GENERATOR_METHODS

    p = cli.group("eval", "evaluate models and generators").add_parser(
        "scenarios", help="SUR, CR, ORR, VDD, ADD, CSD, CPD of scenario generators on the same scenes",
        description="Per scene: COSTER (snapshot + CVAE), Random + CVAE, Snapshot + constant velocity, "
                    "Random + constant velocity, and COSTER with collision time last / random (ablation). "
                    "Every variant is injected into SUMO. Writes OUT/metrics.json, metrics.md, metrics.png and "
                    "summary.json; methods whose weights are missing are reported as skipped.")
    add_scene_source_arguments(p)
    p.add_argument("--method", action="append", dest="methods", choices=[m.name for m in GENERATOR_METHODS],
                   help="only these methods (repeat; default all)")
    p.add_argument("--planner", default="replay", help="who drives the target (default replay: the nominal path)")
    p.add_argument("--traffic", choices=("log", "reactive"), default="log",
                   help="a converted scene's agents in the labels' proofs and the injections: log (replayed; "
                        "default) or reactive (each follows its log until the target's deviation reaches it, then "
                        "SUMO drives it); the two modes' parts are kept apart")
    p.add_argument("--variants", type=int, default=5, help="variants per scene and method (default 5)")
    p.add_argument("--samples", type=int, default=1000, help="CVAE trajectories oversampled (default 1000)")
    p.add_argument("--adversary", default="vehicle", choices=ADVERSARY_CHOICES,
                   help="the adversaries' class: vehicle (default), cyclist, pedestrian or any (as in run); the "
                        "metrics are then that class's (ORR: the share leaving the class's area)")
    p.add_argument("-o", "--out", type=Path, default=Path("out/eval_scenarios"),
                   help="output folder (default out/eval_scenarios)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from coster_sumo.batch.evaluate import EvalOptions, eval_exit_code, evaluate_generators
    from coster_sumo.batch.report import generator_table

    opts = EvalOptions(sources=args.sources, out=args.out, methods=args.methods, planner=args.planner,
                       traffic=args.traffic, variants=args.variants, samples=args.samples, workers=args.workers,
                       executor=args.executor,
                       timeout=args.timeout or None, seed=args.seed, seeds=args.seeds, begin=args.begin,
                       end=args.end, target=args.target, models_dir=args.models, quiet=args.quiet,
                       ray_address=args.ray_address, adversary=args.adversary)
    summary = evaluate_generators(opts)
    if not args.quiet:
        head, rows = generator_table(summary)
        for r in rows:
            print("  ".join(f"{h}={c}" for h, c in zip(head, r, strict=True) if c))
        print(f"wrote {args.out}/metrics.md, {args.out}/metrics.json, {args.out}/metrics.png")
    return eval_exit_code(summary)
