"""Simulation windows as SUMO users expect them: absolute begin/end, late departures, clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from coster_sumo.cli.command_line import main
from coster_sumo.core.spec import GenerationConfig, ScenarioSpec
from coster_sumo.errors import InputError
from coster_sumo.formats.source import simulation_window
from coster_sumo.formats.targets import choose_target
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.method.generation import plan_scenario
from coster_sumo.pipeline.scenario import nominal_scene
from tests.conftest import visible_lines

REPO = Path(__file__).resolve().parents[2]
NET = REPO / "networks" / "intersection" / "intersection.net.xml"
BEGIN = 57600.0  # [s] 16:00, like real city configurations


def _late_config(tmp_path: Path, departures: dict[str, float]) -> Path:
    """The intersection network with demand starting at 16:00 and targets departing later."""
    vehicles = "".join(f'    <trip id="{vid}" type="car" depart="{t}" from="W2C" to="C2N" departSpeed="max"/>\n'
                       for vid, t in sorted(departures.items(), key=lambda kv: kv[1]))
    (tmp_path / "late.rou.xml").write_text(
        '<routes>\n    <vType id="car" length="4.6" width="1.8" sigma="0.5"/>\n'
        f'    <flow id="E_s" type="car" begin="{BEGIN}" end="{BEGIN + 600}" probability="0.15" from="E2C" to="C2W"/>\n'
        f'    <flow id="N_s" type="car" begin="{BEGIN}" end="{BEGIN + 600}" probability="0.10" from="N2C" to="C2S"/>\n'
        + vehicles + "</routes>\n")
    cfg = tmp_path / "late.sumocfg"
    cfg.write_text(f'<configuration><input><net-file value="{NET}"/><route-files value="late.rou.xml"/></input>'
                   f'<time><begin value="16:00:00"/><end value="{BEGIN + 90}"/></time></configuration>')
    return cfg


@pytest.mark.sumo
@pytest.mark.parametrize("depart", [BEGIN + 5.0, BEGIN + 20.0, BEGIN + 31.3])
def test_t_col_lies_inside_a_late_targets_lifetime(tmp_path, depart):
    cfg = _late_config(tmp_path, {"late": depart})
    spec = ScenarioSpec(cfg, seed=1, target="late")
    scene, _ = nominal_scene(spec)
    assert scene.timestamps[0] >= BEGIN  # SUMO's own clock, from the configuration's begin
    target = choose_target(scene, "late", cfg)
    drivable = DrivableArea.from_road_map(scene.road_map)
    planned = plan_scenario(scene, target, 1, GenerationConfig(init="random", rollout="cv"), drivable)
    alive = scene.timestamps[scene.tracks.valid[target]]
    t_col = planned.snapshot.time
    assert alive[0] + 5.0 - 0.1 - 1e-6 <= t_col <= alive[-1]  # room for the 5 s approach, before it leaves
    assert planned.plans[0].t_start >= scene.timestamps[0] - 1e-9


def test_window_from_the_configuration_and_from_flags(tmp_path):
    cfg = _late_config(tmp_path, {"late": BEGIN + 5})
    assert simulation_window(ScenarioSpec(cfg)) == (BEGIN, BEGIN + 90)
    assert simulation_window(ScenarioSpec(cfg, end=BEGIN + 400)) == (BEGIN, BEGIN + 400)
    with pytest.raises(InputError, match="not after begin 57600 s .*--duration"):
        simulation_window(ScenarioSpec(cfg, end=400.0))


def test_end_before_begin_is_one_line_exit_2(tmp_path, capsys):
    cfg = _late_config(tmp_path, {"late": BEGIN + 5})
    assert main(["run", str(cfg), "--target", "late", "--end", "400", "-o", str(tmp_path / "out")]) == 2
    err = visible_lines(capsys.readouterr().err)
    assert len(err) == 1 and str(cfg) in err[0] and not (tmp_path / "out").exists()


@pytest.mark.sumo
def test_duration_counts_from_the_configurations_begin(tmp_path):
    cfg = _late_config(tmp_path, {"late": BEGIN + 5})
    out = tmp_path / "out"
    code = main(["--quiet", "run", str(cfg), "--target", "late", "--duration", "60", "--init", "random", "--rollout",
                 "cv", "--no-render", "-o", str(out)])
    assert code == 0
    import json

    summary = json.loads((out / "summary.json").read_text())
    assert BEGIN < summary["t_col"] < BEGIN + 60
    assert np.isclose(summary["options"]["end"], BEGIN + 60)
