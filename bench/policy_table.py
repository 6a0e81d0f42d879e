"""The downstream table of models/policies.md from the policies' evaluation files.

    python bench/policy_table.py models/policies

Reads, per ``<arm>_s<seed>/`` folder (and ``reference/``, the untrained action (0, 0) of
``policy eval none``, printed last), whichever of these ``policy eval`` files are there:

- ``eval_test.json``: Normal, the nominal held-out scenes;
- ``eval_hard.json``: Hard (``--hard``): the top 20 % of the held-out scenes by criticality and the
  hand-specified adversities on them;
- ``eval_hard_shipped.json``: Hard again on networks no policy was trained on, where the red-light
  runner appears;
- ``eval_coster.json``: COSTER's variants of the held-out scenes, with their avoidability labels
  (not independent of arm (b)'s generator; the defect rate is the share of avoidable variants that
  ended in contact with the adversary).

Prints RCR, CR and ORR per arm (mean ± standard deviation over the seeds found), then the change of
each arm's Hard CR and Normal RCR against the nominal-only arm.
"""

from __future__ import annotations

import json
import re
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

ARMS = ("nominal", "coster", "coster-one-per-snapshot", "random-cvae")
FILES = ("eval_test.json", "eval_hard.json", "eval_hard_shipped.json", "eval_coster.json")
HEAD = ("| arm | seeds | Normal RCR | Normal CR | Normal ORR | Hard RCR | Hard CR | Hard ORR "
        "| Hard, unseen networks RCR | CR | ORR | COSTER variants RCR | CR | ORR | defect rate |")


def _cell(vals: list[float | None]) -> str:
    a = np.array([v for v in vals if v is not None], float)
    return f"{a.mean():.2f} ± {a.std():.2f}" if len(a) else "-"


def _kind(e: dict[str, Any], kind: str, key: str) -> float | None:
    return e["per_kind"][kind][key] if kind in e.get("per_kind", {}) else None


def _line(name: str, seeds: str, ev: dict[str, list[dict]]) -> str:
    cells = [_cell([_kind(e, "nominal", k) for e in ev["eval_test.json"]]) for k in ("rcr", "cr", "orr")]
    cells += [_cell([e[k] for e in ev["eval_hard.json"]]) for k in ("rcr", "cr", "orr")]
    cells += [_cell([e[k] for e in ev["eval_hard_shipped.json"]]) for k in ("rcr", "cr", "orr")]
    cells += [_cell([_kind(e, "variant", k) for e in ev["eval_coster.json"]]) for k in ("rcr", "cr", "orr")]
    cells += [_cell([e.get("defect_rate") for e in ev["eval_coster.json"]])]
    return f"| {name} | {seeds} | " + " | ".join(cells) + " |"


def _mean(vals: list[float | None]) -> float:
    return float(np.mean([v for v in vals if v is not None]))


def main() -> None:
    root = Path(sys.argv[1] if len(sys.argv) > 1 else "models/policies")
    evals: dict[str, dict[str, list[dict]]] = defaultdict(lambda: {f: [] for f in FILES})
    for name in FILES:
        for path in sorted(root.glob(f"*_s*/{name}")):
            m = re.fullmatch(r"(.+)_s(\d+)", path.parent.name)
            if m:
                evals[m.group(1)][name].append(json.loads(path.read_text()))
    print(HEAD)
    print("|" + "---|" * (HEAD.count("|") - 1))
    arms = [a for a in ARMS if a in evals] + sorted(set(evals) - set(ARMS))
    for arm in arms:
        print(_line(arm, str(len(evals[arm]["eval_test.json"])), evals[arm]))
    ref = root / "reference"
    if ref.is_dir():
        print(_line("reference: action (0, 0), no learning", "-",
                    {f: [json.loads((ref / f).read_text())] if (ref / f).exists() else [] for f in FILES}))
    base = evals.get("nominal")
    if not base or not base["eval_hard.json"] or not base["eval_test.json"]:
        return
    b_cr = _mean([e["cr"] for e in base["eval_hard.json"]])
    b_rcr = _mean([_kind(e, "nominal", "rcr") for e in base["eval_test.json"]])
    print()
    for arm in [a for a in arms if a != "nominal" and evals[a]["eval_hard.json"]]:
        cr = _mean([e["cr"] for e in evals[arm]["eval_hard.json"]])
        rcr = _mean([_kind(e, "nominal", "rcr") for e in evals[arm]["eval_test.json"]])
        print(f"- {arm}: Hard CR {cr:.3f} against {b_cr:.3f} ({100 * (cr - b_cr) / max(b_cr, 1e-9):+.1f} %), "
              f"Normal RCR {rcr:.3f} against {b_rcr:.3f} ({rcr - b_rcr:+.3f})")


if __name__ == "__main__":
    main()
