"""Defects in a batch: labels proven in SUMO, the escape planner scores no defect, the report leads
with the defect rate (coster_sumo.avoidability.labels, regress, run)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from coster_sumo.avoidability.evasion import Avoidability
from coster_sumo.avoidability.labels import acted_after_threat, both_clause, label_line
from coster_sumo.batch.store import ResultStore
from coster_sumo.batch.summaries import defect_rates
from coster_sumo.cli.command_line import main
from coster_sumo.core.scene import Scene, SignalStates
from coster_sumo.data import synthetic
from coster_sumo.metrics import RunOutcome

REPO = Path(__file__).resolve().parents[2]
NETWORKS = [REPO / "networks" / n / f"{n}.sumocfg" for n in ("intersection", "merge")]


def _row(avoidable: bool | None, collision: bool, in_horizon: bool | None = None) -> RunOutcome:
    return RunOutcome(avoidable=avoidable, target_collision=collision, contact_in_horizon=in_horizon,
                      route_completed=not collision)


def test_defect_rate_counts_contacts_in_avoidable_variants_only():
    rows = [_row(True, True), _row(True, False), _row(True, True, in_horizon=False),  # a late contact is no defect
            _row(False, True), _row(False, True), _row(None, True)]
    d = defect_rates(rows)
    assert (d.defect_rate.k, d.defect_rate.n) == (1, 3)
    assert (d.unavoidable_contact_rate.k, d.unavoidable_contact_rate.n) == (2, 2)
    assert d.unlabelled_runs == 1
    assert 0.0 <= (d.defect_rate.ci_low or 0.0) < 1 / 3 < (d.defect_rate.ci_high or 0.0) <= 1.0
    assert d.unavoidable.CR.k == 2 and d.avoidable.RCR.k == 1


def test_label_line_says_why():
    lab = Avoidability(t_col=20.0, t_appear=16.0, t_threat=18.0, contact_kind="rear_end_by_adversary",
                       vehicle_class="car", last_moment_s=None, escapes={0.5: None, 1.0: None}, reaction_time_s=1.0)
    assert label_line(lab) == "unavoidable (no escape from a reaction of 1 s after the threat), rear end by adversary"


def test_a_variant_the_target_avoided_but_the_reference_driver_could_not_says_both():
    lab = Avoidability(t_col=20.0, t_appear=16.0, t_threat=18.0, contact_kind="rear_end_by_adversary",
                       vehicle_class="car", last_moment_s=None, escapes={0.5: None, 1.0: None}, reaction_time_s=1.0)
    t = np.round(np.arange(150, 220) * 0.1, 6)
    speed = np.where(t < 18.3, 10.0, np.maximum(10.0 - 4.0 * (t - 18.3), 0.0))  # brakes 0.3 s after the threat
    x = np.concatenate([[0.0], np.cumsum(speed[:-1] * 0.1)])
    tracks = synthetic._tracks([("ego", x, np.zeros(len(t)), np.zeros(len(t)), 10.0)], steps=len(t))
    tracks = dataclasses.replace(tracks, vx=speed[None].copy())
    scene = Scene(scenario_id="s", timestamps=t, tracks=tracks, road_map=synthetic.two_lane_road().road_map,
                  signals=SignalStates.empty(len(t)), sdc_index=0, source="synthetic")
    acted = acted_after_threat(scene, "ego", lab)
    assert acted == pytest.approx(0.3, abs=0.051)
    assert both_clause(lab, acted) == ("unavoidable for a driver reacting 1 s after the threat; this target acted "
                                       "0.3 s after the threat, rear end by adversary")


@pytest.mark.sumo
@pytest.mark.slow
def test_the_escape_planner_scores_no_defect_on_every_avoidable_variant_of_a_batch(tmp_path):
    out = tmp_path / "reg"
    argv = ["-q", "regress", *map(str, NETWORKS), "--variants", "3", "--planner", "escape", "--planner", "replay",
            "--workers", "2", "-o", str(out)]
    assert main(argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    escape = summary["planners"]["escape"]["defects"]
    assert escape["avoidable_runs"] >= 1  # the batch has avoidable variants (2 of 5 when this was written)
    assert escape["defect_rate"]["k"] == 0
    assert escape["unlabelled_runs"] == 0
    # every avoidable label stands on an escape SUMO confirmed; the replay planner (nominal path)
    # hits every variant at t_col, avoidable ones included: defects it has
    for doc in map(lambda p: json.loads(p.read_text()), (out / "plans").glob("*.json")):
        for lab, esc in zip(doc["avoidability"], doc["escapes"], strict=True):
            assert lab["avoidable"] == (esc is not None)
            if lab["avoidable"]:
                assert any(e and e["proven_in_sumo"] for e in lab["escapes"].values())
    replay = summary["planners"]["replay"]["defects"]
    assert replay["defect_rate"]["k"] == replay["avoidable_runs"]
    rows = ResultStore(out / "results").read()
    assert all(str(r.outcome).startswith("avoided") for r in rows if r.planner == "escape" and r.avoidable)
    report = (out / "report.md").read_text()
    assert report.index("## Defects") < report.index("RCR: route completion rate")


@pytest.mark.sumo
@pytest.mark.slow
def test_run_labels_every_variant_and_avoidable_only_keeps_the_avoidable(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", str(NETWORKS[0]), "--planner", "replay", "--no-render", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    for v in summary["variants"]:
        lab = v["avoidability"]
        assert set(lab["avoidable_at"]) == {"0.5", "1", "1.5"}
        assert v["label"] in printed
        assert (out / "variants" / str(v["variant"]) / "escape.csv").exists() == lab["avoidable"]
    n_avoidable = summary["avoidable_variants"]
    assert n_avoidable >= 1
    only = tmp_path / "only"
    assert main(["run", str(NETWORKS[0]), "--planner", "replay", "--no-render", "--avoidable", "only",
                 "-o", str(only)]) == 0
    s2 = json.loads((only / "summary.json").read_text())
    assert all(v["avoidability"]["avoidable"] for v in s2["variants"])
    assert s2["avoidable_only"]["tried"] >= len(s2["variants"]) >= n_avoidable


@pytest.mark.sumo
@pytest.mark.slow
def test_the_api_labels_every_plan_and_keeps_only_avoidable_ones_when_asked():
    from coster_sumo.api import plan_adversaries

    planned = plan_adversaries(NETWORKS[0], seed=0, variants=5, avoidable="only")
    labels = planned.info["avoidability"]
    assert planned.plans and set(labels) == {p.vehicle_id for p in planned.plans}
    assert all(lab["avoidable"] for lab in labels.values())
    assert planned.info["avoidable_only"]["tried"] >= len(planned.plans)


@pytest.mark.sumo
@pytest.mark.slow
def test_regress_avoidable_only_replaces_unavoidable_variants_and_says_how_many_were_tried(tmp_path, capsys):
    out = tmp_path / "only"
    assert main(["regress", str(NETWORKS[0]), "--planner", "sumo", "--variants", "3", "--avoidable", "only",
                 "-o", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    (doc,) = [json.loads(p.read_text()) for p in (out / "plans").glob("*.json")]
    assert all(a["avoidable"] for a in doc["avoidability"]) and doc["avoidability"]
    assert summary["variants_tried"] == doc["avoidable_only"]["tried"] >= summary["variants"]
    assert summary["planners"]["sumo"]["defects"]["unavoidable_runs"] == 0
    if summary["variants_tried"] != summary["variants"]:
        assert f"of {summary['variants_tried']} tried" in capsys.readouterr().out


def test_the_labels_moved_by_reacting_traffic_reach_eval_scenarios_table():
    from coster_sumo.avoidability.labels import avoidability_table
    from coster_sumo.batch.generator_summary import AvoidabilityStats

    def rec(flipped: bool, tried: int, cleared: int) -> dict:
        return {"avoidable": flipped, "avoidable_at": {"1": flipped}, "escape_found_at": {"1": False},
                "contact_kind": "into_vehicle_ahead", "last_moment_s": None, "threat_before_tcol_s": 2.0,
                "blocked_tried": tried, "blocked_cleared": cleared, "flipped_by_reacting_traffic": flipped}

    table = avoidability_table([rec(True, 2, 1), rec(False, 4, 0), rec(False, 0, 0), rec(False, 0, 0)])
    assert table["labels_flipped_by_reacting_traffic"] == {"count": 1, "share": 0.25}
    stats = AvoidabilityStats.from_json(json.loads(json.dumps(table)))
    assert stats.to_json()["blocked_escapes_tried_in_sumo"] == 6
    assert stats.moved_cell() == "1 (25.0 %; 1 of 6 blocked escapes cleared)"
