"""``coster-sumo simulate``: SUMO runs -> a readable dataset of valid WOMD-like clips."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from coster_sumo.batch.nets import netgenerate_options
from coster_sumo.batch.simulate import SimulateConfig, plan_runs, resolve_sources
from coster_sumo.cli.command_line import main
from coster_sumo.data import dataset

REPO = Path(__file__).resolve().parents[2]
INTERSECTION = REPO / "networks" / "intersection" / "intersection.sumocfg"
MERGE = REPO / "networks" / "merge" / "merge.sumocfg"


def _check_dataset(root: Path, min_scenes: int = 1) -> list[Path]:
    paths = dataset.list_scenes(root)
    assert len(paths) >= min_scenes
    for scene in dataset.iter_scenes(paths):
        scene.validate()
        assert scene.num_steps == dataset.CLIP_STEPS
        assert scene.current_time_index == dataset.CURRENT_TIME_INDEX
        assert scene.source == "sumo"
        assert scene.tracks.valid[scene.sdc_index].all()
        np.testing.assert_allclose(np.diff(scene.timestamps), 0.1, atol=1e-6)
        assert len(scene.road_map.lanes) > 0
    return paths


def test_netgenerate_options_are_seeded_and_varied():
    kinds = [netgenerate_options(k, seed=0)[0] for k in range(6)]
    assert kinds == ["grid", "spider", "random"] * 2
    assert netgenerate_options(4, seed=1) == netgenerate_options(4, seed=1)
    assert netgenerate_options(4, seed=1) != netgenerate_options(4, seed=2)


def test_runs_get_seeds_and_scales(tmp_path):
    sources = resolve_sources([INTERSECTION, MERGE])
    cfg = SimulateConfig(sources=[INTERSECTION, MERGE], dataset=tmp_path, seeds=3, seed=10,
                         scale_range=(0.5, 1.5))
    runs = plan_runs(cfg, sources)
    assert [r.run_id for r in runs] == [f"{n}_s{s}" for n in ("intersection", "merge") for s in (10, 11, 12)]
    assert all(0.5 <= r.scale <= 1.5 for r in runs)
    assert len({r.scale for r in runs}) == 6
    assert runs[0].duration_s == 120.0  # the configuration's own end
    assert plan_runs(cfg, sources) == runs


def test_usage_errors_exit_2(tmp_path, capsys):
    assert main(["-q", "simulate", str(tmp_path / "nope.sumocfg"), "-o", str(tmp_path / "d")]) == 2
    assert "nope.sumocfg" in capsys.readouterr().err
    assert main(["-q", "simulate", "-o", str(tmp_path / "d")]) == 2


@pytest.mark.sumo
def test_simulate_writes_a_readable_dataset_and_resumes(tmp_path):
    out = tmp_path / "ds"
    args = ["-q", "simulate", str(INTERSECTION), "-o", str(out), "--seeds", "2", "--duration", "25",
            "--clips-per-run", "3", "--workers", "2"]
    assert main(args) == 0
    paths = _check_dataset(out, min_scenes=4)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["counts"] == {"runs": 2, "runs_failed": 0, "scenes": len(paths)}
    assert {r["seed"] for r in manifest["runs"]} == {0, 1}
    assert manifest["simulated_hours"] == pytest.approx(50.0 / 3600.0, rel=1e-3)
    assert not (out / ".work").exists()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["clips_now"] == len(paths)
    # the same command again: nothing to do, nothing duplicated
    mtimes = {p: p.stat().st_mtime_ns for p in paths}
    assert main(args) == 0
    assert {p: p.stat().st_mtime_ns for p in dataset.list_scenes(out)} == mtimes
    assert json.loads((out / "summary.json").read_text())["runs_done_now"] == 0


@pytest.mark.sumo
def test_a_failing_config_is_reported_and_the_others_go_on(tmp_path, capsys):
    broken = tmp_path / "broken.sumocfg"
    broken.write_text('<configuration><input><net-file value="missing.net.xml"/>'
                      '<route-files value="missing.rou.xml"/></input></configuration>')
    out = tmp_path / "ds"
    rc = main(["-q", "simulate", str(broken), str(INTERSECTION), "-o", str(out), "--seeds", "1",
               "--duration", "12", "--clips-per-run", "1"])
    assert rc == 1
    err = capsys.readouterr().err
    assert "broken.sumocfg" in err and "missing.net.xml" in err
    manifest = dataset.read_manifest(out)
    assert manifest["counts"]["runs"] == 1 and manifest["counts"]["runs_failed"] == 1
    _check_dataset(out, min_scenes=1)


@pytest.mark.sumo
@pytest.mark.slow
def test_generated_networks_with_random_trips(tmp_path):
    out = tmp_path / "ds"
    rc = main(["-q", "simulate", "-o", str(out), "--netgenerate", "3", "--seeds", "1", "--duration", "40",
               "--warmup", "20", "--clips-per-run", "2", "--workers", "2"])
    assert rc == 0
    manifest = dataset.read_manifest(out)
    assert [n["kind"] for n in manifest["generated_nets"]] == ["grid", "spider", "random"]
    assert all(r["demand"] == "randomTrips" for r in manifest["runs"])
    assert len(list((out / "nets").glob("*.net.xml"))) == 3
    _check_dataset(out, min_scenes=3)


@pytest.mark.sumo
def test_a_relative_output_folder_works_with_random_trips(tmp_path, monkeypatch):
    # SUMO's tools run inside the run's work folder: a relative -o once named files they could not find
    monkeypatch.chdir(tmp_path)
    rc = main(["-q", "simulate", "-o", "ds", "--netgenerate", "1", "--seeds", "1", "--duration", "30",
               "--warmup", "10", "--clips-per-run", "1", "--workers", "1"])
    assert rc == 0
    assert dataset.read_manifest(Path("ds"))["runs"][0]["demand"] == "randomTrips"
    _check_dataset(Path("ds"), min_scenes=1)


@pytest.mark.sumo
@pytest.mark.slow
@pytest.mark.parametrize("cfg", [INTERSECTION, MERGE, REPO / "networks" / "arterial" / "arterial.sumocfg"])
def test_every_shipped_scenario_yields_clips(tmp_path, cfg):
    out = tmp_path / "ds"
    assert main(["-q", "simulate", str(cfg), "-o", str(out), "--seeds", "1", "--clips-per-run", "5"]) == 0
    _check_dataset(out, min_scenes=5)


@pytest.mark.sumo
def test_a_run_planned_differently_runs_again_and_leftovers_go(tmp_path):
    out = tmp_path / "ds"
    args = ["-q", "simulate", str(INTERSECTION), "-o", str(out), "--seeds", "1", "--duration", "25",
            "--clips-per-run", "2"]
    assert main(args) == 0
    first = {p.name for p in dataset.list_scenes(out)}
    leftover = dataset.scenes_dir(out) / "intersection_s0_00012.3_ghost.npz"  # a killed attempt's clip
    leftover.write_bytes(next(iter(dataset.list_scenes(out))).read_bytes())
    assert main(args) == 0 and leftover.exists()  # done runs are not touched
    assert main([*args, "--scale-range", "2", "2"]) == 0  # another plan: the run is stale
    manifest = dataset.read_manifest(out)
    assert [r["scale"] for r in manifest["runs"]] == [2.0]
    assert not leftover.exists()
    assert len(dataset.list_scenes(out)) == manifest["counts"]["scenes"]
    assert first  # (the first run made clips)


def test_the_batch_summaries_keep_their_keys_in_order():
    """summary.json of simulate and of corpus build: the counts under the names each has written."""
    from coster_sumo.batch.records import BatchCounts, CorpusSummary, SimulateSummary

    counts = BatchCounts(runs_planned=3, runs_done_now=2, runs_failed_now=1, clips_now=40, failures=["r1: x"],
                         total_clips=80, simulated_hours=0.5, wall_s=12.0)
    tail = ["runs_planned", "runs_done_now", "runs_failed_now", "clips_now", "failures"]
    simulate = SimulateSummary(dataset="d", counts=counts, config={"seeds": [0]}).to_json()
    assert list(simulate) == ["dataset", *tail, "total_scenes", "simulated_hours", "wall_s", "config"]
    assert simulate["total_scenes"] == 80 and simulate["failures"] == ["r1: x"]
    corpus = CorpusSummary(dataset="d", networks=2, counts=counts).to_json()
    assert list(corpus) == ["dataset", "networks", *tail, "total_clips", "simulated_hours", "wall_s"]
    assert corpus["total_clips"] == 80 and corpus["wall_s"] == 12.0
