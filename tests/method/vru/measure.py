"""Acceptance measurements of pedestrian and cyclist adversaries (issue 62), printed as a table.

For every configuration and class: ``coster-sumo run CFG --adversary CLASS --planner replay`` (the
target on its nominal path, so contact belongs at t_col), then per variant: the contact's offset from
t_col, whether the adversary left its class's area, and the densified plan's fastest speed, largest
acceleration and deceleration against the class's limits (coster_sumo.method.vru.classes). Configurations:
the three project networks, the intersection rebuilt by netconvert with guessed sidewalks and
crossings (built here, in a temporary folder), OSM configurations of the eclipse-sumo wheel with
pedestrians or bicycles (fokr_bs_demo, fkk_in, DRT), and the real WOMD samples of ../shared (converted here).

    python tests/method/vru/measure.py [--samples 200] [--variants 3] [--only NAME] [--json OUT.json]
    python tests/method/vru/measure.py --womd-stats
    # with ASAM's checker (pip install asam-qc-openscenarioxml into a venv of its own):
    python tests/method/vru/measure.py --asam-checker /path/to/venv/bin/qc_openscenario

Takes about 20-40 s per configuration and class on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[3]
WOMD = REPO.parent / "shared" / "data" / "womd"
CLASSES = ("pedestrian", "cyclist")


def cli(*args: str | Path, check: bool = False) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "coster_sumo", "--quiet", *map(str, args)], cwd=REPO,
                          capture_output=True, text=True, check=check)


def sidewalk_fixture(tmp: Path) -> Path:
    """networks/intersection with netconvert's guessed sidewalks and crossings (the project's networks have none)."""
    from coster_sumo.infra import sumo_install

    src = REPO / "networks" / "intersection"
    out = tmp / "intersection_sidewalks"
    out.mkdir()
    subprocess.run([sumo_install.binary("netconvert"), "-s", str(src / "intersection.net.xml"), "--sidewalks.guess",
                    "true", "--crossings.guess", "true", "-o", str(out / "intersection.net.xml")],
                   check=True, capture_output=True, env=sumo_install.subprocess_env())
    shutil.copy(src / "intersection.rou.xml", out)
    shutil.copy(src / "intersection.sumocfg", out)
    return out / "intersection.sumocfg"


def headless(cfg: Path, tmp: Path) -> Path:
    """A copy of ``cfg`` without its sumo-gui section, its files named by absolute path. ``run`` on the
    wheel's fokr_bs_demo.sumocfg itself fails before any work: the project's own headless copy of a
    configuration with a gui section rewrites its space-separated insertion checks so that SUMO 1.28
    refuses them ("Unknown value 'collision,leaderGap,...' in insertionChecks")."""
    import re

    text = re.sub(r"<gui_only>.*?</gui_only>", "", cfg.read_text(), flags=re.S)
    text = re.sub(r'value="(fokr_bs_demo/[^"]+)"',
                  lambda m: 'value="' + ",".join(str(cfg.parent / p) for p in m.group(1).split(",")) + '"', text)
    out = tmp / cfg.name
    out.write_text(text)
    return out


def configs(tmp: Path) -> list[tuple[str, Path, list[str]]]:
    """(name, .sumocfg, extra run arguments) of every configuration measured."""
    import sumo

    game = Path(sumo.SUMO_HOME) / "tools" / "game"
    out: list[tuple[str, Path, list[str]]] = [
        (n, REPO / "networks" / n / f"{n}.sumocfg", []) for n in ("intersection", "merge", "arterial")]
    out.append(("intersection+sidewalks", sidewalk_fixture(tmp), []))
    out.append(("fokr_bs_demo", headless(game / "fokr_bs_demo.sumocfg", tmp), ["--targets", "1", "--duration", "90"]))
    out.append(("fkk_in", game / "fkk_in.sumocfg", ["--targets", "1"]))  # OSM Ingolstadt: bicycles, crossings
    out.append(("DRT", game / "DRT.sumocfg", ["--targets", "1", "--duration", "300"]))  # persons, crossings
    inputs = sorted((WOMD / "scenario_proto").glob("*.tfrecord")) + sorted((WOMD / "scenarionet_pkl").glob("*.pkl"))
    if inputs:
        conv = tmp / "womd"
        cli("convert", "-o", conv, *inputs, check=True)
        out += [(f"womd:{c.stem}", c, []) for c in sorted(conv.glob("*/*.sumocfg"))]
    return out


def variants_of(run_out: Path) -> list[dict[str, Any]]:
    """Every variant of a run folder (one target or several) with its plan's kinematics."""
    from coster_sumo.core.plan import AdversaryPlan
    from coster_sumo.method.vru.classes import VRU_CLASSES, class_of_vclass
    from coster_sumo.method.vru.rollout import plan_kinematics

    rows = []
    for summary in sorted(run_out.rglob("summary.json")):
        doc = json.loads(summary.read_text())
        for v in doc.get("variants", ()):
            vfile = summary.parent / "variants" / str(v["variant"]) / "export" / "variant.json"
            plan = AdversaryPlan.from_dict(json.loads(vfile.read_text())["plan"])
            kin = plan_kinematics(plan)
            cls = VRU_CLASSES[class_of_vclass(plan.vclass)]
            gens = [doc.get("generation") or {}, *((s.get("generation") or {}) for s in doc.get("snapshots", ()))]
            rollout = sorted({str(g["rollout"]) for g in gens if "rollout" in g})
            rows.append({"class": v["adversary_class"], "contact": v["collision"], "offset_s": v["contact_offset_s"],
                         "rollout": "+".join(rollout),
                         "off_area": v["adversary_off_road"], "max_speed": float(kin.speed.max()),
                         "max_accel": float(kin.accel.max()), "max_decel": float(-kin.accel.min()),
                         "speed_limit": cls.fast_max, "accel_limit": cls.max_accel, "decel_limit": cls.max_decel})
    return rows


def womd_stats() -> None:
    """Speeds of the WOMD samples' pedestrians and cyclists (the class limits' cross-check in docs/method.md)."""
    import numpy as np
    from coster_sumo.converters.read import read_scenes

    from coster_sumo.core.scene import ObjectType

    inputs = sorted((WOMD / "scenario_proto").glob("*.tfrecord")) + sorted((WOMD / "scenarionet_pkl").glob("*.pkl"))
    seen: set[str] = set()
    speeds: dict[ObjectType, list[float]] = {ObjectType.PEDESTRIAN: [], ObjectType.CYCLIST: []}
    tracks = dict.fromkeys(speeds, 0)
    for f in inputs:
        for scene in read_scenes(f):
            if scene.scenario_id in seen:
                continue
            seen.add(scene.scenario_id)
            t = scene.tracks
            for a in range(t.num_agents):
                kind = ObjectType(int(t.object_type[a]))
                if kind in speeds:
                    tracks[kind] += 1
                    speeds[kind] += np.hypot(t.vx[a], t.vy[a])[t.valid[a]].tolist()
    for kind, v in speeds.items():
        moving = np.array([x for x in v if x > 0.2])
        if len(moving):
            print(f"WOMD {kind.name}: {tracks[kind]} tracks in {len(seen)} scenes; moving speed p50 "
                  f"{np.percentile(moving, 50):.2f}, p95 {np.percentile(moving, 95):.2f}, p99 "
                  f"{np.percentile(moving, 99):.2f}, max {moving.max():.2f} m/s")


def asam_check(checker: Path, tmp: Path) -> None:
    """ASAM's OpenSCENARIO checker (the ``qc_openscenario`` script of the PyPI package
    asam-qc-openscenarioxml, installed anywhere) on the .xosc of a pedestrian and a cyclist variant."""
    import xml.etree.ElementTree as ET

    for cls in CLASSES:
        out = tmp / f"osc_{cls}"
        cli("run", REPO / "networks" / "intersection" / "intersection.sumocfg", "--adversary", cls, "--planner",
            "replay", "--samples", "150", "--variants", "1", "--no-render", "--export", "openscenario", "-o", out,
            check=True)
        xosc = next((out / "variants" / "0" / "openscenario").glob("*.xosc"))
        entity = "Pedestrian" if cls == "pedestrian" else 'vehicleCategory="bicycle"'
        config, report = tmp / f"qc_{cls}.xml", tmp / f"qc_{cls}.xqar"
        config.write_text('<?xml version="1.0" encoding="UTF-8"?>\n'
                          f'<Config>\n<Param name="InputFile" value="{xosc}"/>\n'
                          f'<CheckerBundle application="xoscBundle">\n<Param name="resultFile" value="{report}"/>\n'
                          "</CheckerBundle>\n</Config>\n")
        subprocess.run([str(checker), "-c", str(config)], check=True, capture_output=True, cwd=xosc.parent)
        root = ET.parse(report).getroot()
        statuses = [c.get("status") for c in root.iter("Checker")]
        print(f"ASAM OpenSCENARIO checker, {cls} variant ({entity} in the file: {entity in xosc.read_text()}): "
              f"{statuses.count('completed')}/{len(statuses)} checkers completed, "
              f"{len(list(root.iter('Issue')))} issues")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=200)
    ap.add_argument("--variants", type=int, default=3)
    ap.add_argument("--only", help="only configurations whose name contains this")
    ap.add_argument("--json", type=Path, help="write every variant's row here")
    ap.add_argument("--womd-stats", action="store_true", help="only the WOMD samples' VRU speeds")
    ap.add_argument("--asam-checker", type=Path, metavar="QC_OPENSCENARIO",
                    help="only ASAM's OpenSCENARIO checker on a pedestrian's and a cyclist's .xosc")
    args = ap.parse_args()
    if args.womd_stats:
        womd_stats()
        return 0
    if args.asam_checker:
        with tempfile.TemporaryDirectory(prefix="coster-vru-") as td:
            asam_check(args.asam_checker, Path(td))
        return 0
    table: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="coster-vru-") as td:
        tmp = Path(td)
        for name, cfg, extra in configs(tmp):
            if args.only and args.only not in name:
                continue
            for cls in CLASSES:
                out = tmp / "runs" / f"{name.replace(':', '_')}_{cls}"
                proc = cli("run", cfg, "--adversary", cls, "--planner", "replay", "--samples", args.samples,
                           "--variants", args.variants, "--no-render", "-o", out, *extra)
                rows = variants_of(out) if out.is_dir() else []
                table.append({"config": name, "class": cls, "rc": proc.returncode, "variants": rows,
                              "error": proc.stderr.strip().splitlines()[-1:] if proc.returncode else []})
                within = [r for r in rows if r["contact"] and abs(r["offset_s"]) <= 0.1 + 1e-9]
                ok_kin = [r for r in rows if r["max_speed"] <= r["speed_limit"] + 0.05
                          and r["max_accel"] <= r["accel_limit"] + 0.1 and r["max_decel"] <= r["decel_limit"] + 0.1]
                print(f"{name:34s} {cls:10s} rc={proc.returncode} variants={len(rows)} "
                      f"contact@t_col±0.1s={len(within)}/{len(rows)} within-limits={len(ok_kin)}/{len(rows)} "
                      f"off-area={sum(r['off_area'] for r in rows)}/{len(rows)} "
                      f"rollout={','.join(sorted({r['rollout'] for r in rows})) or '-'} "
                      + (f"max speed {max(r['max_speed'] for r in rows):.2f} m/s, accel "
                         f"{max(r['max_accel'] for r in rows):.2f}, decel {max(r['max_decel'] for r in rows):.2f}"
                         if rows else (table[-1]["error"] or [""])[0]), flush=True)
    every = [r for t in table for r in t["variants"]]
    for cls in CLASSES:
        mine = [r for r in every if r["class"] == cls]
        if mine:
            n = len(mine)
            hit = sum(r["contact"] and abs(r["offset_s"]) <= 0.1 + 1e-9 for r in mine)
            confs = sum(1 for t in table if t["class"] == cls and t["variants"])
            print(f"TOTAL {cls}: {n} variants from {confs} configurations; contact at t_col within 0.1 s "
                  f"{hit}/{n}; off-area {sum(r['off_area'] for r in mine)}/{n}")
    if args.json:
        args.json.write_text(json.dumps(table, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
