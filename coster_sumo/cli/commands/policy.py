"""``coster-sumo policy train SET -o DIR`` and ``coster-sumo policy eval POLICY SET``.

``train`` trains a driving policy (stable-baselines3 PPO or TD3, a small MLP) on the ``train`` split of a
scenario set in ``coster_sumo/Scenario-v0``; rerunning the same command resumes from
DIR/checkpoint.zip. ``eval`` drives every scenario of a split once and prints RCR, CR and ORR
(and writes them with every episode to the JSON file ``-o`` names). The library is
:mod:`coster_sumo.gym.train`; both need the ``rl`` extra.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from coster_sumo.infra.extras import require


def _train(args: argparse.Namespace) -> int:
    require("rl", "coster-sumo policy train")
    from coster_sumo.gym.train import TrainOptions, train

    progress = train(TrainOptions(scenarios=args.scenarios, out=args.out, timesteps=args.timesteps, seed=args.seed,
                                  envs=args.envs, checkpoint_steps=args.checkpoint_steps, quiet=args.quiet,
                                  traffic=args.traffic, car_following=args.car_following,
                                  random_start=args.random_start, observation=args.observation,
                                  learner=args.learner))
    if not args.quiet:
        print(f"{progress.steps} steps in {progress.wall_s:.0f} s; outcomes {progress.outcomes}; "
              f"wrote {args.out}")
    return 0


def _eval(args: argparse.Namespace) -> int:
    require("rl", "coster-sumo policy eval")
    from coster_sumo.gym.train import evaluate
    from coster_sumo.infra.atomic import write_json

    policy = None if args.policy == "none" else args.policy
    result, rows = evaluate(policy, args.scenarios, split=None if args.split == "all" else args.split,
                            max_episodes=args.max_episodes, hard=args.hard, traffic=args.traffic,
                            car_following=args.car_following, observation=args.observation)
    out = {"policy": str(args.policy), "scenarios": str(args.scenarios), "split": args.split,
           "traffic": args.traffic, "car_following": args.car_following, **result.to_json(),
           "episodes_detail": [r.to_json() for r in rows]}
    if args.out:
        write_json(args.out, out)
    if not args.quiet:
        print(json.dumps({k: v for k, v in out.items() if k != "episodes_detail"}, indent=1))
    return 0


def register(cli: Any) -> None:
    group = cli.group("policy", help="train and evaluate driving policies on scenario sets (needs coster-sumo[rl])")
    t = group.add_parser("train", help="PPO or TD3 on a scenario set's train split (resumable)",
                         description=__doc__.split("\n\n")[1] if __doc__ else None)
    t.add_argument("scenarios", type=Path, metavar="SET", help="scenario set (coster-sumo scenarios build)")
    t.add_argument("-o", "--out", type=Path, required=True, help="folder for checkpoint.zip, progress.json, policy.zip")
    t.add_argument("--timesteps", type=int, default=20_000, help="environment steps in all (default 20000)")
    t.add_argument("--seed", type=int, default=0, help="seed of the learner and the scenario draws (default 0)")
    t.add_argument("--envs", type=int, default=1, help="environments, one process each when > 1 (default 1)")
    t.add_argument("--checkpoint-steps", type=int, default=2048, help="save every N steps (default 2048)")
    t.add_argument("--learner", choices=("ppo", "td3"), default="ppo",
                   help="ppo (default) or td3 (Adv-BMT's settings; its replay buffer is saved beside the checkpoint)")
    t.add_argument("--random-start", action="store_true",
                   help="nominal episodes start at a seeded random time within the clip (not at its start)")
    add_traffic_options(t)
    t.set_defaults(func=_train)
    e = group.add_parser("eval", help="drive every scenario of a split once: RCR, CR, ORR")
    e.add_argument("policy", metavar="POLICY",
                   help="policy.zip or checkpoint.zip ('none': the action (0, 0), the nominal path at constant speed; "
                        "'sumo': SUMO's driver model drives the target)")
    e.add_argument("scenarios", type=Path, metavar="SET", help="scenario set")
    e.add_argument("--split", choices=("train", "test", "all"), default="test", help="default test")
    e.add_argument("--max-episodes", type=int, help="at most this many scenarios")
    e.add_argument("--hard", action="store_true",
                   help="Hard (a set built with --method hard): the hand-specified adversities and the top 20 %% "
                        "of the nominal scenes by criticality")
    e.add_argument("-o", "--out", "--json", dest="out", type=Path, metavar="JSON",
                   help="also write the result (and every episode) to this JSON file")
    add_traffic_options(e)
    e.set_defaults(func=_eval)


def add_traffic_options(parser: argparse.ArgumentParser) -> None:
    """``--traffic log|reactive`` and ``--car-following Krauss|IDM`` (coster_sumo.sim.reactive)."""
    parser.add_argument("--traffic", choices=("log", "reactive"), default="log",
                        help="the other vehicles: log (replayed, nothing reacts; default) or reactive (each follows "
                             "its log until the target's deviation reaches it, then SUMO drives it)")
    parser.add_argument("--car-following", choices=("Krauss", "IDM"), default="Krauss",
                        help="the reacting vehicles' car-following model (default Krauss)")
    parser.add_argument("--observation", choices=("default", "avoidance", "lidar"), default="default",
                        help="default (90 numbers), avoidance (and the vehicles ahead/behind in the route corridor: "
                             "gap, closing speed, TTC; time left) or lidar (72 rays to 50 m instead of the vehicle "
                             "list); eval must use the policy's")
