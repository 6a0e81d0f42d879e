"""``coster-sumo simulate``: nominal traffic from SUMO into a dataset of WOMD-like clips.

Each SOURCE (a ``.sumocfg``, or a ``.net.xml`` without demand) is simulated ``--seeds`` times,
every run with its own SUMO ``--seed`` and a demand scale (SUMO's ``--scale``) drawn from
``--scale-range``. Sources without demand get random trips (SUMO's ``randomTrips.py``, seeded with
the run's seed). ``--netgenerate K`` adds K networks made by ``netgenerate`` (grid, spider and
random, with varied lanes, speeds and junction control) under ``DATASET/nets/``. Runs go in
parallel, one process each; a failed run is reported in one line and the others go on (exit code
1); the same command again runs only the runs the manifest does not list as done.

The library is :mod:`coster_sumo.batch.simulate`; this module only parses the command line.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from coster_sumo.batch.simulate import (
    DEFAULT_DURATION_S,
    DEFAULT_TIMEOUT_S,
    GENERATED_WARMUP_S,
    SimulateConfig,
    run_simulate,
)


def _cmd(args: argparse.Namespace) -> int:
    cfg = SimulateConfig(
        sources=[Path(p) for p in args.sources], dataset=Path(args.out), seeds=args.seeds, seed=args.seed,
        duration_s=args.duration, warmup_s=args.warmup, workers=args.workers, netgenerate=args.netgenerate,
        clips_per_run=args.clips_per_run, targets_per_window=args.targets_per_window,
        scale_range=(args.scale_range[0], args.scale_range[1]), timeout_s=args.timeout, quiet=args.quiet,
        debug=args.debug)
    counts = run_simulate(cfg).counts
    if not args.quiet:
        print(f"{counts.runs_done_now - counts.runs_failed_now} runs done, "
              f"{counts.runs_failed_now} failed, {counts.clips_now} clips written; dataset "
              f"{cfg.dataset}: {counts.total_clips} scenes, "
              f"{counts.simulated_hours:.3f} h simulated")
    return 0 if counts.ok else 1


def register(cli: Any) -> None:
    p = cli.commands.add_parser(
        "simulate", help="simulate nominal traffic into a dataset of WOMD-like clips",
        description=__doc__.split("\n\n")[1] if __doc__ else None)
    p.add_argument("sources", nargs="*", metavar="SOURCE",
                   help=".sumocfg files (their own demand) or .net.xml files (random trips)")
    p.add_argument("-o", "--out", "--output", dest="out", required=True, metavar="DATASET",
                   help="dataset folder (created)")
    p.add_argument("--seeds", type=int, default=3, metavar="N", help="runs per source (default 3)")
    p.add_argument("--seed", type=int, default=0, help="first seed; runs use seed, seed+1, ... (default 0)")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help=f"simulated seconds per run (default: the configuration's end, else "
                        f"{DEFAULT_DURATION_S:g})")
    p.add_argument("--warmup", type=float, default=None, metavar="S",
                   help="seconds simulated before clips are cut (default 0 for configurations with "
                        f"demand, {GENERATED_WARMUP_S:g} for random trips)")
    p.add_argument("--workers", type=int, default=1, metavar="W", help="parallel runs (processes)")
    p.add_argument("--netgenerate", type=int, default=0, metavar="K",
                   help="also generate K networks (grid / spider / random) into DATASET/nets/")
    p.add_argument("--clips-per-run", type=int, default=20, metavar="M", help="at most M clips per run")
    p.add_argument("--targets-per-window", type=int, default=3, metavar="T",
                   help="targets per 9.1 s window (default 3)")
    p.add_argument("--scale-range", type=float, nargs=2, default=(0.6, 1.4), metavar=("LO", "HI"),
                   help="demand scale (SUMO --scale) drawn per run from [LO, HI] (default 0.6 1.4)")
    p.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT_S, metavar="S",
                   help=f"wall-clock limit per run (default {DEFAULT_TIMEOUT_S:g})")
    p.set_defaults(func=_cmd)
