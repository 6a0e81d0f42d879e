"""``coster-sumo demo``: the full method on a network shipped inside the package, from any folder."""

from __future__ import annotations

import argparse
from importlib import resources
from pathlib import Path

from coster_sumo.cli.commands import run as run_command

DEMO_NETWORKS = ("intersection", "merge", "arterial")


def shipped_config(network: str) -> Path:
    """The ``.sumocfg`` of a network that travels with the installed package."""
    return Path(str(resources.files("coster_sumo.networks") / network / f"{network}.sumocfg"))


def register(cli) -> None:  # type: ignore[no-untyped-def]
    p = cli.commands.add_parser(
        "demo", help="run COSTER on a network shipped with the package (no files needed)",
        description="`coster-sumo run` on one of the package's own networks with the shipped weights; the "
                    "target replays its nominal path, so every variant makes contact at t_col. Writes "
                    "summary.json and the renders into OUT.")
    p.add_argument("--network", choices=DEMO_NETWORKS, default="intersection", help="(default %(default)s)")
    p.add_argument("--variants", type=int, default=5, help="representatives kept (default 5)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--models", type=Path, help="folder with prior/rollout/vocab weights (default: shipped)")
    run_command.add_export_argument(p)
    run_command.add_output_arguments(p, "out/demo")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    args = argparse.Namespace(**vars(args), config=shipped_config(args.network), target=None, planner="replay",
                              samples=1000, collision_time="entropy", init="snapshot", rollout="cvae",
                              begin=None, end=None, duration=None, traci=False, no_render=False, timeout=None)
    return run_command.run(args)
