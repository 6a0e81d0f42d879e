"""Wall time of the same ``coster-sumo regress`` with 1 and with 2 workers; prints the speed-up (goal >= 1.8x).

    python bench/bench_regress.py [--variants 3] [--end 60] [--planner replay --planner sumo:IDM ...] [SOURCES...]

Both runs start from empty output folders (generation included) with the weight-free generator
(random init, constant-velocity rollout), so the figures need no trained weights. Each run is one
process per task (docs/sumo.md §6), so the ideal ratio is min(workers, cores) minus scheduling tails.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

from coster_sumo.batch.regress import RegressOptions, regress

REPO = Path(__file__).resolve().parents[1]
DEFAULT_SOURCES = [str(REPO / "networks" / n / f"{n}.sumocfg") for n in ("intersection", "merge", "arterial")]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sources", nargs="*", default=DEFAULT_SOURCES)
    ap.add_argument("--planner", action="append", dest="planners")
    ap.add_argument("--variants", type=int, default=3)
    ap.add_argument("--end", type=float, default=60.0, help="[s] end of every scene's window")
    ap.add_argument("--workers", type=int, nargs=2, default=(1, 2), metavar=("A", "B"))
    args = ap.parse_args()
    planners = args.planners or ["replay", "sumo:IDM", "sumo:Krauss"]
    times = {}
    summaries = {}
    for w in args.workers:
        out = Path(tempfile.mkdtemp(prefix=f"bench_regress_w{w}_"))
        try:
            ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            load0 = os.getloadavg()[0]
            t0 = time.perf_counter()
            s = regress(RegressOptions(sources=args.sources, planners=planners, out=out, variants=args.variants,
                                       workers=w, end=args.end, init="random", rollout="cv", report=False,
                                       quiet=True))
            times[w] = time.perf_counter() - t0
            ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
            summaries[w] = s
        finally:
            shutil.rmtree(out, ignore_errors=True)
        runs = s["runs"]
        print(f"workers={w}: {times[w]:.1f} s wall, {s['scenes']['generated']}/{s['scenes']['total']} scenes, "
              f"{runs['ok']}/{runs['expected']} runs ok ({runs['failed']} failed); task CPU {cpu:.1f} s = "
              f"{cpu / times[w]:.2f} cores busy on average; load average before {load0:.1f}")
    a, b = args.workers
    rates = [{p: v["CR"]["rate"] for p, v in summaries[w]["planners"].items()} for w in (a, b)]
    print(f"same results with {a} and {b} workers: {rates[0] == rates[1]}")
    print(f"cores: {os.cpu_count()}; speed-up {a} -> {b} workers: {times[a] / times[b]:.2f}x (goal >= 1.8x)")


if __name__ == "__main__":
    main()
