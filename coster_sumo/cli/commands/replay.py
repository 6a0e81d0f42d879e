"""``coster-sumo replay CFG``: replay a converted WOMD scene from its log, or run any SUMO config.

For a converted scene (the folder of CFG holds ``scene.npz`` and ``lane_map.json``) every logged
agent follows its log through moveToXY and the signals follow the logged states; the summary
reports the centre-position error SUMO reports back against the log. Any other configuration is
simply run (``--fcd-output`` passes through). ``summary.json`` goes to ``-o/--out`` (default
``out/replay``, like every command's output: never into the input's folder, which may be inside
the installed package).
"""

from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path

from coster_sumo.errors import not_found
from coster_sumo.infra.atomic import write_json
from coster_sumo.infra.procs import run_supervised


def register(cli) -> None:  # type: ignore[no-untyped-def]
    p = cli.commands.add_parser(
        "replay", help="replay a converted WOMD scene from its log (or run a plain SUMO configuration)",
        description="Converted scene: logged agents follow the log via moveToXY, signals follow the log; "
                    "reports the centre-position error against the log. Plain configuration: runs it.")
    p.add_argument("config", type=Path, metavar="CFG", help=".sumocfg (converted scene or any SUMO configuration)")
    p.add_argument("--fcd-output", type=Path, metavar="FILE", help="write SUMO's FCD output (positions per step)")
    p.add_argument("--end", type=float, metavar="T", help="[s] stop at this simulation time")
    p.add_argument("--traci", action="store_true", help="use a TraCI socket instead of libsumo")
    p.add_argument("-o", "--out", type=Path, default=Path("out/replay"),
                   help="folder for summary.json (default out/replay)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from coster_sumo.sim.replay import ReplayOptions, replay

    if not args.config.is_file():
        raise not_found(args.config)
    quiet = bool(getattr(args, "quiet", False))
    bar = tqdm(desc="replay", unit="step", disable=quiet, file=sys.stderr, dynamic_ncols=True)

    def progress(step: int, total: int) -> None:
        if total and bar.total != total:
            bar.total = total
        bar.n = step
        if step % 10 == 0:
            bar.refresh()

    if args.fcd_output is not None:
        args.fcd_output.parent.mkdir(parents=True, exist_ok=True)
    options = ReplayOptions(end=args.end, fcd_output=args.fcd_output, traci=args.traci, progress=progress)
    try:  # in a child process: a SUMO crash is one line naming the configuration, not a dead command
        summary = run_supervised(functools.partial(replay, args.config, options), f"replay of {args.config}")
    finally:
        bar.close()
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "summary.json", summary)
    # the one-line result stays with --quiet; the name of the file written does not
    if summary["mode"] == "replay":
        print(f"{summary['scenario_id']}: {summary['steps']} steps, {summary['agents']} agents, "
              f"centre error max {summary['centre_error_max_m']:.2e} m mean "
              f"{summary['centre_error_mean_m']:.2e} m over {summary['valid_states_compared']} states, "
              f"{summary['sim_s']:.2f} s ({summary['steps_per_s']} steps/s)")
    else:
        print(f"{summary['config']}: {summary['steps']} steps to t={summary['end_s']:.1f} s, "
              f"{summary['vehicles']} vehicles, {summary['wall_s']:.2f} s")
    if not quiet:
        print(f"summary: {out / 'summary.json'}")
    return 0
