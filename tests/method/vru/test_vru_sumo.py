"""Pedestrian and cyclist adversaries end to end in SUMO: ``run``, ``regress`` and ``eval scenarios``
with ``--adversary``, the plain-SUMO export, and a network with sidewalks and crossings that
netconvert guesses here (the project's networks have none)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from coster_sumo.cli.command_line import main
from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.formats.sumo_net import read_sumolib_net, sumo_net_to_road_map
from coster_sumo.infra import sumo_install
from coster_sumo.method.vru.classes import VRU_CLASSES
from coster_sumo.method.vru.rollout import plan_within_limits
from tests.exports.test_export_sumo import check_variant

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "networks" / "intersection" / "intersection.sumocfg"
T_COL_TOLERANCE_S = 0.1  # [s] contact within one SUMO step of t_col


def run_vru(cfg: Path, cls: str, out: Path, *extra: str) -> dict:
    assert main(["-q", "run", str(cfg), "--adversary", cls, "--planner", "replay", "--samples", "150",
                 "--variants", "2", "--no-render", "-o", str(out), *extra]) == 0
    return json.loads((out / "summary.json").read_text())


def assert_vru_variants(summary: dict, out: Path, cls: str) -> None:
    """Every variant: of the class, in contact at t_col within 0.1 s, in its class's area and limits."""
    assert summary["adversary"] == cls and summary["variants"]
    assert all(s["adversary_class"] == cls for s in summary["snapshots"])
    for v in summary["variants"]:
        assert v["adversary_class"] == cls
        assert v["collision"] and abs(v["contact_offset_s"]) <= T_COL_TOLERANCE_S + 1e-9, v
        assert not v["adversary_off_road"], v  # its class's area
        plan = AdversaryPlan.from_dict(json.loads((out / "variants" / str(v["variant"]) / "export" /
                                                   "variant.json").read_text())["plan"])
        assert plan.vclass == VRU_CLASSES[cls].vclass and plan_within_limits(plan, VRU_CLASSES[cls])


@pytest.mark.slow
@pytest.mark.sumo
@pytest.mark.parametrize("cls", ["pedestrian", "cyclist"])
def test_run_injects_the_class_in_contact_at_t_col(cls: str, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    summary = run_vru(DEMO, cls, out)
    assert_vru_variants(summary, out, cls)
    text = capsys.readouterr().out
    assert f"adversary {cls}" in text and f"({cls}):" in text  # the console says the class
    vtypes = (out / "variants" / "0" / "export" / "fcd_vtypes.add.xml").read_text()
    assert f'vClass="{VRU_CLASSES[cls].vclass}"' in vtypes
    # plain sumo replays the export: the adversary follows its plan and touches the target at t_col
    _, offset = check_variant(out, 0, tmp_path / "fcd.xml")
    assert abs(offset) <= T_COL_TOLERANCE_S + 1e-9


@pytest.mark.slow
@pytest.mark.sumo
def test_pedestrian_on_a_network_with_guessed_sidewalks_and_crossings(tmp_path: Path) -> None:
    src = REPO / "networks" / "intersection"
    net = tmp_path / "intersection.net.xml"
    subprocess.run([sumo_install.binary("netconvert"), "-s", str(src / "intersection.net.xml"), "--sidewalks.guess",
                    "true", "--crossings.guess", "true", "-o", str(net)], check=True, capture_output=True,
                   env=sumo_install.subprocess_env())
    shutil.copy(src / "intersection.rou.xml", tmp_path)
    shutil.copy(src / "intersection.sumocfg", tmp_path)
    road_map, _ = sumo_net_to_road_map(read_sumolib_net(net))
    assert len(road_map.crosswalks) == 4  # the fixture has what the test is about
    out = tmp_path / "run"
    assert_vru_variants(run_vru(tmp_path / "intersection.sumocfg", "pedestrian", out), out, "pedestrian")


@pytest.mark.slow
@pytest.mark.sumo
def test_regress_reports_the_defect_rate_per_class(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "regress"
    # the kinematic rollout (``--rollout cv``) and the random init (the class's literature rules for
    # speed and heading): their two variants here are avoidable, which the per-class defect rate needs;
    # the learned cyclist rollout gives one unavoidable variant on this net, and so do the learned
    # contact states (a cyclist alongside the target)
    main(["-q", "regress", str(DEMO), "--planner", "replay", "--adversary", "cyclist", "--variants", "2",
          "--rollout", "cv", "--init", "random", "--samples", "150", "--no-report", "-o", str(out)])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["options"]["adversary"] == "cyclist"
    per = summary["defects_by_class"]["replay"]
    assert list(per) == ["cyclist"] and per["cyclist"]["defect_rate"]["n"] >= 1
    assert "cyclist" in capsys.readouterr().out


def test_bad_adversary_exits_2(capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["run", str(DEMO), "--adversary", "horse"])
    assert exc.value.code == 2
    assert "--adversary" in capsys.readouterr().err
