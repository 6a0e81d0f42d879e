"""Scenarios per plain-SUMO pass on a city, for several numbers of targets, beside plain ``sumo``.

    python bench/bench_city_targets.py [--config CFG] [--targets 1 5 20] [--variants 5] [--work DIR] [--pass]

For each N of ``--targets``, in this order and one process after the other: ``coster-sumo run CFG
--targets N --planner replay --variants V --no-render`` (one nominal pass for the N targets), then
plain ``sumo -c CFG --step-length 0.1 --end E`` with E where that run's nominal pass ended
(``nominal_until_s``). Default CFG: the wheel's A10KW motorway interchange. Prints per N the two
wall times and their ratio, the two **CPU times** (user + system of the command and of every
process under it) and their ratio, the run's phases (its start-up and nominal pass; generation,
labels, variants and outputs summed over the targets; generation at most per target), the
scenarios (variants kept, over all targets), how many of them were in contact with their target
within 0.1 s of t_col, and **scenarios per plain-SUMO pass**: the scenarios divided by the ratio,
i.e. how many the run gives in the time plain SUMO takes to simulate the same window once (on wall
and on CPU time). ``--pass`` also times the run's nominal pass alone, as a third child process
after plain ``sumo``: the same targets in the same order, with the held copies a run makes, nothing
after it; its wall time is the run's ``nominal_s`` measured again, its CPU time is the pass's own.

On a machine shared with other jobs the wall ratio depends on what else ran in each command's
minutes; the CPU ratio counts the work each command made the machine do. It also counts work that a
quiet machine would do side by side (the held copies of the pass advancing while generation runs,
torch on more than one thread), so there it is the higher of the two. The bench makes itself a
child subreaper (Linux), so that processes orphaned under the run (a held copy whose holder quit)
are reaped by it and counted.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from coster_sumo.infra import sumo_install

PR_SET_CHILD_SUBREAPER = 36
# the nominal pass of run, alone (as coster_sumo.pipeline.run.run starts it)
_PASS = """
import sys
from pathlib import Path
from coster_sumo.core.spec import ScenarioSpec
from coster_sumo.formats.source import ScenarioSource
from coster_sumo.method.collision_time import PRIOR_RATE_HZ
from coster_sumo.pipeline.scenario import nominal_pass
from coster_sumo.rollout.methods import HORIZON_STEPS
from coster_sumo.sim.hold import HeldStates

cfg, ids = Path(sys.argv[1]), sys.argv[2:]
with HeldStates(ids[0], lead_s=HORIZON_STEPS / PRIOR_RATE_HZ, more_targets=ids[1:]) as held:
    nominal_pass(ScenarioSource.of(ScenarioSpec(cfg, seed=0, target=ids[0])), ids, hold=held)
"""
# the phases of a run's summary.json that come after the pass, each summed over the targets
AFTER_PASS = ("generation_s", "avoidability_s", "proof_s", "labels_other_s", "injection_s", "outputs_s")


def become_subreaper() -> bool:
    """Linux: orphans of the commands run from here are reparented to this process, not to init."""
    with contextlib.suppress(Exception):
        return ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1) == 0
    return False


def reap_orphans(wait_s: float = 60.0) -> tuple[int, bool]:
    """Wait for every process reparented to this one: how many there were, and False where some still
    ran after ``wait_s`` (their CPU time is then missing from RUSAGE_CHILDREN)."""
    deadline, reaped = time.monotonic() + wait_s, 0
    while True:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return reaped, True  # no child left
        if pid:
            reaped += 1
        elif time.monotonic() > deadline:
            return reaped, False
        else:
            time.sleep(0.2)


def timed(cmd: list[str]) -> tuple[float, float]:
    """Wall and CPU time [s] of ``cmd``, the CPU time of every process under it included (with a
    note where some of them were orphaned, i.e. reaped here rather than by their parents)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    orphans, all_reaped = reap_orphans()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{cmd[0]} ... failed ({proc.returncode}): {proc.stderr.strip()[-800:]}")
    if not all_reaped:
        print(f"warning: processes under {cmd[0]} still ran after it: its CPU time misses them", flush=True)
    if orphans:
        print(f"note: {orphans} orphaned processes under {Path(cmd[0]).name} ... reaped here", flush=True)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def target_summaries(out: Path) -> list[dict[str, Any]]:
    """Each target's summary.json of a run (one target: OUT's own; several: their folders')."""
    top = json.loads((out / "summary.json").read_text())
    if "targets" not in top:
        return [top]
    return [json.loads((out / t["folder"] / "summary.json").read_text()) for t in top["targets"] if t.get("folder")]


def one(cfg: Path, n: int, variants: int, work: Path, alone: bool) -> dict[str, Any]:
    out = work / f"run_{n}"
    run_cmd = [sys.executable, "-m", "coster_sumo", "--quiet", "run", str(cfg), "--targets", str(n),
               "--planner", "replay", "--variants", str(variants), "--no-render", "-o", str(out), "--overwrite"]
    t_run, c_run = timed(run_cmd)
    top = json.loads((out / "summary.json").read_text())
    until = float(top["nominal_until_s"])
    t_sumo, c_sumo = timed([sumo_install.binary("sumo"), "-c", str(cfg), "--step-length", "0.1", "--end",
                            f"{until:.1f}", "--no-step-log", "true", "--no-warnings", "true"])
    pass_alone = {}
    if alone:
        ids = [str(t["target"]) for t in top["targets"]] if "targets" in top else [str(top["target"])]
        pass_alone = dict(zip(("pass_s", "pass_cpu_s"), timed([sys.executable, "-c", _PASS, str(cfg), *ids]),
                              strict=True))
    per = target_summaries(out)
    scenarios = sum(len(s["variants"]) for s in per)
    contact = sum(1 for s in per for v in s["variants"]
                  if v.get("collision") and v.get("contact_offset_s") is not None and abs(v["contact_offset_s"]) <= 0.1)
    phases = {k: float(top["timings_s"][k]) for k in ("startup_s", "nominal_s", "drivable_s")}
    phases.update({k: sum(float(s["timings_s"].get(k, 0.0)) for s in per) for k in AFTER_PASS})
    generation = [float(s["timings_s"]["generation_s"]) for s in per]
    return {"targets": n, "with_scenarios": len(per), "run_s": t_run, "sumo_s": t_sumo, "ratio": t_run / t_sumo,
            "run_cpu_s": c_run, "sumo_cpu_s": c_sumo, "cpu_ratio": c_run / c_sumo, "until_s": until,
            "phases_s": phases, "generation_max_s": max(generation, default=0.0),
            "generation_per_target_s": sum(generation) / max(1, len(per)), "scenarios": scenarios,
            "in_contact": contact, "scenarios_per_sumo_pass": scenarios / (t_run / t_sumo),
            "scenarios_per_sumo_pass_cpu": scenarios / (c_run / c_sumo), **pass_alone}


def report(r: dict[str, Any]) -> str:
    ph = r["phases_s"]
    phases = ", ".join(f"{k.removesuffix('_s')} {v:.1f}" for k, v in ph.items())
    alone = (f"  the pass alone: wall {r['pass_s']:.1f} s, CPU {r['pass_cpu_s']:.1f} s, over sumo's "
             f"{r['pass_s'] / r['sumo_s']:.2f} (wall), {r['pass_cpu_s'] / r['sumo_cpu_s']:.2f} (CPU)\n"
             if "pass_s" in r else "")
    return (f"{r['targets']} targets ({r['with_scenarios']} with scenarios) to {r['until_s']:.1f} s:\n"
            f"  wall: run {r['run_s']:.1f} s, sumo {r['sumo_s']:.1f} s, ratio {r['ratio']:.2f}; "
            f"nominal pass / sumo {ph['nominal_s'] / r['sumo_s']:.2f}\n"
            f"  CPU (user+sys, with descendants): run {r['run_cpu_s']:.1f} s, sumo {r['sumo_cpu_s']:.1f} s, "
            f"ratio {r['cpu_ratio']:.2f}\n{alone}"
            f"  phases [s, wall] {phases}; generation per target {r['generation_per_target_s']:.2f}, "
            f"at most {r['generation_max_s']:.2f}\n"
            f"  {r['scenarios']} scenarios ({r['in_contact']} in contact within 0.1 s of t_col); per plain-SUMO pass "
            f"{r['scenarios_per_sumo_pass']:.2f} (wall), {r['scenarios_per_sumo_pass_cpu']:.2f} (CPU)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", type=Path, help="default: the wheel's tools/game/A10KW.sumocfg")
    ap.add_argument("--targets", type=int, nargs="+", default=[1, 5, 20])
    ap.add_argument("--variants", type=int, default=5)
    ap.add_argument("--work", type=Path, default=Path("/tmp/coster-bench-city-targets"))
    ap.add_argument("--pass", dest="alone", action="store_true", help="also time the nominal pass alone")
    args = ap.parse_args()
    cfg = args.config or sumo_install.sumo_home() / "tools" / "game" / "A10KW.sumocfg"
    args.work.mkdir(parents=True, exist_ok=True)
    if not become_subreaper():
        print("warning: not a child subreaper: orphaned processes under the run are not in its CPU time")
    for n in args.targets:
        print(f"load average before: {os.getloadavg()[0]:.2f} ({time.strftime('%Y-%m-%d %H:%M')})", flush=True)
        r = one(cfg, n, args.variants, args.work, args.alone)
        print(report(r), flush=True)
        print(f"load average after: {os.getloadavg()[0]:.2f}", flush=True)
        (args.work / f"result_{n}.json").write_text(json.dumps(r, indent=1))


if __name__ == "__main__":
    main()
