"""Generation for a target with a long life (minutes in a city): the coarse-to-fine collision-time
search against the exact one over every step.

    python bench/bench_long_life.py --config CFG --target ID [--scene pass.npz] [--repeats 1] [--seeds 1]

Records the nominal pass of ``--target`` once (kept in ``--scene``, default
``<work>/<config stem>_<target>.npz``, reused when it exists), then times generation on it
(:func:`coster_sumo.method.generation.plan_scenarios`: one snapshot, 5 variants, the shipped
weights; as ``run``'s ``generation_s`` counts it, the 2 Hz copy of the scene apart), alternating
the search as shipped (coarse to fine above ``LONG_WINDOW_STEPS``) and the exact search (every
step: ``LONG_WINDOW_STEPS`` set past the window). Prints per round the 2 Hz copy's and the
generation's wall time, the generation's CPU time (user + system of every thread of the process:
torch's included), the search window's length, the steps the curve was computed at, the
steps the prior's data was built at, t_col, the variants kept and the draws made (``--seeds N``:
each round for the seeds 0..N-1; a seed's draw can give its best collision time up and take the
next best). The prior's weights are loaded before the first round, as in ``coster-sumo serve``.

The same script times an older version of the package when that version comes first on the path
(``PYTHONPATH=OLD_CHECKOUT``, its ``coster_sumo`` folder): old and new in one session, under the
same load.
"""

from __future__ import annotations

import argparse
import itertools
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


def one_round(scene, target: int, exact: bool, seed: int = 0) -> dict[str, float]:  # type: ignore[no-untyped-def]
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
        t1, c1 = time.perf_counter(), time.process_time()
        planned = plan_scenarios(scene, target, seed, GenerationConfig(), drivable, memo, 1)
        total, cpu = time.perf_counter() - t1, time.process_time() - c1
    finally:
        ct.LONG_WINDOW_STEPS = saved
    window = ct.search_window(memo.low, target)
    p = planned[0]
    built = getattr(memo.prior.data.occupancy, "built", None)  # versions before it built every step
    return {"resample_s": t1 - t0, "generation_s": total, "generation_cpu_s": cpu,
            "window_steps": len(window), "t_col": float(p.snapshot.time),
            "variants": len(p.plans), "computed_steps": int(np.isfinite(np.asarray(memo.prior.entropy)).sum()),
            "data_steps": memo.low.num_steps if built is None else int(built.sum()),
            "draws": int(p.info.get("attempt", 1)), "given_up": len(p.info.get("collision_times_given_up", {}))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", type=Path, required=True)
    ap.add_argument("--target", required=True)
    ap.add_argument("--scene", type=Path)
    ap.add_argument("--work", type=Path, default=Path("/tmp/coster-bench-long-life"))
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--seeds", type=int, default=1, help="each round for the seeds 0..N-1")
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
    import coster_sumo

    print(f"package: {Path(coster_sumo.__file__).parent}")
    for r in range(args.repeats):
        for mode, seed in itertools.product(args.modes, range(args.seeds)):
            exact = mode == "exact"
            res = one_round(scene, target, exact, seed)
            print(f"round {r} {'exact' if exact else 'coarse-to-fine'} seed {seed}: " + ", ".join(
                f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}" for k, v in res.items()), flush=True)


if __name__ == "__main__":
    main()
