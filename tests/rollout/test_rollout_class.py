"""One rollout model per agent class (``--agent-class``): the examples are that class's tracks, the
checkpoint says which class it models, and evaluation refuses another class's checkpoint."""

from __future__ import annotations

import json

import numpy as np
import pytest

from coster_sumo.cli.command_line import main
from coster_sumo.core.scene import ObjectType, resample
from coster_sumo.data import synthetic
from coster_sumo.errors import InputError
from coster_sumo.formats.scene_file import save_scene
from coster_sumo.rollout.cache import ENCODING_FIELDS, cache_key, encoding_settings
from coster_sumo.rollout.checkpoint import load_model
from coster_sumo.rollout.config import CLASS_SCALES, RolloutConfig
from coster_sumo.rollout.data import enumerate_examples

TINY = ["--hidden", "16", "--heads", "2", "--latent", "4", "--batch-size", "32", "--examples-per-epoch", "64",
        "--max-val-examples", "16", "--epochs", "1", "--threads", "1"]
TYPE_OF = {"vehicle": ObjectType.VEHICLE, "pedestrian": ObjectType.PEDESTRIAN, "cyclist": ObjectType.CYCLIST}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("vru_rollout_data")
    (root / "scenes").mkdir()
    for name, fn in synthetic.ALL.items():
        save_scene(synthetic.with_vulnerable_road_users(fn()), root / "scenes" / f"{name}.npz")
    return root


@pytest.mark.parametrize("agent_class", ["vehicle", "pedestrian", "cyclist"])
def test_the_examples_are_the_class_s_tracks_and_all_of_them(agent_class):
    low = resample(synthetic.with_vulnerable_road_users(synthetic.four_way_junction()), 2.0)
    types = low.tracks.object_type
    got = enumerate_examples(low, RolloutConfig(agent_class=agent_class), full_only=True)
    agents = {a for a, _, _ in got}
    assert agents == set(np.flatnonzero(types == TYPE_OF[agent_class]).tolist())
    # every example of an agent of the class, and nothing else
    every = enumerate_examples(low, RolloutConfig(agent_class=agent_class), full_only=True, class_only=False)
    assert got == [e for e in every if types[e[0]] == TYPE_OF[agent_class]]
    assert len(every) > len(got) > 0


def test_a_vehicle_config_its_cache_key_and_its_checkpoint_config_are_as_before():
    """The class is written only when it is not a vehicle: vehicle checkpoints, training states and
    feature caches keep the keys and contents they had before the option existed."""
    vehicle, walker = RolloutConfig(), RolloutConfig(agent_class="pedestrian")
    assert "agent_class" not in vehicle.to_dict() and walker.to_dict()["agent_class"] == "pedestrian"
    assert set(encoding_settings(vehicle, 2)) == {"version", "min_steps", *ENCODING_FIELDS}
    assert RolloutConfig.from_dict(vehicle.to_dict()).agent_class == "vehicle"
    assert RolloutConfig.from_dict(walker.to_dict()).agent_class == "pedestrian"
    assert encoding_settings(walker, 2)["agent_class"] == "pedestrian"
    # the key main computed before the option existed (same settings, no scene files)
    assert cache_key([], vehicle, 2) == "74ffad02364f595221a0e718"
    assert cache_key([], walker, 2) != cache_key([], vehicle, 2)
    with pytest.raises(InputError, match="agent class 'dog'"):
        RolloutConfig(agent_class="dog")


def train(dataset, out, *extra):
    return main(["-q", "train", "rollout", "--data", str(dataset), "-o", str(out), *TINY, *extra])


@pytest.mark.parametrize("agent_class", ["pedestrian", "cyclist"])
def test_a_tiny_training_on_a_class_saves_a_checkpoint_of_that_class(dataset, tmp_path, agent_class):
    out = tmp_path / f"{agent_class}.pt"
    assert train(dataset, out, "--agent-class", agent_class) == 0
    model = load_model(out)
    assert model.cfg.agent_class == agent_class
    assert model.cfg.disp_scale == CLASS_SCALES[agent_class]["disp_scale"]
    assert model.cfg.recon_sigma == CLASS_SCALES[agent_class]["recon_sigma"]
    metrics = json.loads(out.with_suffix(".json").read_text())
    assert metrics["config"]["agent_class"] == agent_class
    # the class's examples only: one agent of each VRU class but two pedestrians per scene
    vehicle = tmp_path / "vehicle.pt"
    assert train(dataset, vehicle) == 0
    counts = {c: json.loads(p.with_suffix(".json").read_text())["examples"]
              for c, p in ((agent_class, out), ("vehicle", vehicle))}
    assert 0 < counts[agent_class]["train"] < counts["vehicle"]["train"]
    assert load_model(vehicle).cfg.agent_class == "vehicle"


def test_eval_refuses_a_checkpoint_of_another_class_in_one_line(dataset, tmp_path, capsys):
    ped = tmp_path / "ped.pt"
    assert train(dataset, ped, "--agent-class", "pedestrian") == 0
    capsys.readouterr()
    for agent_class, flag in (("cyclist", "--checkpoint"), ("vehicle", "--checkpoint-no-dsa")):
        code = main(["eval", "rollout", "--data", str(dataset), "--split", "all", "--agent-class", agent_class,
                     flag, str(ped), "--json", str(tmp_path / "e.json")])
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1, err
        assert str(ped) in err and "a pedestrian rollout checkpoint" in err and agent_class in err
    assert not (tmp_path / "e.json").exists()


def test_eval_of_a_class_scores_its_tracks_against_its_baselines(dataset, tmp_path):
    ped = tmp_path / "ped.pt"
    assert train(dataset, ped, "--agent-class", "pedestrian") == 0
    out = tmp_path / "e.json"
    assert main(["-q", "eval", "rollout", "--data", str(dataset), "--split", "all", "--agent-class", "pedestrian",
                 "--checkpoint", str(ped), "--checkpoint-no-dsa", str(ped), "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["agent_class"] == "pedestrian"
    # no lanes for walkers in the maps: constant velocity is the baseline
    assert set(report["methods"]) == {"constant_velocity", "cvae_no_dsa", "cvae_dsa"}
    # two walkers per scene, 9 full-past steps each at 2 Hz, three scenes
    assert report["num_examples"] == 2 * 9 * 3


def test_a_class_model_may_start_from_a_vehicle_model_and_keeps_its_scales(dataset, tmp_path, capsys):
    vehicle = tmp_path / "vehicle.pt"
    assert train(dataset, vehicle) == 0
    tuned = tmp_path / "tuned.pt"
    assert train(dataset, tuned, "--agent-class", "pedestrian", "--init", str(vehicle)) == 0
    cfg = load_model(tuned).cfg
    assert cfg.agent_class == "pedestrian"
    # its weights correct a constant-velocity step at the vehicle's scales: it keeps them
    assert (cfg.disp_scale, cfg.recon_sigma) == (CLASS_SCALES["vehicle"]["disp_scale"],
                                                 CLASS_SCALES["vehicle"]["recon_sigma"])
    capsys.readouterr()
    # asking for the pedestrian's own scales: the vehicle weights would mean something else, refused
    walker = CLASS_SCALES["pedestrian"]
    code = main(["train", "rollout", "--data", str(dataset), "-o", str(tmp_path / "x.pt"), *TINY,
                 "--agent-class", "pedestrian", "--init", str(vehicle),
                 "--disp-scale", *map(str, walker["disp_scale"]), "--recon-sigma", *map(str, walker["recon_sigma"])])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "disp_scale" in err and str(vehicle) in err
