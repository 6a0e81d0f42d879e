"""Benchmark: wall time of ``coster-sumo demo`` (renders on), this tree against a git ref, in one run.

Each recipe runs the whole command in a fresh process, as a user types it: **baseline** = the
package as of ``--baseline-ref`` (extracted from git with its networks and weights into a
temporary folder, first on ``sys.path``), **current** = this working tree's installed command. One
unmeasured run of each first (a warm machine: files in the page cache), then ``--repeats`` rounds
that alternate the order. Reported per run: the wall time, the phases the run records in
``summary.json`` (``timings_s``), what is left (start-up, renders, writing) and the CPU time of
its processes (user + system: what a loaded machine cannot hide); per recipe the medians; the
median of the per-round ratios baseline / current; and whether every run has the same outcomes
(per variant: contact, contact time, relative speed, impact angle, off-road, route completion,
rounded as ``tests/behaviour.py`` rounds them).

Usage:
    python bench/bench_demo.py [--repeats 5] [--baseline-ref REF] [--network intersection]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_generation import BASELINE_REF, REPO, extract_ref  # noqa: E402

sys.path.insert(0, str(REPO / "tests"))
from behaviour import outcomes_of_run  # noqa: E402

PACKAGE_DATA = (("models", "coster_sumo/models"), ("networks", "coster_sumo/networks"))


def run_demo(cmd: list[str], out: Path, network: str) -> tuple[float, float, dict[str, Any]]:
    """Wall time [s] of one ``demo`` command, the CPU time [s] of its processes (user + system, every
    process of it that was waited for), and its summary."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([*cmd, "--quiet", "demo", "--network", network, "-o", str(out), "--overwrite"], check=True,
                   capture_output=True, text=True, cwd=out.parent)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, json.loads((out / "summary.json").read_text())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--baseline-ref", default=BASELINE_REF)
    ap.add_argument("--network", default="intersection")
    ap.add_argument("--json", type=Path, help="write every measurement here")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-demo-") as tmp:
        root = extract_ref(args.baseline_ref, Path(tmp) / "tree", extra=PACKAGE_DATA)
        launcher = ("import sys; sys.path.insert(0, sys.argv.pop(1)); "
                    "from coster_sumo.cli.command_line import main; sys.exit(main())")
        cmds = {"baseline": [sys.executable, "-c", launcher, str(root)],
                "current": [str(Path(sys.executable).parent / "coster-sumo")]}
        outs = {k: Path(tmp) / f"out_{k}" for k in cmds}
        for k in cmds:  # warm-up
            run_demo(cmds[k], outs[k], args.network)
        load0 = os.getloadavg()
        runs: dict[str, list[dict[str, Any]]] = {k: [] for k in cmds}
        for r in range(args.repeats):
            for k in (("baseline", "current") if r % 2 == 0 else ("current", "baseline")):
                wall, cpu, summary = run_demo(cmds[k], outs[k], args.network)
                phases = summary["timings_s"]
                runs[k].append({"wall_s": wall, "cpu_s": cpu, "phases": phases, "rest_s": wall - sum(phases.values()),
                                "outcomes": outcomes_of_run(outs[k])})
                print(f"round {r} {k}: wall {wall:.2f} s, CPU {cpu:.2f} s; "
                      + ", ".join(f"{p} {v:.2f}" for p, v in phases.items()) + f"; rest {runs[k][-1]['rest_s']:.2f}",
                      flush=True)
        load1 = os.getloadavg()
    reference = runs["baseline"][0]["outcomes"]
    same = all(x["outcomes"] == reference for k in runs for x in runs[k])
    print(f"\n{args.network}, {args.repeats} rounds; outcomes the same in every run: {same} "
          f"({len(reference)} variants)")
    keys = list(dict.fromkeys(p for k in runs for x in runs[k] for p in x["phases"]))
    print("| phase | baseline median [s] | current median [s] |\n|---|---|---|")
    for p in [*keys, "rest_s", "wall_s", "cpu_s"]:
        def med(k: str, p: str = p) -> float:
            return statistics.median(x["phases"].get(p, 0.0) if p in keys else x[p] for x in runs[k])
        print(f"| {p} | {med('baseline'):.2f} | {med('current'):.2f} |")
    ratios = [b["wall_s"] / c["wall_s"] for b, c in zip(runs["baseline"], runs["current"], strict=True)]
    print(f"per-round wall ratio baseline / current: median {statistics.median(ratios):.2f} (min {min(ratios):.2f}, "
          f"max {max(ratios):.2f}); load average {load0[0]:.1f} at the start, {load1[0]:.1f} at the end; "
          f"{os.cpu_count()} cores; {time.strftime('%Y-%m-%d %H:%M')}")
    if args.json:
        args.json.write_text(json.dumps({"runs": runs, "load": [load0, load1]}, indent=1))


if __name__ == "__main__":
    main()
