"""``coster-sumo corpus build DATASET`` and ``coster-sumo corpus card DATASET``.

``build`` simulates the nominal-traffic corpus (real OSM networks from the eclipse-sumo wheel,
authored freeways, roundabouts, rural roads, netgenerate families, the repository's networks; free
flow to congestion; every vehicle class; Krauss / IDM / EIDM; part sublane) into DATASET as 9.1 s
clips, held-out networks apart, then writes the card (docs/corpus.md). Rerunning it finishes
what is missing.

``card`` writes DATASET/card.md and its histograms (DATASET/card/*.png) from the manifest and the
per-run statistics. The libraries are :mod:`coster_sumo.batch.corpus` and
:mod:`coster_sumo.batch.card`.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def _build(args: argparse.Namespace) -> int:
    from coster_sumo.batch.corpus import CorpusConfig, build_corpus

    cfg = CorpusConfig(dataset=Path(args.dataset), runs_per_network=args.runs_per_network,
                       duration_s=args.duration, seed=args.seed, workers=args.workers,
                       networks=args.networks or None, timeout_s=args.timeout, card=not args.no_card, quiet=args.quiet,
                       debug=args.debug, pedestrians=args.pedestrians)
    counts = build_corpus(cfg).counts
    if cfg.card:
        from coster_sumo.batch.card import write_card

        write_card(cfg.dataset)
    if not args.quiet:
        print(f"{counts.runs_done_now - counts.runs_failed_now} runs done, {counts.runs_failed_now} "
              f"failed, {counts.clips_now} clips written in {counts.wall_s:.0f} s; corpus {cfg.dataset}: "
              f"{counts.total_clips} clips, {counts.simulated_hours:.2f} h simulated")
    return 0 if counts.ok else 1


def _card(args: argparse.Namespace) -> int:
    from coster_sumo.batch.card import write_card

    path = write_card(Path(args.dataset), Path(args.out) if args.out else None)
    if not args.quiet:
        print(f"wrote {path}")
    return 0


def register(cli: Any) -> None:
    from coster_sumo.batch.corpus import CLIPS_PER_RUN, RUN_DURATION_S

    group = cli.group("corpus", help="the nominal-traffic corpus: build it, describe it")
    b = group.add_parser("build", help="simulate the corpus (resumable)",
                         description=__doc__.split("\n\n")[1] if __doc__ else None)
    b.add_argument("dataset", metavar="DATASET", help="corpus folder (created)")
    b.add_argument("--runs-per-network", type=int, default=6, metavar="N",
                   help="runs per network (default 6: the full corpus; 1 for a reduced build)")
    b.add_argument("--duration", type=float, default=RUN_DURATION_S, metavar="S",
                   help=f"simulated seconds per run (default {RUN_DURATION_S:g}; up to {CLIPS_PER_RUN} clips each)")
    b.add_argument("--seed", type=int, default=0, help="corpus seed: authored networks, demand, types (default 0)")
    b.add_argument("--workers", type=int, default=1, metavar="W", help="parallel runs (processes)")
    b.add_argument("--networks", nargs="+", metavar="NAME", help="only these networks (default: all)")
    b.add_argument("--timeout", type=float, default=1800.0, metavar="S", help="wall-clock limit per run")
    b.add_argument("--no-card", action="store_true", help="do not write the corpus card at the end")
    b.add_argument("--pedestrians", action="store_true",
                   help="sidewalks and crossings where a network has none (netconvert's guesses), random walks, "
                        "some against the light; recorded as PEDESTRIAN tracks (docs/corpus.md). Off: the "
                        "corpus is what it was without them")
    b.set_defaults(func=_build)
    c = group.add_parser("card", help="write the corpus card (markdown + PNG histograms)",
                         description=__doc__.split("\n\n")[2] if __doc__ else None)
    c.add_argument("dataset", metavar="DATASET", help="corpus folder")
    c.add_argument("-o", "--out", "--output", dest="out", metavar="DIR",
                   help="write card.md and card/*.png here (default: DATASET)")
    c.set_defaults(func=_card)
