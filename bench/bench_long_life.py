"""Generation for a target with a long life (minutes in a city): the coarse-to-fine collision-time
search against the exact one over every step.

    python bench/bench_long_life.py --config CFG --target ID [--scene pass.npz] [--repeats 1]

Records the nominal pass of ``--target`` once (kept in ``--scene``, default
``<work>/<config stem>_<target>.npz``, reused when it exists), then times generation on it
(:func:`coster_sumo.method.generation.plan_scenarios`: one snapshot, 5 variants, the shipped
weights; as ``run``'s ``generation_s`` counts it, the 2 Hz copy of the scene apart), alternating
the search as shipped (coarse to fine above ``LONG_WINDOW_STEPS``) and the exact search (every
step: ``LONG_WINDOW_STEPS`` set past the window). Prints per round the 2 Hz copy's and the
generation's wall time, the search window's length, the steps the curve was computed at, t_col
and the variants kept. The prior's weights are loaded before the first round, as in
``coster-sumo serve``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


def nominal(config: Path, target: str, path: Path) -> None:
    from coster_sumo.core.spec import ScenarioSpec
    from coster_sumo.formats.scene_file import save_scene
    from coster_sumo.pipeline.scenario import nominal_scene

    if path.exists():
        return
    t0 = time.perf_counter()
    scene, _ = nominal_scene(ScenarioSpec(config, seed=0, target=target))
    print(f"nominal pass: {time.perf_counter() - t0:.1f} s, {len(scene.tracks.ids)} agents x {scene.num_steps} steps")
    path.parent.mkdir(parents=True, exist_ok=True)
    save_scene(scene, path)


def one_round(scene, target: int, exact: bool) -> dict[str, float]:  # type: ignore[no-untyped-def]
    from coster_sumo.core.spec import GenerationConfig
    from coster_sumo.geometry.drivable import DrivableArea
    from coster_sumo.method import collision_time as ct
    from coster_sumo.method.generation import DrawMemo, plan_scenarios

    saved = ct.LONG_WINDOW_STEPS
    ct.LONG_WINDOW_STEPS = 10**9 if exact else saved
    try:
        drivable = DrivableArea.from_road_map(scene.road_map)
        t0 = time.perf_counter()
        memo = DrawMemo.of(scene)  # a run makes its 2 Hz copy once for all its targets, before generation
        t1 = time.perf_counter()
        planned = plan_scenarios(scene, target, 0, GenerationConfig(), drivable, memo, 1)
        total = time.perf_counter() - t1
    finally:
        ct.LONG_WINDOW_STEPS = saved
    window = ct.search_window(memo.low, target)
    p = planned[0]
    return {"resample_s": t1 - t0, "generation_s": total, "window_steps": len(window), "t_col": float(p.snapshot.time),
            "variants": len(p.plans), "computed_steps": int(np.isfinite(np.asarray(memo.prior.entropy)).sum())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", type=Path, required=True)
    ap.add_argument("--target", required=True)
    ap.add_argument("--scene", type=Path)
    ap.add_argument("--work", type=Path, default=Path("/tmp/coster-bench-long-life"))
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--modes", nargs="+", choices=("coarse-to-fine", "exact"), default=["coarse-to-fine", "exact"])
    args = ap.parse_args()
    path = args.scene or args.work / f"{args.config.stem}_{args.target}.npz"
    nominal(args.config, args.target, path)

    from coster_sumo.formats.scene_file import load_scene
    from coster_sumo.infra import weights
    from coster_sumo.prior.infer import load_prior

    weights.load_cached(weights.weights_path(weights.PRIOR, None), load_prior)  # loaded, as in a server
    scene = load_scene(path)
    target = scene.tracks.index_of(args.target)
    for r in range(args.repeats):
        for mode in args.modes:
            exact = mode == "exact"
            res = one_round(scene, target, exact)
            print(f"round {r} {'exact' if exact else 'coarse-to-fine'}: " + ", ".join(
                f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}" for k, v in res.items()), flush=True)


if __name__ == "__main__":
    main()
