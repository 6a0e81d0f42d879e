"""``coster-sumo run`` against plain ``sumo`` on a flow freeway with sublane lane changes, in one run.

    python bench/bench_freeway.py [--work DIR] [--end 900] [--target highway1.400]

Builds (in ``--work``) a copy of the wheel's ``tools/game/ramp`` (a motorway with an on- and an
off-ramp, demand as flows) whose own configuration runs to ``--end`` (default 900 s: plain
``sumo`` then takes about as long as on the configuration issue 59 measured, 28 s; the flows
congest the motorway from about 500 s on) and steps at 0.5 s with the sublane model
(``lateral-resolution`` 0.8 m) and declares outputs beside itself (an induction loop writing
``out.xml``, edge data, tripinfo), with a file of the user's already named ``out.xml``. Then runs
``coster-sumo run CFG --target T --planner replay`` (5 variants, renders on) once and plain
``sumo -c CFG --step-length 0.1 --end A`` (A: the end of the run's nominal pass) on a copy of
the folder, and prints: both wall times and their ratio, the run's ``timings_s`` and the share of
its wall time they cover, and whether the configuration's folder is byte-identical afterwards.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

from coster_sumo.infra import sumo_install

CONFIG = """<configuration>
    <input>
        <net-file value="ramp.net.xml"/>
        <route-files value="ramp.rou.xml"/>
        <additional-files value="det.add.xml"/>
    </input>
    <time>
        <begin value="0"/>
        <end value="{end}"/>
        <step-length value="0.5"/>
    </time>
    <processing>
        <lateral-resolution value="0.8"/>
    </processing>
    <output>
        <tripinfo-output value="trips.xml"/>
    </output>
</configuration>
"""
DETECTORS = """<additional>
    <inductionLoop id="loop0" lane="gneE2_0" pos="50" period="60" file="out.xml"/>
    <edgeData id="ed" period="60" file="edges.xml"/>
</additional>
"""


def build(work: Path, end: float) -> Path:
    """The freeway configuration in ``work/cfg`` (rebuilt every time: the check needs the user's file)."""
    folder = work / "cfg"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    ramp = sumo_install.sumo_home() / "tools" / "game" / "ramp"
    for name in ("ramp.net.xml", "ramp.rou.xml"):
        shutil.copy(ramp / name, folder / name)
    (folder / "fw.sumocfg").write_text(CONFIG.replace("{end}", f"{end:g}"))
    (folder / "det.add.xml").write_text(DETECTORS)
    (folder / "out.xml").write_text("<the-users-own-calibration-data/>\n")
    return folder / "fw.sumocfg"


def tree_hash(folder: Path) -> dict[str, str]:
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def timed(cmd: list[str], cwd: Path | None = None) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=cwd)
    if proc.returncode != 0:
        raise SystemExit(f"{cmd[0]} ... failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("/tmp/coster-bench-freeway"))
    ap.add_argument("--end", type=float, default=900.0, help="the configuration's end [s] (default 900)")
    ap.add_argument("--target", default="highway1.400",
                    help="a flow member (default highway1.400: departs at about 685 s, in the congestion)")
    args = ap.parse_args()
    cfg = build(args.work, args.end)
    before = tree_hash(cfg.parent)
    out = args.work / "run"
    shutil.rmtree(out, ignore_errors=True)
    t_run = timed([sys.executable, "-m", "coster_sumo", "--quiet", "run", str(cfg), "--target", args.target,
                   "--planner", "replay", "-o", str(out)])
    untouched = tree_hash(cfg.parent) == before
    summary = json.loads((out / "summary.json").read_text())
    until = summary["nominal_until_s"]
    plain = args.work / "plain"  # plain sumo writes the configuration's outputs: into a copy
    shutil.rmtree(plain, ignore_errors=True)
    shutil.copytree(cfg.parent, plain)
    t_sumo = timed([sumo_install.binary("sumo"), "-c", str(plain / cfg.name), "--step-length", "0.1", "--end",
                    f"{until:.1f}", "--no-step-log", "true", "--no-warnings", "true"])
    timings = summary["timings_s"]
    covered = sum(timings.values())
    print(f"config {cfg} (end {args.end:g} s, 0.5 s steps, sublane 0.8 m, flows), target {args.target}, "
          f"nominal pass to {until:.1f} s")
    print(f"coster-sumo run: {t_run:.1f} s; plain sumo (0.1 s steps, same end): {t_sumo:.1f} s; "
          f"ratio {t_run / t_sumo:.2f}")
    print(f"timings_s: {timings}; sum {covered:.1f} s = {100 * covered / t_run:.1f} % of the run's wall time")
    kept = sorted(p.name for p in (out / "sumo-outputs").iterdir()) if (out / "sumo-outputs").is_dir() else []
    print(f"configuration folder byte-identical after the run: {untouched}; OUT/sumo-outputs: {kept}")


if __name__ == "__main__":
    main()
