"""What the nominal pass adds to SUMO's own stepping, part by part, on one configuration.

    python bench/bench_record_parts.py --config <sumo>/tools/game/A10KW.sumocfg --target veh400 --end 700

In one process tree, ``--repeats`` rounds (default 2), each of these back to back, every one a fresh
child process:

- ``sumo``: the ``sumo`` binary with the options every coster-sumo simulation uses;
- ``libsumo``: libsumo started with the same options, ``simulationStep()`` in a bare loop;
- ``record``: the nominal pass of ``coster-sumo run`` (:func:`coster_sumo.pipeline.scenario.nominal_scene`:
  the target every step, its surroundings at 2 Hz, the signals, the arrays), no held copies;
- ``record+hold``: the same with the held copies a run makes (:class:`coster_sumo.sim.hold.HeldStates`).

Each child's wall and CPU time (user + system, of it and the processes it forked) are printed, then
the median of each part and its ratio to the ``sumo`` binary. Times include starting the simulation
(loading the network) in every part. CPU time is the steadier figure on a shared machine.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

from coster_sumo.infra import sumo_install
from coster_sumo.sim.sumo_options import RECOMMENDED_OPTIONS

_OPTIONS = [x for kv in RECOMMENDED_OPTIONS.items() for x in kv]

_BARE = """
import sys, libsumo
cfg, end, options = sys.argv[1], float(sys.argv[2]), sys.argv[3:]
libsumo.start(["sumo", "-c", cfg, "--seed", "0", *options])
while libsumo.simulation.getTime() < end - 1e-6:
    libsumo.simulationStep()
libsumo.close()
"""

_RECORD = """
import sys
from pathlib import Path
from coster_sumo.method.collision_time import PRIOR_RATE_HZ
from coster_sumo.rollout.methods import HORIZON_STEPS
from coster_sumo.pipeline.scenario import nominal_scene
from coster_sumo.sim.hold import HeldStates
from coster_sumo.core.spec import ScenarioSpec

cfg, target, end, mode = Path(sys.argv[1]), sys.argv[2], float(sys.argv[3]), sys.argv[4]
spec = ScenarioSpec(cfg, seed=0, end=end, target=target)
if mode == "record":
    nominal_scene(spec)
else:
    with HeldStates(target, lead_s=HORIZON_STEPS / PRIOR_RATE_HZ) as held:
        nominal_scene(spec, hold=held)
"""

PARTS = ("sumo", "libsumo", "record", "record+hold")


def timed(cmd: list[str]) -> tuple[float, float]:
    """Wall and CPU time (user + system) [s] of one child process and its descendants."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=sumo_install.subprocess_env())
    wall = time.perf_counter() - t
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd[:3])} ... failed ({proc.returncode}): {proc.stderr.strip()[-400:]}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def commands(cfg: Path, target: str, end: float) -> dict[str, list[str]]:
    py = sys.executable
    return {
        "sumo": [str(sumo_install.binary("sumo")), "-c", str(cfg), "--seed", "0", "--end", f"{end:g}", *_OPTIONS],
        "libsumo": [py, "-c", _BARE, str(cfg), f"{end:g}", *_OPTIONS],
        "record": [py, "-c", _RECORD, str(cfg), target, f"{end:g}", "record"],
        "record+hold": [py, "-c", _RECORD, str(cfg), target, f"{end:g}", "hold"],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", type=Path, required=True)
    ap.add_argument("--target", required=True)
    ap.add_argument("--end", type=float, required=True, help="[s] simulate up to this time")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--parts", nargs="+", choices=PARTS, default=list(PARTS))
    args = ap.parse_args()
    cmds = commands(args.config.resolve(), args.target, args.end)
    times: dict[str, list[tuple[float, float]]] = {p: [] for p in args.parts}
    for r in range(args.repeats):
        for part in args.parts:
            wall, cpu = timed(cmds[part])
            times[part].append((wall, cpu))
            print(f"round {r + 1} {part:12s} wall {wall:7.1f} s  cpu {cpu:7.1f} s", flush=True)
    ref = times.get("sumo")
    print(f"\nmedians over {args.repeats} rounds, {args.config.name} to {args.end:g} s"
          + (" (ratio: to the sumo binary)" if ref else ""))
    for part, ts in times.items():
        wall, cpu = statistics.median(w for w, _ in ts), statistics.median(c for _, c in ts)
        line = f"{part:12s} wall {wall:7.1f} s  cpu {cpu:7.1f} s"
        if ref:
            line += (f"   ratio wall {wall / statistics.median(w for w, _ in ref):.2f}"
                     f"  cpu {cpu / statistics.median(c for _, c in ref):.2f}")
        print(line)


if __name__ == "__main__":
    main()
