"""Train a driving policy on a scenario set (stable-baselines3 PPO or TD3) and evaluate it (RCR, CR, ORR).

Training is resumable: every ``checkpoint_steps`` environment steps the model is saved as
``OUT/checkpoint.zip`` (atomically, with ``OUT/progress.json``: steps done, wall time, episode
outcomes so far; a TD3 learner's replay buffer beside it, :mod:`coster_sumo.gym.learners`); the
same command after an interruption loads it and trains on up to the budget. The finished policy is
``OUT/policy.zip``. Every arm of the downstream experiment uses the same network (an MLP of two
hidden layers of 64), the same learner settings and the same budget.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.gym.learners import LEARNERS
from coster_sumo.infra.atomic import write_json


@dataclass
class TrainOptions:
    """What ``coster-sumo policy train`` takes."""

    scenarios: Path
    out: Path
    timesteps: int = 20_000
    seed: int = 0
    envs: int = 1  # environments (processes when > 1)
    checkpoint_steps: int = 2_048
    control_period_s: float = 0.2
    quiet: bool = False
    traffic: str = "log"  # the environment's traffic: log (replayed) or reactive (coster_sumo.sim.reactive)
    car_following: str = "Krauss"  # the reacting agents' model (traffic="reactive")
    random_start: bool = False  # nominal episodes start at a seeded random time within the clip
    observation: str = "default"  # the environment's observation (coster_sumo.gym.observe)
    learner: str = "ppo"  # ppo or td3 (coster_sumo.gym.learners)
    torch_threads: int = 1  # torch threads of the learner while it trains


@dataclass(frozen=True)
class TrainProgress:
    """What a training run has done (``OUT/progress.json``, rewritten at every checkpoint).

    Attributes:
        options: the :class:`TrainOptions` of the latest call, as strings.
        steps: environment steps trained; wall_s: [s] wall time over every call.
        outcomes: episode outcome -> episodes that ended so.
        curve: (steps, mean episode return since the previous checkpoint) at each checkpoint.
    """

    options: dict[str, str]
    steps: int = 0
    wall_s: float = 0.0
    outcomes: dict[str, int] = field(default_factory=dict)
    curve: tuple[tuple[int, float], ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {"options": self.options, "steps": self.steps, "wall_s": self.wall_s, "outcomes": self.outcomes,
                "curve": [list(point) for point in self.curve]}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> TrainProgress:
        return cls(options=dict(d["options"]), steps=int(d["steps"]), wall_s=float(d["wall_s"]),
                   outcomes=dict(d.get("outcomes", {})), curve=tuple((int(s), float(r)) for s, r in d["curve"]))


def _option_strings(opts: TrainOptions) -> dict[str, str]:
    return {k: str(v) for k, v in asdict(opts).items()}


def _make_env(scenarios: str, split: str | None, seed: int, control_period_s: float,  # type: ignore[no-untyped-def]
              traffic: str = "log", car_following: str = "Krauss", random_start: bool = False,
              observation: str = "default"):
    def make():  # type: ignore[no-untyped-def]
        from stable_baselines3.common.monitor import Monitor

        from coster_sumo.gym.env import ScenarioEnv

        env = ScenarioEnv(scenarios, split=split, control_period_s=control_period_s, traffic=traffic,
                          car_following=car_following, random_start=random_start, observation=observation)
        env.reset(seed=seed)
        return Monitor(env, info_keywords=("outcome",))
    return make


def train(opts: TrainOptions) -> TrainProgress:
    """Train (or resume) ``opts.learner`` on the ``train`` split of ``opts.scenarios``; returns the progress record."""
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    from coster_sumo.gym.learners import load_state, new_model, save_state

    if opts.learner not in LEARNERS:
        raise ValueError(f"learner must be one of {LEARNERS}, not {opts.learner!r}")

    opts.out.mkdir(parents=True, exist_ok=True)
    makers = [_make_env(str(opts.scenarios), "train", opts.seed * 1000 + i, opts.control_period_s, opts.traffic,
                        opts.car_following, opts.random_start, opts.observation) for i in range(opts.envs)]
    venv = SubprocVecEnv(makers) if opts.envs > 1 else DummyVecEnv(makers)
    ckpt = opts.out / "checkpoint.zip"
    progress_path = opts.out / "progress.json"
    progress = TrainProgress(options=_option_strings(opts))
    if ckpt.exists() and progress_path.exists():
        progress = dataclasses.replace(TrainProgress.from_json(json.loads(progress_path.read_text())),
                                       options=_option_strings(opts))  # the budget may have grown
        model = load_state(ckpt, venv)
    else:
        model = new_model(opts.learner, venv, opts.seed)
    # a logger that writes nowhere: SB3's default makes an empty SB3-<date> folder in the temporary
    # directory on every learn() (progress.json holds what this training reports)
    from stable_baselines3.common.logger import Logger

    model.set_logger(Logger(folder=None, output_formats=[]))
    t_start = time.perf_counter()
    wall_before = progress.wall_s
    outcomes: dict[str, int] = dict(progress.outcomes)
    returns: list[float] = []

    def save() -> None:
        nonlocal progress
        save_state(model, ckpt)
        curve = progress.curve
        if returns:
            curve = (*curve, (int(model.num_timesteps), float(np.mean(returns))))
            returns.clear()
        progress = dataclasses.replace(progress, steps=int(model.num_timesteps), outcomes=dict(outcomes), curve=curve,
                                       wall_s=wall_before + time.perf_counter() - t_start)
        write_json(progress_path, progress.to_json())

    class Checkpoints(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.last = progress.steps

        def _on_step(self) -> bool:
            for info in self.locals.get("infos", []):
                ep = info.get("episode")
                if ep is not None:
                    returns.append(float(ep["r"]))
                    outcomes[info.get("outcome", "?")] = outcomes.get(info.get("outcome", "?"), 0) + 1
            if self.num_timesteps - self.last >= opts.checkpoint_steps:
                self.last = self.num_timesteps
                save()
                if not opts.quiet:
                    print(f"{opts.out}: {self.num_timesteps} steps, {progress.wall_s:.0f} s", flush=True)
            return True

    left = opts.timesteps - progress.steps
    if left > 0:
        _learn(model, left, Checkpoints(), opts.torch_threads)
        save()
    venv.close()
    final = opts.out / "policy.zip"
    if progress.steps >= opts.timesteps:
        tmp = opts.out / ".policy.tmp.zip"
        model.save(tmp)
        os.replace(tmp, final)
    return progress


def _learn(model: Any, steps: int, callback: Any, threads: int) -> None:
    """``model.learn`` for ``steps`` more steps with ``threads`` torch threads (restored after)."""
    import torch

    before = torch.get_num_threads()
    # the MLP is small: one thread computes it fastest (two on a busy 2-core machine wait on each
    # other: the same 2,048 PPO steps took 1.8x the time), and leaves the cores to the environments
    torch.set_num_threads(max(1, threads))
    try:
        model.learn(total_timesteps=steps, callback=callback, reset_num_timesteps=False, progress_bar=False)
    finally:
        torch.set_num_threads(before)


@dataclass(frozen=True)
class EpisodeRecord:
    """One evaluation episode: the scenario, its network and kind (nominal / variant), how it ended,
    the route completion (fraction), whether it hit the variant's adversary, and the variant's
    avoidability label (None: unlabelled)."""

    scenario: str
    network: str
    kind: str
    outcome: str
    route_completion: float
    collided_with_adversary: bool
    avoidable: bool | None

    @classmethod
    def from_info(cls, info: dict[str, Any]) -> EpisodeRecord:
        """From the environment's last ``info`` of the episode."""
        return cls(scenario=info["scenario"], network=info["network"], kind=info["kind"], outcome=info["outcome"],
                   route_completion=info["route_completion"], collided_with_adversary=info["collided_with_adversary"],
                   avoidable=info["avoidable"])

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class KindOutcomes:
    """RCR, CR and ORR (as :class:`EvalResult`) over the episodes of one scenario kind."""

    rcr: float
    cr: float
    orr: float
    episodes: int


@dataclass
class EvalResult:
    """Outcomes of a policy on the scenarios of a split (fractions over episodes).

    Attributes:
        episodes: scenarios driven (each once).
        rcr: mean route completion (fraction of the route driven without collision or off-road; an
            episode ended by either counts the part before it).
        cr: share of episodes that ended in a collision.
        orr: share that ended off the road.
        per_kind: the same three per scenario kind (nominal / variant).
        defect_rate: share of the variants labelled avoidable that ended in a collision with their
            adversary (None: no variant with a label); ``avoidable_variants`` how many there were.
        scores: :func:`coster_sumo.gym.scores.scores`: ``rcr`` as the paper defines it (share of episodes
            that complete the route with no collision and no off-road), ``mean_completion`` (= ``rcr``
            above), ``cr`` (anyone), ``cr_adversary``, ``orr``.
    """

    episodes: int
    rcr: float
    cr: float
    orr: float
    per_kind: dict[str, KindOutcomes]
    defect_rate: float | None = None
    avoidable_variants: int = 0
    scores: dict[str, float] = field(default_factory=dict)  # coster_sumo.gym.scores: the paper's RCR, CR by whom
    kept_on_path: int | None = None  # policy "sumo": episodes SUMO could not drive (no lane under the target)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def _summary(rows: list[EpisodeRecord]) -> tuple[float, float, float]:
    if not rows:
        return float("nan"), float("nan"), float("nan")
    return (float(np.mean([r.route_completion for r in rows])),
            float(np.mean([r.outcome == "collision" for r in rows])),
            float(np.mean([r.outcome == "off_road" for r in rows])))


HARD_TOP_FRACTION = 0.2  # the most critical nominal scenes of a hard set (by criticality score) that count


def hard_ids(scenarios: str | Path, split: str | None) -> list[str]:
    """Hard: every hand-specified adversity of the split, and its nominal scenes in the top 20 % by
    criticality (``coster-sumo scenarios build --method hard``)."""
    from coster_sumo.gym.scenario_set import ScenarioSet

    entries = ScenarioSet.load(scenarios).select(split)
    nominal = sorted((e for e in entries if e.kind == "nominal" and "criticality" in e.extra),
                     key=lambda e: -e.extra["criticality"]["score"])
    top = nominal[:max(1, int(round(HARD_TOP_FRACTION * len(nominal))))] if nominal else []
    return [e.id for e in entries if e.kind == "variant"] + [e.id for e in top]


def evaluate(policy: str | Path | None, scenarios: str | Path, split: str | None = "test",
             max_episodes: int | None = None, hard: bool = False,
             **env_options: Any) -> tuple[EvalResult, list[EpisodeRecord]]:
    """Drive every scenario of ``split`` once with ``policy`` (deterministic actions; None: action (0, 0);
    ``"sumo"``: SUMO's driver model, :mod:`coster_sumo.gym.sumo_driver`); ``hard``: only the
    scenarios of :func:`hard_ids`. ``env_options``: the environment's
    (:class:`~coster_sumo.gym.env.ScenarioEnv`: ``control_period_s``, ``traffic``, ``car_following``,
    ``observation``...), which checks them."""
    from coster_sumo.gym.env import ScenarioEnv
    from coster_sumo.gym.sumo_driver import SumoDriverEnv

    ids = hard_ids(scenarios, split) if hard else None
    env_cls = SumoDriverEnv if policy == "sumo" else ScenarioEnv
    env = env_cls(scenarios, split=split, order="cycle", scenario_ids=ids, **env_options)
    model = None
    if policy is not None and policy != "sumo":
        from coster_sumo.sim.policy import load_model

        model = load_model(policy)
    rows: list[EpisodeRecord] = []
    n = len(env.entries) if max_episodes is None else min(max_episodes, len(env.entries))
    for i in range(n):
        obs, info = env.reset(seed=0) if i == 0 else env.reset()
        done = False
        while not done:
            action = model.predict(obs, deterministic=True)[0] if model is not None else np.zeros(2, np.float32)
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        rows.append(EpisodeRecord.from_info(info))
    env.close()
    rcr, cr, orr = _summary(rows)
    per_kind = {}
    for kind in sorted({r.kind for r in rows}):
        of_kind = [r for r in rows if r.kind == kind]
        per_kind[kind] = KindOutcomes(*_summary(of_kind), episodes=len(of_kind))
    avoidable = [r for r in rows if r.kind == "variant" and r.avoidable is True]
    defects = float(np.mean([r.collided_with_adversary for r in avoidable])) if avoidable else None
    from coster_sumo.gym.scores import scores

    return EvalResult(len(rows), rcr, cr, orr, per_kind, defects, len(avoidable), scores(rows),
                      getattr(env, "kept_on_path", None)), rows
