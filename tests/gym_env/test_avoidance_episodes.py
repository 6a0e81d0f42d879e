"""Episodes that can reward avoidance: past t_col, random nominal starts, adversities 3 s in."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("gymnasium")

from coster_sumo.gym.build import BuildOptions, build_set  # noqa: E402
from coster_sumo.gym.env import ScenarioEnv  # noqa: E402
from coster_sumo.gym.hard import ADVERSITY_ONSET_S, AVOIDANCE_TAIL_S  # noqa: E402
from coster_sumo.gym.scenario_set import ScenarioSet  # noqa: E402
from tests.conftest import REPO  # noqa: E402

pytestmark = pytest.mark.sumo
INTERSECTION = str(REPO / "networks" / "intersection" / "intersection.sumocfg")


@pytest.mark.slow
def test_a_variant_episode_runs_past_t_col_along_the_nominal_route(tmp_path):
    out = tmp_path / "coster"
    build_set(BuildOptions(sources=[INTERSECTION], out=out, method="coster", snapshots=1, variants=2, samples=200))
    variants = ScenarioSet.load(out).select(kind="variant")
    assert variants
    for entry in variants:
        assert entry.t_col is not None and entry.t_end >= entry.t_col + AVOIDANCE_TAIL_S
        scene = ScenarioSet.load(out).scene(entry)
        tr = scene.tracks
        i = tr.index_of(entry.target)
        env = ScenarioEnv(out, scenario_ids=[entry.id], traffic="reactive")
        env.reset(seed=0)
        # the route goes on past the planned contact point: to where the target was 5 s after t_col
        k_col = int(np.argmin(np.abs(scene.timestamps - entry.t_col)))
        k_after = int(np.argmin(np.abs(scene.timestamps - entry.t_col - AVOIDANCE_TAIL_S)))
        ahead = float(np.hypot(tr.x[i, k_after] - tr.x[i, k_col], tr.y[i, k_after] - tr.y[i, k_col]))
        assert ahead > 5.0
        from coster_sumo.geometry.boxes import project_points

        s_col, _, _ = project_points(np.array([tr.x[i, k_col], tr.y[i, k_col]]), env.route.points)
        assert env.route.length_m >= float(s_col) + 0.9 * ahead
        # a target that stops early is not hit (the followers react) and its episode runs past t_col
        done, info = False, {}
        while not done:
            _, _, terminated, truncated, info = env.step(np.array([-1.0, 0.0], np.float32))
            done = terminated or truncated
        env.close()
        assert info["outcome"] == "timeout" and info["time"] >= entry.t_col + AVOIDANCE_TAIL_S, info


@pytest.fixture(scope="module")
def nominal_set(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("set") / "nominal"
    build_set(BuildOptions(sources=[INTERSECTION], out=out, method="nominal"))
    return out


def test_nominal_episodes_start_at_a_seeded_random_time(nominal_set):
    (entry,) = ScenarioSet.load(nominal_set).entries
    env = ScenarioEnv(nominal_set, random_start=True)
    starts = []
    for seed in (0, 1, 2, 0):
        _, info = env.reset(seed=seed)
        starts.append(info["time"])
    env.close()
    assert starts[0] == starts[3]  # the seed decides
    assert len(set(starts[:3])) == 3
    assert all(entry.t_start - 0.11 <= t <= entry.t_end - 8.0 + 0.11 for t in starts), (starts, entry)
    fixed = ScenarioEnv(nominal_set)
    assert fixed.reset(seed=1)[1]["time"] == pytest.approx(entry.t_start, abs=0.11)
    fixed.close()


def test_a_hand_made_adversity_starts_3_s_in_and_the_episode_runs_5_s_past_it(tmp_path):
    out = tmp_path / "hard"
    build_set(BuildOptions(sources=[str(REPO / "networks" / "arterial" / "arterial.sumocfg")], out=out,
                           method="hard"))
    s = ScenarioSet.load(out)
    hard = {e.extra["adversity"]: e for e in s.select(kind="variant")}
    assert {"leader-braking", "cut-in"} <= set(hard)
    for name, entry in hard.items():
        assert entry.t_end >= entry.t_start + ADVERSITY_ONSET_S + AVOIDANCE_TAIL_S, name
        scene = s.scene(entry)
        adv = scene.tracks.index_of("adversity")
        ts = scene.timestamps
        if name == "leader-braking":  # at the target's speed until the onset, then braking
            v = np.hypot(scene.tracks.vx[adv], scene.tracks.vy[adv])
            before = (ts >= entry.t_start) & (ts <= entry.t_start + ADVERSITY_ONSET_S - 0.05)
            assert np.ptp(v[before & scene.tracks.valid[adv]]) < 1e-6
            assert v[int(np.argmin(np.abs(ts - entry.t_start - ADVERSITY_ONSET_S - 1.0)))] < v[before][0] - 3.0
        if name == "red-light-runner":
            assert entry.extra["t_conflict"] >= entry.t_start + ADVERSITY_ONSET_S


def test_a_clip_of_9_s_holds_both_adversities(tmp_path):
    """A corpus clip is 9.1 s: an adversity's episode (onset 3 s in, 5 s past it) fits when it starts
    as the target departs (with 2 s more, no held-out clip had one)."""
    from coster_sumo.data import synthetic
    from coster_sumo.gym.hard import hard_variants

    scene = synthetic.four_way_junction()
    target = int(scene.sdc_index)
    valid = scene.timestamps[scene.tracks.valid[target]]
    assert valid[-1] - valid[0] < 9.2  # a clip's length
    (tmp_path / "scenarios").mkdir()
    common = {"network": "n", "split": "test", "source": "s", "target": str(scene.tracks.ids[target]),
              "net": "n.net.xml"}
    entries = hard_variants(tmp_path, scene, target, "x", common, float(valid[0]), float(valid[-1]), 20.0)
    assert {"leader-braking", "cut-in"} <= {e.extra["adversity"] for e in entries}
    for entry in entries:
        assert entry.t_end >= entry.t_start + ADVERSITY_ONSET_S + AVOIDANCE_TAIL_S - 1e-6
