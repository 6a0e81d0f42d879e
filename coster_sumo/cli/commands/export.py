"""``coster-sumo export RUN_OUT``: every variant of a finished run as plain SUMO, OpenSCENARIO + OpenDRIVE,
CSV and JSON (:mod:`coster_sumo.exports.run_folder`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from coster_sumo.errors import not_found
from coster_sumo.exports.run_folder import FORMATS, OSC_DIR, available_formats, export_run


def register(cli) -> None:  # type: ignore[no-untyped-def]
    p = cli.commands.add_parser(
        "export", help="export the variants of a run for other simulators (SUMO, OpenSCENARIO + OpenDRIVE)",
        description="For every variant of RUN_OUT (a `coster-sumo run` output folder): sumo = check the "
                    "standalone SUMO folder variants/<i>/export/ that run wrote; openscenario = write "
                    f"variants/<i>/{OSC_DIR}/ (.xosc validated against OpenSCENARIO 1.2, .xodr by netconvert, "
                    "trajectories.csv/.json of the target, the adversary and the vehicles near the target at "
                    "t_col). The openscenario format needs the optional extra: pip install "
                    "'coster-sumo[openscenario]'.")
    p.add_argument("run_out", type=Path, metavar="RUN_OUT", help="output folder of `coster-sumo run`")
    p.add_argument("--format", choices=FORMATS, default=None,
                   help="(default: all where the OpenSCENARIO extra is installed, else sumo)")
    p.add_argument("--radius", type=float, default=None,
                   help="[m] OpenSCENARIO: vehicles within this distance of the target at t_col are included "
                        "(default 50)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from coster_sumo.infra.progress import progress_bar

    if not args.run_out.is_dir():
        raise not_found(args.run_out, "folder")
    fmt = args.format or available_formats()
    if args.format is None and fmt == "sumo" and not args.quiet:
        from coster_sumo.exports.openscenario import EXTRA_HINT

        print(f"OpenSCENARIO + OpenDRIVE skipped: the optional extra is not installed ({EXTRA_HINT})")
    bars: list[Any] = []  # opened at the first variant: an input error before it is the only line

    def progress(done: int, total: int) -> None:
        if not bars:
            bars.append(progress_bar("export", "variant", total=total, quiet=args.quiet))
        bars[0].update(done - bars[0].n)

    try:
        results = export_run(args.run_out, fmt, args.radius, progress=progress)
    finally:
        for bar in bars:
            bar.close()
    if not args.quiet:
        for r in results:
            parts = []
            if "sumo" in r:
                parts.append(f"sumo -c {r['sumo']['sumocfg']}")
            if "openscenario" in r:
                o = r["openscenario"]
                parts.append(f"{o['xosc']} ({o['vehicles']} vehicles, schema-valid)")
            who = f"target {r['target']}, " if "target" in r else ""
            print(f"{who}variant {r['variant']}: " + "; ".join(parts))
    return 0
