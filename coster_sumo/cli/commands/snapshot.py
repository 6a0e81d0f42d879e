"""``coster-sumo snapshot SCENE_OR_CFG --target ID``: the collision snapshot alone, as JSON and a PNG."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.method.collision_time import COLLISION_TIME_RULES
from coster_sumo.method.snapshot import SNAPSHOT_INITS, PlacementRequest


def register(cli: Any) -> None:
    p = cli.commands.add_parser(
        "snapshot", help="collision time and collision snapshot for a target (JSON + PNG)",
        description="Find when (velocity entropy) and where (prior placement) a collision with the target "
                    "is plausible. SCENE_OR_CFG is a .sumocfg (simulated and recorded), a converted scene "
                    "folder's .sumocfg, a scene .npz, or a WOMD .tfrecord / ScenarioNet .pkl (first record).")
    p.add_argument("source", type=Path, metavar="SCENE_OR_CFG",
                   help=".sumocfg, scene .npz, WOMD .tfrecord or ScenarioNet .pkl")
    p.add_argument("--target", help="target id (default: the SDC / 'ego')")
    p.add_argument("--collision-time", default="entropy", choices=tuple(COLLISION_TIME_RULES))
    p.add_argument("--init", default="snapshot", choices=tuple(SNAPSHOT_INITS))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--end", type=float, help="[s] end of the recorded window for a .sumocfg")
    p.add_argument("--models", type=Path, help="folder with prior.pt (default: shipped)")
    p.add_argument("-o", "--out", type=Path, default=Path("out/snapshot"), help="output folder")
    p.set_defaults(func=run)


def _scene(args: argparse.Namespace) -> Any:
    from coster_sumo.core.spec import ScenarioSpec
    from coster_sumo.pipeline.scenario import nominal_scene

    src: Path = args.source
    if src.suffix == ".sumocfg":
        return nominal_scene(ScenarioSpec(src, seed=args.seed, end=args.end))[0]
    from coster_sumo.converters.read import iter_scenes

    for scene in iter_scenes(src):
        return scene
    from coster_sumo.errors import InputError

    raise InputError(f"{src}: holds no scene")


def run(args: argparse.Namespace) -> int:
    from coster_sumo.core.scene import resample
    from coster_sumo.errors import InputError, NoSnapshot
    from coster_sumo.formats.targets import choose_target
    from coster_sumo.geometry.drivable import DrivableArea
    from coster_sumo.method.snapshot import prior_snapshot
    from coster_sumo.pipeline import viz

    scene = _scene(args)
    target = choose_target(scene, args.target, args.source)
    low = resample(scene, 2.0)
    drivable = DrivableArea.from_road_map(scene.road_map)
    rng = np.random.default_rng(args.seed)
    regions: dict[str, np.ndarray] = {}
    try:
        if args.init == "snapshot":  # the prior's placement, with its regions for the picture
            snap = prior_snapshot(PlacementRequest(low, target, rng, drivable, args.collision_time, args.seed,
                                                   args.models), regions_out=regions)
        else:
            snap = SNAPSHOT_INITS[args.init].place(PlacementRequest(low, target, rng, drivable, args.collision_time,
                                                                    args.seed, args.models))
    except NoSnapshot as exc:
        raise InputError(f"{args.source}: no collision snapshot for target "
                         f"{str(scene.tracks.ids[target])!r}: {exc}") from None
    args.out.mkdir(parents=True, exist_ok=True)
    snap.save(args.out / "snapshot.json")
    moment = viz.CollisionMoment(snap.time, snap.t_index, snap.target, snap.adversary, snap.entropy or None,
                                 low.timestamps, regions.get("xy"), regions.get("presence"))
    viz.render_overview(args.out / "snapshot.png", low, target, moment,
                        [np.array([[snap.adversary.x, snap.adversary.y, snap.adversary.yaw]])])
    if not args.quiet:
        print(f"t_col {snap.time:.2f} s ({snap.collision_time_method}), adversary at ({snap.adversary.x:.2f}, "
              f"{snap.adversary.y:.2f}) heading {np.degrees(snap.adversary.yaw):.0f} deg, "
              f"{snap.adversary.speed:.1f} m/s, signed distance {snap.signed_distance:.2e} m; "
              f"wrote {args.out}/snapshot.json and snapshot.png")
    return 0
