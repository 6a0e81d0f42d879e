"""Scenarios per plain-SUMO pass on a city, for several numbers of targets, beside plain ``sumo``.

    python bench/bench_city_targets.py [--config CFG] [--targets 1 5 20] [--variants 5] [--work DIR]

For each N of ``--targets``, in this order and one process after the other: ``coster-sumo run CFG
--targets N --planner replay --variants V --no-render`` (one nominal pass for the N targets), then
plain ``sumo -c CFG --step-length 0.1 --end E`` with E where that run's nominal pass ended
(``nominal_until_s``). Default CFG: the wheel's A10KW motorway interchange. Prints per N the two
wall times, their ratio, the run's phases (its nominal pass, and generation summed over the
targets and per target), the scenarios (variants kept, over all targets), how many of them were in
contact with their target within 0.1 s of t_col, and **scenarios per plain-SUMO pass**: the
scenarios divided by the ratio, i.e. how many the run gives in the time plain SUMO takes to
simulate the same window once. Timings on a shared machine are noisy: run it when the machine is
quiet, and compare a run only with the ``sumo`` run beside it.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from coster_sumo.infra import sumo_install


def timed(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{cmd[0]} ... failed ({proc.returncode}): {proc.stderr.strip()[-800:]}")
    return time.perf_counter() - t0


def target_summaries(out: Path) -> list[dict[str, Any]]:
    """Each target's summary.json of a run (one target: OUT's own; several: their folders')."""
    top = json.loads((out / "summary.json").read_text())
    if "targets" not in top:
        return [top]
    return [json.loads((out / t["folder"] / "summary.json").read_text()) for t in top["targets"] if t.get("folder")]


def one(cfg: Path, n: int, variants: int, work: Path) -> dict[str, Any]:
    out = work / f"run_{n}"
    run_cmd = [sys.executable, "-m", "coster_sumo", "--quiet", "run", str(cfg), "--targets", str(n),
               "--planner", "replay", "--variants", str(variants), "--no-render", "-o", str(out), "--overwrite"]
    t_run = timed(run_cmd)
    top = json.loads((out / "summary.json").read_text())
    until = float(top["nominal_until_s"])
    t_sumo = timed([sumo_install.binary("sumo"), "-c", str(cfg), "--step-length", "0.1", "--end", f"{until:.1f}",
                    "--no-step-log", "true", "--no-warnings", "true"])
    per = target_summaries(out)
    scenarios = sum(len(s["variants"]) for s in per)
    contact = sum(1 for s in per for v in s["variants"]
                  if v.get("collision") and v.get("contact_offset_s") is not None and abs(v["contact_offset_s"]) <= 0.1)
    generation = [float(s["timings_s"]["generation_s"]) for s in per]
    return {"targets": n, "with_scenarios": len(per), "run_s": t_run, "sumo_s": t_sumo, "ratio": t_run / t_sumo,
            "until_s": until, "nominal_s": float(top["timings_s"]["nominal_s"]), "generation_s": sum(generation),
            "generation_max_s": max(generation, default=0.0), "scenarios": scenarios, "in_contact": contact,
            "scenarios_per_sumo_pass": scenarios / (t_run / t_sumo)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", type=Path, help="default: the wheel's tools/game/A10KW.sumocfg")
    ap.add_argument("--targets", type=int, nargs="+", default=[1, 5, 20])
    ap.add_argument("--variants", type=int, default=5)
    ap.add_argument("--work", type=Path, default=Path("/tmp/coster-bench-city-targets"))
    args = ap.parse_args()
    cfg = args.config or sumo_install.sumo_home() / "tools" / "game" / "A10KW.sumocfg"
    args.work.mkdir(parents=True, exist_ok=True)
    for n in args.targets:
        r = one(cfg, n, args.variants, args.work)
        print(f"{n} targets ({r['with_scenarios']} with scenarios) to {r['until_s']:.1f} s: run {r['run_s']:.1f} s "
              f"(nominal pass {r['nominal_s']:.1f} s, generation {r['generation_s']:.1f} s in all, at most "
              f"{r['generation_max_s']:.1f} s per target), sumo {r['sumo_s']:.1f} s, ratio {r['ratio']:.2f}; "
              f"{r['scenarios']} scenarios ({r['in_contact']} in contact within 0.1 s of t_col), "
              f"{r['scenarios_per_sumo_pass']:.2f} per plain-SUMO pass", flush=True)


if __name__ == "__main__":
    main()
