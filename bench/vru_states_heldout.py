"""How close the learned VRU contact states are to held-out networks, against the classes' rules.

    python bench/vru_states_heldout.py HELDOUT_SCENES... [--states models/vru_states.npz]

Counts the held-out clips exactly as ``coster-sumo train vru-states`` counts the corpus (moving
pedestrians and cyclists on the road surface or a crossing, 2 Hz), then gives per class the
Jensen-Shannon divergence (nats, at most ln 2) of the speed and of the angle to the lane between the
held-out counts and (a) the shipped counts, (b) 200,000 draws of the class's rules (the snapshot's
``--init random`` path: ``_headings`` relative to the target's direction and ``draw_speed``), on the
counts' bins. Lower is closer.
"""

from __future__ import annotations

import argparse
import glob
import json

import numpy as np

from coster_sumo.formats.scene_file import load_scene
from coster_sumo.method.vru.classes import VRU_CLASSES
from coster_sumo.method.vru.contact_states import HEADING_EDGES, SPEED_EDGES, ContactStates, fit_contact_states
from coster_sumo.method.vru.snapshot import _headings


def jsd(p: np.ndarray, q: np.ndarray) -> float:
    p, q = p / p.sum(), q / q.sum()
    m = 0.5 * (p + q)

    def kl(a: np.ndarray) -> float:
        nz = a > 0
        return float((a[nz] * np.log(a[nz] / m[nz])).sum())

    return 0.5 * kl(p) + 0.5 * kl(q)


def rules_counts(name: str, n: int = 200_000, seed: int = 0) -> np.ndarray:
    vru, rng = VRU_CLASSES[name], np.random.default_rng(seed)
    side = np.where(rng.random(n) < 0.5, 1.0, -1.0)
    angle = np.abs(np.angle(np.exp(1j * _headings(vru, 0.0, side, rng))))
    speed = vru.draw_speed(rng, n)
    return np.histogram2d(speed, angle, bins=[SPEED_EDGES, HEADING_EDGES])[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+", help="held-out scene files (globs allowed)")
    ap.add_argument("--states", default="models/vru_states.npz")
    args = ap.parse_args()
    files = sorted({f for pat in args.scenes for f in glob.glob(pat)})
    held = fit_contact_states(load_scene(f) for f in files)
    learned = ContactStates.load(args.states)
    out = {"held_out_scenes": len(files), "held_out_steps": held.meta["steps"]}
    for name in VRU_CLASSES:
        h = held.counts[name].astype(float)
        if h.sum() == 0:
            continue
        row = {}
        for label, c in (("learned", learned.counts[name].astype(float)), ("rules", rules_counts(name))):
            row[label] = {"speed_jsd": round(jsd(h.sum(1), c.sum(1)), 4),
                          "angle_jsd": round(jsd(h.sum(0), c.sum(0)), 4)}
        out[name] = row
        lr, ru = row["learned"], row["rules"]
        print(f"{name}: {int(h.sum())} held-out steps; JSD speed / angle: learned {lr['speed_jsd']:.3f} / "
              f"{lr['angle_jsd']:.3f}, rules {ru['speed_jsd']:.3f} / {ru['angle_jsd']:.3f}")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
