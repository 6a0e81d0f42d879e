"""Speed and leaks of ``coster_sumo/Scenario-v0``, against highway-env's ``highway-fast-v0`` in the same run.

    pip install 'coster-sumo[bench]'   # highway-env, only for this bench (not a dependency of coster-sumo)
    python bench/bench_gym.py --set SET [--womd-set WSET] [--episodes 1000] [--seconds 20]
                              [--traffic log,reactive] [--baseline-ref REF]

1. Speed, per process: for every network of ``SET`` (and of ``WSET``, a set built from converted
   WOMD scenes) episodes run back to back with a fixed action (0, 0) for ``--seconds`` of wall
   time, once per traffic mode (``log``: the other vehicles read from the recorded pass, the
   default; ``sumo``: every vehicle in SUMO, moved by moveToXY; ``reactive``: each follows its log
   until the target's deviation reaches it, then SUMO drives it: with the action (0, 0) the target
   keeps its first speed, so it deviates from its nominal motion wherever that changes speed), each
   slice in a fresh process; it prints simulated seconds per wall second (resets included),
   environment steps per wall second and per CPU second of that process (the rate of a core of its
   own: on a shared machine the wall rate falls with the load, the CPU rate much less).
   ``highway-fast-v0`` (its default configuration: 1 policy step = 1 simulated second, 15
   simulation steps per policy step) runs the same way with its idle action, and the ratio is
   printed. Everything runs in ``--rounds`` interleaved slices (highway-fast-v0 in each round); the
   medians are printed. ``--baseline-ref REF`` times the package of git commit ``REF`` too (its
   sources unpacked into a temporary folder, imported before this checkout's), slice for slice
   beside this checkout's, and prints the speed-up in steps per CPU second.
2. Leaks: ``--episodes`` episodes (resets and steps) of Scenario-v0 in turn over every scenario of
   ``SET``; resident memory (VmRSS), open file descriptors and child processes are read after the
   first 50 episodes and at the end.

Build a set with ``coster-sumo scenarios build networks/*/*.sumocfg -o SET --method coster``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
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


def run_for(env, seconds: float, action, sim_s_per_step) -> tuple[float, float, int, float]:  # type: ignore[no-untyped-def]
    """Episodes back to back for ``seconds`` wall: (simulated s per wall s, env steps per wall s,
    episodes, env steps per CPU second of this process: the rate of one core of its own, which a
    shared machine's load changes less than the wall rate)."""
    t0, c0 = time.perf_counter(), time.process_time()
    sim_s, steps, episodes = 0.0, 0, 0
    env.reset(seed=0)
    while time.perf_counter() - t0 < seconds:
        _, _, term, trunc, _ = env.step(action)
        steps += 1
        sim_s += sim_s_per_step
        if term or trunc:
            episodes += 1
            env.reset()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return sim_s / wall, steps / wall, episodes, steps / max(cpu, 1e-9)


def _worker(root: Path, net: str, traffic: str, seconds: float) -> None:
    """One slice of Scenario-v0 in this process (the code of ``BENCH_GYM_TREE`` when set), as JSON."""
    tree = os.environ.get("BENCH_GYM_TREE")
    if tree:  # the baseline's package before this checkout's editable install
        sys.meta_path[:] = [f for f in sys.meta_path if "editable" not in repr(f).lower()]
        sys.path.insert(0, tree)
    from coster_sumo.gym.env import STEP_S, ScenarioEnv

    env = ScenarioEnv(root, networks=(net,), traffic=traffic)
    env.reset(seed=0)  # not timed: the first reset reads the scenes and builds their drivable areas
    for _ in range(5):
        env.step(np.zeros(2, np.float32))
    rate, steps, _, cpu_steps = run_for(env, seconds, np.zeros(2, np.float32), env.substeps * STEP_S)
    env.close()
    print(json.dumps({"rate": rate, "steps": steps, "cpu_steps": cpu_steps}))


def _slice(tree: Path | None, root: Path, net: str, traffic: str, seconds: float) -> tuple[float, float, float]:
    """:func:`_worker` in a fresh process (``tree``: a baseline's source tree; None: this checkout)."""
    env = dict(os.environ, BENCH_GYM_TREE=str(tree) if tree is not None else "")
    out = subprocess.run([sys.executable, __file__, "--worker", "--set", str(root), "--net", net, "--traffic", traffic,
                          "--seconds", str(seconds)], env=env, capture_output=True, text=True, check=True).stdout
    d = json.loads(out.strip().splitlines()[-1])
    return float(d["rate"]), float(d["steps"]), float(d["cpu_steps"])


def _baseline_tree(ref: str) -> Path:
    """The package sources of git ``ref``, unpacked into a temporary folder."""
    repo = Path(__file__).resolve().parents[1]
    tree = Path(tempfile.mkdtemp(prefix="bench_gym_baseline_"))
    archive = subprocess.run(["git", "-C", str(repo), "archive", ref, "coster_sumo"], capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", str(tree)], input=archive.stdout, check=True)
    return tree


def _highway():  # type: ignore[no-untyped-def]
    """highway-env's ``highway-fast-v0`` and its simulated seconds per step (None where not installed)."""
    try:
        import gymnasium
        import highway_env  # noqa: F401
    except ImportError:
        print("highway-env not installed (pip install 'coster-sumo[bench]'): no comparison")
        return None, 0.0
    gymnasium.register_envs(highway_env)
    hw = gymnasium.make("highway-fast-v0")
    return hw, 1.0 / hw.unwrapped.config["policy_frequency"]  # type: ignore[attr-defined]


def measure(configs: list[tuple[Path, str, str]], rounds: int, slice_s: float, baseline: Path | None
            ) -> dict[str, dict[str, list[float]]]:
    """Per environment (and per baseline environment) and round: sim s / wall s, env steps / wall s,
    env steps / CPU s, and the ratio of the first to highway-fast-v0's in the same round."""
    hw, hw_per_step = _highway()
    out: dict[str, dict[str, list[float]]] = {}

    def add(key: str, **values: float) -> None:
        for name, v in values.items():
            out.setdefault(key, {}).setdefault(name, []).append(v)

    idle = 1  # highway-env's DiscreteMetaAction: IDLE
    for _ in range(rounds):  # rounds of short slices, every environment in each: robust to a changing load
        hw_rate = float("nan")
        if hw is not None:
            hw_rate, hw_steps, _, hw_cpu = run_for(hw, slice_s, idle, hw_per_step)
            add("highway-fast-v0", rate=hw_rate, steps=hw_steps, cpu_steps=hw_cpu, ratio=1.0)
        for root, net, traffic in configs:
            for tree, label in ((None, ""), (baseline, " (baseline)")):
                if label and tree is None:
                    continue
                rate, steps, cpu_steps = _slice(tree, root, net, traffic, slice_s)
                add(f"Scenario-v0 {net} traffic={traffic}{label}", rate=rate, steps=steps, cpu_steps=cpu_steps,
                    ratio=rate / hw_rate if hw_rate > 0 else float("nan"))
    if hw is not None:
        hw.close()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", required=True, type=Path, help="scenario set (shipped networks)")
    ap.add_argument("--womd-set", type=Path, help="scenario set of converted WOMD scenes")
    ap.add_argument("--seconds", type=float, default=20.0, help="wall seconds per speed measurement")
    ap.add_argument("--episodes", type=int, default=1000, help="episodes of the leak check (0: skip)")
    ap.add_argument("--rounds", type=int, default=5, help="slices per measurement, interleaved (default: %(default)s)")
    ap.add_argument("--traffic", default="log,sumo",
                    help="the environment's traffic modes to time, comma-separated (default: %(default)s)")
    ap.add_argument("--baseline-ref", help="also time the package of this git commit, in the same rounds")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--net", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        _worker(args.set, args.net, args.traffic, args.seconds)
        return

    from coster_sumo.gym.scenario_set import ScenarioSet

    configs = [(root, net, traffic) for root in [args.set] + ([args.womd_set] if args.womd_set else [])
               for net in sorted({e.network for e in ScenarioSet.load(root).entries})
               for traffic in args.traffic.split(",")]
    baseline = _baseline_tree(args.baseline_ref) if args.baseline_ref else None
    results = measure(configs, args.rounds, args.seconds / args.rounds, baseline)
    print(f"load average (1 min) at the end: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"{'environment':62s} {'sim s / wall s':>14s} {'steps / wall s':>14s} {'steps / CPU s':>13s} "
          f"{'/ highway-fast-v0':>18s}   (medians of the rounds)")
    med = {key: {name: float(np.median(v)) for name, v in d.items()} for key, d in results.items()}
    for key, m in med.items():
        print(f"{key:62s} {m['rate']:14.1f} {m['steps']:14.0f} {m['cpu_steps']:13.0f} {m['ratio']:18.2f}")
    for key, m in med.items():
        base = med.get(f"{key} (baseline)")
        if base is not None:
            print(f"speed-up over {args.baseline_ref}, {key}: steps / CPU s x{m['cpu_steps'] / base['cpu_steps']:.2f}")
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
