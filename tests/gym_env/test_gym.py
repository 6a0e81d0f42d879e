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
from coster_sumo.gym.env import ScenarioEnv  # noqa: E402
from coster_sumo.gym.scenario_set import ScenarioSet  # noqa: E402
from coster_sumo.sim.driver import MAX_ACCEL, MAX_DECEL, OBS_SIZE, STEP_S  # noqa: E402
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


def keep_or_brake(env: ScenarioEnv, scenario: str) -> dict[str, tuple[str | None, float]]:
    """``scenario`` driven twice, at the target's logged speed (``nominal``) and braking fully from the
    start (``brake``): whom the target touched first and when."""
    outcomes = {}
    for name in ("nominal", "brake"):
        env.reset(options={"scenario": scenario})
        done, info = False, {}
        while not done:
            action = nominal_action(env) if name == "nominal" else np.array([-1.0, 0.0], np.float32)
            _, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        outcomes[name] = (info["collided_with"], info["time"])
    return outcomes


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
        # generation's label, proven in SUMO (docs/method.md), travels with the scenario
        assert isinstance(info["avoidable"], bool) and info["avoidable"] == entry.avoidable
        assert entry.extra["contact"] and ("last_moment_s" in entry.extra)
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


def _episode(scenarios: Path, scenario: str, traffic: str, actions: np.ndarray,
             env: ScenarioEnv | None = None) -> list[tuple]:
    """One episode of ``scenario`` driven by ``actions``: (obs, reward, terminated, truncated, outcome,
    collided_with) per step; in a new environment, or in ``env`` (left open)."""
    own = env is None
    if env is None:
        env = ScenarioEnv(scenarios, scenario_ids=[scenario], traffic=traffic)
    obs, info = env.reset(seed=0, options={"scenario": scenario})
    rows = [(obs, 0.0, False, False, info["outcome"], info["collided_with"])]
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        rows.append((obs, reward, terminated, truncated, info["outcome"], info["collided_with"]))
        if terminated or truncated:
            break
    if own:
        env.close()
    return rows


def _same_episodes_with_the_log_as_with_sumo(scenarios: Path) -> list[str]:
    """Every scenario of the set driven by the same random actions with the other vehicles read from
    the log and with them in SUMO: the same observations, rewards and outcomes, step for step. The
    log's episodes run one after the other in one environment (which keeps a network loaded where it
    can), SUMO's each in a new one."""
    ids = [e.id for e in ScenarioSet.load(scenarios).entries]
    ids = ids + ids[:1]  # the first again, after the others
    rng = np.random.default_rng(0)
    actions = [rng.uniform(-0.4, 0.4, (300, 2)).astype(np.float32) for _ in ids]
    one = ScenarioEnv(scenarios, traffic="log")  # libsumo: one simulation per process, so one after the other
    logs = [_episode(scenarios, sid, "log", a, one) for sid, a in zip(ids, actions, strict=True)]
    one.close()
    outcomes = []
    for sid, acts, log in zip(ids, actions, logs, strict=True):
        sumo = _episode(scenarios, sid, "sumo", acts)
        assert len(log) == len(sumo), sid
        for k, (a, b) in enumerate(zip(log, sumo, strict=True)):
            # SUMO reports the pose moveToXY gave it; the observation is float32 of values scaled to
            # [-1, 1]: equal to float32 rounding (measured: equal bit for bit)
            np.testing.assert_allclose(a[0], b[0], rtol=0, atol=1e-6, err_msg=f"{sid} step {k}")
            assert a[2:] == b[2:] and a[1] == pytest.approx(b[1], abs=1e-9), (sid, k, a[1:], b[1:])
        outcomes.append(log[-1][4])
    return outcomes


def test_the_other_vehicles_read_from_the_log_give_the_same_episodes_as_in_sumo(nominal_set, variant_set):
    outcomes = _same_episodes_with_the_log_as_with_sumo(nominal_set) + _same_episodes_with_the_log_as_with_sumo(
        variant_set)
    assert "collision" in outcomes  # the variants' adversaries are among the vehicles read from the log


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
    _same_episodes_with_the_log_as_with_sumo(out)  # some 75 logged agents around the target


@pytest.mark.slow
@pytest.mark.parametrize("observation", ["default", "avoidance", "lidar"])
def test_a_trained_policy_is_a_planner_for_run(nominal_set, tmp_path, observation):
    """The planner reads the observation the policy was trained on (its size tells which)."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import Logger

    from coster_sumo.cli.command_line import main

    env = ScenarioEnv(nominal_set, split="train", observation=observation)
    model = PPO("MlpPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.set_logger(Logger(folder=None, output_formats=[]))  # SB3's default leaves a folder in /tmp
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
    assert {e.extra.get("adversity") for e in s.select(kind="variant")} == {
        "leader-braking", "cut-in", "red-light-runner", "pedestrian-behind-vehicle"}
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


def test_sumos_driver_brakes_for_the_braking_leader_that_a_constant_speed_target_hits(tmp_path):
    """The reference row "SUMO's driver" (policy "sumo"): SUMO drives the target after its first step
    and sees the braking leader, in both traffic modes; in the log the replayed follower then drives
    into it, in reactive traffic nobody does. Actions are ignored."""
    from coster_sumo.gym.sumo_driver import SumoDriverEnv

    out = tmp_path / "hard"
    build_set(BuildOptions(sources=CONFIGS[2:], out=out, method="hard"))
    (entry,) = [e for e in ScenarioSet.load(out).entries if e.extra.get("adversity") == "leader-braking"]
    seen = {}
    for traffic in ("log", "reactive"):
        env = SumoDriverEnv(out, traffic=traffic)
        env.reset(options={"scenario": entry.id})
        assert env.sumo_drives and env.kept_on_path == 0
        done, info, speeds = False, {}, []
        first = env.v
        while not done:
            _, _, terminated, truncated, info = env.step(np.array([1.0, 1.0], np.float32))  # ignored
            speeds.append(env.v)
            done = terminated or truncated
        env.close()
        seen[traffic] = (info["collided_with"], info["outcome"], min(speeds))
    assert seen["log"][0] not in (None, "adversity")  # a replayed follower, which does not react
    assert seen["reactive"][:2] == (None, "completed")
    assert all(low < 0.25 * first for _, _, low in seen.values())  # it slowed behind the leader (16.7 -> 2.0 m/s)
    from coster_sumo.gym.train import evaluate

    result, rows = evaluate("sumo", out, split=None, traffic="reactive")
    assert result.kept_on_path == 0 and len(rows) == result.episodes > 1  # SUMO drove every episode


def test_hard_set_red_light_runner_crosses_on_red_into_a_target_that_keeps_its_nominal_speed(tmp_path):
    from coster_sumo.core.scene import SignalState

    out = tmp_path / "hard"
    build_set(BuildOptions(sources=CONFIGS[2:], out=out, method="hard"))
    s = ScenarioSet.load(out)
    (entry,) = [e for e in s.entries if e.extra.get("adversity") == "red-light-runner"]
    scene = s.scene(entry)
    tr, sig = scene.tracks, scene.signals
    runner = tr.index_of("adversity")
    t_conflict = entry.extra["t_conflict"]
    k = int(np.argmin(np.abs(scene.timestamps - t_conflict)))
    # the lane it runs shows stop then, and the runner is on that lane's centreline
    column = entry.extra["signal"]
    assert int(sig.state[k, column]) in (SignalState.STOP, SignalState.ARROW_STOP)
    line = np.asarray(scene.road_map.lanes.centerline[int(sig.lane_index[column])])
    import shapely

    assert shapely.LineString(line).distance(shapely.Point(tr.x[runner, k], tr.y[runner, k])) < 0.5
    env = ScenarioEnv(out)
    outcomes = keep_or_brake(env, entry.id)
    env.close()
    assert outcomes["nominal"][0] == "adversity" and abs(outcomes["nominal"][1] - t_conflict) < 1.0, outcomes
    assert outcomes["brake"][0] != "adversity", outcomes



@pytest.mark.slow
def test_policy_training_resumes_and_leaves_nothing_in_the_temporary_directory(nominal_set, tmp_path, monkeypatch):
    import tempfile

    from coster_sumo.gym.train import TrainOptions, train

    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    out = tmp_path / "policy"
    first = train(TrainOptions(scenarios=nominal_set, out=out, timesteps=512, checkpoint_steps=512, quiet=True))
    assert first.steps >= 512 and (out / "policy.zip").exists() and (out / "checkpoint.zip").exists()
    again = train(TrainOptions(scenarios=nominal_set, out=out, timesteps=1024, checkpoint_steps=512, quiet=True))
    assert again.steps >= 1024 and again.wall_s > first.wall_s  # went on from the checkpoint
    assert not [p.name for p in scratch.iterdir() if p.name.startswith("SB3-")]  # SB3's default logger folders
