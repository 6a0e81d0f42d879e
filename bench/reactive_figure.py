"""docs/gym_reactive.png: a target that brakes, its follower in log replay and in reactive traffic.

    python bench/reactive_figure.py [-o docs/gym_reactive.png] [--network intersection] [--seed 1]

Builds a nominal scenario set of one shipped network (in a temporary folder), drives its
target (from a seeded random time in the clip) braking at 4 m/s^2 in ``traffic="log"`` and in
``traffic="reactive"`` (Krauss and IDM), and plots, against time, the target's and each of its
followers' positions along the target's route (the follower that runs into it in the log; the
same vehicle in reactive traffic, where SUMO drives it from the moment the target's deviation
reaches it). The same runs are the test ``tests/sim/test_reactive.py``.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

BRAKE_MPS2 = 4.0  # [m/s^2]
START_SEED = 0  # the episode starts at a random time in the clip (seeded): the target has followers then


def drive(scenarios: Path, traffic: str, car_following: str = "Krauss") -> tuple[dict, str, dict[str, list]]:
    """One braking episode: the last info, the target's id, and per vehicle in the target's route
    corridor its (time, arc length) samples."""
    from coster_sumo.geometry.boxes import project_points
    from coster_sumo.gym.env import ScenarioEnv
    from coster_sumo.sim.driver import MAX_DECEL

    env = ScenarioEnv(scenarios, traffic=traffic, car_following=car_following, order="cycle", random_start=True)
    env.reset(seed=START_SEED)
    # the route, extended 100 m straight back from where the episode starts (the followers are there)
    first, second = env.route.points[0], env.route.points[1]
    back = (first - second) / np.hypot(*(first - second))
    route = np.concatenate([first + np.linspace(100.0, 0.5, 200)[:, None] * back, env.route.points])
    target = env.target_id
    along: dict[str, list] = {}
    done, info = False, {}
    while not done:
        st = env.states
        s, d, _ = project_points(np.stack([st.x, st.y], -1), route)
        for vid, si, di in zip(st.id_list(), s.tolist(), d.tolist(), strict=True):
            if abs(di) < 2.0:
                along.setdefault(vid, []).append((env._now(), si - 100.0))
        _, _, terminated, truncated, info = env.step(np.array([-BRAKE_MPS2 / MAX_DECEL, 0.0], np.float32))
        done = terminated or truncated
    env.close()
    return info, target, along


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--out", type=Path, default=Path("docs/gym_reactive.png"))
    ap.add_argument("--network", default="intersection")
    ap.add_argument("--seed", type=int, default=1, help="SUMO seed of the nominal pass (default 1)")
    args = ap.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from coster_sumo.gym.build import BuildOptions, build_set

    repo = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "set"
        build_set(BuildOptions(sources=[str(repo / "networks" / args.network / f"{args.network}.sumocfg")], out=out,
                               method="nominal", seed=args.seed, quiet=True))
        runs = {mode: drive(out, *mode.split(":")) for mode in ("log", "reactive:Krauss", "reactive:IDM")}
    log_info = runs["log"][0]
    follower = log_info["collided_with"]
    fig, axes = plt.subplots(1, 3, figsize=(13, 4), sharey=True)
    for ax, (mode, (info, target, along)) in zip(axes, runs.items(), strict=True):
        for vid, rows in along.items():
            t, s = np.array(rows).T
            if vid == follower:
                ax.plot(t, s, ".", ms=3, color="tab:red", label=f"follower {vid}")
            elif vid == target:
                ax.plot(t, s, ".", ms=3, color="tab:blue", label="target (braking 4 m/s$^2$)")
            else:
                ax.plot(t, s, ".", ms=1.5, color="0.7")
        ax.set_title(f"{mode}: {info['outcome']}" + (f" with {info['collided_with']}" if info["collided_with"] else "")
                     + f", {info['reacting']} reacting")
        ax.set_xlabel("time [s]")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("position along the target's route [m]")
    axes[0].legend(loc="upper left", fontsize=8)
    fig.suptitle(f"Scenario-v0 on {args.network} (seed {args.seed}): the log's follower drives into a braking target; "
                 "reactive followers brake (grey: other vehicles in the corridor)", fontsize=10)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}: log {log_info['outcome']} with {follower}; "
          + ", ".join(f"{m} {r[0]['outcome']}" for m, r in runs.items() if m != "log"))


if __name__ == "__main__":
    main()
