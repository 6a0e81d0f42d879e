"""Speed and leaks of ``coster_sumo/Scenario-v0``, against highway-env's ``highway-fast-v0`` in the same run.

    pip install highway-env            # only for this bench (not a dependency of coster-sumo)
    python bench/bench_gym.py --set SET [--womd-set WSET] [--episodes 1000] [--seconds 20]

1. Speed, per process: for every network of ``SET`` (and of ``WSET``, a set built from converted
   WOMD scenes) episodes run back to back with a fixed action (0, 0) for ``--seconds`` of wall
   time; it prints simulated seconds per wall second (resets included) and environment steps per
   second. Then ``highway-fast-v0`` (its default configuration: 1 policy step = 1 simulated
   second, 15 simulation steps per policy step) runs the same way with its idle action, and the
   ratio is printed. Both run in this one process, one after the other.
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
    args = ap.parse_args()

    from coster_sumo.gym.env import STEP_S, ScenarioEnv
    from coster_sumo.gym.scenario_set import ScenarioSet

    rows: list[tuple[str, float, float, int]] = []
    sets = [args.set] + ([args.womd_set] if args.womd_set else [])
    for root in sets:
        for net in sorted({e.network for e in ScenarioSet.load(root).entries}):
            env = ScenarioEnv(root, networks=(net,))
            per_step = env.substeps * STEP_S
            rate, sps, eps = run_for(env, args.seconds, np.zeros(2, np.float32), per_step)
            env.close()
            rows.append((f"Scenario-v0 {net}", rate, sps, eps))
            print(f"Scenario-v0 {net:24s} {rate:8.1f} sim s/wall s  {sps:7.1f} steps/s  ({eps} episodes)", flush=True)
    try:
        import gymnasium
        import highway_env  # noqa: F401

        gymnasium.register_envs(highway_env)
        hw = gymnasium.make("highway-fast-v0")
        freq = hw.unwrapped.config["policy_frequency"]
        idle = 1  # DiscreteMetaAction: IDLE
        rate, sps, eps = run_for(hw, args.seconds, idle, 1.0 / freq)
        hw.close()
        print(f"highway-fast-v0 {'':20s} {rate:8.1f} sim s/wall s  {sps:7.1f} steps/s  ({eps} episodes)")
        ours = [r[1] for r in rows]
        print(f"ratio Scenario-v0 / highway-fast-v0: min {min(ours) / rate:.2f}, max {max(ours) / rate:.2f}")
    except ImportError:
        print("highway-env not installed (pip install highway-env): no comparison")

    if args.episodes > 0:
        env = ScenarioEnv(args.set, order="cycle")
        env.reset(seed=0)
        t0 = time.perf_counter()
        first: tuple[float, int, int] | None = None
        for ep in range(args.episodes):
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
            print(f"leaks over {args.episodes} episodes ({time.perf_counter() - t0:.0f} s): RSS {first[0]:.1f} -> "
                  f"{rss:.1f} MB after episode 50 -> end; fds {first[1]} -> {fds}; "
                  f"child processes {first[2]} -> {kids}")


if __name__ == "__main__":
    main()
