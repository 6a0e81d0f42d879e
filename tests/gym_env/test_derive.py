"""``scenarios one-per-snapshot``: the coster-one-per-snapshot set taken from a coster set is the one
``scenarios build --method coster-one-per-snapshot`` generates."""

from __future__ import annotations

import json

import numpy as np
import pytest

from coster_sumo.errors import InputError
from coster_sumo.formats.scene_file import load_scene
from coster_sumo.gym.build import BuildOptions, build_set
from coster_sumo.gym.derive import one_per_snapshot
from coster_sumo.gym.scenario_set import MANIFEST, ScenarioSet
from tests.conftest import REPO

pytestmark = pytest.mark.sumo

CONFIG = str(REPO / "networks" / "intersection" / "intersection.sumocfg")


def _options(out, method):
    return BuildOptions(sources=[CONFIG], out=out, method=method, seeds=2, snapshots=2, variants=3, samples=200)


def test_one_per_snapshot_of_a_coster_set_is_the_built_one(tmp_path):
    build_set(_options(tmp_path / "coster", "coster"))
    build_set(_options(tmp_path / "built", "coster-one-per-snapshot"))
    counts = one_per_snapshot(tmp_path / "coster", tmp_path / "derived")
    built, derived = ScenarioSet.load(tmp_path / "built"), ScenarioSet.load(tmp_path / "derived")
    coster = ScenarioSet.load(tmp_path / "coster")
    assert sum(e.kind == "variant" for e in coster.entries) > counts["variants"] > 0  # something was left out
    assert [e.to_dict() for e in derived.entries] == [e.to_dict() for e in built.entries]
    m_built = json.loads((tmp_path / "built" / MANIFEST).read_text())
    m_derived = json.loads((tmp_path / "derived" / MANIFEST).read_text())
    assert m_derived == m_built
    for e in built.entries:
        a, b = load_scene(tmp_path / "built" / "scenarios" / f"{e.id}.npz"), derived.scene(e)
        for field in ("x", "y", "heading", "vx", "vy", "valid"):
            np.testing.assert_array_equal(getattr(a.tracks, field), getattr(b.tracks, field))
        assert (tmp_path / "derived" / e.net).read_bytes() == (tmp_path / "built" / e.net).read_bytes()


def test_one_per_snapshot_needs_a_coster_set(tmp_path):
    build_set(BuildOptions(sources=[CONFIG], out=tmp_path / "nominal", method="nominal"))
    with pytest.raises(InputError, match="'nominal' set"):
        one_per_snapshot(tmp_path / "nominal", tmp_path / "out")
