"""Training driving policies on scenario sets (needs the ``rl`` extra: ``pip install coster-sumo[rl]``).

``import coster_sumo.gym`` registers ``coster_sumo/Scenario-v0``::

    import gymnasium, coster_sumo.gym
    env = gymnasium.make("coster_sumo/Scenario-v0", scenarios="SET", split="train")

The scenario set is built with ``coster-sumo scenarios build`` (:mod:`coster_sumo.gym.build`); the
environment is :class:`coster_sumo.gym.env.ScenarioEnv`. One SUMO simulation per process (libsumo):
vectorise with ``gymnasium.vector.AsyncVectorEnv`` or stable-baselines3's ``SubprocVecEnv``.
"""

from __future__ import annotations

ENV_ID = "coster_sumo/Scenario-v0"

try:
    import gymnasium
except ModuleNotFoundError:  # building scenario sets (gym.build) needs none; the environment does (extra rl)
    pass
else:
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point="coster_sumo.gym.env:ScenarioEnv", disable_env_checker=False)
