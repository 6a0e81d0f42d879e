"""Choosing targets from the demand (``run --targets N``, coster_sumo/formats/targets.py)."""

from __future__ import annotations

import importlib
import json
import shutil
from pathlib import Path

import pytest

from coster_sumo.core.spec import ScenarioSpec
from coster_sumo.errors import InputError
from coster_sumo.formats.targets import MIN_IN_WINDOW_S, choose_targets, config_demand, long_lived
from coster_sumo.infra.sumo_install import sumo_home
from coster_sumo.pipeline.scenario import nominal_scene
from coster_sumo.sim import session

ROOT = Path(__file__).resolve().parents[2]
NET = ROOT / "networks" / "intersection" / "intersection.net.xml"

# straight across the junction: N2C + C2S; W2C + C2E; every edge of the net is 200 m or so
DEMAND = """<routes>
  <vType id="car"/>
  <route id="ns" edges="N2C C2S"/>
  <vehicle id="named_route" type="car" depart="20" route="ns"/>
  <vehicle id="nested_route" type="car" depart="5"><route edges="W2C C2E"/></vehicle>
  <vehicle id="before_begin" type="car" depart="1"><route edges="W2C C2E"/></vehicle>
  <vehicle id="waits" type="car" depart="triggered"><route edges="W2C C2E"/></vehicle>
  <trip id="trip" type="car" depart="30" from="E2C" to="C2W"/>
  <flow id="periodic" type="car" begin="0" end="100" period="7" from="S2C" to="C2N"/>
  <flow id="random" type="car" begin="0" end="100" probability="0.25" route="late"/>
  <vehicle id="late_route" type="car" depart="40" route="late"/>
  <route id="late" edges="E2C C2N"/>
  <vehicle id="too_late" type="car" depart="118"><route edges="W2C C2E"/></vehicle>
</routes>
"""


def _config(tmp_path: Path, begin: float = 3.0, end: float = 120.0) -> Path:
    (tmp_path / "demand.rou.xml").write_text(DEMAND)
    cfg = tmp_path / "t.sumocfg"
    cfg.write_text(f"""<configuration><input><net-file value="{NET}"/><route-files value="demand.rou.xml"/></input>
<time><begin value="{begin}"/><end value="{end}"/></time></configuration>""")
    return cfg


def test_long_lived_reads_routes_trips_and_flows(tmp_path: Path) -> None:
    chosen = long_lived(_config(tmp_path), 20)
    ids = [c.vehicle_id for c in chosen]
    # named, nested and late-defined routes; a trip (routed); one vehicle per flow, the first that
    # departs at or after the begin (periodic: 0, 7 -> "periodic.1"; random: mean gap 4 s, vehicle k
    # expected at 4 (k + 1) s -> .0 at 4 s)
    assert set(ids) == {"named_route", "nested_route", "late_route", "trip", "periodic.1", "random.0"}
    # left out: departs before the begin, no departure time, too little of its life in the window
    assert not {"before_begin", "waits", "too_late"} & set(ids)
    by_id = {c.vehicle_id: c for c in chosen}
    assert by_id["periodic.1"].depart_s == pytest.approx(7.0)
    assert by_id["random.0"].depart_s == pytest.approx(4.0)
    assert by_id["trip"].route_m > 100  # routed through the junction, not a guess
    assert all(c.in_window_s >= MIN_IN_WINDOW_S for c in chosen)
    # ranked by time in the window (5 s ties by departure)
    assert [round(c.in_window_s / 5) for c in chosen] == sorted((round(c.in_window_s / 5) for c in chosen),
                                                                  reverse=True)
    assert len(long_lived(_config(tmp_path), 2)) == 2


def test_a_rare_random_flow_is_not_expected_at_its_begin(tmp_path: Path) -> None:
    # one vehicle in 100 s on average: its first is expected 100 s after the flow's begin, so a
    # vehicle departing at 5 s on the same route has more of the window (the shipped arterial's
    # rare flows were expected at 0 s and chosen, and never ran in a 150 s window)
    (tmp_path / "d.rou.xml").write_text("""<routes>
  <flow id="rare" begin="0" end="3600" probability="0.01"><route edges="W2C C2E"/></flow>
  <flow id="every_3s" begin="0" end="3600" period="exp(0.33333)"><route edges="W2C C2E"/></flow>
  <vehicle id="car" depart="5"><route edges="N2C C2S"/></vehicle>
</routes>""")
    cfg = tmp_path / "t.sumocfg"
    cfg.write_text(f"""<configuration><input><net-file value="{NET}"/><route-files value="d.rou.xml"/></input>
<time><end value="150"/></time></configuration>""")
    by_id = {c.vehicle_id: c for c in long_lived(cfg, 5)}
    assert by_id["rare.0"].depart_s == pytest.approx(100.0)
    assert by_id["every_3s.0"].depart_s == pytest.approx(3.0, abs=1e-3)
    assert [c.vehicle_id for c in long_lived(cfg, 2)] == ["every_3s.0", "car"]


def test_long_lived_respects_the_window(tmp_path: Path) -> None:
    chosen = long_lived(_config(tmp_path), 20, begin=3.0, end=25.0)
    assert all(c.depart_s < 25.0 for c in chosen)
    assert all(c.in_window_s <= 25.0 - max(c.depart_s, 3.0) + 1e-9 for c in chosen)
    with pytest.raises(InputError, match="t.sumocfg: no vehicle"):
        long_lived(_config(tmp_path), 3, begin=119.0, end=120.0)
    with pytest.raises(InputError, match="--targets must be >= 1"):
        long_lived(_config(tmp_path), 0)


def test_targets_are_road_vehicles(tmp_path: Path, monkeypatch) -> None:
    """A train is no target (the prior places road vehicles); a config with trains only says so."""
    # any simulation fails the test: the class's start is replaced, not the class (modules imported
    # lazily while the test runs would keep a replaced class for the tests after it)
    monkeypatch.setattr(session.SumoSession, "start", lambda *_a, **_k: pytest.fail("simulated"))
    (tmp_path / "d.rou.xml").write_text("""<routes>
  <vehicle id="train" type="loco" depart="0"><route edges="W2C C2E"/></vehicle>
  <vehicle id="car" depart="5"><route edges="N2C C2S"/></vehicle>
  <vType id="loco" vClass="rail"/>
</routes>""")
    cfg = tmp_path / "t.sumocfg"
    cfg.write_text(f"""<configuration><input><net-file value="{NET}"/><route-files value="d.rou.xml"/></input>
<time><end value="120"/></time></configuration>""")
    assert [c.vehicle_id for c in long_lived(cfg, 5)] == ["car"]
    (tmp_path / "d.rou.xml").write_text("""<routes><vType id="loco" vClass="rail"/>
  <vehicle id="train" type="loco" depart="0"><route edges="W2C C2E"/></vehicle></routes>""")
    with pytest.raises(InputError, match=r"t.sumocfg: no road vehicle in its demand \(only rail\)"):
        long_lived(cfg, 1)
    # named: an error before any simulation
    with pytest.raises(InputError, match=r"t.sumocfg: target 'train' is a rail vehicle"):
        nominal_scene(ScenarioSpec(cfg, target="train"))


def test_config_demand_knows_what_the_files_can_insert(tmp_path: Path) -> None:
    demand = config_demand(_config(tmp_path))
    assert demand is not None
    for vid in ("named_route", "nested_route", "waits", "trip", "periodic.0", "periodic.13", "random.2"):
        assert demand.vclass(vid) == "passenger", vid
    for vid in ("ego", "periodic", "periodic.x", "trip.0", "ns"):  # a route's id is no vehicle's
        assert demand.vclass(vid) is None, vid
    assert demand.examples(["NESTED"]) == ["nested_route"]
    assert demand.examples([], n=3) == ["named_route", "nested_route", "before_begin"]
    # when each is planned to depart (the held copies wait for it); none for a flow's or a triggered one
    assert (demand.depart_s("named_route"), demand.depart_s("trip")) == (20.0, 30.0)
    assert demand.depart_s("waits") is None and demand.depart_s("periodic.0") is None
    # a calibrator inserts vehicles the files do not name; a missing file is the simulation's to report
    (tmp_path / "calib.add.xml").write_text('<additional><calibrator id="c" lane="N2C_0" pos="5"/></additional>')
    cfg = tmp_path / "c.sumocfg"
    cfg.write_text(f"""<configuration><input><net-file value="{NET}"/><route-files value="demand.rou.xml"/>
<additional-files value="calib.add.xml"/></input></configuration>""")
    assert config_demand(cfg) is None
    cfg.write_text(f"""<configuration><input><net-file value="{NET}"/><route-files value="gone.rou.xml"/>
</input></configuration>""")
    assert config_demand(cfg) is None
    # a saved state holds vehicles of its own
    cfg.write_text(f"""<configuration><input><net-file value="{NET}"/><route-files value="demand.rou.xml"/>
<load-state value="state.xml"/></input></configuration>""")
    assert config_demand(cfg) is None


@pytest.mark.parametrize(("target", "message"), [
    (None, "no vehicle 'ego' in its demand (route and additional files); pick a target with --target, e.g. "
           "named_route, nested_route, before_begin"),
    ("periodc", "target 'periodc' is not in its demand (route and additional files); candidates: "),
])
def test_a_target_not_in_the_demand_fails_before_the_pass(tmp_path: Path, monkeypatch, target, message) -> None:
    def no_pass(*_a, **_k):
        raise AssertionError("simulated although the demand has no such vehicle")

    monkeypatch.setattr(session.SumoSession, "start", no_pass)  # the class stays (see above)
    with pytest.raises(InputError) as err:
        nominal_scene(ScenarioSpec(_config(tmp_path), target=target))
    assert message in str(err.value) and "t.sumocfg" in str(err.value)


def test_a_target_that_never_runs_is_named_after_one_pass(tmp_path: Path, monkeypatch) -> None:
    """In the demand but departing after the window: one focused pass, whose error names the
    vehicles that ran, longest first."""
    record = importlib.import_module("coster_sumo.sim.record")  # the package exports a function of that name

    passes = []
    real = record.record
    monkeypatch.setattr(record, "record", lambda *a, **k: passes.append(1) or real(*a, **k))
    (tmp_path / "d.rou.xml").write_text("""<routes><vType id="car"/>
  <vehicle id="short" type="car" depart="0"><route edges="N2C C2S"/></vehicle>
  <vehicle id="long" type="car" depart="1" departSpeed="0"><route edges="W2C C2E"/></vehicle>
  <vehicle id="too_late" type="car" depart="100"><route edges="W2C C2E"/></vehicle></routes>""")
    cfg = tmp_path / "late.sumocfg"
    cfg.write_text(f"""<configuration><input><net-file value="{NET}"/><route-files value="d.rou.xml"/></input>
</configuration>""")
    with pytest.raises(InputError, match=r"late.sumocfg: target 'too_late' never runs in the window "
                                         r"\(0\.\d-40\.0 s\); candidates: short, long"):
        nominal_scene(ScenarioSpec(cfg, target="too_late", end=40.0))
    assert passes == [1]
    with pytest.raises(InputError, match="no vehicle 'ego' in its demand"):
        nominal_scene(ScenarioSpec(cfg, end=40.0))
    # candidates: names like the one asked for, else those that ran (for the default, longest first)
    from coster_sumo.formats.targets import missing_target

    ran = {"short": 12.0, "long": 30.0, "longer": 31.0}
    assert str(missing_target(cfg, ["x"], "w", ran)).endswith("candidates: short, long, longer")
    assert str(missing_target(cfg, ["LONG"], "w", ran)).endswith("candidates: long, longer")
    assert str(missing_target(cfg, [None], "w", ran)).endswith("e.g. longer, long, short")


@pytest.mark.parametrize("name", ["A10KW", "grid6", "corridor"])
def test_long_lived_on_scenarios_we_did_not_write(name: str) -> None:
    cfg = sumo_home() / "tools" / "game" / f"{name}.sumocfg"
    chosen = long_lived(cfg, 3)
    assert len(chosen) == 3 and len({c.vehicle_id for c in chosen}) == 3
    assert all(c.in_window_s >= MIN_IN_WINDOW_S and c.free_flow_s >= c.in_window_s for c in chosen)


def test_run_with_chosen_targets(tmp_path: Path) -> None:
    from coster_sumo.cli.command_line import main

    cfg_dir = tmp_path / "net"
    shutil.copytree(ROOT / "networks" / "intersection", cfg_dir)
    out = tmp_path / "out"
    code = main(["run", str(cfg_dir / "intersection.sumocfg"), "--targets", "2", "--planner", "replay",
                 "--samples", "200", "--no-render", "--quiet", "-o", str(out)])
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    chosen = [c["target"] for c in summary["options"]["target_choice"]]
    assert len(chosen) == 2 and [t["target"] for t in summary["targets"]] == chosen
    assert chosen == [c.vehicle_id for c in choose_targets(cfg_dir / "intersection.sumocfg", 2)]

