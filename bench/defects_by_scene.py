"""Defect and unavoidable-contact rates of a ``regress`` folder, per planner and per configuration.

    python bench/defects_by_scene.py OUT [--group shipped=intersection,merge,arterial]

Reads ``OUT/results/`` (one row per run, ``avoidable`` and ``contact_in_horizon`` set by
generation's labels) and prints a Markdown table: per group of configurations (default: each
configuration on its own) and planner, the defect rate (contact up to the label's horizon in an
avoidable variant) and the unavoidable-contact rate, Wilson 95 % intervals.
"""

from __future__ import annotations

import argparse
import re
from collections import defaultdict
from pathlib import Path

from coster_sumo.batch.store import ResultRow, ResultStore
from coster_sumo.metrics import rate_with_ci


def config_of(scene_key: str) -> str:
    """``merge_s1_f413aea1`` -> ``merge``; ``A10KW_s0_b300_e480_6a5e6a21`` -> ``A10KW``."""
    return re.sub(r"_s\d+_.*$", "", scene_key)


def fmt(r: dict) -> str:
    if not r["n"]:
        return "n/a"
    return f"{100 * r['rate']:.0f} % [{100 * r['ci_low']:.0f}, {100 * r['ci_high']:.0f}] ({r['k']}/{r['n']})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--group", action="append", default=[], help="NAME=cfg1,cfg2: report these configurations together")
    args = ap.parse_args()
    groups = {c: name for g in args.group for name, cfgs in [g.split("=", 1)] for c in cfgs.split(",")}
    table: dict[tuple[str, str], list[ResultRow]] = defaultdict(list)
    for r in ResultStore(args.out / "results").read():
        if r.ok and r.avoidable is not None:
            cfg = config_of(r.scene_key)
            table[(groups.get(cfg, cfg), r.planner)].append(r)
    print("| scenes | planner | defect rate | unavoidable-contact rate |\n|---|---|---|---|")
    for (group, planner), rows in sorted(table.items()):
        hit = [bool(r.contact_in_horizon) for r in rows]
        av = [h for h, r in zip(hit, rows, strict=True) if r.avoidable]
        un = [h for h, r in zip(hit, rows, strict=True) if not r.avoidable]
        print(f"| {group} | {planner} | {fmt(rate_with_ci(av))} | {fmt(rate_with_ci(un))} |")


if __name__ == "__main__":
    main()
