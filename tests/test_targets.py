"""Choosing targets from the demand (``run --targets N``, coster_sumo/targets.py)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from coster_sumo.errors import InputError
from coster_sumo.sumo_env import sumo_home
from coster_sumo.targets import MIN_IN_WINDOW_S, choose_targets, long_lived

ROOT = Path(__file__).resolve().parents[1]
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
    # departs at or after the begin (periodic: 0, 7 -> "periodic.1"; random: mean gap 4 s -> .1)
    assert set(ids) == {"named_route", "nested_route", "late_route", "trip", "periodic.1", "random.1"}
    # left out: departs before the begin, no departure time, too little of its life in the window
    assert not {"before_begin", "waits", "too_late"} & set(ids)
    by_id = {c.vehicle_id: c for c in chosen}
    assert by_id["periodic.1"].depart_s == pytest.approx(7.0)
    assert by_id["trip"].route_m > 100  # routed through the junction, not a guess
    assert all(c.in_window_s >= MIN_IN_WINDOW_S for c in chosen)
    # ranked by time in the window (5 s ties by departure)
    assert [round(c.in_window_s / 5) for c in chosen] == sorted((round(c.in_window_s / 5) for c in chosen),
                                                                  reverse=True)
    assert len(long_lived(_config(tmp_path), 2)) == 2


def test_long_lived_respects_the_window(tmp_path: Path) -> None:
    chosen = long_lived(_config(tmp_path), 20, begin=3.0, end=25.0)
    assert all(c.depart_s < 25.0 for c in chosen)
    assert all(c.in_window_s <= 25.0 - max(c.depart_s, 3.0) + 1e-9 for c in chosen)
    with pytest.raises(InputError, match="t.sumocfg: no vehicle"):
        long_lived(_config(tmp_path), 3, begin=119.0, end=120.0)
    with pytest.raises(InputError, match="--targets must be >= 1"):
        long_lived(_config(tmp_path), 0)


@pytest.mark.parametrize("name", ["A10KW", "grid6", "corridor"])
def test_long_lived_on_scenarios_we_did_not_write(name: str) -> None:
    cfg = sumo_home() / "tools" / "game" / f"{name}.sumocfg"
    chosen = long_lived(cfg, 3)
    assert len(chosen) == 3 and len({c.vehicle_id for c in chosen}) == 3
    assert all(c.in_window_s >= MIN_IN_WINDOW_S and c.free_flow_s >= c.in_window_s for c in chosen)


def test_run_with_chosen_targets(tmp_path: Path) -> None:
    from coster_sumo.cli import main

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
