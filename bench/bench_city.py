"""``coster-sumo run`` against plain ``sumo`` on the same configuration, up to the target's arrival.

    python bench/bench_city.py [--vehicles-per-s 5] [--duration 1200] [--work DIR] [--target ID]
    python bench/bench_city.py --config networks/intersection/intersection.sumocfg   # any configuration
    python bench/bench_city.py --config networks/merge/merge.sumocfg --served       # through coster-sumo serve

Without ``--config`` it builds a city-scale configuration first (once, cached in ``--work``): the
real OSM network of Braunschweig that ships in the eclipse-sumo wheel (``tools/game/DRT``) with
``randomTrips.py`` demand (``--vehicles-per-s`` x ``--duration`` trips, validated by duarouter).
The target is a vehicle departing a quarter into the window with one of the longest routes.

Then, in this process tree, alternating ``--repeats`` times (default 2): ``coster-sumo run CFG
--target T --planner replay`` (5 variants, renders on) and plain ``sumo -c CFG --step-length 0.1
--end A`` (A: the target's arrival, as the coster-sumo run found it). It prints every wall time,
the best and worst run against the mean of the sumo runs, and the ratio of each back-to-back
(run, sumo) pair with their median (the machine's drift between pairs cancels in a pair). Goal on
a city-scale configuration: <= 1.3.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

from coster_sumo.cli import server
from coster_sumo.formats.sumocfg import read_sumocfg
from coster_sumo.formats.targets import config_demand
from coster_sumo.infra import sumo_install

REPO = Path(__file__).resolve().parents[1]


def build_city(work: Path, vehicles_per_s: float, duration_s: float, seed: int = 7) -> Path:
    """The city configuration in ``work`` (built once)."""
    cfg = work / "city.sumocfg"
    if cfg.is_file():
        return cfg
    work.mkdir(parents=True, exist_ok=True)
    net = sumo_install.sumo_home() / "tools" / "game" / "DRT" / "osm.net.xml"
    shutil.copy(net, work / "city.net.xml")
    subprocess.run([sys.executable, sumo_install.tool("randomTrips.py"), "-n", str(work / "city.net.xml"),
                    "-o", str(work / "city.trips.xml"), "-r", str(work / "city.rou.xml"), "-b", "0",
                    "-e", str(duration_s), "-p", str(1.0 / vehicles_per_s), "--seed", str(seed),
                    "--fringe-factor", "5", "--min-distance", "300", "--validate", "--vehicle-class", "passenger"],
                   check=True, capture_output=True, env=sumo_install.subprocess_env())
    cfg.write_text('<configuration>\n  <input>\n    <net-file value="city.net.xml"/>\n'
                   '    <route-files value="city.rou.xml"/>\n  </input>\n'
                   f'  <time>\n    <begin value="0"/>\n    <end value="{duration_s:g}"/>\n  </time>\n'
                   '</configuration>\n')
    return cfg


def pick_target(cfg: Path) -> str:
    """A vehicle departing a quarter into the window with one of the longest routes."""
    conf = read_sumocfg(cfg)
    begin, end = conf.begin or 0.0, conf.end or 3600.0
    best, best_len = None, -1
    pattern = re.compile(r'<vehicle id="([^"]+)"[^>]*depart="([0-9.]+)"[^>]*>\s*<route edges="([^"]+)"')
    text = conf.route_files[0].read_text()
    for m in pattern.finditer(text):
        depart = float(m.group(2))
        if begin + 0.2 * (end - begin) <= depart <= begin + 0.3 * (end - begin):
            n = len(m.group(3).split())
            if n > best_len:
                best, best_len = m.group(1), n
    if best is None:
        raise SystemExit(f"{cfg}: no vehicle departs a quarter into the window; pass --target")
    return best


def timed(cmd: list[str], env: dict[str, str] | None = None) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    if proc.returncode != 0:
        raise SystemExit(f"{cmd[0]} ... {cmd[-1]} failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", type=Path, help="a configuration (default: build the city)")
    ap.add_argument("--target", help="target vehicle (default: picked, or 'ego' for --config)")
    ap.add_argument("--vehicles-per-s", type=float, default=5.0)
    ap.add_argument("--duration", type=float, default=1200.0, help="[s] demand window of the city")
    ap.add_argument("--work", type=Path, default=Path("/tmp/coster-bench-city"))
    ap.add_argument("--repeats", type=int, default=2,
                    help="pairs of (run, sumo), alternating; the ratio of each pair and their median are printed")
    ap.add_argument("--served", action="store_true",
                    help="run through `coster-sumo serve` (started here, its own socket in --work): the run "
                         "without the imports every fresh command pays")
    args = ap.parse_args()
    if args.served:
        with server.serving(args.work / "sock" / "s.sock") as env:
            bench(args, env)
    else:
        bench(args, None)


def bench(args: argparse.Namespace, env: dict[str, str] | None) -> None:
    """The pairs of (run, sumo); ``env``: the environment of a running server (None: fresh processes)."""
    cfg = args.config or build_city(args.work, args.vehicles_per_s, args.duration)
    target = args.target or ("ego" if args.config else pick_target(cfg))
    demand = config_demand(cfg)  # what its route and additional files insert (gzipped ones too)
    vehicles = "?" if demand is None else f"{len(demand.vehicles)} vehicles and {len(demand.flows)} flows"
    out = args.work / "run"
    shutil.rmtree(out, ignore_errors=True)
    entry = "coster_sumo" if env is None else "coster_sumo.cli.client"  # the client hands the run to the server
    run_cmd = [sys.executable, "-m", entry, "--quiet", "run", str(cfg), "--target", target,
               "--planner", "replay", "-o", str(out), "--overwrite"]
    t_run = timed(run_cmd, env)
    summary = json.loads((out / "summary.json").read_text())
    until = summary["nominal_until_s"]
    sumo_cmd = [sumo_install.binary("sumo"), "-c", str(cfg), "--step-length", "0.1", "--end", f"{until:.1f}",
                "--no-step-log", "true", "--no-warnings", "true"]
    runs, t_sumo = [t_run], [timed(sumo_cmd)]
    n_pairs = max(2, args.repeats)
    for i in range(1, n_pairs + 1):
        if i > 1:
            runs.append(timed(run_cmd, env))
            t_sumo.append(timed(sumo_cmd))
        print(f"pair {i}/{n_pairs}: run {runs[-1]:.1f} s, sumo {t_sumo[-1]:.1f} s, ratio {runs[-1] / t_sumo[-1]:.2f}",
              flush=True)
    summary = json.loads((out / "summary.json").read_text())  # the last run's
    plain = sum(t_sumo) / len(t_sumo)
    pairs = [r / s for r, s in zip(runs, t_sumo, strict=True)]
    print(f"config {cfg} ({vehicles} in its demand), target {target}, simulated to {until:.1f} s")
    print(f"plain sumo (0.1 s steps, to the target's arrival): {' '.join(f'{t:.1f}' for t in t_sumo)} s")
    print(f"coster-sumo run (5 variants, renders): {' '.join(f'{t:.1f}' for t in runs)} s "
          f"(timings of the last: {summary['timings_s']}; {summary.get('num_variants')} variants kept)")
    print(f"ratio run / sumo: {min(runs) / plain:.2f} (best run), {max(runs) / plain:.2f} (worst run), against "
          "the mean of the sumo runs")
    print(f"ratio of each (run, sumo) pair: {' '.join(f'{r:.2f}' for r in pairs)}; "
          f"median {statistics.median(pairs):.2f}")
    print(f"run - sumo of each pair [s]: {' '.join(f'{r - s:.2f}' for r, s in zip(runs, t_sumo, strict=True))}; "
          f"median {statistics.median(r - s for r, s in zip(runs, t_sumo, strict=True)):.2f}"
          + (" (through coster-sumo serve)" if env is not None else ""))


if __name__ == "__main__":
    main()
