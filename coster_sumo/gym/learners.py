"""The learners ``coster-sumo policy train`` offers (stable-baselines3), built, saved and loaded alike.

- ``ppo`` (default): PPO, 512 steps per update and environment, batch 128, 5 epochs, learning rate
  3e-4, gamma 0.99, initial action standard deviation 0.37 (log -1).
- ``td3``: TD3 with Adv-BMT's settings as issue 61 states them: learning rate 1e-4, a large batch
  (:data:`TD3_BATCH`), one gradient step per environment step (``train_freq`` 1); Gaussian action
  noise of standard deviation :data:`TD3_NOISE`; a replay buffer of :data:`TD3_BUFFER` transitions.

Both use the same MLP (:data:`POLICY_LAYERS`) for every arm. An off-policy learner's state is its
model and its replay buffer: a TD3 checkpoint is ``checkpoint.zip`` and ``replay_buffer.pkl`` beside
it (both replaced atomically); a resume without the buffer file starts an empty buffer (the model
goes on, the buffer refills). A saved policy names its learner in its zip, so :func:`load_model`
loads either.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.sim.policy import load_model

LEARNERS = ("ppo", "td3")
POLICY_LAYERS = (64, 64)  # hidden units of the policy and value MLPs (the same for every arm)
# log of the initial standard deviation of PPO's Gaussian actions: SB3's default (0, std 1 on actions
# in [-1, 1]) swerves a full lane and brakes at 8 m/s^2 at random, so early episodes end off the road
# before anything is learnt; std 0.37 explores around the action (0, 0), which drives the route at
# constant speed
INITIAL_LOG_STD = -1.0
TD3_LEARNING_RATE = 1e-4
TD3_BATCH = 1024
TD3_BUFFER = 200_000  # transitions (a 90-number observation: about 150 MB when saved)
TD3_NOISE = 0.1  # standard deviation of the exploration noise on each action in [-1, 1]
TD3_LEARNING_STARTS = 1_000  # [steps] of random actions before the first update
REPLAY_BUFFER_FILE = "replay_buffer.pkl"


def new_model(learner: str, venv: Any, seed: int) -> Any:
    """A fresh ``learner`` (one of :data:`LEARNERS`) on ``venv``."""
    if learner == "ppo":
        from stable_baselines3 import PPO

        return PPO("MlpPolicy", venv, seed=seed, device="cpu", n_steps=512, batch_size=128, n_epochs=5,
                   learning_rate=3e-4, gamma=0.99, verbose=0,
                   policy_kwargs={"net_arch": list(POLICY_LAYERS), "log_std_init": INITIAL_LOG_STD})
    if learner == "td3":
        from stable_baselines3 import TD3
        from stable_baselines3.common.noise import NormalActionNoise

        dims = int(np.prod(venv.action_space.shape))
        noise = NormalActionNoise(mean=np.zeros(dims), sigma=TD3_NOISE * np.ones(dims))
        return TD3("MlpPolicy", venv, seed=seed, device="cpu", learning_rate=TD3_LEARNING_RATE, batch_size=TD3_BATCH,
                   buffer_size=TD3_BUFFER, learning_starts=TD3_LEARNING_STARTS, train_freq=1, gradient_steps=1,
                   gamma=0.99, action_noise=noise, verbose=0, policy_kwargs={"net_arch": list(POLICY_LAYERS)})
    raise ValueError(f"learner must be one of {LEARNERS}, not {learner!r}")


def save_state(model: Any, ckpt: Path) -> None:
    """``model`` as ``ckpt`` and, for an off-policy learner, its replay buffer beside it (atomically)."""
    tmp = ckpt.with_name(".checkpoint.tmp.zip")
    model.save(tmp)
    os.replace(tmp, ckpt)
    if hasattr(model, "replay_buffer") and model.replay_buffer is not None:
        tmp_buffer = ckpt.with_name(f".{REPLAY_BUFFER_FILE}.tmp")
        model.save_replay_buffer(tmp_buffer)
        os.replace(tmp_buffer, ckpt.with_name(REPLAY_BUFFER_FILE))


def load_state(ckpt: Path, env: Any) -> Any:
    """The model of ``ckpt`` on ``env``, with its replay buffer where one was saved beside it."""
    model = load_model(ckpt, env=env)
    buffer = ckpt.with_name(REPLAY_BUFFER_FILE)
    if hasattr(model, "load_replay_buffer") and buffer.exists():
        model.load_replay_buffer(buffer)
    return model
