"""The trained policies as planners: one row per (regress output, planner) from ``summary.json``.

    python bench/policy_regress.py OUT [OUT ...]

Each OUT is a ``coster-sumo regress`` output folder (e.g. a policy with ``--planner sumo`` beside it);
a row gives the runs, the collision rate (the target touched anyone), the adversary's contact rate,
the defect rate (contact in a variant labelled avoidable) with the unavoidable-contact rate, the
off-road rate and route completion, each as k/n with its rate (issue 61's regress table).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def _kn(rate: dict | None) -> str:
    if not rate or not rate.get("n"):
        return "-"
    return f"{rate['k']}/{rate['n']} ({rate['rate']:.2f})"


def rows(out: Path) -> list[list[str]]:
    """The table's rows of one regress output."""
    summary = json.loads((out / "summary.json").read_text())
    found = []
    for planner, p in summary["planners"].items():
        d = p.get("defects") or {}
        name = planner.split("/")[-2] if planner.startswith("policy:") else planner
        found.append([out.name, name, str(p["runs"]), _kn(p.get("CR")), _kn(p.get("adversary_contact_rate")),
                      _kn(d.get("defect_rate")), _kn(d.get("unavoidable_contact_rate")), _kn(p.get("ORR")),
                      _kn(p.get("RCR"))])
    return found


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("outs", nargs="+", type=Path)
    args = ap.parse_args()
    head = ["regress", "planner", "runs", "CR (anyone)", "adversary contact", "defect rate", "unavoidable contact",
            "ORR", "RCR"]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for out in args.outs:
        for row in rows(out):
            print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
