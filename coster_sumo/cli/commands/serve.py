"""``coster-sumo serve``: keep the heavy imports loaded for the next commands (:mod:`coster_sumo.cli.server`)."""

from __future__ import annotations

import argparse
import sys

from coster_sumo.cli import server


def register(cli) -> None:  # type: ignore[no-untyped-def]
    p = cli.commands.add_parser(
        "serve", help="keep torch, SUMO and the renders loaded: later commands start in a fraction of a second",
        description="Listen on a Unix socket only this user can reach; every `coster-sumo` command started "
                    "while it runs is handed to it and runs in a fork with the imports done (about 3 s saved per "
                    "command). It exits after 30 minutes without a command, on `coster-sumo serve --stop`, or "
                    "when the installed package changes. COSTER_SUMO_SERVER=off makes a command run alone.")
    p.add_argument("--stop", action="store_true", help="stop the running server")
    p.add_argument("--idle-exit", type=float, default=server.IDLE_EXIT_S, metavar="S",
                   help="[s] exit after this long without a command (default %(default)g)")
    p.set_defaults(func=lambda args: run(args, cli.run))


def run(args: argparse.Namespace, run_command: server.Runner) -> int:
    if args.stop:
        if server.stop():
            print(f"coster-sumo server on {server.socket_path()}: stopped")
            return 0
        print(f"coster-sumo: error: no server answers on {server.socket_path()}", file=sys.stderr)
        return 1
    return server.serve(run_command, idle_exit_s=args.idle_exit, quiet=args.quiet)
