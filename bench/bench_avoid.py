"""What avoidability (the escape search and its SUMO proof) adds to generation, measured in one run.

For each configuration, ``coster-sumo run`` (replay planner, no renders) is timed phase by phase in
one process: generation alone is the nominal pass, the drivable area, the snapshot + CVAE + vocabulary
and the variants' injection passes (what a run cost before labels); avoidability is the kinematic
search (``avoidability_s``) plus the SUMO replays of the escapes (``proof_s``). Prints both per
variant and the ratio (goal: at most 30 %).

    python bench/bench_avoid.py [CFG ...] [--seeds 3] [--traffic log|reactive]

``--traffic``: a converted scene's logged agents in every pass, the labels' proof included.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from coster_sumo.core.spec import GenerationConfig, ScenarioSpec
from coster_sumo.infra.progress import bars
from coster_sumo.pipeline.run import RunOptions, run

REPO = Path(__file__).resolve().parents[1]
DEFAULT = [REPO / "networks" / n / f"{n}.sumocfg" for n in ("intersection", "merge", "arterial")]
GENERATION = ("nominal_s", "drivable_s", "generation_s", "injection_s")
AVOIDABILITY = ("avoidability_s", "proof_s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("configs", nargs="*", type=Path, default=DEFAULT)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--json", type=Path, help="write the rows here too")
    ap.add_argument("--traffic", choices=("log", "reactive"), default="log")
    args = ap.parse_args()
    rows = []
    for cfg in args.configs:
        for seed in range(args.seeds):
            with tempfile.TemporaryDirectory(prefix="bench-avoid-") as tmp:
                opts = RunOptions(spec=ScenarioSpec(cfg, seed=seed), out=Path(tmp) / "out",
                                  generation=GenerationConfig(), planner="replay", render=False,
                                  traffic=args.traffic)
                s = run(opts, bars(quiet=True)).to_json()
            t = s["timings_s"]
            n = s["num_variants"]
            gen = sum(t.get(k, 0.0) for k in GENERATION)
            avo = sum(t.get(k, 0.0) for k in AVOIDABILITY)
            rows.append({"config": cfg.stem, "seed": seed, "variants": n, "generation_s": gen, "avoidability_s":
                         t.get("avoidability_s", 0.0), "proof_s": t.get("proof_s", 0.0), "ratio": avo / gen,
                         "avoidable": s["avoidable_variants"]})
            r = rows[-1]
            print(f"{cfg.stem:14s} seed {seed}: {n} variants, generation {gen / n:.2f} s/variant, search "
                  f"{r['avoidability_s'] / n:.3f} + SUMO proof {r['proof_s'] / n:.3f} s/variant = "
                  f"{100 * r['ratio']:.1f} % ({r['avoidable']} avoidable)", flush=True)
    gen = sum(r["generation_s"] for r in rows)
    avo = sum(r["avoidability_s"] + r["proof_s"] for r in rows)
    print(f"all {len(rows)} runs: avoidability adds {100 * avo / gen:.1f} % to generation "
          f"(search {sum(r['avoidability_s'] for r in rows):.1f} s, proof {sum(r['proof_s'] for r in rows):.1f} s, "
          f"generation {gen:.1f} s)")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
