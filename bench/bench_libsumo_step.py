"""Stepping alone: a bare libsumo loop against the ``sumo`` binary, on one configuration.

    python bench/bench_libsumo_step.py --config <sumo>/tools/game/A10KW.sumocfg --end 1800

In one process tree, back to back: ``sumo`` with no extra options, ``sumo`` with the options
every coster-sumo simulation uses (:data:`coster_sumo.sim.sumo_options.RECOMMENDED_OPTIONS`), and
a child process that starts libsumo with the same options and calls ``simulationStep()`` once per
0.1 s step with nothing else (no recording, no held copies). It prints the three wall times and
the ratio libsumo / sumo: what ``coster-sumo run``'s nominal pass costs beyond these is the
recording's (bench/RESULTS.md, the ``bench_city.py`` section).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

from coster_sumo import sumo_env
from coster_sumo.sim.sumo_options import RECOMMENDED_OPTIONS

_LOOP = """
import sys, libsumo
libsumo.start(sys.argv[1:])
end = float(sys.argv[sys.argv.index("--end") + 1])
while libsumo.simulation.getTime() < end - 1e-6:
    libsumo.simulationStep()
libsumo.close()
"""


def timed(cmd: list[str]) -> float:
    t = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, env=sumo_env.subprocess_env())
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", type=Path, required=True)
    ap.add_argument("--end", type=float, required=True, help="[s] absolute simulation end")
    args = ap.parse_args()
    base = [sumo_env.binary("sumo"), "-c", str(args.config), "--end", f"{args.end:g}", "--step-length", "0.1",
            "--no-step-log", "true", "--no-warnings", "true"]
    ours = [v for kv in RECOMMENDED_OPTIONS.items() for v in kv if kv[0] not in base]  # SUMO refuses repeats
    plain = timed(base)
    with_opts = timed(base + ours)
    loop = timed([sys.executable, "-c", _LOOP, *base, *ours])
    print(f"sumo, plain: {plain:.1f} s; sumo, coster-sumo's options: {with_opts:.1f} s; "
          f"libsumo step loop, same options: {loop:.1f} s; libsumo / sumo with options: {loop / with_opts:.2f}")


if __name__ == "__main__":
    main()
