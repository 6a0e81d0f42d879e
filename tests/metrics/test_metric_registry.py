"""The metrics' registry: one typed signature, and ``run``, ``regress`` and ``eval scenarios`` take
their figures from it (coster_sumo.metrics.REGISTRY)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from coster_sumo import metrics
from coster_sumo.batch.evaluate import GeneratorMethod, aggregate_generator_metrics, part_key
from coster_sumo.batch.generator_summary import GeneratorResult
from coster_sumo.batch.regress import summarize_regression
from coster_sumo.batch.store import ResultStore, result_row
from coster_sumo.core.results import VariantOutcome
from coster_sumo.core.spec import ScenarioSpec
from coster_sumo.metrics import Metric, MetricSample, MetricValue, RunOutcome
from coster_sumo.pipeline.outputs import run_metrics


def _contact(scene: str, speed: float, angle: float) -> RunOutcome:
    return RunOutcome(scene=scene, adversary_contact=True, target_collision=True, relative_speed=speed,
                      impact_angle=angle)


def _fixed(name: str, value: float) -> Metric:
    """A stand-in for a registered metric: every sample scores ``value``."""
    return Metric(name, "fraction", "a stand-in", lambda s: MetricValue(value, value, value, 1, 1))


def test_every_registered_metric_has_its_name_and_one_typed_signature():
    sample = MetricSample((_contact("a", 5.0, 10.0), RunOutcome(scene="b", adversary_off_road=True)),
                          scenes=("a", "b"), nominal_speed_hist=np.ones(100), generated_speed_hist=np.ones(100))
    assert {"SUR", "CR", "ORR", "VDD", "ADD", "CSD", "CPD"} <= set(metrics.REGISTRY)
    for name, metric in metrics.REGISTRY.items():
        assert metric.name == name and metric.unit and metric.description
        assert isinstance(metric.compute(sample), MetricValue)


def test_rates_are_the_plain_functions_with_their_wilson_interval():
    sample = MetricSample((_contact("a", 5.0, 10.0), RunOutcome(scene="a"), RunOutcome(scene="b")),
                          scenes=("a", "b", "c"))
    cr = metrics.compute("CR", sample)
    assert cr.value == metrics.collision_rate([True, False, False]) and (cr.k, cr.n) == (1, 3)
    assert (cr.ci_low, cr.ci_high) == metrics.wilson_interval(1, 3)
    sur = metrics.compute("SUR", sample)  # one scene of three has a contact
    assert sur.value == metrics.success_rate(3, 1) and (sur.k, sur.n) == (1, 3)
    assert metrics.compute("CR", MetricSample()).rate_json() == {"rate": None, "ci_low": None, "ci_high": None,
                                                                 "k": 0, "n": 0}


def test_diversity_interval_resamples_scenes():
    sample = MetricSample((_contact("a", 2.0, 0.0), _contact("a", 4.0, 10.0), _contact("b", 9.0, 90.0)),
                          scenes=("a", "b"))
    csd = metrics.compute("CSD", sample)
    assert csd.value == pytest.approx(np.std([2.0, 4.0, 9.0]))
    assert (csd.value, csd.ci_low, csd.ci_high) == pytest.approx(metrics.scene_bootstrap(
        metrics.collision_speed_diversity, [np.array([2.0, 4.0]), np.array([9.0])]))
    assert metrics.compute("CSD", MetricSample(scenes=("a",))).value is None  # no contact


def test_run_summary_takes_its_rates_from_the_registry(monkeypatch):
    variants = [VariantOutcome(0, collision=True, relative_speed=3.0, impact_angle=20.0),
                VariantOutcome(1, adversary_off_road=True, min_ttc=1.5)]
    assert run_metrics(variants) == {"collision_rate": 0.5, "off_road_rate": 0.5, "impact_angle_spread_deg": 0.0}
    monkeypatch.setitem(metrics.REGISTRY, "CR", _fixed("CR", 0.25))
    assert run_metrics(variants)["collision_rate"] == 0.25


def _write_rows(out: Path) -> dict[str, ScenarioSpec]:
    store = ResultStore(out / "results")
    for i, (contact, other) in enumerate([(True, False), (False, True), (False, False)]):
        payload = {"run_key": f"s__v{i}__replay", "scene_key": "s", "variant": i, "planner": "replay"}
        store.write(result_row(payload, status="ok", reason="", collision=contact or other, adversary_contact=contact,
                               target_off_road=False, adversary_off_road=False, route_completed=not contact,
                               relative_speed=6.0 if contact else None, min_ttc=None if contact else 2.0 + i,
                               avoidable=i == 0))
    return {"s": ScenarioSpec(Path("net.sumocfg"))}


def test_regress_takes_its_rates_from_the_registry(tmp_path, monkeypatch):
    keys = _write_rows(tmp_path)
    p = summarize_regression(tmp_path, keys, ["replay"]).planners["replay"]
    # CR: the target touched anyone (2 of 3); adversary contact: 1 of 3
    assert (p.CR.k, p.adversary_contact_rate.k, p.RCR.k) == (2, 1, 2)
    assert p.median_min_ttc_s == 3.5 and p.mean_relative_speed_mps == 6.0
    assert (p.defects.defect_rate.k, p.defects.defect_rate.n) == (1, 1)
    monkeypatch.setitem(metrics.REGISTRY, "CR_target", _fixed("CR_target", 0.125))
    p = summarize_regression(tmp_path, keys, ["replay"]).planners["replay"]
    assert p.CR.value == 0.125 and p.defects.avoidable.CR.value == 0.125
    assert p.adversary_contact_rate.k == 1  # another metric: not replaced


def test_eval_scenarios_takes_its_figures_from_the_registry(tmp_path, monkeypatch):
    method = GeneratorMethod("Random+CV", "random", "cv", "last")
    hist = {"speed_hist": [1] * 100, "accel_hist": [1] * 200}
    (tmp_path / "s__scene.json").write_text(json.dumps({"status": "ok", **hist,
                                                        "speed_hist_by_lane_type": {"FREEWAY": [1] * 100}}))
    records = [{"variant": i, "collision": i < 2, "adversary_off_road": False, "relative_speed": [3.0, 7.0, None][i],
                "impact_angle": [10.0, -30.0, None][i], "t_col": 5.0, "adversary_speed": 20.0 + i,
                "adversary_length": 4.5, "adversary_width": 1.9, "adversary_lane_type": "FREEWAY"} for i in range(3)]
    (tmp_path / f"{part_key('s', method.name, 3, 'w')}.json").write_text(json.dumps(
        {"status": "ok", "records": records, "generation_s": 3.0, "scene_key": "s", **hist}))
    keys = {"s": ScenarioSpec(Path("net.sumocfg"))}

    def table() -> GeneratorResult:
        return aggregate_generator_metrics(tmp_path, keys, [method], {}, 3, "w").ran[method.name]

    m = table()
    assert (m.SUR.value, m.CR.value, m.ORR.value) == (1.0, pytest.approx(2 / 3), 0.0)
    assert m.CSD.value == pytest.approx(2.0) and m.VDD == 0.0 and m.size_in_class == 1.0
    assert m.adversaries_by_lane_type == {"FREEWAY": 3} and m.VDD_tcol is not None
    written = json.dumps(m.to_json())  # the rates' k and n are not in the file: the JSON round-trips
    assert json.dumps(GeneratorResult.from_json(method.name, json.loads(written)).to_json()) == written
    monkeypatch.setitem(metrics.REGISTRY, "CSD", Metric("CSD", "m/s", "a stand-in",
                                                        lambda s: MetricValue(42.0, 40.0, 44.0)))
    m = table()
    assert m.CSD == MetricValue(42.0, 40.0, 44.0) and m.to_json()["CSD_ci"] == [40.0, 44.0]


def test_regression_summary_round_trips_through_its_json(tmp_path):
    from coster_sumo.batch.summaries import RegressionSummary

    summary = summarize_regression(tmp_path, _write_rows(tmp_path), ["replay"])
    doc = json.loads(json.dumps(summary.to_json()))
    assert RegressionSummary.from_json(doc) == summary
    assert doc["runs"] == {"expected": 0, "recorded": 3, "ok": 3, "failed": 0, "failures": []}
    assert doc["planners"]["replay"]["defects"]["by_label"]["avoidable"]["CR"]["k"] == 1


def test_eval_summary_round_trips_through_its_json_and_skipped_methods_keep_their_reason(tmp_path):
    from coster_sumo.batch.generator_summary import EvalSummary, SkippedGenerator, VariantRecord

    ran, skipped = GeneratorMethod("Random+CV", "random", "cv", "last"), GeneratorMethod("COSTER", "snapshot", "cvae")
    hist = {"speed_hist": [1] * 100, "accel_hist": [1] * 200}
    (tmp_path / "s__scene.json").write_text(json.dumps({"status": "ok", **hist}))
    record = VariantRecord(variant=0, collision=True, relative_speed=3.0, impact_angle=10.0, t_col=5.0,
                           adversary_speed=20.0, adversary_length=4.5, adversary_width=1.9,
                           adversary_lane_type="FREEWAY", avoidable=True,
                           extra={"avoidable_at": {"1": True}, "escape_found_at": {"1": True},
                                  "contact_kind": "head_on", "last_moment_s": 0.7})
    assert VariantRecord.from_json(record.to_json()) == record
    (tmp_path / f"{part_key('s', ran.name, 1, 'w')}.json").write_text(json.dumps(
        {"status": "ok", "records": [record.to_json()], "generation_s": 1.0, "scene_key": "s", **hist}))
    table = aggregate_generator_metrics(tmp_path, {"s": ScenarioSpec(Path("net.sumocfg")), "t": ScenarioSpec(
        Path("other.sumocfg"))}, [ran, skipped], {"COSTER": "no weights"}, 1, "w")
    assert table.table["COSTER"] == SkippedGenerator(skipped, "no weights")
    assert [f.scene_key for f in table.failed_scenes] == ["t"]  # no nominal pass: not run
    assert table.ran["Random+CV"].avoidability.variants == 1
    summary = EvalSummary(scenes={"s": "net.sumocfg"}, planner="replay", variants=1, samples=10, methods=table,
                          wall_time_s=1.5, report=("metrics.json",))
    written = json.dumps(summary.to_json())
    assert list(json.loads(written)) == ["command", "adversary", "traffic", "scenes", "planner", "variants",
                                         "samples", "methods", "wall_time_s", "units", "report"]
    assert json.dumps(EvalSummary.from_json(json.loads(written)).to_json()) == written
