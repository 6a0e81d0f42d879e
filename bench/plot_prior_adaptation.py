"""Picture of the prior's context mode with and without the adaptation to the scene's traffic.

Usage: python bench/plot_prior_adaptation.py LABEL=EVAL.json [LABEL=EVAL.json ...] -o OUT.png
EVAL.json: the output of ``coster-sumo eval prior --json`` (made with the adaptation, so that it
holds the raw model's numbers too). Left: agents in the hidden disc per scene, predicted by the raw
and the adapted prior, relative to the vehicles that were there (the +-20 % band shaded). Right:
presence ECE in context mode, raw and adapted (the 0.05 line dashed).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("inputs", nargs="+", help="LABEL=EVAL.json")
    ap.add_argument("-o", "--out", type=Path, required=True)
    args = ap.parse_args()
    labels, count_err, ece = [], [], []
    for item in args.inputs:
        label, _, path = item.rpartition("=")
        r = json.loads(Path(path).read_text())
        h, presence = r["agents_in_hidden_disc"], r["presence"]
        if "prior_context_raw_expected" not in h:
            raise SystemExit(f"{path}: no raw context-mode numbers (made before the adaptation?)")
        truth = h["ground_truth"]
        labels.append(label or Path(path).stem)
        count_err.append([100.0 * (h["prior_context_raw_expected"] / truth - 1.0),
                          100.0 * (h["prior_context_expected"] / truth - 1.0)])
        ece.append([presence["prior_context_raw"]["ece"], presence["prior_context"]["ece"]])
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    y = np.arange(len(labels))
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(10, 0.5 * len(labels) + 1.6), sharey=True)
    for ax, values, band, unit in ((ax0, np.asarray(count_err), (-20.0, 20.0), "%"),
                                   (ax1, np.asarray(ece), (0.0, 0.05), "")):
        ax.barh(y + 0.2, values[:, 0], height=0.38, color="0.7", label="raw model")
        ax.barh(y - 0.2, values[:, 1], height=0.38, color="tab:blue", label="adapted to the scene")
        for yi, pair in zip(y, values, strict=True):
            for dy, v in zip((0.2, -0.2), pair, strict=True):
                text = f"{v:+.1f}{unit}" if unit else f"{v:.3f}"
                ax.text(v, yi + dy, f" {text} " if v else text, va="center", fontsize=7,
                        ha="right" if v < 0 else "left")
        if unit:
            ax.axvspan(*band, color="tab:green", alpha=0.08)
            ax.axvline(0.0, color="k", lw=0.8)
        else:
            ax.axvline(band[1], color="tab:red", ls="--", lw=0.8)
    ax0.set_yticks(y, labels)
    ax0.invert_yaxis()
    ax0.set_xlabel("agents in the hidden disc: predicted vs observed [%]")
    ax1.set_xlabel("presence ECE (context mode)")
    ax0.legend(loc="lower left", fontsize=7)
    ax0.margins(x=0.15)
    ax1.margins(x=0.15)
    fig.suptitle("Traffic prior around the target, raw and adapted to the visible traffic", fontsize=10)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=120)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
