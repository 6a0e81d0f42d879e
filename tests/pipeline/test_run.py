"""End to end: `coster-sumo run` on the project's networks with the weight-free baselines."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from coster_sumo.cli.command_line import main
from tests.conftest import NO_WOMD_REASON, WOMD_PKL, WOMD_PROTO, visible_lines

REPO = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.sumo


def _run(tmp_path: Path, *extra: str) -> tuple[int, Path]:
    out = tmp_path / "out"
    rc = main(["-q", "run", str(REPO / "networks/intersection/intersection.sumocfg"), "--init", "random",
               "--rollout", "cv", "--end", "45", "-o", str(out), *extra])
    return rc, out


def test_run_writes_every_output_and_contact_is_at_t_col(tmp_path, capsys):
    rc, out = _run(tmp_path, "--planner", "replay", "--seed", "3", "--collision-time", "random")
    assert rc == 0
    printed = capsys.readouterr()
    # --quiet: no progress bars, no file list; the one-line results stay
    assert printed.out.startswith("target ego: t_col = ") and "  variant 0: " in printed.out
    assert "wrote " not in printed.out and "nominal pass" not in printed.err
    summary = json.loads((out / "summary.json").read_text())
    for name in ("snapshot.json", "events.jsonl", "collisions.xml", "overview.png"):
        assert (out / name).exists(), name
    assert summary["target"] == "ego"
    assert 0.0 <= summary["snapshot_signed_distance"] <= 0.05
    for v in summary["variants"]:
        vdir = out / "variants" / str(v["variant"])
        assert (vdir / "trajectory.csv").exists() and (vdir / "render.png").exists()
        assert (vdir / "export" / "variant.json").exists()
        if v["collision"]:
            assert abs(v["contact_offset_s"]) <= 0.1 + 1e-6
    assert not list(tmp_path.glob(".out.*")), "staging folder left behind"


def test_a_variant_whose_export_sumo_refuses_keeps_the_run(tmp_path, capsys, monkeypatch):
    """The standalone export is written after the variants ran: when SUMO refuses it (a demand the
    export cannot reproduce), the run keeps its results and names the reason per variant."""
    from coster_sumo.errors import SumoError
    from coster_sumo.exports import sumo as sumo_export

    def refuse(folder, config, *_a, **_k):
        raise SumoError(f"{folder}/x.sumocfg: expanding its flows with sumo failed: Error: refused")

    monkeypatch.setattr(sumo_export, "write_sumo_export", refuse)
    rc, out = _run(tmp_path, "--planner", "replay", "--seed", "3", "--no-render")
    assert rc == 0
    printed = capsys.readouterr().out
    assert "; no SUMO export (" in printed and "Error: refused" in printed
    summary = json.loads((out / "summary.json").read_text())
    assert summary["variants"] and all("Error: refused" in v["export_error"] for v in summary["variants"])
    for v in summary["variants"]:
        vdir = out / "variants" / str(v["variant"])
        assert (vdir / "trajectory.csv").exists() and not (vdir / "export").exists()
    from coster_sumo.exports.run_folder import export_run

    assert all("skipped" in r for r in export_run(out, "sumo"))


def test_same_seed_same_result(tmp_path):
    a = json.loads((_run(tmp_path / "a", "--seed", "5", "--no-render")[1] / "summary.json").read_text())
    b = json.loads((_run(tmp_path / "b", "--seed", "5", "--no-render")[1] / "summary.json").read_text())
    strip = ("timings_s", "options", "wall_time_s")
    for s in (a, b):
        for k in strip:
            s.pop(k, None)
        for v in s["variants"]:
            v.pop("wall_time_s", None)
    assert a == b


@pytest.mark.parametrize(("args", "message"), [
    (["--target", "nobody"], "target 'nobody' is not in its demand"),
    (["--target", "ego", "--end", "1.5"], "target 'ego' never runs in the window (0.1-1.5 s)"),  # departs at 2 s
    (["--end", "1.5"], "no vehicle 'ego' runs in the window"),
    (["--collision-time", "entropy", "--init", "snapshot", "--models", "/nonexistent"], "no such file (model weights"),
])
def test_bad_input_is_one_line_exit_2_and_no_output(tmp_path, capsys, args, message):
    rc, out = _run(tmp_path, *args)
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert message in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_broken_config_is_one_line_exit_2_and_no_output(tmp_path, capsys):
    cfg = tmp_path / "broken.sumocfg"
    cfg.write_text("<configuration><input><net-file value='x.net.xml'/></input>")  # cut off
    out = tmp_path / "o"
    assert main(["run", str(cfg), "-o", str(out)]) == 2
    err = visible_lines(capsys.readouterr().err)
    assert len(err) == 1 and "broken.sumocfg" in err[0]
    assert not out.exists()


def test_missing_config_is_exit_2(tmp_path, capsys):
    rc = main(["run", str(tmp_path / "nope.sumocfg"), "-o", str(tmp_path / "o")])
    assert rc == 2
    assert "nope.sumocfg" in capsys.readouterr().err


@pytest.mark.parametrize("network", ["intersection", "merge", "arterial"])
def test_coster_snapshot_with_shipped_prior_contacts_at_t_col(tmp_path, network):
    out = tmp_path / network
    # the CVAE, whose samples through other vehicles are dropped: the constant-velocity baseline's
    # one straight line may run into a vehicle behind the target before t_col (arterial does)
    rc = main(["-q", "run", str(REPO / f"networks/{network}/{network}.sumocfg"), "--init", "snapshot",
               "--collision-time", "entropy", "--rollout", "cvae", "--samples", "200", "--variants", "2",
               "--planner", "replay", "--no-render", "-o", str(out)])
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["init_method"] == "snapshot" and summary["collision_time_method"] == "entropy"
    assert 0.0 <= summary["snapshot_signed_distance"] <= 0.05
    for v in summary["variants"]:
        assert v["collision"] and abs(v["contact_offset_s"]) <= 0.1 + 1e-6


def test_full_coster_with_shipped_weights(tmp_path):
    """Default run: entropy t_col, prior snapshot, CVAE oversampling, K-means, vocabulary."""
    out = tmp_path / "full"
    rc = main(["-q", "run", str(REPO / "networks/intersection/intersection.sumocfg"), "--planner", "replay",
               "--samples", "200", "--variants", "3", "--no-render", "-o", str(out)])
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["generation"]["kept"] >= 1
    for v in summary["variants"]:
        assert v["collision"] and abs(v["contact_offset_s"]) <= 0.1 + 1e-6


def test_snapshot_command_writes_json_and_png(tmp_path):
    out = tmp_path / "snap"
    rc = main(["-q", "snapshot", str(REPO / "networks/merge/merge.sumocfg"), "--end", "40", "-o", str(out)])
    assert rc == 0
    snap = json.loads((out / "snapshot.json").read_text())
    assert 0.0 <= snap["signed_distance"] <= 0.05 and snap["collision_time_method"] == "entropy"
    assert (out / "snapshot.png").stat().st_size > 10_000


def test_snapshot_same_seed_same_snapshot(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for o in (a, b):
        assert main(["-q", "snapshot", str(REPO / "networks/merge/merge.sumocfg"), "--end", "40", "--seed", "7",
                     "-o", str(o)]) == 0
    assert (a / "snapshot.json").read_text() == (b / "snapshot.json").read_text()


def _sumo_game(name: str) -> Path:
    import sumo

    return Path(sumo.__file__).parent / "tools" / "game" / f"{name}.sumocfg"


@pytest.mark.parametrize(("config", "target"), [("square", "horiz.1"), ("grid6", "leftRight.1")])
def test_scenarios_shipped_with_sumo_contact_at_t_col(tmp_path, config, target):
    """Configurations we did not write (SUMO's own game scenarios, from the eclipse-sumo wheel)."""
    cfg = _sumo_game(config)
    if not cfg.is_file():
        pytest.skip(f"{cfg} not in this SUMO build")
    out = tmp_path / config
    rc = main(["-q", "run", str(cfg), "--target", target, "--planner", "replay", "--samples", "200",
               "--variants", "2", "--no-render", "-o", str(out)])
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["variants"]
    for v in summary["variants"]:
        assert v["collision"] and abs(v["contact_offset_s"]) <= 0.1 + 1e-6


def test_sumolib_rilsa_scenario_that_names_its_net_by_a_synonym(tmp_path, capsys):
    """sumolib's RiLSA real-world junction (eclipse-sumo wheel): its configuration writes `<net>`
    for `<net-file>`, options straight under its root, and its routes come from the folder's own
    script. Before its routes exist the run stops on one line naming the missing file."""
    import shutil
    import subprocess
    import sys

    import sumo

    src = Path(sumo.__file__).parent / "tools/sumolib/scenario/scenarios/RealWorld/RiLSA_example1"
    if not (src / "run.sumo.cfg").is_file():
        pytest.skip(f"{src} not in this SUMO build")
    folder = tmp_path / "rilsa1"
    shutil.copytree(src, folder, ignore=shutil.ignore_patterns("__pycache__"))
    assert main(["-q", "run", str(folder / "run.sumo.cfg"), "--targets", "1", "-o", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "flows.rou.xml: no such file" in err[0], err
    subprocess.run([sys.executable, "makeRoutes.py"], cwd=folder, check=True, capture_output=True)
    out = tmp_path / "run"
    assert main(["-q", "run", str(folder / "run.sumo.cfg"), "--targets", "1", "--duration", "90", "--planner",
                 "replay", "--samples", "200", "--variants", "2", "--no-render", "-o", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["variants"]
    for v in summary["variants"]:
        assert v["collision"] and abs(v["contact_offset_s"]) <= 0.1 + 1e-6


def test_off_road_after_a_missed_contact_is_not_the_adversarys(tmp_path):
    """On the wheel's cross SUMO's driver keeps the target out of every contact; each adversary
    then drives on at constant velocity past t_col and off the road. Its trajectory ended at t_col
    on the road: the variant is not off-road (ORR counts trajectories), the events still say where
    it went."""
    cfg = _sumo_game("cross")
    if not cfg.is_file():
        pytest.skip(f"{cfg} not in this SUMO build")
    out = tmp_path / "o"
    assert main(["-q", "run", str(cfg), "--target", "1_horizontal.0", "--samples", "200", "--variants", "2",
                 "--no-render", "-o", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    missed = [v for v in summary["variants"] if not v["collision"]]
    assert missed and not any(v["adversary_off_road"] for v in missed)
    events = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]
    later = [e for e in events if e["kind"] == "off_road" and e["vehicles"][0].startswith("adversary")]
    assert later and all(e["time"] > summary["t_col_sim"] for e in later)


def test_sumo_scenario_without_ego_names_candidates(tmp_path, capsys):
    cfg = _sumo_game("square")
    if not cfg.is_file():
        pytest.skip(f"{cfg} not in this SUMO build")
    out = tmp_path / "o"
    assert main(["run", str(cfg), "-o", str(out)]) == 2
    err = visible_lines(capsys.readouterr().err)
    assert len(err) == 1 and "--target" in err[0] and "horiz.0" in err[0] and "--targets N" in err[0]
    assert not out.exists() or not any(out.iterdir())


REAL = [*WOMD_PROTO, *WOMD_PKL]


@pytest.mark.realdata
@pytest.mark.slow
@pytest.mark.skipif(not REAL, reason=NO_WOMD_REASON)
def test_real_womd_scenes_contact_within_one_step_of_t_col(tmp_path, capsys):
    """The issue's acceptance on the real samples: replay planner, every kept variant hits at t_col +- 0.1 s."""
    assert main(["-q", "convert", *map(str, REAL), "-o", str(tmp_path / "conv")]) == 0
    folders = sorted(p for p in (tmp_path / "conv").iterdir() if p.is_dir())
    assert len(folders) == 4
    for folder in folders:
        out = tmp_path / "runs" / folder.name
        rc = main(["-q", "run", str(folder / f"{folder.name}.sumocfg"), "--planner", "replay", "--samples", "300",
                   "--no-render", "-o", str(out)])
        assert rc == 0, (folder.name, capsys.readouterr().err)
        summary = json.loads((out / "summary.json").read_text())
        assert summary["num_variants"] >= 1 and summary["collision_rate"] == 1.0, folder.name
        for v in summary["variants"]:
            assert abs(v["contact_offset_s"]) <= 0.1 + 1e-9, (folder.name, v["variant"], v["contact_offset_s"])
    capsys.readouterr()


@pytest.mark.parametrize("extra", [[], ["--init", "random", "--rollout", "cv"]], ids=["prior", "random"])
def test_no_lanes_near_the_target_is_one_line_exit_2_and_no_output(tmp_path, capsys, extra):
    """A converted scene whose map lies 2 km from the target: nothing to place an adversary on."""
    from coster_sumo.converters.to_sumo import convert_scene

    from coster_sumo.data import synthetic
    from coster_sumo.formats.scene_file import load_scene, save_scene

    folder = convert_scene(synthetic.two_lane_road(), tmp_path).folder
    scene = load_scene(folder / "scene.npz")
    scene.road_map.lanes.centerline.values[:, 1] += 2000.0
    save_scene(scene, folder / "scene.npz")
    (cfg,) = folder.glob("*.sumocfg")
    out = tmp_path / "out"
    assert main(["-q", "run", str(cfg), "-o", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and cfg.name in err and "no lanes near the target" in err
    assert not out.exists() and not list(tmp_path.glob(".out*"))


def test_several_targets_share_one_pass(tmp_path, capsys):
    """`--target` repeated: one folder per target laid out as a one-target run, every variant in
    contact at its t_col, and a target without a scenario listed with its reason while the others
    go on."""
    rc, out = _run(tmp_path, "--seed", "2", "--no-render", "--planner", "replay", "--target", "ego",
                   "--target", "pre_W.1", "--target", "nobody")
    assert rc == 0
    printed = capsys.readouterr().out
    assert "target ego: t_col = " in printed and "target pre_W.1: t_col = " in printed
    assert "target nobody: no scenario (" in printed and "never runs in the window" in printed
    listed = json.loads((out / "summary.json").read_text())
    assert [t["target"] for t in listed["targets"]] == ["ego", "pre_W.1", "nobody"]
    assert "error" in listed["targets"][2] and not (out / "nobody").exists()
    assert listed["options"]["more_targets"] == ["pre_W.1", "nobody"]
    for entry in listed["targets"][:2]:
        one = json.loads((out / entry["folder"] / "summary.json").read_text())
        assert one["target"] == entry["target"] and one["num_variants"] == entry["num_variants"] >= 1
        assert one["t_col"] == entry["t_col"]
        for v in one["variants"]:
            assert v["collision"] and abs(v["contact_offset_s"]) <= 0.1 + 1e-6, (entry["target"], v)
            assert (out / entry["folder"] / "variants" / str(v["variant"]) / "export" / "variant.json").exists()
    assert not list(tmp_path.glob(".out.*")), "staging folder left behind"


def test_several_targets_need_ids(tmp_path, capsys):
    from coster_sumo.core.spec import ScenarioSpec
    from coster_sumo.errors import InputError
    from coster_sumo.pipeline.run import RunOptions, run

    spec = ScenarioSpec(REPO / "networks/intersection/intersection.sumocfg", seed=0, end=45.0)
    with pytest.raises(InputError, match="every one needs an id"):
        run(RunOptions(spec=spec, out=tmp_path / "out", more_targets=("ego",)))


def test_target_folders_are_distinct_and_file_name_safe():
    from coster_sumo.pipeline.run import target_folder

    taken = {"summary.json"}
    names = [target_folder(t, taken) for t in ("a/b", "a_b", "summary.json", "..", "veh 1")]
    assert names == ["a_b", "a_b_1", "summary.json_1", "target", "veh_1"]
    assert len(set(names)) == len(names)
