"""Stored expectations of what ``run`` and ``regress`` produce, to prove a redesign kept behaviour.

The outcomes of a variant: collision, contact time, relative speed, impact angle, off-road (both
vehicles) and route completion. ``tests/expectations/behaviour.json`` holds them for

- ``coster-sumo run CFG --planner replay --seed 0`` on the three project networks and the four
  real WOMD samples of ../shared (converted first), and
- ``coster-sumo regress`` on six scenes (the three networks and three WOMD samples) x the planners
  ``replay`` and ``sumo``, three variants each.

Record them again (after a change of behaviour made on purpose, say why in the commit)::

    python tests/behaviour.py --record          # about 5 minutes on 2 cores
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
EXPECTATIONS = REPO / "tests" / "expectations" / "behaviour.json"
WOMD = REPO.parent / "shared" / "data" / "womd"
NETWORKS = ("intersection", "merge", "arterial")
WOMD_IDS = ("2a1e44d405a6833f", "637f20cafde22ff8", "eb4b91b10ca94ff2", "ee519cf571686d19")
REGRESS_WOMD = WOMD_IDS[:3]
FLOAT_TOLERANCE = 1e-3  # [s, m/s, deg] outcomes are printed to this precision


def cli(*args: str | Path, cwd: Path = REPO) -> subprocess.CompletedProcess[str]:
    """``coster-sumo --quiet ARGS`` in a subprocess (its own libsumo)."""
    return subprocess.run([sys.executable, "-m", "coster_sumo", "--quiet", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, check=True)


def convert_womd(out: Path) -> dict[str, Path]:
    """The four real WOMD samples converted into ``out``: scenario id -> .sumocfg."""
    inputs = sorted((WOMD / "scenario_proto").glob("*.tfrecord")) + sorted((WOMD / "scenarionet_pkl").glob("*.pkl"))
    cli("convert", "-o", out, *inputs)
    return {sid: out / sid / f"{sid}.sumocfg" for sid in WOMD_IDS}


def _r(v: float | None, digits: int = 3) -> float | None:
    return None if v is None else round(float(v), digits) + 0.0  # + 0.0: no -0.0


def run_outcomes(config: Path, out: Path) -> list[dict[str, Any]]:
    """Per variant outcomes of ``coster-sumo run CONFIG --planner replay --seed 0``."""
    cli("run", config, "--planner", "replay", "--seed", "0", "--no-render", "-o", out)
    return outcomes_of_run(out)


def outcomes_of_run(out: Path) -> list[dict[str, Any]]:
    """Per variant outcomes in the summary.json of a ``run`` output folder."""
    summary = json.loads((out / "summary.json").read_text())
    return [{"t_col": _r(summary["t_col"], 5), "collision": v["collision"], "contact_time": _r(v["collision_time"]),
             "relative_speed": _r(v["relative_speed"]), "impact_angle": _r(v["impact_angle"], 2),
             "adversary_off_road": v["adversary_off_road"], "target_off_road": v["target_off_road"],
             "route_completed": v["route_completed"]} for v in summary["variants"]]


def regress_outcomes(configs: list[Path], out: Path) -> dict[str, dict[str, Any]]:
    """Per (scene, variant, planner) outcomes of ``coster-sumo regress`` (3 variants, replay and sumo)."""
    cli("regress", *configs, "--planner", "replay", "--planner", "sumo", "--variants", "3", "--no-report",
        "-o", out)
    return outcomes_of_regress(out)


def outcomes_of_regress(out: Path) -> dict[str, dict[str, Any]]:
    """Per (scene, variant, planner) outcomes in the result store of a ``regress`` output folder."""
    import pyarrow.dataset as ds

    rows = ds.dataset(out / "results", format="parquet").to_table().to_pylist()
    result = {}
    for r in rows:
        scene = Path(r["config"]).stem
        result[f"{scene}/v{r['variant']}/{r['planner']}"] = {
            "status": r["status"], "collision": r["collision"], "adversary_contact": r["adversary_contact"],
            "contact_time": _r(r["contact_time"]), "relative_speed": _r(r["relative_speed"]),
            "impact_angle": _r(r["impact_angle"], 2), "adversary_off_road": r["adversary_off_road"],
            "target_off_road": r["target_off_road"], "route_completed": r["route_completed"]}
    return dict(sorted(result.items()))


def differences(expected: Any, actual: Any, where: str = "") -> list[str]:
    """Human-readable differences (floats within :data:`FLOAT_TOLERANCE` are equal)."""
    if isinstance(expected, dict) and isinstance(actual, dict):
        out = []
        for k in sorted(set(expected) | set(actual)):
            if k not in actual or k not in expected:
                out.append(f"{where}/{k}: {'missing' if k not in actual else 'unexpected'}")
            else:
                out += differences(expected[k], actual[k], f"{where}/{k}")
        return out
    if isinstance(expected, list) and isinstance(actual, list):
        if len(expected) != len(actual):
            return [f"{where}: {len(actual)} items, expected {len(expected)}"]
        pairs = enumerate(zip(expected, actual, strict=True))
        return [d for i, (e, a) in pairs for d in differences(e, a, f"{where}[{i}]")]
    if isinstance(expected, float) and isinstance(actual, float) and not isinstance(expected, bool):
        return [] if math.isclose(expected, actual, abs_tol=FLOAT_TOLERANCE) else [f"{where}: {actual} != {expected}"]
    return [] if expected == actual else [f"{where}: {actual!r} != {expected!r}"]


def record() -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        cfgs = {n: REPO / "networks" / n / f"{n}.sumocfg" for n in NETWORKS}
        womd = convert_womd(work / "conv") if WOMD.is_dir() else {}
        runs = {name: run_outcomes(cfg, work / f"run_{name}") for name, cfg in {**cfgs, **womd}.items()}
        scenes = list(cfgs.values()) + [womd[s] for s in REGRESS_WOMD if s in womd]
        return {"run": runs, "regress": regress_outcomes(scenes, work / "regress")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--record", action="store_true", help=f"write {EXPECTATIONS.relative_to(REPO)}")
    args = ap.parse_args()
    got = record()
    if args.record:
        EXPECTATIONS.parent.mkdir(parents=True, exist_ok=True)
        EXPECTATIONS.write_text(json.dumps(got, indent=1) + "\n")
        print(f"wrote {EXPECTATIONS}")
    else:
        diff = differences(json.loads(EXPECTATIONS.read_text()), got)
        print("\n".join(diff) or "same outcomes")
        raise SystemExit(1 if diff else 0)  # scripts and CI can tell


if __name__ == "__main__":
    main()
