"""OpenSCENARIO + OpenDRIVE export (``coster-sumo export``, ``run --export``) and its round trip.

Round trip: the .xosc read back (plain XML and scenariogeneration's parser) gives the adversary's
trajectory within 0.01 m of its plan at every 2 Hz knot; the .xodr lane centre lines (reference
line shifted by the lane widths: netconvert puts a road's reference line on the left border of its
leftmost lane) lie on the SUMO lane shapes they came from; the SUMO export of the same run still
plays in plain sumo with the contact at t_col (helpers of test_export_sumo.py).
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

from coster_sumo.cli.command_line import main
from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.data import synthetic
from coster_sumo.exports import opendrive as odr
from coster_sumo.exports import openscenario as osc
from coster_sumo.exports.trajectories import (
    Trajectory,
    read_trajectories_csv,
    select_near,
    write_selection,
    write_trajectories_csv,
)
from tests.conftest import NO_WOMD_REASON, WOMD_PKL, WOMD_PROTO

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "networks" / "intersection" / "intersection.sumocfg"
WOMD_SAMPLES = [*WOMD_PROTO, *WOMD_PKL]  # the four real samples (one scene each)
HAS_EXTRA = all(importlib.util.find_spec(m) is not None for m in ("scenariogeneration", "xmlschema"))
needs_extra = pytest.mark.skipif(not HAS_EXTRA, reason="optional extra not installed: pip install "
                                                       "'coster-sumo[openscenario]' (dev installs it)")
KNOT_TOLERANCE_M = 0.01
# the bound, roads and connecting roads alike, max both ways (lanes fitted onto the SUMO shapes)
XODR_TOLERANCE_M = 0.1
# [m] on the converted WOMD maps, where logged lanes start and end apart, a road spans only the
# stretch its linked lanes share (opendrive_ends): a lane that no connection enters loses what sticks
# out before that (one lane of 637f20, 0.79 m: its SUMO points up to 0.23 m from the xodr); and lanes
# that start or end within MIN_SECTION_M of each other do so together (no lane section shorter
# than pyxodr's 0.1 m sampling can hold): up to 0.33 m (637f20) at such a lane end
LANE_END_TOLERANCE_M = 0.35
# connecting roads leave their incoming lane at its heading and width and reach their outgoing lane
# at its heading and width (readers check both borders at every lane link, within 1 cm); where
# netconvert's own internal lanes start or end at an angle to their lanes (up to ~8 deg on the demo
# networks), a curve without that heading jump runs up to 0.36 m beside them (measured: demo
# intersection 0.35, arterial 0.35, game square 0.21, grid6 0.32, where it also bends so that its
# lane does not fold (opendrive_bend); WOMD samples <= 0.34 m, where their logged interior lanes
# turn tighter than their lanes can follow and the curve leaves them so that the lane does not fold)
XODR_JUNCTION_TOLERANCE_M = 0.4


def knot_error(vdir: Path, xosc: Path, contact_time: float | None = None) -> tuple[float, int, int]:
    """Max distance [m] between the adversary's plan knots and its .xosc polyline at the knot times,
    over the knots the pass drove: from its first recorded state (a converted scene's knot times
    jitter around SUMO's 0.1 s grid by milliseconds; a first knot a few ms past a step is driven
    from the next step on) to its first contact (``contact_time``, SUMO time [s]; the pass freezes
    the adversary at its contact pose, so a contact one step before t_col leaves the last knot
    unreached). Also returns the number of knots before the recording and after the contact."""
    plan = AdversaryPlan.from_dict(json.loads((vdir / "export" / "variant.json").read_text())["plan"])
    t0 = float(osc.read_parameters(xosc)["SumoTimeOffset"])
    t, x, y, _ = osc.read_xosc_trajectories(xosc)[plan.vehicle_id]
    ts = plan.times - t0
    before = ts < t[0] - 1e-3
    after = ts > (contact_time - t0 if contact_time is not None else t[-1]) + 1e-3
    keep = ~before & ~after
    err = np.hypot(np.interp(ts[keep], t, x) - plan.x[keep], np.interp(ts[keep], t, y) - plan.y[keep])
    return float(np.max(err)), int(before.sum()), int(after.sum())


def _traj(vid: str, t0: float, n: int, x0: float, y0: float, heading: float, speed: float,
          kind: str = "VEHICLE", vclass: str = "") -> Trajectory:
    t = t0 + 0.1 * np.arange(n)
    d = speed * (t - t0)
    return Trajectory(vid, kind, t, x0 + d * math.cos(heading), y0 + d * math.sin(heading), np.full(n, heading),
                      np.full(n, speed), np.full(n, 4.5), np.full(n, 1.9), vclass)


def xosc_categories(path: Path) -> dict[str, str]:
    """Entity name -> its vehicleCategory (pedestrianCategory for pedestrians) in an .xosc."""
    from defusedxml import ElementTree as SafeET

    root = SafeET.parse(str(path)).getroot()
    out = {}
    for obj in root.iter("ScenarioObject"):
        for el in obj:
            if el.tag == "Vehicle":
                out[obj.get("name", "")] = el.get("vehicleCategory", "")
            elif el.tag == "Pedestrian":
                out[obj.get("name", "")] = "pedestrian:" + el.get("pedestrianCategory", "")
    return out


def test_trajectories_csv_round_trip(tmp_path):
    scene = synthetic.ALL[sorted(synthetic.ALL)[0]]()
    write_trajectories_csv(tmp_path / "t.csv", scene)
    back = read_trajectories_csv(tmp_path / "t.csv")
    tr = scene.tracks
    for a, vid in enumerate(tr.ids.tolist()):
        v = tr.valid[a]
        if not v.any():
            assert vid not in back
            continue
        got = back[vid]
        assert np.allclose(got.t, scene.timestamps[v], atol=1e-3)
        assert np.allclose(got.x, tr.x[a, v], atol=1e-4) and np.allclose(got.y, tr.y[a, v], atol=1e-4)
        assert np.allclose(got.heading, tr.heading[a, v], atol=1e-6)


def test_select_near_keeps_target_adversary_and_the_radius():
    trajs = {"ego": _traj("ego", 0, 50, 0, 0, 0, 10), "adv": _traj("adv", 1, 40, 200, 0, math.pi, 10),
             "near": _traj("near", 0, 50, 0, 30, 0, 10), "far": _traj("far", 0, 50, 0, 80, 0, 10),
             "gone": _traj("gone", 0, 5, 0, 1, 0, 10)}
    assert select_near(trajs, "ego", "adv", 3.0, 50.0) == ["ego", "adv", "near"]


XODR = """<?xml version="1.0"?>
<OpenDRIVE><header revMajor="1" revMinor="4"/>
 <road id="1" junction="-1" length="{L}">
  <planView>
   <geometry s="0" x="10" y="5" hdg="0" length="20"><line/></geometry>
   <geometry s="20" x="30" y="5" hdg="0" length="{arc}"><arc curvature="0.1"/></geometry>
   <geometry s="{s2}" x="40" y="15" hdg="{h2}" length="10"><paramPoly3 aU="0" bU="10" cU="0" dU="0"
     aV="0" bV="0" cV="0" dV="0" pRange="normalized"/></geometry>
  </planView>
  <lanes>
   <laneOffset s="0" a="0.5" b="0" c="0" d="0"/>
   <laneSection s="0"><center><lane id="0"/></center><right>
    <lane id="-1" type="driving"><width sOffset="0" a="3" b="0" c="0" d="0"/></lane>
    <lane id="-2" type="driving"><width sOffset="0" a="4" b="0" c="0" d="0"/></lane>
   </right></laneSection>
  </lanes>
 </road>
</OpenDRIVE>
"""


def test_xodr_sampler_on_line_arc_and_parampoly3(tmp_path):
    arc = math.pi / 2 / 0.1  # a quarter circle of radius 10 from (30, 5) heading east: ends at (40, 15) north
    path = tmp_path / "t.xodr"
    path.write_text(XODR.format(L=30 + arc, arc=arc, s2=20 + arc, h2=math.pi / 2))
    lanes = {ln.lane: ln.xy for ln in odr.xodr_lane_centres(path, step=0.5)}
    # lane -1 centre: 0.5 - 1.5 = 1 m right of the reference line; lane -2: 0.5 - 3 - 2 = 4.5 m right
    for lane, off in ((-1, 1.0), (-2, 4.5)):
        xy = lanes[lane]
        assert np.allclose(xy[0], (10, 5 - off))  # line start
        on_line = xy[xy[:, 0] <= 30 + 1e-9]
        assert np.allclose(on_line[:, 1], 5 - off)
        on_arc = xy[(xy[:, 0] > 30 + 1e-6) & (xy[:, 1] < 15 - 1e-6)]
        r = np.hypot(on_arc[:, 0] - 30, on_arc[:, 1] - 15)  # arc centre (30, 15), radius 10 + off
        assert np.allclose(r, 10 + off, atol=1e-9)
        assert np.allclose(xy[-1], (40 + off, 25), atol=1e-9)  # paramPoly3: 10 m north from (40, 15)


@needs_extra
def test_xosc_validates_and_reads_back(tmp_path):
    trajs = {"ego": _traj("ego", 2.0, 40, 0, 0, 0.3, 10), "adv": _traj("adv", 2.5, 30, 50, -20, 2.0, 8),
             "ped": _traj("ped", 2.0, 40, 5, 5, 1.0, 1.2, kind="PEDESTRIAN")}
    path = osc.write_xosc(tmp_path / "s.xosc", "road.xodr", trajs, list(trajs), t0=2.0, description="test",
                          parameters={"SumoTimeOffset": 2.0, "Target": "ego"})
    assert osc.validate_xosc(path) == []
    back = osc.read_xosc_trajectories(path)
    for vid, tr in trajs.items():
        t, x, y, h = back[vid]
        assert np.allclose(t, tr.t - 2.0, atol=1e-6) and np.allclose(x, tr.x, atol=1e-6)
        assert np.allclose(y, tr.y, atol=1e-6) and np.allclose(h, tr.heading, atol=1e-6)
    assert osc.read_parameters(path)["Target"] == "ego"
    from scenariogeneration import xosc

    parsed = xosc.ParseOpenScenario(str(path))
    assert isinstance(parsed, xosc.Scenario)
    assert parsed == xosc.ParseOpenScenario(str(path))  # parses the same every time


@needs_extra
def test_vehicle_category_comes_from_the_sumo_class(tmp_path):
    classes = {"car": ("passenger", "car"), "lorry": ("truck", "truck"), "van": ("delivery", "van"),
               "moto": ("motorcycle", "motorbike"), "coach": ("bus", "bus"), "bike": ("bicycle", "bicycle"),
               "artic": ("trailer", "semitrailer"), "odd": ("ship", "car")}
    trajs = {vid: _traj(vid, 2.0, 20, 4.0 * k, 0, 0.0, 5, vclass=vc)
             for k, (vid, (vc, _)) in enumerate(classes.items())}
    trajs["walker"] = _traj("walker", 2.0, 20, 0, 9, 1.0, 1.2, kind="PEDESTRIAN", vclass="pedestrian")
    trajs["womd_cyclist"] = _traj("womd_cyclist", 2.0, 20, 0, 19, 1.0, 4, kind="CYCLIST")  # no class recorded
    path = osc.write_xosc(tmp_path / "s.xosc", "road.xodr", trajs, list(trajs), t0=2.0, description="test",
                          parameters={})
    assert osc.validate_xosc(path) == []
    got = xosc_categories(path)
    assert {vid: got[vid] for vid in classes} == {vid: cat for vid, (_, cat) in classes.items()}
    assert got["walker"] == "pedestrian:pedestrian" and got["womd_cyclist"] == "bicycle"


def test_trajectories_csv_keeps_the_vehicle_class_and_reads_files_without_it(tmp_path):
    trajs = {"t": _traj("t", 0.0, 5, 0, 0, 0, 10, vclass="truck"), "c": _traj("c", 0.0, 5, 0, 9, 0, 10)}
    csv_path, _ = write_selection(tmp_path, trajs, ["t", "c"], {}, {})
    back = read_trajectories_csv(csv_path)
    assert back["t"].vclass == "truck" and back["c"].vclass == ""
    old = tmp_path / "old.csv"  # a file from before the column existed
    lines = csv_path.read_text().splitlines()
    old.write_text("\n".join(",".join(ln.split(",")[:9]) for ln in lines) + "\n")
    assert read_trajectories_csv(old)["t"].vclass == ""


def test_missing_extra_is_one_line_exit_2(tmp_path, monkeypatch, capsys):
    real = importlib.import_module

    def fake(name, *args, **kwargs):
        if name == "scenariogeneration":
            raise ImportError(name)
        return real(name, *args, **kwargs)

    monkeypatch.setattr(osc.importlib, "import_module", fake)
    assert main(["export", str(tmp_path), "--format", "openscenario"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "coster-sumo[openscenario]" in err[0], err
    assert main(["run", str(DEMO), "--export", "all", "-o", str(tmp_path / "never")]) == 2
    assert not (tmp_path / "never").exists()


def assert_xodr_on_lanes(xodr: Path, net: Path, roads: float = XODR_TOLERANCE_M) -> dict:
    """The .xodr lane centre lines within ``roads`` [m] (:data:`XODR_TOLERANCE_M`) of the SUMO lane
    shapes, both ways, on roads (:data:`XODR_JUNCTION_TOLERANCE_M` in junctions); returns the
    comparison."""
    cmp = odr.compare_with_net(xodr, net)
    for part, bound in (("roads", roads), ("junctions", XODR_JUNCTION_TOLERANCE_M)):
        if "xodr_to_net_max" in cmp[part]:
            assert cmp[part]["xodr_to_net_max"] <= bound, (part, cmp)
            assert cmp[part]["net_to_xodr_max"] <= bound, (part, cmp)
    print(f"{net.name}: " + ", ".join(f"{p} {d}_max {cmp[p][d + '_max']:.4f} m mean {cmp[p][d + '_mean']:.4f} m"
                                      for p in ("roads", "junctions") if "xodr_to_net_max" in cmp[p]
                                      for d in ("xodr_to_net", "net_to_xodr")))
    return cmp


def check_openscenario(out: Path) -> list[dict]:
    """Every variant's .xosc valid, knots within 0.01 m, xodr lanes on the SUMO lanes; returns the numbers."""
    summary = json.loads((out / "summary.json").read_text())
    rows = []
    for v in summary["variants"]:
        vdir = out / "variants" / str(v["variant"])
        (xosc_path,) = sorted((vdir / "openscenario").glob("*.xosc"))
        (xodr_path,) = sorted((vdir / "openscenario").glob("*.xodr"))
        assert osc.validate_xosc(xosc_path) == []
        err, before, after = knot_error(vdir, xosc_path, v["collision_time"])
        assert err <= KNOT_TOLERANCE_M, (v["variant"], err)
        assert before <= 1 and after <= 1, (v["variant"], before, after)  # one step (0.1 s) at most
        doc = json.loads((vdir / "openscenario" / "trajectories.json").read_text())
        assert {doc["target"], doc["adversary"]} <= set(doc["vehicles"])
        print(f"variant {v['variant']}: .xosc valid, adversary knot error {err:.4f} m "
              f"({before} knot(s) before the recording, {after} after the contact)")
        rows.append({"variant": v["variant"], "knot_error_m": err, "knots_before": before,
                     "knots_after_contact": after, "xodr": xodr_path,
                     "net": next((vdir / "export").glob("*.net.xml"))})
    return rows


@needs_extra
@pytest.mark.sumo
def test_demo_variant_exports_openscenario_and_sumo(tmp_path):
    """One variant of the shipped demo (weight-free generator), exported by `run --export all`."""
    import test_export_sumo as sumo_checks

    out = tmp_path / "run"
    assert main(["-q", "run", str(DEMO), "--planner", "replay", "--init", "random", "--rollout", "cv",
                 "--no-render", "--export", "all", "-o", str(out)]) == 0
    rows = check_openscenario(out)
    assert_xodr_on_lanes(rows[0]["xodr"], rows[0]["net"])
    # every entity's category is its SUMO class's (the demo's traffic has trucks, vans and motorcycles)
    osc_dir = out / "variants" / str(rows[0]["variant"]) / "openscenario"
    doc = json.loads((osc_dir / "trajectories.json").read_text())
    got = xosc_categories(next(osc_dir.glob("*.xosc")))
    assert all(v["vclass"] for v in doc["vehicles"].values()), doc["vehicles"]
    assert got == {vid: osc.vehicle_category(v["vclass"], v["type"]) for vid, v in doc["vehicles"].items()}
    sumo_checks.check_variant(out, 0, tmp_path / "plain.fcd.xml")
    # export again from the folder alone: same files, the SUMO folder located
    assert main(["-q", "export", str(out), "--format", "all"]) == 0
    assert main(["-q", "export", str(out), "--format", "sumo"]) == 0


@needs_extra
@pytest.mark.sumo
@pytest.mark.slow
@pytest.mark.realdata
@pytest.mark.skipif(not WOMD_SAMPLES, reason=NO_WOMD_REASON)
@pytest.mark.parametrize("sample", WOMD_SAMPLES, ids=lambda p: p.stem)
def test_womd_scene_exports_openscenario(tmp_path, sample):
    """A converted real WOMD scene: every variant valid with its knots exact; the xodr lanes on the
    SUMO lanes (each lane keeps its logged centre line: netconvert's lanes alone were metres off)."""
    conv = tmp_path / "conv"
    assert main(["-q", "convert", "-o", str(conv), str(sample)]) == 0
    (cfg,) = sorted(conv.glob("*/*.sumocfg"))
    out = tmp_path / "run"
    assert main(["-q", "run", str(cfg), "--no-render", "-o", str(out)]) == 0
    assert main(["-q", "export", str(out)]) == 0
    rows = check_openscenario(out)
    assert_xodr_on_lanes(rows[0]["xodr"], rows[0]["net"], roads=LANE_END_TOLERANCE_M)
