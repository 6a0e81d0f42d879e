"""A run's results as objects: the JSON of summary.json round-trips through them unchanged."""

from __future__ import annotations

from pathlib import Path

import pytest

from coster_sumo.errors import InputError
from coster_sumo.results import RunSummary, TargetEntry, TargetResult, VariantOutcome, plain_json, read_run


def _variant(i: int, collision: bool) -> dict:
    return {"variant": i, "adversary_id": f"adversary{i}", "plan_start_s": 10.0, "approach_m": 41.2,
            "collision": collision, "collision_time": 15.0 if collision else None,
            "contact_offset_s": 0.0 if collision else None, "relative_speed": 7.5 if collision else None,
            "impact_angle": 30.0 if collision else None, "no_contact_reason": None if collision else "braked",
            "closest_distance_m": 0.0, "adversary_off_road": False, "target_off_road": False,
            "route_completed": not collision, "target_arrived": False, "min_ttc": None, "other_collisions": 0,
            "other_collisions_list": [], "sumo_only_collisions": 0, "sumo_reported_contact": collision,
            "wall_time_s": 1.2, "snapshot": 0, "t_col": 15.0, "label": "avoidable (1.0 s)"}


def _summary() -> dict:
    return {"config": "a.sumocfg", "scenario_id": "a", "target": "ego", "planner": "replay", "seed": 0,
            "t_col": 15.0, "num_snapshots": 1, "num_variants": 2, "collision_rate": 0.5, "off_road_rate": 0.0,
            "impact_angle_spread_deg": 0.0, "variants": [_variant(0, True), _variant(1, False)],
            "snapshots": [{"snapshot": 0, "t_col": 15.0, "generation": {"failed": [{"candidate": "adversary2",
                                                                                      "t_col": 15.0,
                                                                                      "reason": "crashed"}]}}],
            "timings_s": {"nominal_s": 1.0}, "defects": 0}


def test_a_target_result_round_trips_its_summary():
    d = _summary()
    result = TargetResult.from_json(d, Path("out"))
    assert result.to_json() == d
    assert result.variants[0].collision and result.variants[1].no_contact_reason == "braked"
    assert result.variants[0].extra == {"label": "avoidable (1.0 s)"}  # what later steps add is kept
    assert [f["candidate"] for f in result.failed] == ["adversary2"]


def test_a_run_with_several_targets_lists_each_with_its_result_or_reason():
    one = TargetResult.from_json(_summary(), Path("out/ego"))
    run = RunSummary(Path("out"), "a.sumocfg", (TargetEntry("ego", "ego", result=one, extra={"t_col": 15.0}),
                                                TargetEntry("veh1", error="no snapshot")), extra={"options": {}})
    d = run.to_json()
    assert d["num_targets"] == 2 and d["targets"][1] == {"target": "veh1", "error": "no snapshot"}
    assert RunSummary.from_json(d, Path("out")).to_json() == d
    assert run.results == [one]


def test_plain_json_is_what_a_reader_of_the_file_gets():
    import numpy as np

    assert plain_json({"a": np.float64(1.5), "b": (1, 2), "c": Path("x")}) == {"a": 1.5, "b": [1, 2], "c": "x"}


def test_reading_a_folder_that_is_no_run_is_one_line(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_run(tmp_path)
    (tmp_path / "summary.json").write_text('{"jobs": []}')
    with pytest.raises(InputError, match="not the summary of a `coster-sumo run` output"):
        read_run(tmp_path)


def test_an_outcome_keeps_unknown_keys():
    v = VariantOutcome.from_json({**_variant(0, True), "new_key": 1})
    assert v.extra["new_key"] == 1 and v.to_json()["new_key"] == 1
