"""Traffic that reacts (coster_sumo.sim.reactive): who reacts, and episodes in traffic="reactive"."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from coster_sumo.core.scene import ObjectType, Scene, Tracks
from coster_sumo.data.synthetic import two_lane_road
from coster_sumo.sim.reactive import DEVIATION_M, Pose, car_following_types, deviates, reacting_agents

NETWORKS = ("intersection", "arterial")
BRAKE_MPS2 = 4.0  # [m/s^2] the target's constant braking


def _lane_scene() -> Scene:
    """Four cars on one straight lane along +x at 10 m/s, 1 s apart: target ``t`` at x = 0 at
    t = 0, ``behind`` 15 m behind it, ``ahead`` 30 m ahead, and ``oncoming`` on the next lane the
    other way; ``crossing`` crosses the lane at x = 30 at t = 3 s (from y = -30, at 10 m/s)."""
    steps = 60
    t = np.arange(steps) * 0.1
    x = np.stack([10 * t, 10 * t - 15, 10 * t + 30, 100 - 10 * t, np.full(steps, 30.0)])
    y = np.stack([np.zeros(steps), np.zeros(steps), np.zeros(steps), np.full(steps, 3.5), 10 * t - 30])
    heading = np.array([0.0, 0.0, 0.0, np.pi, np.pi / 2])[:, None].repeat(steps, 1)
    n = len(x)
    tracks = Tracks(ids=np.array(["t", "behind", "ahead", "oncoming", "crossing"]),
                    object_type=np.full(n, int(ObjectType.VEHICLE), np.int8), x=x, y=y, heading=heading,
                    vx=10 * np.cos(heading), vy=10 * np.sin(heading), length=np.full((n, steps), 4.5),
                    width=np.full((n, steps), 1.9), valid=np.ones((n, steps), bool))
    return dataclasses.replace(two_lane_road(), timestamps=t, tracks=tracks)


def test_a_target_on_its_log_does_not_deviate_and_a_braking_one_does():
    scene = _lane_scene()
    on_log = Pose(10.0, 0.0, 0.0, 10.0, 4.5, 1.9)
    assert not deviates(on_log, scene, 0, 10)
    assert deviates(Pose(10.0 - 2 * DEVIATION_M, 0.0, 0.0, 10.0, 4.5, 1.9), scene, 0, 10)
    assert deviates(Pose(10.0, 0.0, 0.0, 8.0, 4.5, 1.9), scene, 0, 10)  # 2 m/s slower


def test_the_follower_and_the_leader_react_to_a_braking_target_the_oncoming_car_does_not():
    scene = _lane_scene()
    route = np.stack([np.linspace(-20, 80, 201), np.zeros(201)], -1)
    braking = Pose(10.0, 0.0, 0.0, 6.0, 4.5, 1.9)  # at its logged place, 4 m/s slower
    cand = np.array([1, 2, 3])
    hit = reacting_agents(scene, 10, [braking], cand, route, braking)
    assert hit.tolist() == [True, True, False]
    # without the corridor (no route), the follower is still reached: its log drives into the
    # braking target within the horizon; the leader, driving away, is not
    hit = reacting_agents(scene, 10, [braking], cand)
    assert hit.tolist() == [True, False, False]
    assert not reacting_agents(scene, 10, [], cand, route, braking).any()  # nobody deviates


def test_a_crossing_agent_reacts_when_the_paths_would_meet():
    scene = _lane_scene()
    # the target stopped at x = 29: the crossing car's log passes x = 30 at t = 3 s, within the horizon
    stopped = Pose(29.0, 0.0, 0.0, 0.0, 4.5, 1.9)
    assert reacting_agents(scene, 10, [stopped], np.array([4])).tolist() == [True]
    # a target far from its path does not reach it
    away = Pose(-50.0, 0.0, 0.0, 0.0, 4.5, 1.9)
    assert reacting_agents(scene, 10, [away], np.array([4])).tolist() == [False]


def test_car_following_models():
    assert car_following_types("Krauss") == (None, "")
    path, suffix = car_following_types("IDM")
    assert suffix == "@idm" and path is not None and 'carFollowModel="IDM"' in path.read_text()
    with pytest.raises(ValueError, match="car_following"):
        car_following_types("Wiedemann")


# ----------------------------------------------------------------------------- in the environment

@pytest.fixture(scope="module")
def nominal_set(tmp_path_factory) -> Path:
    pytest.importorskip("gymnasium")
    from coster_sumo.gym.build import BuildOptions, build_set
    from tests.conftest import REPO

    out = tmp_path_factory.mktemp("set") / "nominal"
    build_set(BuildOptions(sources=[str(REPO / "networks" / n / f"{n}.sumocfg") for n in NETWORKS], out=out,
                           method="nominal", heldout=("arterial",)))
    return out


def _drive(scenarios: Path, scenario: str, traffic: str, policy: str, car_following: str = "Krauss"
           ) -> tuple[dict, list]:
    """One episode; ``policy`` ``nominal`` (the target's logged speed) or ``brake`` (BRAKE_MPS2 from the
    start). Returns the last info and the states of every step."""
    from coster_sumo.gym.env import ScenarioEnv
    from coster_sumo.sim.driver import MAX_DECEL
    from tests.gym_env.test_gym import nominal_action

    env = ScenarioEnv(scenarios, scenario_ids=[scenario], traffic=traffic, car_following=car_following)
    _, info = env.reset(seed=0)
    states = [env.states]
    done = False
    while not done:
        a = nominal_action(env) if policy == "nominal" else np.array([-BRAKE_MPS2 / MAX_DECEL, 0.0], np.float32)
        _, _, terminated, truncated, info = env.step(a)
        states.append(env.states)
        done = terminated or truncated
    env.close()
    return info, states


@pytest.mark.sumo
@pytest.mark.parametrize("network", NETWORKS)
def test_a_reactive_follower_does_not_hit_a_braking_target_where_the_logs_follower_does(nominal_set, network):
    from coster_sumo.gym.scenario_set import ScenarioSet

    entry = ScenarioSet.load(nominal_set).select(networks=(network,))[0]
    log, _ = _drive(nominal_set, entry.id, "log", "brake")
    assert log["outcome"] == "collision" and log["collided_with"] is not None, log
    for model in ("Krauss", "IDM"):
        reactive, _ = _drive(nominal_set, entry.id, "reactive", "brake", model)
        assert reactive["outcome"] != "collision", (model, reactive)
        assert reactive["reacting"] >= 1


@pytest.mark.sumo
@pytest.mark.parametrize("network", NETWORKS)
def test_a_target_on_its_nominal_motion_gives_the_logs_trajectories_in_reactive_traffic(nominal_set, network):
    from coster_sumo.gym.scenario_set import ScenarioSet

    entry = ScenarioSet.load(nominal_set).select(networks=(network,))[0]
    log_info, log = _drive(nominal_set, entry.id, "log", "nominal")
    info, reactive = _drive(nominal_set, entry.id, "reactive", "nominal")
    assert info["reacting"] == 0 and info["outcome"] == log_info["outcome"]
    assert len(log) == len(reactive)
    compared = 0
    for k, (a, b) in enumerate(zip(log, reactive, strict=True)):
        ids_a, ids_b = a.id_list(), b.id_list()
        assert sorted(ids_a) == sorted(ids_b), k
        j = [ids_b.index(v) for v in ids_a]
        off = np.hypot(a.x - b.x[j], a.y - b.y[j])
        assert off.max(initial=0.0) <= 0.05, (k, off.max())
        compared += len(off)
    assert compared > 100


@pytest.mark.sumo
@pytest.mark.parametrize("traffic", ["log", "reactive"])
def test_check_env_passes_in_both_traffic_modes(nominal_set, traffic):
    gymnasium = pytest.importorskip("gymnasium")
    from gymnasium.utils.env_checker import check_env

    import coster_sumo.gym  # noqa: F401  (registers the id)

    env = gymnasium.make("coster_sumo/Scenario-v0", scenarios=nominal_set, traffic=traffic)
    check_env(env.unwrapped)
    env.close()


@pytest.mark.sumo
@pytest.mark.realdata
def test_reactive_traffic_on_a_converted_womd_scene(tmp_path):
    """On a real WOMD scene (2a1e44d405a6833f): braking at 4 m/s^2 from the start, a logged agent runs
    into the target in the log and none does in reactive traffic; on its nominal motion the reactive
    episode is the log's."""
    from coster_sumo.converters.read import read_scenes
    from coster_sumo.converters.to_sumo import convert_scene

    from coster_sumo.gym.build import BuildOptions, build_set
    from coster_sumo.gym.scenario_set import ScenarioSet
    from tests.conftest import NO_WOMD_REASON, WOMD_PKL

    pytest.importorskip("gymnasium")
    pkl = [p for p in WOMD_PKL if "2a1e44d405a6833f" in p.name]
    if not pkl:
        pytest.skip(NO_WOMD_REASON)
    scene = next(iter(read_scenes(pkl[0])))
    folder = convert_scene(scene, tmp_path / "converted").folder
    out = tmp_path / "set"
    build_set(BuildOptions(sources=[str(folder)], out=out, method="nominal"))
    (entry,) = [e.id for e in ScenarioSet.load(out).entries]
    log, _ = _drive(out, entry, "log", "brake")
    reactive, _ = _drive(out, entry, "reactive", "brake")
    assert log["outcome"] == "collision", log
    assert reactive["outcome"] != "collision" and reactive["reacting"] >= 1, reactive
    log_info, log_states = _drive(out, entry, "log", "nominal")
    info, states = _drive(out, entry, "reactive", "nominal")
    assert info["reacting"] == 0 and len(states) == len(log_states)
    for a, b in zip(log_states, states, strict=True):
        ids_b = b.id_list()
        j = [ids_b.index(v) for v in a.id_list()]
        assert np.hypot(a.x - b.x[j], a.y - b.y[j]).max(initial=0.0) <= 0.05


@pytest.mark.slow
@pytest.mark.sumo
@pytest.mark.realdata
def test_run_with_reactive_traffic_on_a_converted_womd_scene(tmp_path):
    """`coster-sumo run --planner sumo` on a real WOMD scene (2a1e44d405a6833f): the target brakes for
    the adversary; in the log logged agents drive into it, with --traffic reactive none does."""
    import json
    import subprocess
    import sys

    from coster_sumo.converters.read import read_scenes
    from coster_sumo.converters.to_sumo import convert_scene

    from tests.conftest import NO_WOMD_REASON, WOMD_PKL

    pkl = [p for p in WOMD_PKL if "2a1e44d405a6833f" in p.name]
    if not pkl:
        pytest.skip(NO_WOMD_REASON)
    folder = convert_scene(next(iter(read_scenes(pkl[0]))), tmp_path / "converted").folder
    (cfg,) = folder.glob("*.sumocfg")
    others = {}
    for traffic in ("log", "reactive"):
        out = tmp_path / traffic
        subprocess.run([sys.executable, "-m", "coster_sumo", "run", str(cfg), "-o", str(out), "--planner", "sumo",
                        "--traffic", traffic, "--samples", "200", "--variants", "2", "--no-render"], check=True,
                       capture_output=True)
        summary = json.loads((out / "summary.json").read_text())
        others[traffic] = [c for v in summary["variants"] for c in v["other_collisions_list"]
                           if c.startswith(f"{summary['target']} vs")]
    assert others["log"], others  # the logged followers ran into the braking target
    assert not others["reactive"], others


@pytest.mark.slow
@pytest.mark.sumo
@pytest.mark.realdata
def test_scenarios_build_proves_the_labels_in_reactive_traffic(tmp_path):
    """`scenarios build --traffic reactive` on a real WOMD scene: every variant gets a label whose
    escapes were replayed (one pass each, the logged agents reacting), and the manifest says so."""
    from coster_sumo.converters.read import read_scenes
    from coster_sumo.converters.to_sumo import convert_scene

    from coster_sumo.gym.build import BuildOptions, build_set
    from coster_sumo.gym.scenario_set import ScenarioSet
    from tests.conftest import NO_WOMD_REASON, WOMD_PKL

    pkl = [p for p in WOMD_PKL if "2a1e44d405a6833f" in p.name]
    if not pkl:
        pytest.skip(NO_WOMD_REASON)
    folder = convert_scene(next(iter(read_scenes(pkl[0]))), tmp_path / "converted").folder
    out = tmp_path / "set"
    build_set(BuildOptions(sources=[str(folder)], out=out, method="coster-one-per-snapshot", snapshots=1,
                           samples=200, traffic="reactive"))
    s = ScenarioSet.load(out)
    assert s.meta["options"]["traffic"] == "reactive"
    variants = s.select(kind="variant")
    assert variants and all(isinstance(e.avoidable, bool) for e in variants)


def test_an_agent_that_left_the_network_is_not_asked_for_its_state():
    """A held-out corpus clip in reactive traffic: an agent handed to SUMO had arrived, and reading it
    raised ``TraCIException: Vehicle '27' is not known``; it is skipped, the others still react."""
    from types import SimpleNamespace

    from coster_sumo.sim.reactive import _react
    from coster_sumo.sim.states import VehicleStates

    scene = _lane_scene()
    k = 10
    braking = (10.0, 0.0, 0.0, 6.0)  # the target at its logged place, 4 m/s slower: it deviates
    behind = (float(scene.tracks.x[1, k]), 0.0, 0.0, 10.0)
    in_sumo = {"t": braking, "behind": behind}  # "ahead" has left the network

    def vehicle_states(ids):
        ids = list(ids)
        unknown = [v for v in ids if v not in in_sumo]
        assert not unknown, f"Vehicle {unknown[0]!r} is not known"
        rows = [in_sumo[v] for v in ids]
        col = [np.array([r[j] for r in rows], float) for j in range(4)]
        n = len(ids)
        return VehicleStates(ids=np.array(ids), x=col[0], y=col[1], yaw=col[2], speed=col[3],
                             length=np.full(n, 4.5), width=np.full(n, 1.9), vclass=np.full(n, "passenger"),
                             type_id=np.full(n, "car"))

    session = SimpleNamespace(time=float(scene.timestamps[k]), hidden=set(), vehicle_ids=lambda: tuple(in_sumo),
                              vehicle_states=vehicle_states)
    replayer = SimpleNamespace(scene=scene, step_at=lambda t: k, active={0: "t", 1: "behind", 2: "ahead"},
                               released={0}, handover={}, lengths=np.full(5, 4.5), widths=np.full(5, 1.9),
                               dt=scene.dt)
    _react(replayer, session, "t")
    assert set(replayer.handover) == {1}  # the follower reacts; the agent that left is left alone


def _poses(times, x, y, yaw, speed) -> SimpleNamespace:
    return SimpleNamespace(times=times, x=x, y=y, yaw=yaw, speed=speed)


def _reached_one_by_one(scene: Scene, target: int, times, x, y, yaw, speed, margin_m: float) -> bool:
    """reaches_no_one by its definition: reacting_agents pose by pose, at the log steps next to each."""
    tr = scene.tracks
    others = np.flatnonzero((np.arange(tr.num_agents) != target) & (tr.object_type != int(ObjectType.PEDESTRIAN)))
    length = float(np.median(tr.length[target])) + 2 * margin_m
    width = float(np.median(tr.width[target])) + 2 * margin_m
    for i, t in enumerate(times):
        k0 = int(np.clip(np.searchsorted(scene.timestamps, t), 0, scene.num_steps - 1))
        for k in range(max(k0 - 1, 0), min(k0 + 2, scene.num_steps)):
            cand = others[tr.valid[others, k]]
            pose = Pose(float(x[i]), float(y[i]), float(yaw[i]), float(speed[i]), length, width)
            if reacting_agents(scene, k, [pose], cand, dt=round(scene.dt, 6)).any():
                return True
    return False


def test_reaches_no_one_is_reacting_agents_pose_by_pose():
    # escapes of the lane scene's target (braking or not, shifted and turned at random), many of
    # them at the edge of reaching an agent: the batched test must say what the pose-by-pose one says
    from coster_sumo.sim.quiet_escapes import reaches_no_one

    whole = _lane_scene()
    rng = np.random.default_rng(0)
    outcomes = []
    for case in range(150):
        scene = whole
        if case % 2:  # agents that come and go (the target stays)
            valid = rng.random(whole.tracks.valid.shape) < rng.choice([0.3, 0.7])
            valid[0] = True
            scene = dataclasses.replace(whole, tracks=dataclasses.replace(whole.tracks, valid=valid))
        times = np.arange(rng.uniform(0.5, 2.0), 5.0, 0.1) + rng.uniform(-0.003, 0.003)
        v = np.maximum(10.0 - rng.uniform(0, 8) * (times - times[0]), 0.0)
        x = 10.0 * times[0] + np.cumsum(v) * 0.1 + rng.uniform(-60, 60)
        y = np.full_like(times, rng.uniform(-12, 12))
        yaw = np.full_like(times, rng.uniform(-0.5, 0.5))
        for margin in (0.0, 1.0):
            expect = not _reached_one_by_one(scene, 0, times, x, y, yaw, v, margin)
            assert reaches_no_one(scene, 0, _poses(times, x, y, yaw, v), margin_m=margin) == expect
            outcomes.append(expect)
    assert 0.2 < np.mean(outcomes) < 0.8  # both outcomes, often


def test_a_braking_target_reaches_its_follower_and_a_far_one_no_one():
    from coster_sumo.sim.quiet_escapes import reaches_no_one

    scene = _lane_scene()
    times = np.arange(1.0, 4.0, 0.1)
    v = np.maximum(10.0 - 4.0 * (times - 1.0), 0.0)  # braking at 4 m/s^2 from its log's 10 m/s
    x = 10.0 + np.concatenate([[0.0], np.cumsum(v[:-1]) * 0.1])
    zeros = np.zeros_like(times)
    assert not reaches_no_one(scene, 0, _poses(times, x, zeros, zeros, v))  # "behind" closes in on it
    assert reaches_no_one(scene, 0, _poses(times, x, zeros - 200.0, zeros, v))  # 200 m aside: nobody's path
