"""Avoidability of generated variants on held-out corpus networks, from an ``eval scenarios`` folder.

Reads ``OUT/parts/*.json`` (it works on a finished run and on one still going: every finished
scene and method counts) and prints Markdown tables: the share of avoidable variants (escape proven
in SUMO) at reaction times 0.5 / 1 / 1.5 s per collision-time rule, per network and per kind of
contact; the distribution of the last moment to act; how many kinematic escapes SUMO refuted; the
labels' cost against generation (both measured in the same task).

    coster-sumo convert -o CONV CORPUS/heldout/*.npz
    coster-sumo eval scenarios CONV --method COSTER --method "COSTER t_col=last" \\
        --method "COSTER t_col=random" --workers 2 -o OUT
    python bench/avoidability_corpus.py OUT
"""

from __future__ import annotations

import argparse
import json
import re
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.metrics import rate_with_ci

TIMES = ("0.5", "1", "1.5")


def network_of(scene_key: str) -> str:
    """The corpus network of a clip's scene key (``fkk_in_r1_00123.4_7_s0_ab12cd34`` -> ``fkk_in``)."""
    m = re.match(r"(.+?)_r\d+_", scene_key)
    return m.group(1) if m else scene_key


def pct(flags: list[bool]) -> str:
    r = rate_with_ci(flags)
    if r["rate"] is None:
        return "n/a"
    return f"{100 * r['rate']:.0f}% [{100 * r['ci_low']:.0f}, {100 * r['ci_high']:.0f}] ({r['k']}/{r['n']})"


def table(title: str, groups: dict[str, list[dict[str, Any]]]) -> list[str]:
    lines = [f"### {title}", "", "| group | variants | " + " | ".join(f"avoidable @{t} s" for t in TIMES) + " |",
             "|---|---|" + "---|" * len(TIMES)]
    for name, recs in sorted(groups.items()):
        lines.append(f"| {name} | {len(recs)} | " + " | ".join(pct([bool(r["avoidable_at"].get(t)) for r in recs])
                                                             for t in TIMES) + " |")
    return lines + [""]


def before_after(records: list[dict[str, Any]]) -> list[str]:
    """Avoidable shares per rule with and without the escapes only SUMO's reacting traffic cleared.

    "before" counts a variant avoidable at a reaction time only through an escape clear of every
    other vehicle moving as recorded (the search of issue 44); "after" adds the escapes blocked only
    by vehicles SUMO drives that SUMO's proof cleared (``flipped_at``)."""
    lines = ["### Avoidable before / after trying blocked escapes in SUMO", "",
             "| rule | variants | " + " | ".join(f"before @{t} s | after @{t} s" for t in TIMES) + " |",
             "|---|---|" + "---|---|" * len(TIMES)]
    for method, recs in sorted(_group(records, "method").items()):
        if not all("flipped_at" in r for r in recs):
            continue
        cells = []
        for t in TIMES:
            after = [bool(r["avoidable_at"].get(t)) for r in recs]
            before = [a and not r["flipped_at"].get(t, False) for a, r in zip(after, recs, strict=True)]
            cells += [pct(before), pct(after)]
        lines.append(f"| {method} | {len(recs)} | " + " | ".join(cells) + " |")
    tried = sum(int(r.get("blocked_tried", 0)) for r in records)
    cleared = sum(int(r.get("blocked_cleared", 0)) for r in records)
    return lines + ["", f"Blocked escapes tried in SUMO: {tried}; cleared there: {cleared}.", ""]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--all-scenes", action="store_true",
                    help="every finished part (default: only the scenes every method finished, so the rules compare)")
    args = ap.parse_args()
    records: list[dict[str, Any]] = []
    gen_s = avoid_s = 0.0
    scenes: dict[str, set[str]] = defaultdict(set)
    for p in sorted((args.out / "parts").glob("*.json")):
        if p.name.endswith("__scene.json"):
            continue
        doc = json.loads(p.read_text())
        if doc.get("status") != "ok" or "avoidability_s" not in doc:
            continue
        scenes[doc["method"]].add(doc["scene_key"])
        gen_s += doc["generation_s"]
        avoid_s += doc["avoidability_s"]
        for r in doc["records"]:
            records.append({**r, "method": doc["method"], "network": network_of(doc["scene_key"]),
                            "scene_key": doc["scene_key"]})
    if not args.all_scenes and scenes:
        common = set.intersection(*scenes.values())
        records = [r for r in records if r["scene_key"] in common]
        scenes = {m: s & common for m, s in scenes.items()}
    print(f"{len(records)} variants; scenes per method: " + ", ".join(f"{m} {len(s)}" for m, s in scenes.items()))
    out = table("By collision-time rule", _group(records, "method"))
    out += before_after(records)
    for method in sorted({r["method"] for r in records}):
        mine = [r for r in records if r["method"] == method]
        out += table(f"{method}: by network", _group(mine, "network"))
        out += table(f"{method}: by kind of contact", _group(mine, "contact_kind"))
    out += ["### Last moment to act [s before t_col]", "", "| rule | variants | with an escape | p10 | p25 | p50 | "
            "p75 | p90 |", "|---|---|---|---|---|---|---|---|"]
    for method, recs in sorted(_group(records, "method").items()):
        last = np.array([r["last_moment_s"] for r in recs if r.get("last_moment_s") is not None], float)
        qs = " | ".join(f"{np.percentile(last, q):.1f}" if len(last) else "n/a" for q in (10, 25, 50, 75, 90))
        out.append(f"| {method} | {len(recs)} | {len(last)} | {qs} |")
    found = {t: sum(bool(r["escape_found_at"].get(t)) for r in records) for t in TIMES}
    refuted = sum(int(r.get("escapes_refuted", 0)) for r in records)
    replayed = sum(int(r.get("escapes_replayed", 0)) for r in records)
    out += ["", f"Kinematic escapes found per reaction time: {found}; escapes replayed in SUMO (counted per "
                f"reaction time): {replayed}, refuted there: {refuted}.",
            f"Cost: generation {gen_s:.0f} s, labels (search + SUMO proof from the begin) {avoid_s:.0f} s: "
            f"{100 * avoid_s / max(gen_s, 1e-9):.1f} % of generation."]
    print("\n".join(out))


def _group(records: list[dict[str, Any]], key: str) -> dict[str, list[dict[str, Any]]]:
    groups: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in records:
        groups[str(r[key])].append(r)
    return groups


if __name__ == "__main__":
    main()
