"""Training curves of the downstream experiment's policies as one picture for models/policies.md.

    python bench/policy_curves.py models/policies -o models/policies/curves.png

Reads ``<arm>_s<seed>/progress.json`` (``curve``: [steps, mean training-episode return since the
previous checkpoint] at every checkpoint) and draws, per arm, the mean over its seeds with the
seeds' range shaded. A last point that covers less than half a checkpoint interval (the few steps a
run makes past its budget to finish its rollout: a handful of episodes) is left out as noise.
"""

from __future__ import annotations

import argparse
import json
import re
from collections import defaultdict
from pathlib import Path

import numpy as np

ARMS = ("nominal", "coster", "coster-one-per-snapshot", "random-cvae")


def _full_intervals(curve: np.ndarray) -> np.ndarray:
    """``curve`` (N, 2) without a last point whose interval is under half the median one."""
    if len(curve) < 3:
        return curve
    gaps = np.diff(curve[:, 0])
    return curve[:-1] if gaps[-1] < 0.5 * float(np.median(gaps)) else curve


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", type=Path)
    ap.add_argument("-o", "--out", type=Path, required=True)
    args = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves: dict[str, list[np.ndarray]] = defaultdict(list)
    for path in sorted(args.root.glob("*_s*/progress.json")):
        m = re.fullmatch(r"(.+)_s(\d+)", path.parent.name)
        if m and json.loads(path.read_text()).get("curve"):
            curves[m.group(1)].append(_full_intervals(np.array(json.loads(path.read_text())["curve"], float)))
    fig, ax = plt.subplots(figsize=(7, 4))
    for arm in [a for a in ARMS if a in curves] + sorted(set(curves) - set(ARMS)):
        n = min(len(c) for c in curves[arm])
        steps = curves[arm][0][:n, 0]
        ret = np.stack([c[:n, 1] for c in curves[arm]])
        ax.plot(steps, ret.mean(0), label=f"{arm} ({len(curves[arm])} seeds)")
        ax.fill_between(steps, ret.min(0), ret.max(0), alpha=0.2)
    ax.set_xlabel("environment steps (0.2 s each)")
    ax.set_ylabel("mean training-episode return")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.out, dpi=100)
    print(args.out)


if __name__ == "__main__":
    main()
