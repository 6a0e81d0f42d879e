"""The nominal-traffic corpus: catalogue, run plan, held-out networks never trained on, the card."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from coster_sumo import save_scene
from coster_sumo.batch import corpus
from coster_sumo.batch.corpus import CorpusConfig, catalogue, plan_corpus, vtypes_xml
from coster_sumo.cli.command_line import main
from coster_sumo.data import dataset, synthetic


def _plan(tmp_path: Path, runs: int = 2) -> tuple[list[corpus.Network], list]:
    nets, errors = catalogue(tmp_path, build=False)
    assert errors == []
    return nets, plan_corpus(CorpusConfig(dataset=tmp_path, runs_per_network=runs), nets)


def test_catalogue_covers_the_road_types_and_names_its_heldout_networks(tmp_path):
    nets, _ = _plan(tmp_path)
    assert len(nets) >= 40 and len({n.name for n in nets}) == len(nets)
    fam = {n.name: n.family for n in nets}
    for name in ("A10KW", "bs3d", "DRT", "fkk_in", "fokr_bs_demo"):
        assert fam[name] == "wheel-osm"
    assert {"freeway", "roundabout", "rural", "netgenerate", "project"} <= set(fam.values())
    held = [n for n in nets if n.heldout]
    assert {n.name for n in held} == set(corpus.HELDOUT)
    assert sum(n.family == "freeway" for n in held) >= 1
    assert sum(n.family == "wheel-osm" for n in held) >= 2
    assert sum(n.family in ("netgenerate", "roundabout", "rural") for n in held) >= 1
    assert all(n.source for n in nets)


def test_plan_sweeps_demand_models_and_sublane_and_is_deterministic(tmp_path):
    _, tasks = _plan(tmp_path, runs=2)
    assert plan_corpus(CorpusConfig(dataset=tmp_path, runs_per_network=2), catalogue(tmp_path, build=False)[0]) == tasks
    assert {t.info["level"] for t in tasks} == set(corpus.LEVELS)
    share = np.mean([t.info["sublane"] for t in tasks])
    assert 0.2 < share < 0.5
    assert all("--lateral-resolution" in t.options or "--lanechange.duration" in t.options for t in tasks)
    models = {m for t in tasks for m in t.info["car_following"].values()}
    assert models == {"Krauss", "IDM", "EIDM"}
    own = [t for t in tasks if t.source.has_demand]
    assert {t.network for t in own} >= {"A10KW", "fokr_bs_demo"}  # own demand where it covers a run
    assert all(t.source.begin_s >= 54000 for t in own if t.network == "fokr_bs_demo")
    # one run per network still covers every variant (a reduced build is representative)
    one = plan_corpus(CorpusConfig(dataset=tmp_path, runs_per_network=1), catalogue(tmp_path, build=False)[0])
    assert {t.info["level"] for t in one} == set(corpus.LEVELS) and any(t.info["sublane"] for t in one)


def test_vtype_mix_has_the_vehicle_classes():
    xml, models = vtypes_xml(np.random.default_rng(0), freeway=False)
    for vclass in ("passenger", "delivery", "truck", "trailer", "bus", "coach", "motorcycle", "bicycle"):
        assert f'vClass="{vclass}"' in xml
    assert '<vTypeDistribution id="mix"' in xml and set(models.values()) <= {"Krauss", "IDM", "EIDM"}


def test_heldout_networks_never_reach_a_training_split(tmp_path):
    """By construction: held-out runs write to DATASET/heldout/, and every split (prior, rollout,
    dataset.split) starts from dataset.list_scenes, which lists DATASET/scenes/ only."""
    from coster_sumo.prior.data import split_files
    from coster_sumo.rollout.train import split_scene_files

    _, tasks = _plan(tmp_path, runs=1)
    clip = synthetic.two_lane_road()
    for t in tasks:  # one clip per run, where the run would write it
        assert t.clips_dir == (dataset.heldout_dir(tmp_path) if t.network in corpus.HELDOUT
                               else dataset.scenes_dir(tmp_path))
        t.clips_dir.mkdir(parents=True, exist_ok=True)
        save_scene(clip, t.clips_dir / f"{t.run_id}_0060.0_veh0.npz")
    heldout_runs = {t.run_id for t in tasks if t.heldout}
    assert len(dataset.list_heldout(tmp_path)) == len(heldout_runs) == len(corpus.HELDOUT)

    def runs_of(paths: list[Path]) -> set[str]:
        return {p.name.rsplit("_", 2)[0] for p in paths}

    listed = dataset.list_scenes(tmp_path)
    assert len(listed) == len(tasks) - len(heldout_runs) and not runs_of(listed) & heldout_runs
    for frac in (0.0, 0.1, 0.5, 1.0):
        for seed in (0, 1):
            train, val = split_files(tmp_path, frac, seed)
            assert not runs_of(train + val) & heldout_runs
    train, val = split_scene_files(tmp_path, 0.1, 0)
    assert not runs_of(train + val) & heldout_runs


@pytest.mark.sumo
@pytest.mark.slow
def test_build_writes_heldout_clips_apart_stats_and_a_card(tmp_path):
    out = tmp_path / "c"
    args = ["-q", "corpus", "build", str(out), "--runs-per-network", "1", "--duration", "75",
            "--networks", "roundabout00", "roundabout02"]
    assert main(args) == 0
    m = dataset.read_manifest(out)
    assert m["counts"]["runs"] == 2 and m["heldout_networks"] == sorted(corpus.HELDOUT)
    assert {p.name.split("_")[0] for p in dataset.list_scenes(out)} == {"roundabout00"}
    assert {p.name.split("_")[0] for p in dataset.list_heldout(out)} == {"roundabout02"}
    assert sorted(p.name for p in (out / "stats").glob("*.npz")) == ["roundabout00_r0.npz", "roundabout02_r0.npz"]
    assert (out / "nets" / "roundabout00.net.xml").exists() and not (out / "nets" / "freeway00.net.xml").exists()
    assert main(args) == 0  # nothing left to do
    assert json.loads((out / "summary.json").read_text())["runs_done_now"] == 0
    assert main(["-q", "corpus", "card", str(out)]) == 0
    card = (out / "card.md").read_text()
    assert "roundabout02 | roundabout | yes" in card
    assert len(list((out / "card").glob("*.png"))) >= 6


def test_card_from_manifest_and_stats(tmp_path):
    """The card reads only the manifest and stats/ (fake ones here): totals, classes, acceptance lines."""
    from coster_sumo.batch.card import write_card

    m = dataset.read_manifest(tmp_path)
    m["networks"] = [{"name": "fw", "family": "freeway", "source": "authored", "heldout": False, "freeway": True},
                     {"name": "town", "family": "wheel-osm", "source": "wheel", "heldout": True, "freeway": False}]
    m["heldout_networks"] = ["town"]
    rng = np.random.default_rng(0)
    (tmp_path / "stats").mkdir()
    for net, sub, speed in (("fw", False, 33.0), ("town", True, 3.0)):
        run = f"{net}_r0"
        m["runs"].append({"run_id": run, "network": net, "status": "ok", "clips": 2, "duration_s": 1800.0,
                          "wall_s": 60.0, "cpu_s": 50.0, "sublane": sub, "level": "free"})
        n = 500
        np.savez(tmp_path / "stats" / f"{run}.npz", speed=rng.normal(speed, 1.0, n).astype(np.float32),
                 accel=rng.normal(0, 1, n).astype(np.float32),
                 lat_speed=rng.normal(0, 0.6 if sub else 0.01, n).astype(np.float32),
                 limit=np.full(n, 36.1 if net == "fw" else 13.9, np.float32),
                 length=np.where(np.arange(n) % 2, 4.4, 12.0).astype(np.float32), width=np.full(n, 1.8, np.float32),
                 vclass=np.where(np.arange(n) % 2, "passenger", "bus"), clip_agents=np.array([5.0, 9.0], np.float32),
                 clip_median_speed=np.array([speed, speed], np.float32),
                 clip_speed_limit=np.array([36.1 if net == "fw" else 13.9] * 2, np.float32),
                 clip_target_speed=np.array([speed, speed], np.float32))
    dataset.write_manifest(tmp_path, m)
    card = write_card(tmp_path).read_text()
    assert "simulated: **1.00 h**" in card and "networks with runs: **2**" in card
    assert "vehicle classes (2): bus, passenger" in card
    assert "2 congested" in card and "2 free flow" in card
    assert "| town | wheel-osm | yes |" in card
    assert "| bus | 500 | 12 (100%) | 12 |" in card
    assert len(list((tmp_path / "card").glob("*.png"))) == 8
