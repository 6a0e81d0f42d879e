"""``coster-sumo demo`` as a user types it, alone and with ``coster-sumo serve`` running, in one run.

    python bench/bench_demo_server.py [--repeats 5] [--network intersection]

Starts a server on a socket of its own (:mod:`coster_sumo.cli.server`), then alternates ``--repeats``
times: the demo alone (``COSTER_SUMO_SERVER=off``: a fresh process that imports everything) and the
demo handed to the server (the client process, a fork of the server runs it). One unmeasured run of
each first (files in the page cache). Every run is the whole command (renders on, a fresh OUT).
Printed: each run's wall time, the medians, the per-round ratio alone / served, and whether every
run had the same outcomes (tests/behaviour.py's rounding). The CPU time of a served run is the
server's child's, which this process cannot see: only wall times are compared.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
from behaviour import outcomes_of_run  # noqa: E402

from coster_sumo.cli import server  # noqa: E402

CLIENT = [sys.executable, "-m", "coster_sumo.cli.client"]


def demo(env: dict[str, str], out: Path, network: str) -> float:
    t = time.perf_counter()
    subprocess.run([*CLIENT, "--quiet", "demo", "--network", network, "-o", str(out), "--overwrite"], env=env,
                   check=True, capture_output=True)
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--network", default="intersection")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-serve-") as tmp:
        tmpdir = Path(tmp)
        sock = tmpdir / "sock" / "s.sock"
        with server.serving(sock) as served:
            alone = {**served, "COSTER_SUMO_SERVER": "off"}
            demo(alone, tmpdir / "warm-alone", args.network)
            demo(served, tmpdir / "warm-served", args.network)
            times: dict[str, list[float]] = {"alone": [], "served": []}
            outcomes = set()
            for r in range(args.repeats):
                order = ("alone", "served") if r % 2 == 0 else ("served", "alone")
                for how in order:
                    out = tmpdir / f"{how}{r}"
                    times[how].append(demo(alone if how == "alone" else served, out, args.network))
                    outcomes.add(repr(outcomes_of_run(out)))
                    print(f"round {r + 1} {how:6s} wall {times[how][-1]:6.2f} s", flush=True)
    ratios = [a / s for a, s in zip(times["alone"], times["served"], strict=True)]
    med = {how: statistics.median(ts) for how, ts in times.items()}
    print(f"\nmedian wall: alone {med['alone']:.2f} s, served {med['served']:.2f} s; per-round ratio alone / served: "
          f"median {statistics.median(ratios):.2f} ({min(ratios):.2f}-{max(ratios):.2f})")
    print("same outcomes in every run" if len(outcomes) == 1 else f"OUTCOMES DIFFER: {len(outcomes)} kinds")


if __name__ == "__main__":
    main()
