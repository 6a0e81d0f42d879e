"""Generation over a long life costs the steps the collision-time search reads, not the life.

A target that lives minutes in a jam (2,800 steps at 2 Hz for veh400 on the wheel's A10KW): the
prior's data (which agent is in which region) is built at the steps the search and the placement
read, never at every step of the life, and it is the same there as the whole life's.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from coster_sumo.core import scene as sc
from coster_sumo.data.synthetic import two_lane_road
from coster_sumo.method import collision_time as ct
from coster_sumo.method.snapshot import PriorMemo, _scene_prior
from coster_sumo.prior import data as prior_data
from coster_sumo.prior.model import PriorConfig, TrafficPrior

LIFE_STEPS = 1_400  # [2 Hz steps] 700 s in a jam
JAM_SPEED = 0.1  # [m/s] 70 m over the life: the target stays on the 200 m road


def _jam(steps: int = LIFE_STEPS) -> sc.Scene:
    """The two-lane road at 2 Hz for ``steps`` steps, its four vehicles crawling along +x."""
    road = two_lane_road()
    tr = road.tracks
    t = np.arange(steps) * 0.5  # [s]
    n = tr.num_agents
    x = tr.x[:, :1] + JAM_SPEED * t[None]  # (n, steps)
    full = np.ones((n, steps))
    tracks = sc.Tracks(ids=tr.ids, object_type=tr.object_type, x=x, y=tr.y[:, :1] * full, heading=0.0 * full,
                       vx=JAM_SPEED * full, vy=0.0 * full, length=4.5 * full, width=1.9 * full,
                       valid=np.ones((n, steps), bool))
    return dataclasses.replace(road, timestamps=t, tracks=tracks, signals=sc.SignalStates.empty(steps),
                               current_time_index=0).validate()


@pytest.fixture(scope="module")
def model() -> TrafficPrior:
    torch.manual_seed(0)
    return TrafficPrior(PriorConfig(hidden=16, head_hidden=16, num_blocks=1)).eval()


def test_a_long_life_builds_the_prior_data_at_the_searched_steps_only(model, monkeypatch):
    scene = _jam()
    target = scene.sdc_index
    window = ct.search_window(scene, target)
    assert len(window) > ct.LONG_WINDOW_STEPS
    built: list[np.ndarray] = []
    assign = prior_data.assigned_agent

    def counted(regions, tracks, st, *args, **kwargs):  # noqa: ANN001, ANN202 - assigned_agent's signature
        built.append(np.asarray(st))
        return assign(regions, tracks, st, *args, **kwargs)

    monkeypatch.setattr(prior_data, "assigned_agent", counted)
    memo = PriorMemo()
    _scene_prior(model, scene, target, memo)
    steps = np.concatenate(built)
    assert len(steps) == len(np.unique(steps))  # no step assigned twice
    searched = np.flatnonzero(np.isfinite(memo.entropy))
    assert set(searched.tolist()) <= set(steps.tolist())
    bound = -(-len(window) // ct.COARSE_STRIDE) + ct.FINE_CANDIDATES * (2 * ct.COARSE_STRIDE - 1)
    assert len(steps) <= bound < scene.num_steps / 4  # the search's steps, not the life's
    np.testing.assert_array_equal(np.flatnonzero(memo.data.occupancy.built), np.sort(steps))


def test_the_adaptation_is_fitted_around_the_candidate_times(model):
    scene = _jam()
    target = scene.sdc_index
    memo = PriorMemo()
    _scene_prior(model, scene, target, memo)
    around = ct.candidate_steps(scene, target, memo.entropy)
    assert 0 < len(around) <= ct.FINE_CANDIDATES * (2 * ct.COARSE_STRIDE - 1)
    best = int(np.nanargmax(memo.entropy))
    assert best in around  # t_col's own minutes
    short = _jam(200)
    np.testing.assert_array_equal(ct.candidate_steps(short, target, np.zeros(200)), ct.search_window(short, target))


def test_the_occupancy_built_at_some_steps_is_the_whole_life_s_there(model):
    scene = _jam(300)
    target = scene.sdc_index
    cfg = model.config
    whole = prior_data.prepare_scene(scene, radius=cfg.radius, spacing=cfg.region_spacing, width=cfg.region_width,
                                      crop=scene.tracks.xy_of(target))
    lazy = prior_data.prepare_around(scene, target, radius=cfg.radius, spacing=cfg.region_spacing,
                                     width=cfg.region_width)
    np.testing.assert_array_equal(lazy.regions.q1, whole.regions.q1)
    np.testing.assert_array_equal(lazy.signal, whole.signal)
    steps = np.array([3, 150, 151, 299, 3])
    regions = np.arange(len(whole.regions))
    for t in (steps[:, None], steps[::-1, None]):
        for got, want in zip(lazy.occupancy.gather(t, regions[None]), whole.occupancy.gather(t, regions[None]),
                             strict=True):
            assert got.dtype == want.dtype and got.tobytes() == want.tobytes()
    assert np.flatnonzero(lazy.occupancy.built).tolist() == [3, 150, 151, 299]
    assert (lazy.centres[:, 1] == target).all() and len(lazy.centres) == scene.num_steps
