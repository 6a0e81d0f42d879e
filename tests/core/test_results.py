"""A run's results as objects: the JSON of summary.json round-trips through them unchanged."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from coster_sumo.core.results import RunSummary, TargetEntry, TargetResult, VariantOutcome, read_run
from coster_sumo.errors import InputError


def _variant(i: int, collision: bool) -> dict:
    return {"variant": i, "adversary_id": f"adversary{i}", "adversary_class": "vehicle", "plan_start_s": 10.0,
            "approach_m": 41.2,
            "collision": collision, "collision_time": 15.0 if collision else None,
            "contact_offset_s": 0.0 if collision else None, "relative_speed": 7.5 if collision else None,
            "impact_angle": 30.0 if collision else None, "no_contact_reason": None if collision else "braked",
            "closest_distance_m": 0.0, "adversary_off_road": False, "target_off_road": False,
            "route_completed": not collision, "target_arrived": False, "min_ttc": None, "other_collisions": 0,
            "other_collisions_list": [], "sumo_only_collisions": 0, "sumo_reported_contact": collision,
            "wall_time_s": 1.2, "snapshot": 0, "t_col": 15.0, "label": "avoidable (1.0 s)"}


def _summary() -> dict:
    """A summary.json as this version writes it (every key, in its order)."""
    generation = {"failed": [{"candidate": "adversary2", "t_col": 15.0, "reason": "crashed"}]}
    return {"target": "ego", "config": "a.sumocfg", "planner": "replay", "seed": 0, "t_col": 15.0,
            "num_snapshots": 1, "num_variants": 2, "collision_rate": 0.5, "off_road_rate": 0.0,
            "impact_angle_spread_deg": 0.0, "variants": [_variant(0, True), _variant(1, False)],
            "snapshots": [{"snapshot": 0, "t_col": 15.0, "t_col_sim": 15.0, "t_col_index_2hz": 30,
                           "collision_time_method": "entropy", "init_method": "snapshot", "signed_distance": -0.1,
                           "adversary": {"x": 1.0, "y": 2.0, "heading_deg": 90.0, "speed": 5.0, "length": 4.5,
                                         "width": 1.8},
                           "variants": [0, 1], "generation": generation, "impact_angles_deg": [30.0],
                           "adversary_class": "vehicle"}],
            "scenario_id": "a", "t_col_sim": 15.0, "t_col_index_2hz": 30, "collision_time_method": "entropy",
            "init_method": "snapshot", "snapshot_signed_distance": -0.1, "nominal_until_s": 40.0,
            "target_motion": {"in_window_s": 40.0, "stopped_s": 0.0, "distance_m": 300.0},
            "generation": generation, "timings_s": {"nominal_s": 1.0}, "options": {"variants": 2},
            "renders": ["overview.png"], "avoidable_only": {"tried": 3, "kept": 2, "extra_draws": 1},
            "adversary": "vehicle",
            "avoidable_variants": 2, "reaction_time_s": 1.0, "defects": 1, "unavoidable_contacts": 0,
            "avoidable_share": 1.0}


def test_a_target_result_round_trips_its_summary():
    d = _summary()
    result = TargetResult.from_json(d, Path("out"))
    assert result.to_json() == d and list(result.to_json()) == list(d)  # the same keys in the same order
    assert result.variants[0].collision and result.variants[1].no_contact_reason == "braked"
    assert result.variants[0].label == "avoidable (1.0 s)" and result.variants[0].to_json() == _variant(0, True)
    assert [f["candidate"] for f in result.failed] == ["adversary2"]
    assert result.avoidable_only is not None and result.avoidable_only.extra_draws == 1
    assert result.labels is not None and result.labels.defects == 1
    assert result.target_motion.distance_m == 300.0


def test_a_summary_without_the_optional_keys_leaves_them_out():
    d = _summary()
    for key in ("avoidable_only", "avoidable_variants", "reaction_time_s", "defects", "unavoidable_contacts",
                "avoidable_share"):
        del d[key]
    result = TargetResult.from_json(d, Path("out"))
    assert result.labels is None and result.avoidable_only is None
    assert result.to_json() == d


def test_a_run_with_several_targets_lists_each_with_its_result_or_reason():
    one = TargetResult.from_json(_summary(), Path("out/ego"))
    run = RunSummary(Path("out"), "a.sumocfg", (TargetEntry("ego", "ego", result=one, extra={"t_col": 15.0}),
                                                TargetEntry("veh1", error="no snapshot")), extra={"options": {}})
    d = run.to_json()
    assert d["num_targets"] == 2 and d["targets"][1] == {"target": "veh1", "error": "no snapshot"}
    assert RunSummary.from_json(d, Path("out")).to_json() == d
    assert run.results == [one]


def test_reading_a_folder_that_is_no_run_is_one_line(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_run(tmp_path)
    (tmp_path / "summary.json").write_text('{"jobs": []}')
    with pytest.raises(InputError, match="not the summary of a `coster-sumo run` output"):
        read_run(tmp_path)
    # a summary whose records have the wrong shape (edited by hand, or cut short) is one line too
    for key, value in (("target_motion", None), ("avoidable_only", {"tried": 1}), ("variants", [3])):
        (tmp_path / "summary.json").write_text(json.dumps({**_summary(), key: value}))
        with pytest.raises(InputError, match=r"summary.json: not the summary of a `coster-sumo run` output \("):
            read_run(tmp_path)
    (tmp_path / "summary.json").write_text(json.dumps({"config": "a.sumocfg", "targets": [{"folder": "x"}]}))
    with pytest.raises(InputError, match="KeyError"):
        read_run(tmp_path)


def test_an_outcome_keeps_unknown_keys():
    v = VariantOutcome.from_json({**_variant(0, True), "new_key": 1})
    assert v.extra["new_key"] == 1 and v.to_json()["new_key"] == 1
