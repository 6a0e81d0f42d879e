"""Observations for avoidance (coster_sumo.gym.observe) on hand-made scenes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from coster_sumo.gym.observe import CORRIDOR_FEATURES, NUM_RAYS, corridor_features, lidar
from coster_sumo.sim.driver import Driver, Route
from coster_sumo.sim.states import VehicleStates


def _driver(others: list[tuple[str, float, float, float, float]]) -> Driver:
    """The target ``ego`` at x = 0 on a straight route along +x at 10 m/s; ``others``: (id, x, y, yaw,
    speed), every vehicle 4.5 x 1.9 m."""
    d = Driver()
    d.route = Route(np.stack([np.linspace(-100, 200, 601), np.zeros(601)], -1), 0.0)
    d.s = 100.0  # x = 0
    d.v = 10.0
    d.length, d.width = 4.5, 1.9
    d.target_id = "ego"
    rows = [("ego", 0.0, 0.0, 0.0, 10.0), *others]
    n = len(rows)
    d.states = VehicleStates(ids=np.array([r[0] for r in rows]), x=np.array([r[1] for r in rows]),
                             y=np.array([r[2] for r in rows]), yaw=np.array([r[3] for r in rows]),
                             speed=np.array([r[4] for r in rows]), length=np.full(n, 4.5), width=np.full(n, 1.9),
                             vclass=np.full(n, "passenger"), type_id=np.full(n, "t"))
    return d


def test_the_vehicles_ahead_and_behind_in_the_corridor():
    d = _driver([("lead", 20.0, 0.3, 0.0, 5.0),  # gap 15.5 m, closing 5 m/s: TTC 3.1 s
                 ("far_lead", 40.0, 0.0, 0.0, 0.0),  # farther: not the nearest ahead
                 ("follower", -12.0, -0.5, 0.0, 14.0),  # gap 7.5 m, closing 4 m/s: TTC 1.875 s
                 ("next_lane", 5.0, 3.5, 0.0, 0.0),  # beside, not in the corridor
                 ("oncoming", 10.0, 0.0, math.pi, 10.0)])  # the other way: not in it
    f = corridor_features(d, time_left_s=6.0)
    assert f.shape == (CORRIDOR_FEATURES,)
    np.testing.assert_allclose(f[:4], [1.0, 15.5 / 50, 5.0 / 30, 3.1 / 10], atol=1e-6)
    np.testing.assert_allclose(f[4:8], [1.0, 7.5 / 50, 4.0 / 30, 1.875 / 10], atol=1e-6)
    assert f[8] == pytest.approx(6.0 / 20)


def test_nobody_in_the_corridor_and_an_opening_gap():
    f = corridor_features(_driver([("leaving", 20.0, 0.0, 0.0, 15.0)]), time_left_s=30.0)
    assert f[0] == 1.0 and f[2] == pytest.approx(-5.0 / 30) and f[3] == 1.0  # opening: no TTC
    assert f[4:8].tolist() == [0.0, 1.0, 0.0, 1.0] and f[8] == 1.0


def test_lidar_rays_meet_the_nearest_box():
    d = _driver([("ahead", 10.0, 0.0, 0.0, 0.0), ("left", 0.0, 6.0, 0.0, 0.0)])
    rays = lidar(d)
    assert rays.shape == (NUM_RAYS,)
    assert rays[0] == pytest.approx((10.0 - 2.25) / 50)  # straight ahead: its rear bumper
    assert rays[NUM_RAYS // 4] == pytest.approx((6.0 - 0.95) / 50)  # to the left: its right side
    assert rays[NUM_RAYS // 2] == 1.0 and rays[3 * NUM_RAYS // 4] == 1.0  # behind, to the right: nothing


@pytest.mark.sumo
@pytest.mark.parametrize("observation", ["avoidance", "lidar"])
def test_check_env_passes_with_the_avoidance_observations(tmp_path_factory, observation):
    pytest.importorskip("gymnasium")
    from gymnasium.utils.env_checker import check_env

    from coster_sumo.gym.build import BuildOptions, build_set
    from coster_sumo.gym.env import ScenarioEnv
    from tests.conftest import REPO

    out = tmp_path_factory.mktemp("set") / "nominal"
    build_set(BuildOptions(sources=[str(REPO / "networks" / "merge" / "merge.sumocfg")], out=out, method="nominal"))
    env = ScenarioEnv(out, observation=observation)
    check_env(env)
    obs, _ = env.reset(seed=0)
    for _ in range(20):
        obs, _, terminated, truncated, _ = env.step(np.zeros(2, np.float32))
        assert env.observation_space.contains(obs)
        if terminated or truncated:
            break
    env.close()
