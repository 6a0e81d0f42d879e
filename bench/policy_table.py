"""The downstream table of models/policies.md from the policies' evaluation files.

    python bench/policy_table.py models/policies

Reads ``<arm>_s<seed>/eval_test.json`` (``policy eval`` on the COSTER set's test split: its nominal
scenes are Normal, its variants the COSTER-generated held-out scenarios) and ``eval_hard.json``
(``policy eval --hard`` on the hard set's test split) and prints, per arm, RCR, CR and ORR: mean and
standard deviation over the seeds found, and how many seeds there were.
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
    hard: dict[str, list[dict]] = defaultdict(list)
    for name, into in (("eval_test.json", found), ("eval_hard.json", hard)):
        for path in sorted(root.glob(f"*_s*/{name}")):
            m = re.fullmatch(r"(.+)_s(\d+)", path.parent.name)
            if m:
                into[m.group(1)].append(json.loads(path.read_text()))

    def cell(vals: list[float]) -> str:
        a = np.array(vals)
        return f"{a.mean():.2f} ± {a.std():.2f}" if len(a) else "-"

    print("| arm | seeds | Normal RCR | Normal CR | Normal ORR | Hard RCR | Hard CR | Hard ORR "
          "| COSTER variants RCR | COSTER variants CR | COSTER variants ORR |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for arm in [a for a in ARMS if a in found] + sorted(set(found) - set(ARMS)):
        cells = [cell([e["per_kind"]["nominal"][k] for e in found[arm] if "nominal" in e["per_kind"]])
                 for k in ("rcr", "cr", "orr")]
        cells += [cell([e[k] for e in hard.get(arm, [])]) for k in ("rcr", "cr", "orr")]
        cells += [cell([e["per_kind"]["variant"][k] for e in found[arm] if "variant" in e["per_kind"]])
                  for k in ("rcr", "cr", "orr")]
        print(f"| {arm} | {len(found[arm])} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
