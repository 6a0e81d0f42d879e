"""Are the flows' members an export takes from the nominal pass those a plain sumo run writes?

``python bench/flow_members.py CFG TARGET OUT [run options...]`` runs ``coster-sumo run CFG --target
TARGET --planner replay`` twice in this process: once as shipped (the members from the nominal
pass's vehroute output) and once with the pass's routes withheld (the plain ``sumo`` run of each
export), then compares every variant's ``flows_expanded.rou.xml`` vehicle by vehicle and prints
the wall time and ``outputs_s`` of both runs (docs/performance.md, issue 59).
"""

from __future__ import annotations

import json
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

from coster_sumo.cli.command_line import main as cli
from coster_sumo.exports import demand
from coster_sumo.exports import sumo as sumo_export


def _members(out: Path) -> dict[int, dict[str, bytes] | None]:
    """variant -> {member id: its element} of that variant's export (None: nothing expanded)."""
    found: dict[int, dict[str, bytes] | None] = {}
    for v in json.loads((out / "summary.json").read_text())["variants"]:
        export = out / "variants" / str(v["variant"]) / "export"
        info = json.loads((export / "variant.json").read_text())["export"]["demand"]
        path = export / (info["expanded_file"] or "-")
        found[v["variant"]] = ({el.get("id", ""): ET.tostring(el) for el in ET.parse(path).getroot().iter("vehicle")}
                               if path.is_file() else None)
    return found


def main() -> None:
    cfg, target, out = sys.argv[1], sys.argv[2], Path(sys.argv[3])
    shipped = sumo_export.pass_routes
    runs = {}
    for how in ("pass", "plain"):
        sumo_export.pass_routes = shipped if how == "pass" else (lambda *a, **k: None)  # type: ignore[assignment]
        demand._EXPANDED.clear()
        t0 = time.perf_counter()
        rc = cli(["-q", "run", cfg, "--target", target, "--planner", "replay", "--no-render", "-o", str(out / how),
                  *sys.argv[4:]])
        outputs_s = json.loads((out / how / "summary.json").read_text())["timings_s"]["outputs_s"]
        print(f"{how}: exit {rc}, {time.perf_counter() - t0:.1f} s, outputs_s {outputs_s:.2f}")
        runs[how] = _members(out / how)
    for k, a in runs["pass"].items():
        b = runs["plain"].get(k)
        if a is None or b is None:
            print(f"variant {k}: no expansion (pass {a is not None}, plain {b is not None})")
            continue
        both = set(a) & set(b)
        differ = sorted(i for i in both if a[i] != b[i])
        print(f"variant {k}: pass {len(a)}, plain {len(b)}, identical {len(both) - len(differ)}, differ {len(differ)}, "
              f"only in the pass {len(set(a) - set(b))}, only in the plain run {len(set(b) - set(a))}")


if __name__ == "__main__":
    main()
