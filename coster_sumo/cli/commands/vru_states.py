"""``coster-sumo train vru-states``: the learned speed and heading of pedestrian and cyclist adversaries."""

from __future__ import annotations

import argparse
import sys
import time

from coster_sumo.errors import InputError

DEFAULT_OUT = "models/vru_states.npz"


def register(cli) -> None:  # type: ignore[no-untyped-def]
    train = cli.training(
        "vru-states", help="count the speeds and headings of pedestrians and cyclists on the road",
        description="Count, per class, the speed and the angle to the nearest lane of every pedestrian and "
                    "cyclist that moves on the road surface or a crossing in DATASET/scenes/*.npz (2 Hz). A "
                    "pedestrian or cyclist adversary's state at contact is drawn from these counts "
                    "(docs/method.md, 'Pedestrian and cyclist adversaries'). Held-out clips are never read.",
        out=DEFAULT_OUT, what="counts file (.npz)")
    train.set_defaults(func=run_train)


def run_train(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from coster_sumo.data.dataset import list_scenes
    from coster_sumo.formats.scene_file import load_scene
    from coster_sumo.method.vru.contact_states import MIN_SAMPLES, fit_contact_states

    files = list_scenes(args.data)
    if not files:
        raise InputError(f"{args.data}: no scenes (DATASET/scenes/*.npz)")
    t0 = time.perf_counter()

    def progress(it):  # type: ignore[no-untyped-def]
        return tqdm(it, total=len(files), desc="scenes", disable=args.quiet, leave=False)

    states = fit_contact_states((load_scene(f) for f in files), progress=progress, source=str(args.data))
    states.meta["wall_time_s"] = round(time.perf_counter() - t0, 1)
    path = states.save(args.out)
    for name, n in states.meta["steps"].items():
        enough = "" if states.has(name) else f" (fewer than {MIN_SAMPLES}: the class's rules stay)"
        share = f", {100 * states.crossing_share(name):.0f} % across the lane" if n else ""
        print(f"{name}: {n} steps on the road{share}{enough}", file=sys.stderr)
    print(f"wrote {path} ({len(files)} scenes, {states.meta['wall_time_s']:.0f} s)")
    return 0
