"""The Gymnasium environment coster_sumo/Scenario-v0 and the scenario sets it reads."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

import coster_sumo.gym  # noqa: E402,F401  (registers the id)
from coster_sumo.gym.build import BuildOptions, build_set  # noqa: E402
from coster_sumo.gym.env import MAX_ACCEL, MAX_DECEL, OBS_SIZE, STEP_S, ScenarioEnv  # noqa: E402
from coster_sumo.gym.scenario_set import ScenarioSet  # noqa: E402
from tests.conftest import NO_WOMD_REASON, REPO, WOMD_PKL, WOMD_PROTO  # noqa: E402

pytestmark = pytest.mark.sumo

NETWORKS = ("intersection", "merge", "arterial")
CONFIGS = [str(REPO / "networks" / n / f"{n}.sumocfg") for n in NETWORKS]


@pytest.fixture(scope="module")
def nominal_set(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("set") / "nominal"
    build_set(BuildOptions(sources=CONFIGS, out=out, method="nominal", heldout=("arterial",)))
    return out


@pytest.fixture(scope="module")
def variant_set(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("set") / "coster"
    build_set(BuildOptions(sources=CONFIGS[:1], out=out, method="coster", snapshots=1, variants=3, samples=200))
    return out


def nominal_action(env: ScenarioEnv) -> np.ndarray:
    """The action that keeps the target at its recorded speed on its recorded path."""
    scene, entry = env.scene, env.entry
    assert entry is not None
    tr = scene.tracks
    i = tr.index_of(entry.target)
    t_next = env._session.time + env.substeps * STEP_S
    k = int(np.argmin(np.abs(scene.timestamps - t_next)))
    v_next = float(np.hypot(tr.vx[i, k], tr.vy[i, k])) if tr.valid[i, k] else env.v
    a = (v_next - env.v) / (env.substeps * STEP_S)
    return np.array([a / MAX_ACCEL if a >= 0 else a / MAX_DECEL, 0.0], np.float32)


def test_check_env_passes(nominal_set):
    from gymnasium.utils.env_checker import check_env

    env = gymnasium.make("coster_sumo/Scenario-v0", scenarios=nominal_set)
    check_env(env.unwrapped)
    env.close()


def test_splits_are_by_network(nominal_set):
    s = ScenarioSet.load(nominal_set)
    assert {e.network for e in s.select("test")} == {"arterial"}
    assert {e.network for e in s.select("train")} == {"intersection", "merge"}
    manifest = json.loads((nominal_set / "manifest.json").read_text())
    assert manifest["splits"] == {"train": ["intersection", "merge"], "test": ["arterial"]}


@pytest.mark.parametrize("network", NETWORKS)
def test_short_episode_on_every_shipped_network(nominal_set, network):
    env = ScenarioEnv(nominal_set, networks=(network,))
    obs, info = env.reset(seed=0)
    assert obs.shape == (OBS_SIZE,) and env.observation_space.contains(obs)
    assert info["network"] == network and info["outcome"] == "running"
    t0 = info["time"]
    for _ in range(10):
        obs, reward, terminated, truncated, info = env.step(np.zeros(2, np.float32))
        assert env.observation_space.contains(obs) and math.isfinite(reward)
        assert not terminated and not truncated, info
    assert info["time"] == pytest.approx(t0 + 10 * 0.2)
    assert reward > 0  # the target moves along its route
    env.close()


def test_following_the_nominal_speed_completes_the_nominal_scene(nominal_set):
    env = ScenarioEnv(nominal_set, networks=("intersection",))
    env.reset(seed=0)
    info: dict = {}
    terminated = truncated = False
    while not (terminated or truncated):
        _, _, terminated, truncated, info = env.step(nominal_action(env))
    assert info["outcome"] == "completed" and info["route_completion"] == 1.0
    env.close()


def test_steering_off_the_ramp_is_off_road(nominal_set):
    env = ScenarioEnv(nominal_set, networks=("merge",))
    env.reset(seed=0)
    info: dict = {}
    for _ in range(60):
        _, reward, terminated, truncated, info = env.step(np.array([0.0, -1.0], np.float32))
        if terminated or truncated:
            break
    assert info["outcome"] == "off_road" and info["off_road"] and reward < 0
    env.close()


def test_a_rebuild_resumes_without_duplicates(nominal_set):
    before = (nominal_set / "manifest.json").read_text()
    build_set(BuildOptions(sources=CONFIGS, out=nominal_set, method="nominal", heldout=("arterial",)))
    assert json.loads((nominal_set / "manifest.json").read_text())["scenarios"] == json.loads(before)["scenarios"]


@pytest.mark.slow
def test_variant_replays_its_contact_at_t_col(variant_set):
    """A target that keeps its nominal speed meets the adversary at the planned collision time."""
    s = ScenarioSet.load(variant_set)
    variants = s.select(kind="variant")
    assert variants and s.select(kind="nominal")
    env = ScenarioEnv(variant_set, kind="variant", order="cycle")
    for i, entry in enumerate(variants):
        _, info = env.reset(seed=i)
        assert info["scenario"] == entry.id
        assert entry.t_col is not None and entry.t_start < entry.t_col
        terminated = truncated = False
        while not (terminated or truncated):
            _, _, terminated, truncated, info = env.step(nominal_action(env))
        assert info["outcome"] == "collision" and info["collided_with_adversary"], info
        assert info["time"] == pytest.approx(entry.t_col, abs=0.25)
    env.close()


@pytest.mark.slow
def test_vectorised_with_async_vector_env(nominal_set):
    envs = gymnasium.vector.AsyncVectorEnv(
        [lambda: gymnasium.make("coster_sumo/Scenario-v0", scenarios=str(nominal_set)) for _ in range(2)])
    obs, _ = envs.reset(seed=3)
    assert obs.shape == (2, OBS_SIZE)
    for _ in range(5):
        obs, reward, _, _, _ = envs.step(np.zeros((2, 2), np.float32))
    assert np.isfinite(reward).all()
    envs.close()


@pytest.mark.realdata
@pytest.mark.skipif(not (WOMD_PROTO or WOMD_PKL), reason=NO_WOMD_REASON)
def test_short_episode_on_a_converted_womd_scene(tmp_path):
    from coster_sumo.converters.read import read_scenes
    from coster_sumo.converters.to_sumo import convert_scene

    scene = next(iter(read_scenes((WOMD_PROTO or WOMD_PKL)[0])))
    folder = convert_scene(scene, tmp_path / "converted").folder
    out = tmp_path / "set"
    build_set(BuildOptions(sources=[str(folder)], out=out, method="nominal"))
    env = ScenarioEnv(out)
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs) and info["kind"] == "nominal"
    assert obs[18] == 1.0  # logged agents around the SDC are observed
    for _ in range(10):
        obs, reward, terminated, truncated, info = env.step(nominal_action(env))
        assert env.observation_space.contains(obs) and math.isfinite(reward)
        if terminated or truncated:
            break
    assert info["outcome"] in ("running", "completed"), info
    env.close()


@pytest.mark.slow
def test_a_trained_policy_is_a_planner_for_run(nominal_set, tmp_path):
    from stable_baselines3 import PPO

    from coster_sumo.cli import main

    env = ScenarioEnv(nominal_set, split="train")
    model = PPO("MlpPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(64)
    path = tmp_path / "policy.zip"
    model.save(path)
    env.close()  # libsumo: one simulation per process
    out = tmp_path / "run"
    assert main(["run", CONFIGS[0], "--planner", f"policy:{path}", "-o", str(out), "--variants", "1",
                 "--samples", "50", "--from-begin", "-q"]) == 0  # no fork after torch ran here
    summary = json.loads((out / "summary.json").read_text())
    assert summary["planner"] == f"policy:{path}" and summary["num_variants"] == 1


def test_policy_planner_names_a_missing_file():
    from coster_sumo.errors import InputError
    from coster_sumo.sim.planners import check_planner

    with pytest.raises(InputError, match="no such policy file"):
        check_planner("policy:/nonexistent/policy.zip")


def test_hard_set_leader_braking_hits_a_target_that_keeps_its_speed(tmp_path):
    out = tmp_path / "hard"
    build_set(BuildOptions(sources=CONFIGS[2:], out=out, method="hard"))
    s = ScenarioSet.load(out)
    assert {e.extra.get("adversity") for e in s.select(kind="variant")} == {"leader-braking", "cut-in"}
    assert "score" in s.select(kind="nominal")[0].extra["criticality"]
    (entry,) = [e for e in s.entries if e.extra.get("adversity") == "leader-braking"]
    env = ScenarioEnv(out)
    outcomes = {}
    for name, action in (("keep", [0.0, 0.0]), ("brake", [-1.0, 0.0])):
        env.reset(options={"scenario": entry.id})
        done, info = False, {}
        while not done:
            _, _, terminated, truncated, info = env.step(np.array(action, np.float32))
            done = terminated or truncated
        outcomes[name] = info["collided_with"]
    env.close()
    assert outcomes["keep"] == "adversity"
    assert outcomes["brake"] != "adversity"  # (a replayed follower may still run into it: replay does not react)
