"""Benchmark: reading training batches from a rollout feature cache larger than memory, with the
kernel's read-ahead (the mapping's default advice) against ``MADV_RANDOM``
(:func:`coster_sumo.rollout.cache.random_access`, what training uses), in one run.

Each variant runs in its own process, alternating, ``--repeats`` times: it opens the cache, picks
``--batches`` batches of ``--batch`` random examples (rows drawn from its own seed, so no variant
reads rows another one has just brought into the page cache) and assembles them
(:meth:`~coster_sumo.rollout.cache.CachedExamples.batch`). It reports the milliseconds per batch and
the megabytes read from the disk per batch (``read_bytes`` of ``/proc/self/io``). Only a cache much
larger than the machine's memory shows the difference: on one that fits, both variants read each
page once and then hit the page cache.

Usage:
    python bench/bench_cache_io.py DATASET [--batches 20] [--batch 256] [--repeats 3]

DATASET: a dataset folder whose training-split cache exists (``coster-sumo train rollout --data
DATASET`` builds it; the largest ``DATASET/.cache/rollout-*`` folder is read).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def one(folder: str, advice: str, batches: int, batch: int, seed: int) -> dict[str, float]:
    from coster_sumo.rollout import cache
    from coster_sumo.rollout.config import RolloutConfig

    if advice == "default":  # what the mapping gets without the advice
        cache.random_access = lambda array: None  # type: ignore[assignment]
    ex = cache.CachedExamples(folder)
    cfg = RolloutConfig()
    rng = np.random.default_rng(seed)

    def read_bytes() -> int:
        for line in Path("/proc/self/io").read_text().splitlines():
            if line.startswith("read_bytes:"):
                return int(line.split()[1])
        return 0

    b0, t0 = read_bytes(), time.perf_counter()
    for _ in range(batches):
        ex.batch(rng.choice(len(ex), batch, replace=False), cfg)
    return {"ms_per_batch": (time.perf_counter() - t0) / batches * 1e3,
            "mb_read_per_batch": (read_bytes() - b0) / batches / 1e6, "examples": len(ex)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", nargs="?")
    ap.add_argument("--batches", type=int, default=20)
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--one", nargs=3, metavar=("FOLDER", "ADVICE", "SEED"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(one(args.one[0], args.one[1], args.batches, args.batch, int(args.one[2]))))
        return 0
    if not args.data:
        ap.error("DATASET is required")
    sizes = {p: sum(f.stat().st_size for f in p.iterdir()) for p in Path(args.data, ".cache").glob("rollout-*")}
    if not sizes:
        print(f"{args.data}: no rollout feature cache (run coster-sumo train rollout --data {args.data} first)",
              file=sys.stderr)
        return 2
    folder = max(sizes, key=sizes.__getitem__)
    size_gb = sizes[folder] / 1e9
    mem_gb = next(int(line.split()[1]) for line in Path("/proc/meminfo").read_text().splitlines()
                  if line.startswith("MemTotal:")) / 1e6
    print(f"cache {folder} ({size_gb:.1f} GB; memory {mem_gb:.1f} GB)")
    results: dict[str, list[dict[str, float]]] = {"default": [], "random": []}
    for r in range(args.repeats):
        for i, advice in enumerate(results):
            out = subprocess.run([sys.executable, __file__, "--one", str(folder), advice, str(1000 * r + i),
                                  "--batches", str(args.batches), "--batch", str(args.batch)],
                                 check=True, capture_output=True, text=True).stdout
            results[advice].append(json.loads(out))
            print(f"  {advice:8s} repeat {r + 1}: {results[advice][-1]['ms_per_batch']:.0f} ms/batch, "
                  f"{results[advice][-1]['mb_read_per_batch']:.1f} MB read/batch")
    med = {k: {m: float(np.median([x[m] for x in v])) for m in ("ms_per_batch", "mb_read_per_batch")}
           for k, v in results.items()}
    print(f"\n| advice | ms per batch of {args.batch} | MB read per batch |\n|---|---|---|")
    for k, v in med.items():
        print(f"| {k} | {v['ms_per_batch']:.0f} | {v['mb_read_per_batch']:.1f} |")
    ratio = med["default"]["ms_per_batch"] / max(med["random"]["ms_per_batch"], 1e-9)
    print(f"\nMADV_RANDOM assembles a batch {ratio:.1f}x as fast (medians of {args.repeats} repeats)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
