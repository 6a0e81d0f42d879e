"""The downstream table of models/policies.md from the policies' evaluation files.

    python bench/policy_table.py models/policies

Reads ``<arm>_s<seed>/eval_test.json`` (``coster-sumo policy eval ... --json``) and prints, per arm,
RCR, CR and ORR on the held-out Normal (nominal scenes) and adversarial (generated variants)
scenarios: mean and standard deviation over the seeds found, and how many seeds there were.
"""

from __future__ import annotations

import json
import re
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

ARMS = ("nominal", "coster", "coster-one-per-snapshot", "random-cvae")


def main() -> None:
    root = Path(sys.argv[1] if len(sys.argv) > 1 else "models/policies")
    found: dict[str, list[dict]] = defaultdict(list)
    for path in sorted(root.glob("*_s*/eval_test.json")):
        m = re.fullmatch(r"(.+)_s(\d+)", path.parent.name)
        if m:
            found[m.group(1)].append(json.loads(path.read_text()))
    print("| arm | seeds | Normal RCR | Normal CR | Normal ORR | Adversarial RCR | Adversarial CR | Adversarial ORR |")
    print("|---|---|---|---|---|---|---|---|")
    for arm in [a for a in ARMS if a in found] + sorted(set(found) - set(ARMS)):
        cells = []
        for kind in ("nominal", "variant"):
            for key in ("rcr", "cr", "orr"):
                vals = np.array([e["per_kind"][kind][key] for e in found[arm] if kind in e["per_kind"]])
                cells.append(f"{vals.mean():.2f} ± {vals.std():.2f}" if len(vals) else "-")
        print(f"| {arm} | {len(found[arm])} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
