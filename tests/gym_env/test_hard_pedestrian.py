"""The Hard set's pedestrian who steps out from behind a stopped vehicle, and VRU variants in sets."""

from __future__ import annotations

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")
shapely = pytest.importorskip("shapely")

from coster_sumo.core.scene import ObjectType  # noqa: E402
from coster_sumo.gym.build import BuildOptions, build_set  # noqa: E402
from coster_sumo.gym.env import ScenarioEnv  # noqa: E402
from coster_sumo.gym.hard import ADVERSITY_ONSET_S, PED_SPEED  # noqa: E402
from coster_sumo.gym.scenario_set import ScenarioSet  # noqa: E402
from tests.conftest import REPO  # noqa: E402
from tests.gym_env.test_gym import keep_or_brake, nominal_action  # noqa: E402

pytestmark = pytest.mark.sumo

NAME = "pedestrian-behind-vehicle"


@pytest.fixture(scope="module")
def hard_set(tmp_path_factory):
    out = tmp_path_factory.mktemp("set") / "hard"
    build_set(BuildOptions(sources=[str(REPO / "networks" / "intersection" / "intersection.sumocfg")], out=out,
                           method="hard"))
    return out


def _box(tr, a: int, k: int):
    half = shapely.box(-tr.length[a, k] / 2, -tr.width[a, k] / 2, tr.length[a, k] / 2, tr.width[a, k] / 2)
    turned = shapely.affinity.rotate(half, float(tr.heading[a, k]), use_radians=True, origin=(0, 0))
    return shapely.affinity.translate(turned, float(tr.x[a, k]), float(tr.y[a, k]))


def test_the_pedestrian_waits_hidden_behind_the_stopped_vehicle_then_walks_across(hard_set):
    s = ScenarioSet.load(hard_set)
    (entry,) = [e for e in s.select(kind="variant") if e.extra.get("adversity") == NAME]
    scene = s.scene(entry)
    tr, ts = scene.tracks, scene.timestamps
    ped, occ, me = tr.index_of("adversity"), tr.index_of("occluder"), tr.index_of(entry.target)
    assert int(tr.object_type[ped]) == ObjectType.PEDESTRIAN and int(tr.object_type[occ]) == ObjectType.VEHICLE
    onset = entry.t_start + ADVERSITY_ONSET_S
    before = np.flatnonzero(tr.valid[ped] & (ts < onset - 1e-6))
    assert len(before) > 10 and np.ptp(tr.x[occ, tr.valid[occ]]) == 0.0  # it stands; so does the vehicle
    assert np.ptp(tr.x[ped, before]) == 0.0 and np.ptp(tr.y[ped, before]) == 0.0
    for k in before:  # every sight line from the target's centre to the pedestrian crosses the vehicle
        corners = np.asarray(_box(tr, ped, k).exterior.coords)[:4]
        eye = (float(tr.x[me, k]), float(tr.y[me, k]))
        assert all(shapely.LineString([eye, tuple(c)]).intersects(_box(tr, occ, k)) for c in corners), ts[k]
    later = np.flatnonzero(tr.valid[ped] & (ts > onset + 0.5))
    step = np.hypot(np.diff(tr.x[ped, later]), np.diff(tr.y[ped, later]))
    assert step.max() == pytest.approx(PED_SPEED * 0.1, rel=0.05)  # 5 km/h at 10 Hz, then it stands
    assert not _box(tr, occ, before[0]).intersects(shapely.LineString(np.stack([tr.x[me, tr.valid[me]],
                                                                                 tr.y[me, tr.valid[me]]], -1)))


@pytest.mark.parametrize("traffic", ["log", "reactive"])
def test_a_target_that_keeps_its_speed_hits_the_pedestrian_and_one_that_brakes_does_not(hard_set, traffic):
    s = ScenarioSet.load(hard_set)
    (entry,) = [e for e in s.select(kind="variant") if e.extra.get("adversity") == NAME]
    env = ScenarioEnv(hard_set, traffic=traffic)
    outcomes = keep_or_brake(env, entry.id)
    if traffic == "reactive":  # the stopped vehicle never drives off
        assert env._reactive is not None
        assert not env._reactive.may_react[env.scene.tracks.index_of("occluder")]
    env.close()
    assert outcomes["nominal"][0] == "adversity" and abs(outcomes["nominal"][1] - entry.extra["t_conflict"]) < 1.0
    assert outcomes["brake"][0] != "adversity", outcomes


@pytest.mark.slow
@pytest.mark.parametrize("adversary", ["pedestrian", "cyclist"])
def test_a_vru_variant_keeps_its_class_and_meets_a_nominal_target_at_t_col(tmp_path, adversary):
    """``scenarios build --adversary pedestrian|cyclist``: the adversary joins the scene with its class's
    object type (the replay adds it as a vehicle of class pedestrian / bicycle) and a target that
    keeps its nominal speed meets it at t_col. A cyclist mostly rides along the target's direction
    (its learned contact states: models/vru_states.md), and then its box can run alongside the
    target's within centimetres for a while before t_col (here 0.8 s, with the target tracking its
    nominal path within 0.1 m): the first touch may come up to 1 s early; never late."""
    out = tmp_path / adversary
    build_set(BuildOptions(sources=[str(REPO / "networks" / "intersection" / "intersection.sumocfg")], out=out,
                           method="coster", snapshots=1, variants=2, samples=200, adversary=adversary))
    s = ScenarioSet.load(out)
    variants = s.select(kind="variant")
    assert variants
    want = {"pedestrian": ObjectType.PEDESTRIAN, "cyclist": ObjectType.CYCLIST}[adversary]
    env = ScenarioEnv(out, kind="variant", order="cycle")
    try:  # a failed assertion must not leave libsumo's one simulation running for the next test
        for i, entry in enumerate(variants):
            tr = s.scene(entry).tracks
            assert int(tr.object_type[tr.index_of(entry.adversary)]) == want
            _, info = env.reset(seed=i)
            assert info["scenario"] == entry.id
            terminated = truncated = False
            while not (terminated or truncated):
                _, _, terminated, truncated, info = env.step(nominal_action(env))
            assert info["collided_with_adversary"], info
            early = 1.0 if adversary == "cyclist" else 0.25
            assert entry.t_col - early <= info["time"] <= entry.t_col + 0.25, (info["time"], entry.t_col)
    finally:
        env.close()
