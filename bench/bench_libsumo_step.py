"""Stepping alone: a bare libsumo loop against the ``sumo`` binary, on one configuration.

    python bench/bench_libsumo_step.py --config <sumo>/tools/game/A10KW.sumocfg --end 1800

In one process tree, back to back: ``sumo`` with no extra options, ``sumo`` with the options
every coster-sumo simulation uses (:data:`coster_sumo.sim.sumo_options.RECOMMENDED_OPTIONS`), and
a child process that starts libsumo with the same options and calls ``simulationStep()`` once per
0.1 s step with nothing else (no recording, no held copies). It prints the three wall and CPU
times and the ratios: what ``coster-sumo run``'s nominal pass costs beyond these is the
recording's (bench/RESULTS.md, the ``bench_city.py`` section).
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import time
from pathlib import Path

from coster_sumo.infra import sumo_install
from coster_sumo.sim.sumo_options import RECOMMENDED_OPTIONS

_LOOP = """
import sys, libsumo
libsumo.start(sys.argv[1:])
end = float(sys.argv[sys.argv.index("--end") + 1])
while libsumo.simulation.getTime() < end - 1e-6:
    libsumo.simulationStep()
libsumo.close()
"""


def timed(cmd: list[str]) -> tuple[float, float]:
    """Wall time and CPU time (user + system) [s] of one child process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, env=sumo_install.subprocess_env())
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", type=Path, required=True)
    ap.add_argument("--end", type=float, required=True, help="[s] absolute simulation end")
    args = ap.parse_args()
    base = [sumo_install.binary("sumo"), "-c", str(args.config), "--end", f"{args.end:g}", "--step-length", "0.1",
            "--no-step-log", "true", "--no-warnings", "true"]
    ours = [v for kv in RECOMMENDED_OPTIONS.items() for v in kv if kv[0] not in base]  # SUMO refuses repeats
    plain = timed(base)
    with_opts = timed(base + ours)
    loop = timed([sys.executable, "-c", _LOOP, *base, *ours])
    for name, (wall, cpu) in (("sumo, plain", plain), ("sumo, coster-sumo's options", with_opts),
                              ("libsumo step loop, same options", loop)):
        print(f"{name}: {wall:.1f} s wall, {cpu:.1f} s CPU")
    print(f"libsumo / sumo with options: {loop[0] / with_opts[0]:.2f} (wall), {loop[1] / with_opts[1]:.2f} (CPU); "
          f"sumo with options / plain: {with_opts[0] / plain[0]:.2f} (wall), {with_opts[1] / plain[1]:.2f} (CPU)")


if __name__ == "__main__":
    main()
