"""``coster-sumo run --planner replay`` on real-world SUMO configurations the project did not write.

    python bench/real_configs.py [--out DIR] [NAME ...]

The configurations ship in the eclipse-sumo wheel (``sumo/tools/game/``, found through the ``sumo``
package); each runs at its full configured duration (no --end), with a target named below. Prints
one row per configuration: exit code, wall time, t_col, and every variant's contact offset from
t_col on SUMO's step grid (acceptance: every variant in contact within 0.1 s).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from coster_sumo.infra import sumo_install

# name: (configuration under tools/game, target vehicle, what it is)
CONFIGS = {
    "fokr_bs_demo": ("fokr_bs_demo.sumocfg", "1695567712787794",
                     "Braunschweig intersection, measured demand 15:00-16:00, begin 54000 s, 0.05 s steps"),
    "fkk_in": ("fkk_in.sumocfg", "1_horizontal.0", "Ingolstadt (OSM) signalised junction, 180 s"),
    "bs3Dosm": ("bs3Dosm.sumocfg", "1_right.0", "Braunschweig (OSM) junction, made for sumo-gui's 3D view"),
    "A10KW": ("A10KW.sumocfg", "veh400", "motorway interchange A10 (OSM), 6,400 vehicles over 1,800 s"),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("names", nargs="*", default=list(CONFIGS))
    ap.add_argument("--out", type=Path, default=Path("/tmp/coster-real-configs"))
    args = ap.parse_args()
    game = sumo_install.sumo_home() / "tools" / "game"
    print("| configuration | what | target | exit | wall [s] | t_col [s] | contact offsets [s] |")
    print("|---|---|---|---|---|---|---|")
    for name in args.names:
        cfg, target, what = CONFIGS[name]
        out = args.out / name
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "coster_sumo", "--quiet", "run", str(game / cfg), "--target",
                               target, "--planner", "replay", "--no-render", "-o", str(out)],
                              capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if proc.returncode != 0:
            print(f"| {name} | {what} | {target} | {proc.returncode} | {wall:.0f} | - | "
                  f"{proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else ''} |", flush=True)
            continue
        summary = json.loads((out / "summary.json").read_text())
        offsets = [v["contact_offset_s"] for v in summary["variants"]]
        shown = " ".join("none" if o is None else f"{o:+.1f}" for o in offsets)
        print(f"| {name} | {what} | {target} | 0 | {wall:.0f} | {summary['t_col']:.1f} | {shown} |", flush=True)


if __name__ == "__main__":
    main()
