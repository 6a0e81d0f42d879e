"""Speed and leaks of ``coster_sumo/Scenario-v0``, against highway-env's ``highway-fast-v0`` in the same run.

    pip install highway-env            # only for this bench (not a dependency of coster-sumo)
    python bench/bench_gym.py --set SET [--womd-set WSET] [--episodes 1000] [--seconds 20] [--traffic log,reactive]

1. Speed, per process: for every network of ``SET`` (and of ``WSET``, a set built from converted
   WOMD scenes) episodes run back to back with a fixed action (0, 0) for ``--seconds`` of wall
   time, once per traffic mode (``log``: the other vehicles read from the recorded pass, the
   default; ``sumo``: every vehicle in SUMO, moved by moveToXY; ``reactive``: each follows its log
   until the target's deviation reaches it, then SUMO drives it: with the action (0, 0) the target
   keeps its first speed, so it deviates from its nominal motion wherever that changes speed); it
   prints simulated seconds per wall second (resets included) and environment steps per second.
   Then ``highway-fast-v0`` (its default configuration: 1 policy step = 1 simulated second, 15
   simulation steps per policy step) runs the same way with its idle action, and the ratio is
   printed. Both run in this one process,
   in ``--rounds`` interleaved slices (highway-fast-v0 in each round); the medians are printed.
2. Leaks: ``--episodes`` episodes (resets and steps) of Scenario-v0 in turn over every scenario of
   ``SET``; resident memory (VmRSS), open file descriptors and child processes are read after the
   first 50 episodes and at the end.

Build a set with ``coster-sumo scenarios build networks/*/*.sumocfg -o SET --method coster``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np


def _rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return float(line.split()[1]) / 1024.0
    return float("nan")


def _children() -> int:
    me = str(os.getpid())
    n = 0
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                if (p / "stat").read_text().split(") ", 1)[1].split()[1] == me:
                    n += 1
            except (OSError, IndexError):
                pass
    return n


def _fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def run_for(env, seconds: float, action, sim_s_per_step) -> tuple[float, float, int]:  # type: ignore[no-untyped-def]
    """Episodes back to back for ``seconds`` wall: (simulated s per wall s, env steps per s, episodes)."""
    t0 = time.perf_counter()
    sim_s, steps, episodes = 0.0, 0, 0
    env.reset(seed=0)
    while time.perf_counter() - t0 < seconds:
        _, _, term, trunc, _ = env.step(action)
        steps += 1
        sim_s += sim_s_per_step
        if term or trunc:
            episodes += 1
            env.reset()
    wall = time.perf_counter() - t0
    return sim_s / wall, steps / wall, episodes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", required=True, type=Path, help="scenario set (shipped networks)")
    ap.add_argument("--womd-set", type=Path, help="scenario set of converted WOMD scenes")
    ap.add_argument("--seconds", type=float, default=20.0, help="wall seconds per speed measurement")
    ap.add_argument("--episodes", type=int, default=1000, help="episodes of the leak check (0: skip)")
    ap.add_argument("--rounds", type=int, default=5, help="slices per measurement, interleaved (default: %(default)s)")
    ap.add_argument("--traffic", default="log,sumo",
                    help="the environment's traffic modes to time, comma-separated (default: %(default)s)")
    args = ap.parse_args()

    from coster_sumo.gym.env import STEP_S, ScenarioEnv
    from coster_sumo.gym.scenario_set import ScenarioSet

    try:
        import gymnasium
        import highway_env  # noqa: F401

        gymnasium.register_envs(highway_env)
        hw = gymnasium.make("highway-fast-v0")
        hw_per_step = 1.0 / hw.unwrapped.config["policy_frequency"]
    except ImportError:
        hw = None
        print("highway-env not installed (pip install highway-env): no comparison")
    idle = 1  # highway-env's DiscreteMetaAction: IDLE
    configs = [(root, net, traffic) for root in [args.set] + ([args.womd_set] if args.womd_set else [])
               for net in sorted({e.network for e in ScenarioSet.load(root).entries})
               for traffic in args.traffic.split(",")]
    # rounds of short slices, highway-fast-v0 in every round: a ratio per round, robust to a load that
    # changes during the bench (other processes on the machine)
    slice_s = args.seconds / args.rounds
    rates: dict[str, list[float]] = {}
    step_rates: dict[str, list[float]] = {}
    ratios: dict[str, list[float]] = {}
    for _ in range(args.rounds):
        hw_rate, hw_steps, _ = run_for(hw, slice_s, idle, hw_per_step) if hw is not None else (float("nan"),) * 3
        rates.setdefault("highway-fast-v0", []).append(hw_rate)
        step_rates.setdefault("highway-fast-v0", []).append(hw_steps)
        for root, net, traffic in configs:
            env = ScenarioEnv(root, networks=(net,), traffic=traffic)
            rate, steps, _ = run_for(env, slice_s, np.zeros(2, np.float32), env.substeps * STEP_S)
            env.close()
            key = f"Scenario-v0 {net} traffic={traffic}"
            rates.setdefault(key, []).append(rate)
            step_rates.setdefault(key, []).append(steps)
            ratios.setdefault(key, []).append(rate / hw_rate if hw_rate > 0 else float("nan"))
    if hw is not None:
        hw.close()
    print(f"{'environment':52s} {'sim s / wall s (median of rounds)':>34s} {'env steps / s':>14s} "
          f"{'/ highway-fast-v0':>18s}")
    for key, vals in rates.items():
        ratio = f"{float(np.median(ratios[key])):.2f}" if key in ratios else ""
        print(f"{key:52s} {float(np.median(vals)):34.1f} {float(np.median(step_rates[key])):14.0f} {ratio:>18s}")
    for traffic in args.traffic.split(","):
        mine = [float(np.median(v)) for k, v in ratios.items() if k.endswith(f"traffic={traffic}")]
        if mine:
            print(f"ratio Scenario-v0 (traffic={traffic}) / highway-fast-v0: min {min(mine):.2f}, max {max(mine):.2f}")

    if args.episodes > 0:
        for root in [args.set] + ([args.womd_set] if args.womd_set else []):
            leak_check(root, args.episodes)


def leak_check(root: Path, episodes: int) -> None:
    """``episodes`` short episodes in turn over every scenario of ``root`` in one environment
    (which keeps a network loaded across the episodes on it where it can): memory, descriptors and
    child processes after episode 50 and at the end."""
    from coster_sumo.gym.env import ScenarioEnv

    env = ScenarioEnv(root, order="cycle")
    env.reset(seed=0)
    t0 = time.perf_counter()
    first: tuple[float, int, int] | None = None
    for ep in range(episodes):
        if ep:
            env.reset()
        for _ in range(15):  # 3 simulated seconds per episode: resets dominate, as they would for leaks
            _, _, term, trunc, _ = env.step(env.action_space.sample())
            if term or trunc:
                break
        if ep == 49:
            first = (_rss_mb(), _fds(), _children())
    env.close()
    rss, fds, kids = _rss_mb(), _fds(), _children()
    if first is not None:
        print(f"leaks, {root.name}, over {episodes} episodes ({time.perf_counter() - t0:.0f} s): RSS "
              f"{first[0]:.1f} -> {rss:.1f} MB after episode 50 -> end; fds {first[1]} -> {fds}; "
              f"child processes {first[2]} -> {kids}")


if __name__ == "__main__":
    main()
