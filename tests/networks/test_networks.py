"""The project's own SUMO scenarios (networks/): present, well-formed, loadable, with an early ego."""

from __future__ import annotations

import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from coster_sumo.infra import sumo_install

REPO = Path(__file__).resolve().parents[2]
NETWORKS = REPO / "networks"
SCENARIOS = ["intersection", "merge", "arterial"]
EGO_LATEST_DEPART_S = 5.0  # [s]
# an edge ego must reach in each scenario: past the interesting part
EGO_PASSES = {"intersection": "C2N", "merge": "M2B", "arterial": "J2_J3"}


def _cfg(name: str) -> Path:
    return NETWORKS / name / f"{name}.sumocfg"


@pytest.mark.parametrize("name", SCENARIOS)
def test_scenario_files_are_complete_and_relative(name):
    cfg = _cfg(name)
    root = ET.parse(cfg).getroot()
    values = {el.tag: el.get("value") for el in root.iter() if el.get("value") is not None}
    assert values["step-length"] == "0.1"
    assert float(values["end"]) >= 60.0
    for key in ("net-file", "route-files"):
        assert not Path(values[key]).is_absolute()
        assert (cfg.parent / values[key]).is_file()
    total_kb = sum(p.stat().st_size for p in cfg.parent.iterdir()) / 1024
    assert total_kb < 500, f"{name}: {total_kb:.0f} KB"


@pytest.mark.parametrize("name", SCENARIOS)
def test_net_keeps_our_coordinates(name):
    net = ET.parse(NETWORKS / name / f"{name}.net.xml").getroot()
    loc = net.find("location")
    assert loc is not None and loc.get("netOffset") == "0.00,0.00"  # --offset.disable-normalization


@pytest.mark.parametrize("name", SCENARIOS)
def test_demand_has_an_early_ego_and_background_flows(name):
    routes = ET.parse(NETWORKS / name / f"{name}.rou.xml").getroot()
    ego = [el for el in routes if el.get("id") == "ego" and el.tag in ("vehicle", "trip", "flow")]
    assert len(ego) == 1
    assert float(ego[0].get("depart", "inf")) <= EGO_LATEST_DEPART_S
    flows = routes.findall("flow")
    assert len(flows) >= 2
    assert all(f.get("probability") or f.get("number") for f in flows)


def _committed_version() -> str | None:
    head = (NETWORKS / "intersection" / "intersection.net.xml").read_text()[:400]
    m = re.search(r"eclipse-sumo ([\w.]+)", head)
    return m.group(1) if m else None


@pytest.mark.sumo
def test_build_script_reproduces_the_committed_files(tmp_path):
    proc = subprocess.run([sys.executable, str(NETWORKS / "build.py"), "--out", str(tmp_path)],
                          capture_output=True, text=True, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    head = (tmp_path / "intersection" / "intersection.net.xml").read_text()[:400]
    version = re.search(r"eclipse-sumo ([\w.]+)", head)
    if version is None or version.group(1) != _committed_version():
        pytest.skip("another netconvert version than the one that built the committed files")
    for name in SCENARIOS:
        built = sorted(p.name for p in (tmp_path / name).iterdir())
        committed = sorted(p.name for p in (NETWORKS / name).iterdir())
        assert built == committed
        for f in built:
            assert (tmp_path / name / f).read_bytes() == (NETWORKS / name / f).read_bytes(), f"{name}/{f}"


@pytest.mark.sumo
@pytest.mark.parametrize("name", SCENARIOS)
def test_scenario_runs_with_traffic_around_ego(name):
    from coster_sumo.sim.session import SumoSession

    passed_at = depart = None
    near = []
    with SumoSession(_cfg(name)) as sim:
        while sim.time < 80.0 and passed_at is None:
            sim.step()
            if "ego" in sim.departed_ids():
                depart = sim.time
            states = sim.vehicle_states()
            if "ego" in states.ids:
                i = states.index_of("ego")
                near.append(int(np.sum(np.hypot(states.x - states.x[i], states.y - states.y[i]) < 60.0)) - 1)
                if sim.api.vehicle.getRoadID("ego") == EGO_PASSES[name]:
                    passed_at = sim.time
    assert depart is not None and depart <= EGO_LATEST_DEPART_S
    assert passed_at is not None, f"ego did not reach {EGO_PASSES[name]} within 80 s"
    assert np.mean(near) >= 2.0, "ego drives alone"
    env = sumo_install.subprocess_env()  # the sumo binary loads the configuration without errors too
    out = subprocess.run([sumo_install.binary("sumo"), "-c", str(_cfg(name)), "--end", "5"],
                         capture_output=True, text=True, env=env)
    assert out.returncode == 0 and "Error" not in out.stderr, out.stderr
