"""The tables of issue 61's downstream experiment (models/policies.md) from ``policy eval`` files.

    python bench/policy_tables.py ROOT [--json OUT.json]

``ROOT/<arm>_s<seed>/`` and the reference rows ``ROOT/reference/none/`` (the action (0, 0): the
nominal path at constant speed) and ``ROOT/reference/sumo/`` (SUMO's driver model) hold, per traffic
mode ``T`` (``log`` or ``reactive``), whichever of these ``policy eval`` files exist (``-o``):

- ``eval_normal_T.json``: Normal, the nominal scenes of the held-out clips;
- ``eval_hard_T.json`` (``--hard``): its nominal episodes are Hard (the top 20 % of the held-out
  clips by log criticality); its variants are the hand-made adversities, reported apart per kind
  (the scenario id ends with ``_hard_<kind>``);
- ``eval_coster_T.json``: COSTER's variants of held-out clips with their avoidability labels (the
  defect rate: the share of the variants labelled avoidable that ended in contact with the adversary).

Per traffic mode and episode group, one row per arm and reference: each score of
:mod:`coster_sumo.gym.scores` with its 95 % bootstrap interval over the seeds and episodes; then
the learning gate (the nominal-only arm against constant speed on Normal: RCR and CR), then every
arm against the nominal-only arm on the same episodes (the paired difference and its interval):
Hard CR (also relative), Normal RCR, the leader-braking and cut-in adversities' CR and the defect
rate on COSTER's held-out variants; and COSTER against Random + CVAE on Hard CR.
"""

from __future__ import annotations

import argparse
import json
import re
from collections import defaultdict
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from coster_sumo.gym.scores import Interval, bootstrap, bootstrap_difference, episode_values

ARMS = ("nominal", "coster", "coster-one-per-snapshot", "random-cvae")
REFERENCES = {"none": "constant speed (action 0, 0)", "sumo": "SUMO's driver (Krauss)"}
SETS = ("normal", "hard", "coster")
MODES = ("log", "reactive")
SCORES = ("rcr", "mean_completion", "cr", "cr_adversary", "orr")


def _groups(set_name: str, rows: list[dict]) -> dict[str, list[dict]]:
    """The episode groups of one evaluation file (see the module docstring)."""
    if set_name == "normal":
        return {"Normal": rows}
    if set_name == "coster":
        return {"COSTER held-out variants": [r for r in rows if r["kind"] == "variant"]}
    out: dict[str, list[dict]] = {"Hard": [r for r in rows if r["kind"] == "nominal"]}
    for r in rows:
        m = re.search(r"_hard_([a-z-]+)$", r["scenario"])
        if r["kind"] == "variant" and m:
            out.setdefault(f"adversity: {m.group(1)}", []).append(r)
    return out


def _load(root: Path) -> dict[tuple[str, str], dict[str, dict[str, list[list[dict]]]]]:
    """(mode, group) -> row name -> the episodes of each seed, sorted by scenario."""
    found: dict[tuple[str, str], dict[str, dict[str, list[list[dict]]]]] = defaultdict(lambda: defaultdict(dict))
    folders = [(m.group(1), p) for p in sorted(root.glob("*_s*")) if (m := re.fullmatch(r"(.+)_s(\d+)", p.name))]
    folders += [(f"reference: {REFERENCES[p.name]}", p) for p in sorted((root / "reference").glob("*"))
                if p.name in REFERENCES]
    for name, folder in folders:
        for set_name in SETS:
            for mode in MODES:
                path = folder / f"eval_{set_name}_{mode}.json"
                if not path.is_file():
                    continue
                rows = sorted(json.loads(path.read_text())["episodes_detail"], key=lambda r: r["scenario"])
                for group, episodes in _groups(set_name, rows).items():
                    if episodes:
                        found[mode, group].setdefault(name, {}).setdefault("seeds", []).append(episodes)
    return found


def _values(seeds: list[list[dict]], score: str) -> np.ndarray:
    """(S, E) one score per seed and episode (the seeds must share their episodes)."""
    ids = [[r["scenario"] for r in s] for s in seeds]
    if any(i != ids[0] for i in ids):
        raise SystemExit(f"the seeds were evaluated on different episodes ({len(ids[0])} episodes)")
    return np.stack([episode_values([SimpleNamespace(**r) for r in s], score) for s in seeds])


def _defects(seeds: list[list[dict]]) -> Interval | None:
    avoidable = [[r for r in s if r.get("avoidable") is True] for s in seeds]
    if not avoidable[0]:
        return None
    return bootstrap(_values(avoidable, "cr_adversary"))


def _fmt(iv: Interval | None) -> str:
    return "-" if iv is None else f"{iv.mean:.3f} [{iv.low:.3f}, {iv.high:.3f}]"


def table(rows: dict[str, dict[str, list[list[dict]]]]) -> tuple[list[str], dict[str, Any]]:
    """Markdown lines and the numbers of one (mode, group)."""
    head = "| row | seeds | episodes | " + " | ".join(SCORES) + " | defect rate |"
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    numbers: dict[str, Any] = {}
    order = [a for a in ARMS if a in rows] + sorted(n for n in rows if n not in ARMS)
    for name in order:
        seeds = rows[name]["seeds"]
        ivs = {s: bootstrap(_values(seeds, s)) for s in SCORES}
        defects = _defects(seeds)
        numbers[name] = {"seeds": len(seeds), "episodes": len(seeds[0]),
                         **{s: iv.to_json() for s, iv in ivs.items()},
                         "defect_rate": None if defects is None else defects.to_json()}
        lines.append(f"| {name} | {len(seeds)} | {len(seeds[0])} | " + " | ".join(_fmt(ivs[s]) for s in SCORES)
                     + f" | {_fmt(defects)} |")
    return lines, numbers


def differences(found: dict[tuple[str, str], dict[str, dict[str, list[list[dict]]]]], mode: str) -> list[str]:
    """The learning gate (nominal only against constant speed: Normal RCR and CR), each arm against
    nominal only (Hard CR, Normal RCR, the adversities' CR, the defect rate), and COSTER against
    Random + CVAE on Hard CR."""
    out = []
    constant = f"reference: {REFERENCES['none']}"
    pairs = [(constant, "nominal", "Normal", "rcr"), (constant, "nominal", "Normal", "cr")]
    pairs += [("nominal", a, "Hard", "cr") for a in ARMS[1:]] + [("nominal", a, "Normal", "rcr") for a in ARMS[1:]]
    pairs.append(("random-cvae", "coster", "Hard", "cr"))
    # where the arms differ most: the adversities, and COSTER's own variants (the defect rate)
    pairs += [("nominal", a, f"adversity: {kind}", "cr") for kind in ("leader-braking", "cut-in") for a in ARMS[1:]]
    pairs += [("nominal", a, "COSTER held-out variants", "defect rate") for a in ARMS[1:]]
    for base, arm, group, score in pairs:
        rows = found.get((mode, group), {})
        if base not in rows or arm not in rows:
            continue
        if score == "defect rate":  # contact with the adversary, over the variants labelled avoidable
            pick = [[[r for r in s if r.get("avoidable") is True] for s in rows[n]["seeds"]] for n in (base, arm)]
            if not pick[0][0]:
                continue
            va, vb = _values(pick[0], "cr_adversary"), _values(pick[1], "cr_adversary")
        else:
            va, vb = _values(rows[base]["seeds"], score), _values(rows[arm]["seeds"], score)
        d = bootstrap_difference(va, vb)
        rel = (f", {100 * d.mean / va.mean():+.1f} % of {base}'s" if score in ("cr", "defect rate") and va.mean() > 0
               else "")
        out.append(f"- {mode}, {group} {score}: {arm} - {base} = {_fmt(d)}{rel}; "
                   f"interval {'excludes' if d.excludes_zero() else 'includes'} 0")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", type=Path)
    ap.add_argument("--json", type=Path, default=None, help="also write every number here")
    args = ap.parse_args()
    found = _load(args.root)
    everything: dict[str, Any] = {}
    def order(group: str) -> tuple[int, str]:  # Normal, Hard, the adversities, COSTER's variants
        return (["Normal", "Hard"].index(group) if group in ("Normal", "Hard") else
                2 if group.startswith("adversity") else 3, group)

    for mode in MODES:
        for (m, group), rows in sorted(found.items(), key=lambda item: order(item[0][1])):
            if m != mode:
                continue
            lines, numbers = table(rows)
            everything[f"{mode} / {group}"] = numbers
            print(f"\n**{group}, {mode} traffic**\n")
            print("\n".join(lines))
        diffs = differences(found, mode)
        if diffs:
            print(f"\nDifferences ({mode} traffic):\n")
            print("\n".join(diffs))
    if args.json:
        args.json.write_text(json.dumps(everything, indent=1))


if __name__ == "__main__":
    main()
