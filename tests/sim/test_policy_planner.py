"""The policy planner hands the target back to SUMO's driver at its route's end."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from coster_sumo.sim.policy import PolicyPlanner
from coster_sumo.sim.session import SumoSession
from tests.sim.test_session import make_grid

pytestmark = pytest.mark.sumo


class KeepSpeed:
    """A stand-in for a trained policy: always the action (0, 0) (keep the speed, keep the lane)."""

    def predict(self, observation: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
        return np.zeros(2, np.float32), None


def _straight_nominal(sim: SumoSession, route_m: float, speed: float | None = None) -> SimpleNamespace:
    """A nominal trajectory of ``route_m`` straight ahead of the grid's ego from now, at ``speed``
    (default: its own, at least 5 m/s), at 10 Hz."""
    st = sim.vehicle_states(["ego"])
    x0, y0, yaw = float(st.x[0]), float(st.y[0]), float(st.yaw[0])
    v = speed if speed is not None else max(float(st.speed[0]), 5.0)
    t = sim.time + 0.1 * np.arange(int(route_m / v / 0.1) + 1)
    run = v * (t - t[0])
    return SimpleNamespace(times=t, x=x0 + run * np.cos(yaw), y=y0 + run * np.sin(yaw),
                           yaw=np.full(len(t), yaw), valid=np.ones(len(t), bool))


def _drive(tmp_path, route_m: float, t_col_in_s: float | None) -> tuple[PolicyPlanner, float | None, bool]:
    """The grid's ego driven by a keep-speed policy from 2 s on along a straight route of ``route_m``
    ahead; with a plan whose t_col is ``t_col_in_s`` after the takeover when given. Returns the
    planner, when it handed the target over [s] and whether the target arrived within 120 s."""
    cfg = make_grid(tmp_path / "grid")
    (tmp_path / "policy.zip").write_bytes(b"")
    with SumoSession(cfg, seed=0) as sim:
        for _ in range(20):
            sim.step()
        nominal = _straight_nominal(sim, route_m)
        planner = PolicyPlanner(tmp_path / "policy.zip", nominal)
        planner._model = KeepSpeed()
        if t_col_in_s is not None:
            planner.set_plan(SimpleNamespace(t_col=sim.time + t_col_in_s))  # type: ignore[arg-type]
        planner.setup(sim, "ego")
        released_at = None
        for _ in range(1200):  # 120 s: a red light may hold it
            present = "ego" in sim.vehicle_ids()
            if not present:
                break
            planner.before_step(sim, "ego", sim.time + 0.1, present)
            if planner._released and released_at is None:
                released_at = sim.time + 0.1
            sim.step()
        return planner, released_at, "ego" not in sim.vehicle_ids()


def test_a_policy_target_at_its_routes_end_is_handed_to_sumo_and_arrives(tmp_path):
    """The route ends 25 m into the target's first edge; SUMO's own route goes on for about 150 m.
    Before the hand-over the target drove on straight and then stood at the run-on's end, for ever."""
    planner, released_at, arrived = _drive(tmp_path, 25.0, None)
    assert released_at is not None, "the planner never reached its route's end"
    assert arrived, "the target never arrived after its route's end"


def test_a_policy_drives_a_variant_only_as_long_as_its_episodes_ran(tmp_path):
    """With a plan, SUMO's driver takes the target at t_col + AVOIDANCE_TAIL_S, route or not."""
    from coster_sumo.gym.hard import AVOIDANCE_TAIL_S

    planner, released_at, arrived = _drive(tmp_path, 500.0, 1.0)
    assert released_at is not None and arrived
    assert released_at == pytest.approx(planner.until + 0.1, abs=1e-6)
    assert planner.until == pytest.approx(2.0 + 1.0 + AVOIDANCE_TAIL_S, abs=0.05)


def test_the_policys_time_left_runs_to_its_hand_over_as_in_its_episodes(tmp_path):
    """The avoidance observation's last number is the time left over TIME_LEFT_SCALE_S: to t_col + the
    tail with a plan (a variant's episode end), not to the end of the target's nominal life."""
    from coster_sumo.gym.observe import TIME_LEFT_SCALE_S

    cfg = make_grid(tmp_path / "grid")
    (tmp_path / "policy.zip").write_bytes(b"")
    with SumoSession(cfg, seed=0) as sim:
        for _ in range(20):
            sim.step()
        nominal = _straight_nominal(sim, 300.0, speed=5.0)  # a 60 s nominal life
        planner = PolicyPlanner(tmp_path / "policy.zip", nominal)
        planner._model = KeepSpeed()
        planner.observation = "avoidance"
        planner.set_plan(SimpleNamespace(t_col=sim.time + 2.0))  # type: ignore[arg-type]
        planner.setup(sim, "ego")
        planner.before_step(sim, "ego", sim.time + 0.1, True)
        sim.step()
        planner.states = sim.vehicle_states()
        left = planner.until - sim.time
        assert 0.0 < left < TIME_LEFT_SCALE_S
        assert float(planner._observation(sim.time)[-1]) == pytest.approx(left / TIME_LEFT_SCALE_S, abs=1e-6)
