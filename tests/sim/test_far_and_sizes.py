"""far_agents and agent_sizes against their per-agent definitions (every reset of the environment
asks both for every agent, so they are computed block-wise; the answers must not move)."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from coster_sumo.data import synthetic
from coster_sumo.formats.scene_folder import MIN_SIZE_M, agent_sizes, vtype_for
from coster_sumo.sim.replay import far_agents


def _far_by_definition(tracks, path, radius_m, from_step=0):
    """Agent by agent: far when every valid position from ``from_step`` on is over ``radius_m`` from
    every path point, or when its positions hold a NaN (nothing can be near it); no valid position:
    not listed."""
    path = np.asarray(path, np.float64).reshape(-1, 2)
    far = set()
    for a in range(tracks.num_agents):
        keep = tracks.valid[a, from_step:]
        pts = np.stack([tracks.x[a, from_step:][keep], tracks.y[a, from_step:][keep]], -1)
        if len(pts) == 0:
            continue
        if (len(path) == 0 or np.isnan(pts).any()
                or np.min(np.hypot(*(pts[:, None, :] - path[None, :, :]).transpose(2, 0, 1))) > radius_m):
            far.add(str(tracks.ids[a]))
    return far


def _sizes_by_definition(scene):
    """Per agent: np.median over its valid sizes, the vType's default when never valid, MIN_SIZE_M
    when one of them is not finite or the median is tiny."""
    tr = scene.tracks
    out = []
    for values, col in ((tr.length, 3), (tr.width, 4)):
        sizes = np.empty(tr.num_agents)
        for a in range(tr.num_agents):
            v = values[a][tr.valid[a]]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                sizes[a] = np.median(v) if len(v) else vtype_for(int(tr.object_type[a]))[col]
            if not np.isfinite(v).all():
                sizes[a] = np.nan
        sizes[~np.isfinite(sizes) | (sizes < MIN_SIZE_M)] = MIN_SIZE_M
        out.append(sizes)
    return out[0], out[1]


def _random_tracks(seed: int, agents: int = 300, steps: int = 60):
    scene = synthetic.ALL[sorted(synthetic.ALL)[0]]()
    rng = np.random.default_rng(seed)
    tr = scene.tracks
    shape = (agents, steps)
    x = rng.uniform(-300, 300, (agents, 1)) + np.cumsum(rng.normal(0, 2, shape), axis=1)
    y = rng.uniform(-300, 300, (agents, 1)) + np.cumsum(rng.normal(0, 2, shape), axis=1)
    valid = rng.random(shape) < rng.uniform(0.0, 1.0, (agents, 1))  # some rows never valid
    x[rng.random(shape) < 0.002] = np.nan  # a broken log value here and there
    length = np.where(rng.random((agents, 1)) < 0.5, 4.5, rng.uniform(0.0, 6.0, shape)).astype(tr.length.dtype)
    width = np.where(rng.random((agents, 1)) < 0.7, 1.8, rng.uniform(0.0, 2.5, shape)).astype(tr.width.dtype)
    length[rng.random(shape) < 0.001] = np.inf
    fields = {f.name: getattr(tr, f.name) for f in dataclasses.fields(tr)}
    for name, arr in list(fields.items()):
        if isinstance(arr, np.ndarray) and arr.ndim == 2 and arr.shape[0] == tr.num_agents:
            fields[name] = np.zeros(shape, arr.dtype)
    fields.update(x=x, y=y, valid=valid, length=length, width=width,
                  ids=np.array([f"a{i}" for i in range(agents)]),
                  object_type=rng.integers(1, 4, agents).astype(tr.object_type.dtype))
    return dataclasses.replace(scene, tracks=dataclasses.replace(tr, **fields))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_far_agents_is_its_definition(seed):
    scene = _random_tracks(seed)
    rng = np.random.default_rng(100 + seed)
    path = np.cumsum(rng.normal(0, 8, (80, 2)), axis=0)
    for radius, start, p in ((30.0, 0, path), (80.0, 17, path), (5.0, 59, path[::7]), (50.0, 3, path[:0])):
        got = far_agents(scene.tracks, p, radius, from_step=start)
        assert got == _far_by_definition(scene.tracks, p, radius, from_step=start)
    assert 0 < len(far_agents(scene.tracks, path, 80.0)) < scene.tracks.num_agents  # both kinds occur


@pytest.mark.parametrize("seed", [0, 1])
def test_agent_sizes_is_the_median_of_valid_steps(seed):
    scene = _random_tracks(seed)
    lengths, widths = agent_sizes(scene)
    ref_l, ref_w = _sizes_by_definition(scene)
    np.testing.assert_array_equal(lengths, ref_l)
    np.testing.assert_array_equal(widths, ref_w)


def test_agent_sizes_of_every_synthetic_scene(synthetic_scene):
    lengths, widths = agent_sizes(synthetic_scene)
    ref_l, ref_w = _sizes_by_definition(synthetic_scene)
    np.testing.assert_array_equal(lengths, ref_l)
    np.testing.assert_array_equal(widths, ref_w)
