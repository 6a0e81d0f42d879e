"""Outcomes that explain themselves (issue 42, first bullet of "Why"): on a SUMO scenario the
project did not write, every variant asked for and missing, and every variant without contact,
has its one-line reason on the console, in summary.json and in the API's result; renders draw
what SUMO drove."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from coster_sumo.cli.command_line import main
from coster_sumo.method.generation import PlannedScenario
from coster_sumo.pipeline import outputs

pytestmark = pytest.mark.sumo


def _sumo_game(name: str) -> Path:
    import sumo

    return Path(sumo.__file__).parent / "tools" / "game" / f"{name}.sumocfg"


def test_ramp_every_missing_variant_and_every_miss_has_its_reason(tmp_path, capsys, monkeypatch):
    """The wheel's ramp with the shipped weights kept 1 of 5 variants and printed a bare "no
    contact"; the adversary had hit highway1.18 and 6 collisions followed, which the console did not say."""
    cfg = _sumo_game("ramp")
    if not cfg.is_file():
        pytest.skip(f"{cfg} not in this SUMO build")
    real = outputs.viz.render_variant
    log = tmp_path / "drawn.jsonl"  # run works in a child process: the spy reports through a file

    def spy(path, scene, *args, **kwargs):  # type: ignore[no-untyped-def]
        with log.open("a") as fh:
            fh.write(json.dumps([str(args[2]), scene.tracks.ids.tolist()]) + "\n")
        return real(path, scene, *args, **kwargs)

    monkeypatch.setattr(outputs.viz, "render_variant", spy)
    out = tmp_path / "ramp"
    rc = main(["-q", "run", str(cfg), "--target", "onramp.3", "--duration", "120", "-o", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    asked = summary["options"]["variants"]
    dropped = summary["snapshots"][0]["generation"]["dropped"]
    # every candidate asked for is a variant or a dropped line with its reason
    assert len(summary["variants"]) + len(dropped) == asked
    for d in dropped:
        assert d["reason"] and re.search(rf"dropped .*{re.escape(d['reason'])}", printed)
    if len(summary["variants"]) < asked:
        assert f"{len(summary['variants'])} of {asked} variants kept" in printed
    for v in summary["variants"]:
        line = next(x for x in printed.splitlines() if x.startswith(f"  variant {v['variant']}: "))
        if not v["collision"]:
            assert v["no_contact_reason"] and f"no contact: {v['no_contact_reason']}" in line
            assert v["closest_distance_m"] is not None
        if v["other_collisions"]:
            assert f"{v['other_collisions']} other collision" in line
            assert len(v["other_collisions_list"]) == v["other_collisions"]
    # the renders draw the injection pass (not the nominal scene) and say so
    drawn = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
    assert drawn and all("as driven in SUMO" in title for title, _ in drawn)
    assert all(any(str(i).startswith("adversary") for i in ids) for _, ids in drawn)


def test_dropped_lines_name_every_candidate_with_its_reason():
    planned = PlannedScenario(scene=None, scene_2hz=None, target_index=0, snapshot=None, plans=[],  # type: ignore[arg-type]
                              info={"dropped": [{"candidate": 3, "reason": "would hit the target at 20.1 s"},
                                                {"candidate": "cluster 1", "reason": "its one trajectory is off"}]})
    assert planned.dropped == ["candidate 3: would hit the target at 20.1 s",
                               "cluster 1: its one trajectory is off"]


def test_cluster_without_usable_member_is_reported():
    from coster_sumo.rollout import sample as S

    # two clusters of straight paths (1 at 10 m/s, 5 at 2 m/s); an off-road rule that refuses y > 5; with
    # fewer usable samples than clusters all of them are clustered, so the second yields nothing
    t = np.linspace(-4.5, 0.0, 10)
    a = np.stack([np.stack([10 * t, np.zeros_like(t), np.zeros_like(t)], 1)])
    b = np.stack([np.stack([2 * t, np.full_like(t, 10.0 + 0.01 * k), np.zeros_like(t)], 1) for k in range(5)])
    rejected: list[dict] = []
    reps = S.select_representatives(np.concatenate([a, b]), k=2, seed=0, size=(4.6, 1.9),
                                    drivable=lambda x, y, yaw, length, width: np.asarray(y) > 5.0,
                                    rejected=rejected)
    assert len(reps) == 1 and len(rejected) == 1
    assert rejected[0]["members"] == 5 and "5 leave the road" in rejected[0]["reason"]


@pytest.mark.slow
def test_quiet_regress_keeps_its_failure_lines_and_the_html_report_says_what_the_markdown_says(
        tmp_path, capsys, recwarn):
    """`-q regress` with a failed run printed nothing but two matplotlib legend warnings; report.html
    dropped the metric definitions, the examples' captions and the "no failure" line."""
    import html as html_lib
    import warnings

    warnings.simplefilter("always")
    repo = Path(__file__).resolve().parents[2]
    out = tmp_path / "reg"
    rc = main(["-q", "regress", str(repo / "networks/intersection/intersection.sumocfg"), "--end", "40",
               "--init", "random", "--rollout", "cv", "--variants", "1", "--planner", "replay",
               "--planner", "tests.misbehaving_planners:Abort", "--timeout", "60", "-o", str(out)])
    assert rc == 1
    printed = capsys.readouterr().out
    assert re.search(r"run failed: \S+Abort: .*SIGABRT", printed), printed
    assert "1 failed" in printed and "replay" in printed  # the table and the count stay
    assert not [w for w in recwarn if "No artists with labels" in str(w.message)]
    md = (out / "report.md").read_text()
    page = html_lib.unescape(re.sub(r"<[^>]+>", " ", (out / "report.html").read_text()))
    def words(text: str) -> str:  # tags became spaces: compare words and punctuation only
        return re.sub(r"\s+([:.,;)])", r"\1", " ".join(text.split()))

    page = words(page)
    for line in md.splitlines():
        text = re.sub(r"!\[[^]]*\]\([^)]*\)|`|^#+ |^- ", "", line).strip()
        if text and not text.startswith("|"):
            assert words(text) in page, text


def test_outputs_name_their_units_carry_nulls_and_round_times(tmp_path, capsys):
    """trajectory.csv had yaw_deg beside trajectories.csv's radians, off-road events carried
    relative_speed 0.0 and impact_angle 0.0, summary.json t_col 2.20003, and --targets' choice
    was only under options where the README says target_choice; the variants' console lines were
    identical with nothing to tell them apart."""
    from coster_sumo.sim.events import Event

    repo = Path(__file__).resolve().parents[2]
    out = tmp_path / "o"
    assert main(["-q", "run", str(repo / "networks/intersection/intersection.sumocfg"), "--targets", "1",
                 "--init", "random", "--rollout", "cv", "--end", "45", "--variants", "3", "--no-render",
                 "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["target_choice"] and summary["target_choice"] == summary["options"]["target_choice"]
    for key in ("t_col", "t_col_sim"):
        assert summary[key] == round(summary[key], 3)
    assert summary["snapshot_signed_distance"] == round(summary["snapshot_signed_distance"], 3)
    lines = [x for x in printed.splitlines() if x.startswith("  variant ")]
    assert lines and all(" approach " in x for x in lines)
    assert len(set(lines)) == len(lines)
    vdir = out / "variants" / "0"
    assert (vdir / "trajectory.csv").read_text().splitlines()[0] == "time_s,vehicle,x_m,y_m,heading_deg,speed_mps"
    head = (vdir / "trajectories.csv").read_text().splitlines()[0].split(",")
    assert "heading_deg" in head and all(c in ("vehicle", "type", "vclass")
                                         or c.rsplit("_", 1)[-1] in ("s", "m", "deg", "mps") for c in head)
    for line in (out / "events.jsonl").read_text().splitlines():
        e = json.loads(line)
        assert e["time"] == round(e["time"], 3)
        if e["kind"] == "off_road":
            assert e["relative_speed"] is None and e["impact_angle"] is None
    off = Event(time=1.0, kind="off_road", vehicles=["a"], positions=[[0.0, 0.0]]).to_dict()
    assert off["relative_speed"] is None and off["impact_angle"] is None


def test_an_error_after_a_progress_bar_starts_its_own_line_in_a_log(tmp_path, capsys):
    """In a log (stderr not a terminal) a closed bar's clearing is just characters on its line:
    the error that followed landed on the bar's line."""
    cfg = _sumo_game("square")  # no 'ego': the pass runs, then the run stops naming candidates
    if not cfg.is_file():
        pytest.skip(f"{cfg} not in this SUMO build")
    assert main(["run", str(cfg), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    errors = [line for line in err.split("\n") if "coster-sumo: error:" in line]
    assert len(errors) == 1 and errors[0].startswith("coster-sumo: error: "), err[-300:]


def test_quiet_keeps_the_one_line_result_of_replay(tmp_path, capsys):
    repo = Path(__file__).resolve().parents[2]
    out = tmp_path / "r"
    assert main(["-q", "replay", str(repo / "networks/intersection/intersection.sumocfg"), "--end", "3",
                 "-o", str(out)]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert len(printed) == 1 and "steps to t=3.0 s" in printed[0]
    assert (out / "summary.json").is_file()


def test_overview_has_a_legend_for_every_mark_and_paths_above_the_boxes(tmp_path, monkeypatch):
    """The demo's overview had no legend for its heat map, dashed ellipse and boxes, and two
    variants' short paths were hidden under the boxes."""
    from coster_sumo.core.snapshot import AgentState
    from coster_sumo.data import synthetic
    from coster_sumo.pipeline import viz

    scene = synthetic.two_lane_road()
    tr = scene.tracks
    target_state = AgentState.from_tracks(tr, 0, 10)
    reps = [np.stack([tr.x[0, 5:11] + d, tr.y[0, 5:11]], 1) for d in (0.0, 3.0)]
    samples = np.stack([r for r in reps for _ in range(5)])
    figures = []
    monkeypatch.setattr(viz.plt, "close", figures.append)
    viz.render_overview(tmp_path / "o.png", scene, 0, viz.CollisionMoment(1.0, 10, target_state), reps, samples)
    ax = figures[0].axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert {"variant 0", "variant 1", "target at t_col", "other vehicles at t_col",
            "ellipse of the collision-time regions", "where a variant starts"} <= set(labels)
    assert any(label.startswith("density of the 10 oversampled paths") for label in labels)
    boxes = max(p.get_zorder() for p in ax.patches)
    assert all(line.get_zorder() > boxes for line in ax.get_lines() if line.get_label().startswith("variant"))


def test_generation_is_not_silent(tmp_path, capfd):
    """The console said nothing for about 10 s while the adversaries were generated."""
    repo = Path(__file__).resolve().parents[2]
    assert main(["run", str(repo / "networks/intersection/intersection.sumocfg"), "--init", "random",
                 "--rollout", "cv", "--end", "45", "--variants", "1", "--no-render", "-o", str(tmp_path / "o")]) == 0
    assert "generation (ego)" in capfd.readouterr().err  # the bar is drawn by run's child process
