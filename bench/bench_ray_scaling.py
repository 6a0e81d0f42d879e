"""Runs per CPU-minute of ``coster-sumo regress`` at 1 and 2 workers: local, Ray on one node, Ray on two nodes.

    python bench/bench_ray_scaling.py [--variants 3] [--end 60] [--planner replay ...] [SOURCES...]

The same batch (by default the three shipped networks, the weight-free generator: random init and
constant-velocity rollout, 3 variants, planners replay, sumo:IDM and sumo:Krauss) runs from an empty
OUT six times: the local executor with ``--workers 1`` and ``2``; a Ray cluster with one worker node
of 2 CPUs, ``--workers 1`` and ``2``; a Ray cluster with two worker nodes of 1 CPU each, ``--workers
1`` and ``2``. The clusters are real ``ray start`` processes on this machine (tests/ray_nodes.py): a
head that runs no task and worker nodes that cannot see the driver's folder, so every file travels
through Ray as on a cluster without a shared disk. Each run is the command line a user types; its
wall time includes the driver's start and, on Ray, connecting to the cluster (not starting it).

runs per CPU-minute = finished runs / (workers x wall minutes): the throughput per CPU the batch
was given. Parallel efficiency = the 2-worker figure / the 1-worker figure of the same setup (1.0:
two workers do twice the work of one). The script also checks that every setup recorded the same
outcome for every run.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from ray_nodes import ray_cluster  # noqa: E402

from coster_sumo.batch.store import ResultStore  # noqa: E402

DEFAULT_SOURCES = [str(REPO / "networks" / n / f"{n}.sumocfg") for n in ("intersection", "merge", "arterial")]
OUTCOME = ("status", "collision", "adversary_contact", "target_off_road", "route_completed", "min_ttc",
           "contact_time", "t_col")


def regress(args: argparse.Namespace, out: Path, cwd: Path, env: dict[str, str], workers: int,
            *extra: str) -> tuple[float, dict[str, tuple]]:
    cmd = [sys.executable, "-m", "coster_sumo", "-q", "regress", *args.sources, "--end", str(args.end), "--init",
           "random", "--rollout", "cv", "--variants", str(args.variants), "--workers", str(workers), "--no-report",
           "-o", str(out), *extra]
    for p in args.planners:
        cmd += ["--planner", p]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode not in (0, 1):
        raise SystemExit(f"regress failed ({done.returncode}): {done.stderr[-2000:]}")
    rows = {r.run_key: tuple(getattr(r, k) for k in OUTCOME) for r in ResultStore(out / "results").read()}
    return wall, rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sources", nargs="*", default=DEFAULT_SOURCES)
    ap.add_argument("--planner", action="append", dest="planners")
    ap.add_argument("--variants", type=int, default=3)
    ap.add_argument("--end", type=float, default=60.0, help="[s] end of every scene's window")
    args = ap.parse_args()
    args.planners = args.planners or ["replay", "sumo:IDM", "sumo:Krauss"]
    args.sources = [os.path.abspath(s) for s in args.sources]
    base = Path(tempfile.mkdtemp(prefix="bench_ray_scaling_"))
    driver = base / "driver"  # every OUT; hidden from the worker nodes
    driver.mkdir()
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0",
           "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    results: list[tuple[str, int, float, int, float]] = []
    rows: dict[str, dict[str, tuple]] = {}

    def one(setup: str, workers: int, run_env: dict[str, str], *extra: str) -> None:
        load = os.getloadavg()[0]
        out = driver / f"{setup.replace(' ', '_')}_w{workers}"
        wall, got = regress(args, out, driver, run_env, workers, *extra)
        ok = sum(r[0] == "ok" for r in got.values())
        rows[f"{setup} w{workers}"] = got
        results.append((setup, workers, wall, ok, load))
        print(f"{setup:<22} workers={workers}: {wall:6.1f} s wall, {ok}/{len(got)} runs ok, "
              f"{ok / (workers * wall / 60):.2f} runs per CPU-minute; load average before {load:.2f}", flush=True)

    try:
        for w in (1, 2):
            one("local", w, env)
        for setup, cpus in (("ray, one node", (2,)), ("ray, two nodes", (1, 1))):
            with ray_cluster(base / setup.replace(" ", "_").replace(",", ""), cpus, hidden=[driver]) as c:
                for w in (1, 2):
                    one(setup, w, c.env, "--executor", "ray", "--address", c.address)
    finally:
        shutil.rmtree(base, ignore_errors=True)
    print()
    print("| setup | workers | wall [s] | runs ok | runs per CPU-minute | parallel efficiency | load before |")
    print("|---|---|---|---|---|---|---|")
    rate = {(s, w): ok / (w * wall / 60) for s, w, wall, ok, _ in results}
    for s, w, wall, ok, load in results:
        eff = f"{rate[(s, 2)] / rate[(s, 1)]:.2f}" if w == 2 else ""
        print(f"| {s} | {w} | {wall:.1f} | {ok} | {rate[(s, w)]:.2f} | {eff} | {load:.2f} |")
    first = next(iter(rows.values()))
    print(f"\nsame outcome for every run in all {len(rows)} batches: {all(r == first for r in rows.values())} "
          f"({len(first)} runs each); cores: {os.cpu_count()}")


if __name__ == "__main__":
    main()
