"""policy train with TD3: resumable from its checkpoint and replay buffer; policies load as their learner."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("stable_baselines3")

from coster_sumo.gym.build import BuildOptions, build_set  # noqa: E402
from tests.conftest import REPO  # noqa: E402

pytestmark = pytest.mark.sumo


@pytest.fixture(scope="module")
def merge_set(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("set") / "nominal"
    build_set(BuildOptions(sources=[str(REPO / "networks" / "merge" / "merge.sumocfg")], out=out, method="nominal"))
    return out


@pytest.mark.slow
def test_td3_training_resumes_with_its_replay_buffer(merge_set, tmp_path, monkeypatch):
    from coster_sumo.gym import learners
    from coster_sumo.gym.train import TrainOptions, evaluate, train
    from coster_sumo.sim import policy

    monkeypatch.setattr(learners, "TD3_BUFFER", 2_000)  # a small buffer file
    monkeypatch.setattr(learners, "TD3_LEARNING_STARTS", 200)  # gradient steps within the budget
    monkeypatch.setattr(learners, "TD3_BATCH", 32)  # a few fast ones
    out = tmp_path / "td3"
    opts = dict(scenarios=merge_set, out=out, checkpoint_steps=128, quiet=True, learner="td3")
    first = train(TrainOptions(timesteps=256, **opts))
    assert first.steps >= 256 and (out / "policy.zip").exists() and (out / learners.REPLAY_BUFFER_FILE).exists()
    assert policy.learner_of(out / "policy.zip") == "td3"
    model = learners.load_state(out / "checkpoint.zip", env=None)
    held = model.replay_buffer.size()
    assert held >= 256 - 1
    again = train(TrainOptions(timesteps=512, **opts))
    assert again.steps >= 512 and again.wall_s > first.wall_s
    model = learners.load_state(out / "checkpoint.zip", env=None)
    assert model.replay_buffer.size() >= held + 256 - 1  # the buffer went on from the saved one, not from empty
    result, rows = evaluate(out / "policy.zip", merge_set, split=None, max_episodes=1)
    assert len(rows) == 1 and result.episodes == 1


@pytest.mark.slow
def test_a_ppo_policy_loads_as_ppo(merge_set, tmp_path):
    from coster_sumo.gym.train import TrainOptions, train
    from coster_sumo.sim import policy

    out = tmp_path / "ppo"
    train(TrainOptions(scenarios=merge_set, out=out, timesteps=64, checkpoint_steps=64, quiet=True))
    assert policy.learner_of(out / "policy.zip") == "ppo"
    assert type(policy.load_model(out / "policy.zip")).__name__ == "PPO"
    with pytest.raises(ValueError, match="learner"):
        train(TrainOptions(scenarios=merge_set, out=tmp_path / "x", timesteps=64, quiet=True, learner="sac"))
