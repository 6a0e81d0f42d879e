"""``coster-sumo scenarios build SOURCES -o SET``: a scenario set for the Gymnasium environment.

Nominal scenes and generated variants (``--method``) of every source, with a manifest and splits by
network (``--heldout NET,...`` go to the test split). Rerunning the same command resumes the build.
The library is :mod:`coster_sumo.gym.build`; the environment that reads the set is
``coster_sumo/Scenario-v0`` (:mod:`coster_sumo.gym`).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def _build(args: argparse.Namespace) -> int:
    from coster_sumo.gym.build import BuildOptions, build_set, parse_networks

    opts = BuildOptions(sources=args.sources, out=args.out, method=args.method, seed=args.seed, seeds=args.seeds,
                        target=args.target, heldout=parse_networks(args.heldout or []), snapshots=args.snapshots,
                        variants=args.variants, samples=args.samples, models_dir=args.models, quiet=args.quiet,
                        progress=None if args.quiet else print, traffic=args.traffic,
                        adversary=getattr(args, "adversary", "vehicle"))
    summary = build_set(opts)
    if not args.quiet:
        print(f"{summary['scenarios']} scenarios ({summary['variants']} variants) on "
              f"{len(summary['networks'])} networks in {args.out}/manifest.json; "
              f"{len(summary['failed'])} source(s) without scenarios")
        for f in summary["failed"]:
            print(f"  {f['source']}: {f['reason']}")
    return 1 if summary["failed"] and summary["scenarios"] == 0 else 0


def _one_per_snapshot(args: argparse.Namespace) -> int:
    from coster_sumo.gym.derive import one_per_snapshot

    counts = one_per_snapshot(args.set, args.out)
    print(f"{counts['scenarios']} scenarios ({counts['variants']} variants, the first of each snapshot) in "
          f"{args.out}/manifest.json")
    return 0


def register(cli: Any) -> None:
    from coster_sumo.gym.build import HORIZON_S, METHODS

    group = cli.group("scenarios", help="scenario sets for training driving policies (Gymnasium)")
    b = group.add_parser("build", help="nominal scenes and generated variants into a scenario set (resumable)",
                         description=__doc__.split("\n\n")[1] if __doc__ else None)
    b.add_argument("sources", nargs="+", metavar="SOURCE",
                   help="scene sources: CFG.sumocfg[@seed=N,target=ID], a folder (every .sumocfg below, e.g. "
                        "converted WOMD scenes) or a text file listing sources")
    b.add_argument("-o", "--out", type=Path, required=True, help="scenario set folder (created; resumed if present)")
    b.add_argument("--method", choices=list(METHODS), default="coster",
                   help="generator: coster (every variant of each snapshot), coster-one-per-snapshot, random-cvae, "
                        "snapshot-cv, or nominal (no adversaries); adversarial sets keep the nominal scenes too")
    b.add_argument("--heldout", action="append", metavar="NET[,NET]",
                   help="networks of the test split (net file stem, or a converted scene's folder name)")
    b.add_argument("--traffic", choices=("log", "reactive"), default="log",
                   help="a converted source's agents in the avoidability labels' escape proof: log (replayed; "
                        "default) or reactive (each follows its log until the target's deviation reaches it)")
    b.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    b.add_argument("--seeds", type=int, default=1, help="scenes per configuration (default 1)")
    b.add_argument("--target", help="target vehicle id (default: the SDC of a converted scene, else 'ego')")
    b.add_argument("--snapshots", type=int, default=2, help="collision snapshots per scene (default 2)")
    b.add_argument("--variants", type=int, default=5, help="variants per snapshot (default 5)")
    b.add_argument("--samples", type=int, default=1000, help="CVAE trajectories oversampled (default 1000)")
    b.add_argument("--models", type=Path, help="folder with prior/rollout weights (default: shipped)")
    b.add_argument("--adversary", default="vehicle", choices=("vehicle", "cyclist", "pedestrian", "any"),
                   help="the adversaries' class (as in run; default vehicle)")
    b.set_defaults(func=_build, horizon=HORIZON_S)
    d = group.add_parser("one-per-snapshot", help="the coster-one-per-snapshot set of a coster set, without "
                         "generating again", description=("The set `scenarios build --method "
                         "coster-one-per-snapshot` gives for the same sources and options: the coster set's "
                         "nominal scenes and the first variant of each snapshot (hard links where possible)."))
    d.add_argument("set", type=Path, metavar="SET", help="a scenario set built with --method coster")
    d.add_argument("-o", "--out", type=Path, required=True, help="the new set's folder")
    d.set_defaults(func=_one_per_snapshot)
