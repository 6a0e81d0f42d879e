"""The standalone SUMO export of every variant plays in the plain ``sumo`` binary, adversary included.

For each exported variant: ``sumo -c variants/<i>/export/<name>.sumocfg --fcd-output F`` (no Python,
no TraCI), then from F (front-bumper positions): the adversary's box centre within 0.1 m of its plan
at every 2 Hz knot, and its first oriented-box contact with the target within 0.1 s of t_col
(``summary.json``'s ``t_col_sim``). SUMO's FCD output labels the state a step reaches with the time
the step starts at; the tests check that convention instead of assuming it.
"""

from __future__ import annotations

import json
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from coster_sumo.cli.command_line import main
from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.exports.demand import demand_ids, rewrite_demand
from coster_sumo.exports.fcd import FCD_FILE, VTYPE_SUFFIX, VTYPES_FILE
from coster_sumo.exports.sumo_config import source_options
from coster_sumo.geometry import frames
from coster_sumo.geometry.boxes import box_signed_distance, make_boxes
from coster_sumo.infra import sumo_install
from coster_sumo.pipeline.outputs import sim_time_of
from coster_sumo.sim.events import CONTACT_TOLERANCE_M
from tests.conftest import NO_WOMD_REASON, WOMD_PKL, WOMD_PROTO

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "networks" / "intersection" / "intersection.sumocfg"
WOMD_SAMPLES = [*WOMD_PROTO, *WOMD_PKL]  # the four real samples (one scene each)
KNOT_TOLERANCE_M = 0.1
CONTACT_OFFSET_TOLERANCE_S = 0.1

States = dict[str, dict[float, tuple[float, float, float, float]]]  # id -> label [s] -> x, y, angle, speed


def read_fcd(path: Path) -> States:
    """SUMO FCD output (or an FCD replay file): front-bumper x, y [m], SUMO angle [deg], speed [m/s]."""
    out: States = {}
    for ts in ET.parse(path).getroot().iter("timestep"):
        t = round(float(ts.get("time", "nan")), 3)
        for v in ts.iter("vehicle"):
            out.setdefault(v.get("id", ""), {})[t] = (float(v.get("x", "nan")), float(v.get("y", "nan")),
                                                      float(v.get("angle", "nan")), float(v.get("speed", "nan")))
    return out


def play(cfg: Path, fcd: Path) -> States:
    """Run the plain sumo binary on ``cfg`` (no extra options but the FCD output) and read F."""
    proc = subprocess.run([sumo_install.binary("sumo"), "-c", str(cfg), "--fcd-output", str(fcd)],
                          capture_output=True, text=True, env=sumo_install.subprocess_env(), timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return read_fcd(fcd)


def centres(states: States, vid: str, length: float) -> dict[float, tuple[float, float, float]]:
    """label -> box centre x, y [m], yaw [rad] of one vehicle."""
    out = {}
    for t, (x, y, angle, _) in states.get(vid, {}).items():
        cx, cy, yaw = frames.from_sumo(x, y, angle, length)
        out[t] = (float(cx), float(cy), float(yaw))
    return out


def knot_errors(plan: AdversaryPlan, adv: dict[float, tuple[float, float, float]], step: float,
                shift_steps: int, until: float = float("inf")) -> float:
    """Max centre distance [m] to the plan's knots up to simulation time ``until`` (the pass's
    contact: the adversary stays where it touched) when the knot at simulation time T is looked up
    under the label ``T - step + shift_steps * step`` (inf when a knot has no such label)."""
    # the pass drives the plan sampled at the simulation's own step times: a converted log's knot
    # times sit milliseconds off that grid, which is 0.15 m at 10 m/s, so compare at the grid time
    grid = np.array([sim_time_of(float(t), step) for t in plan.times])
    kx, ky, _, _ = plan.sample(grid)
    worst = 0.0
    for t, x, y in zip(plan.times, kx, ky, strict=True):
        if sim_time_of(float(t), step) > until + 1e-6:
            break
        label = round(sim_time_of(float(t), step) - step + shift_steps * step, 3)
        if label not in adv:
            return float("inf")
        worst = max(worst, float(np.hypot(adv[label][0] - x, adv[label][1] - y)))
    return worst


def first_contact(adv: dict[float, tuple[float, float, float]], tgt: dict[float, tuple[float, float, float]],
                  plan: AdversaryPlan, target_size: tuple[float, float], step: float) -> float | None:
    """Simulation time [s] of the first step where the two oriented boxes touch (None: never)."""
    for label in sorted(set(adv) & set(tgt)):
        a, b = adv[label], tgt[label]
        gap = box_signed_distance(make_boxes(a[0], a[1], a[2], plan.length, plan.width),
                                  make_boxes(b[0], b[1], b[2], *target_size))
        if float(gap) <= CONTACT_TOLERANCE_M:
            return round(label + step, 6)
    return None


def vtype_sizes(export: Path) -> dict[str, tuple[float, float]]:
    """Vehicle id -> (length, width) [m] of the vehicles the export's FCD file drives."""
    return {v.get("id", "")[:-len(VTYPE_SUFFIX)]: (float(v.get("length", "nan")), float(v.get("width", "nan")))
            for v in ET.parse(export / VTYPES_FILE).getroot().iter("vType")}


def assert_self_contained(cfg: Path) -> None:
    """Every file the exported configuration names is a plain file name in its folder (it runs,
    in sumo or sumo-gui, from wherever the folder is moved to)."""
    for el in ET.parse(cfg).getroot().iter():
        if el.tag in ("net-file", "route-files", "additional-files", "gui-settings-file",
                      "device.fcd-replay.files", "fcd-output.filter-edges.input-file"):
            for name in el.get("value", "").split(","):
                assert name and Path(name).name == name and (cfg.parent / name).is_file(), (el.tag, name)


def check_variant(out: Path, i: int, fcd: Path, replay_cli: bool = False) -> tuple[float, float]:
    """Play variant ``i`` of a run in plain sumo (or ``coster-sumo replay``); returns (max knot
    error [m] up to the pass's contact, contact offset from t_col_sim [s]) after asserting both are within
    tolerance and that plain sumo touches when the pass did."""
    summary = json.loads((out / "summary.json").read_text())
    export = out / "variants" / str(i) / "export"
    variant = json.loads((export / "variant.json").read_text())
    plan = AdversaryPlan.from_dict(variant["plan"])
    step = float(variant["export"]["step_length"])
    cfg = export / variant["export"]["sumocfg"]
    assert_self_contained(cfg)
    if replay_cli:
        assert main(["-q", "replay", str(cfg), "--fcd-output", str(fcd), "-o", str(fcd.parent / "replay")]) == 0
        states = read_fcd(fcd)
    else:
        states = play(cfg, fcd)
    adv = centres(states, plan.vehicle_id, plan.length)
    assert adv, f"variant {i}: the adversary never shows up in the export"
    record = next(v for v in summary["variants"] if v["variant"] == i)
    assert record["collision"], f"variant {i}: no contact in the pass itself"
    passed = float(record["collision_time"])  # the pass's contact (SUMO time); the adversary stays there
    errors = {shift: knot_errors(plan, adv, step, shift, until=passed) for shift in (-1, 0, 1)}
    # the state at simulation time T is labelled T - step: exact there, a step's motion off elsewhere
    assert errors[0] <= KNOT_TOLERANCE_M, (i, errors)
    assert errors[0] <= min(errors[-1], errors[1]), (i, errors)
    _, _, _, speeds = plan.sample(plan.times[plan.times <= passed + 1e-6])
    if float(np.max(speeds)) > 0.5:  # a moving adversary tells the labels apart (one that waits does not)
        assert errors[0] < min(errors[-1], errors[1]), (i, errors)
    target = variant["target_id"]
    assert variant["export"]["target_driven_by"] == "fcd-replay"
    size = vtype_sizes(export)[target]
    contact = first_contact(adv, centres(states, target, size[0]), plan, size, step)
    assert contact is not None, f"variant {i}: no contact in the export"
    offset = round(contact - float(summary["t_col_sim"]), 6)
    assert abs(contact - passed) < 1e-6, (i, contact, passed)  # the export plays what the pass did
    assert abs(offset) <= CONTACT_OFFSET_TOLERANCE_S + 1e-6, (i, contact, summary["t_col_sim"])
    print(f"variant {i}: max knot error {errors[0]:.4f} m, contact {contact:.2f} s, offset {offset:+.2f} s")
    return errors[0], offset


def test_rewrite_demand_drops_the_target_and_sets_insertion_checks(tmp_path):
    rou = tmp_path / "r.rou.xml"
    rou.write_text('<routes xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
                   'xsi:noNamespaceSchemaLocation="http://sumo.dlr.de/xsd/routes_file.xsd">\n'
                   '  <vType id="car"/>\n  <flow id="f" type="car" begin="0" end="9" number="3" from="a" to="b"/>\n'
                   '  <trip id="ego" type="car" depart="2" from="a" to="b"/>\n'
                   '  <vehicle id="other" depart="1" route="r0" insertionChecks="collision"/>\n</routes>\n')
    assert demand_ids(rou) == {"vehicle": {"ego", "other"}, "flow": {"f"}}
    none = {"vehicles": [], "flows": [], "flows_after_end": []}
    assert rewrite_demand(rou, drop_vehicles=frozenset({"f.1"})) == none
    assert rewrite_demand(rou, checks="all", drop_vehicles=frozenset({"ego"})) == {**none, "vehicles": ["ego"]}
    root = ET.parse(rou).getroot()
    assert [el.get("id") for el in root] == ["car", "f", "other"]
    # the device's vehicles take the option (none), the file's keep what the pass used
    assert [el.get("insertionChecks") for el in root] == [None, "all", "collision"]
    assert "noNamespaceSchemaLocation" in rou.read_text() and "xmlns:xsi" in rou.read_text()
    assert rewrite_demand(rou, drop_flows=True) == {**none, "flows": ["f"]}
    assert [el.get("id") for el in ET.parse(rou).getroot()] == ["car", "other"]


def test_the_variants_copies_of_one_demand_file_are_parsed_once(tmp_path, monkeypatch):
    """Every variant's export rewrites its copy of the same file alike: the content is read once;
    a copy whose content differs is read again."""
    from coster_sumo.exports import demand

    text = ('<routes>\n  <trip id="ego" depart="2" from="a" to="b"/>\n'
            '  <trip id="other" depart="1" from="a" to="b"/>\n</routes>\n')
    reads = []
    real_read = demand._read
    monkeypatch.setattr(demand, "_read", lambda path: reads.append(path) or real_read(path))
    copies = [tmp_path / f"v{i}" / "r.rou.xml" for i in range(3)]
    for c in copies:
        c.parent.mkdir()
        c.write_text(text)
    results = [(demand_ids(c), rewrite_demand(c, checks="all", drop_vehicles=frozenset({"ego"}))) for c in copies]
    assert len(reads) == 2  # once for the ids, once for the rewrite
    assert all(r == results[0] for r in results)
    assert len({c.read_bytes() for c in copies}) == 1 and b'id="ego"' not in copies[2].read_bytes()
    results[0][0]["vehicle"].add("changed by a caller")  # a caller's changes do not reach the memo
    fresh = tmp_path / "fresh.rou.xml"
    fresh.write_text(text)
    assert demand_ids(fresh) == {"vehicle": {"ego", "other"}, "flow": set()} and len(reads) == 2
    edited = tmp_path / "edited.rou.xml"
    edited.write_text(text.replace("other", "third"))
    assert demand_ids(edited)["vehicle"] == {"ego", "third"} and len(reads) == 3


def test_flows_that_begin_after_the_export_ends_leave_it(tmp_path):
    """SUMO ends a flow without ``end`` at the run's end and refuses one that then ends before it
    begins: an export that stops at its contact must not carry flows that begin later (the wheel's
    corridor begins S20_0 at 18 s; its export of target N30.1 ends at 17.9 s)."""
    rou = tmp_path / "r.rou.xml"
    rou.write_text('<routes>\n  <vType id="car"/>\n'
                   '  <flow id="early" type="car" begin="0" period="3" from="W2C" to="C2E"/>\n'
                   '  <flow id="late" type="car" begin="18" period="exp(0.05)" from="W2C" to="C2E"/>\n'
                   '  <flow id="later" type="car" begin="0:01:00" number="3" period="2" from="W2C" to="C2E"/>\n'
                   '</routes>\n')
    assert rewrite_demand(rou, end=17.9)["flows_after_end"] == ["late", "later"]
    assert [el.get("id") for el in ET.parse(rou).getroot()] == ["car", "early"]
    net = REPO / "networks" / "intersection" / "intersection.net.xml"
    proc = subprocess.run([sumo_install.binary("sumo"), "-n", str(net), "-r", str(rou), "--end", "17.9",
                           "--no-step-log", "true"], capture_output=True, text=True, env=sumo_install.subprocess_env(),
                          timeout=60)
    assert proc.returncode == 0, proc.stderr[-500:]


def test_export_config_keeps_the_source_options_but_inputs_outputs_and_gui(tmp_path):
    src = tmp_path / "a.sumocfg"
    src.write_text('<configuration><input><net-file value="x/a.net.xml"/><route-files value="x/r.xml"/></input>'
                   '<output><tripinfo-output value="t.xml"/><human-readable-time value="true"/></output>'
                   '<processing><lateral-resolution value="0.8"/><remote-port value="8813"/></processing>'
                   '<routing><weights.random-factor value="1.2"/></routing><random_number><random value="true"/>'
                   '</random_number><report><xml-validation value="never"/><summary-output value="s.xml"/></report>'
                   '<gui_only><gui-settings-file value="x/settings.xml"/></gui_only></configuration>')
    assert source_options(src) == [("processing", "lateral-resolution", "0.8"),
                                   ("routing", "weights.random-factor", "1.2"), ("report", "xml-validation", "never")]


def test_export_config_takes_the_source_options_by_sumos_own_names(tmp_path):
    # <b> is begin to sumo: kept beside the export's own <begin> it would be set twice, which sumo refuses
    src = tmp_path / "a.sumocfg"
    src.write_text('<c><n value="a.net.xml"/><r value="r.xml"/><b value="10"/><e value="90"/><W value="true"/>'
                   '<srand value="3"/><tripinfo value="t.xml"/><netstate value="d.xml"/><l value="log.txt"/>'
                   '<lateral-resolution value="0.8"/></c>')
    assert source_options(src) == [("source", "begin", "10"), ("source", "end", "90"),
                                   ("source", "no-warnings", "true"), ("source", "seed", "3"),
                                   ("source", "lateral-resolution", "0.8")]


def _sumo_game(name: str) -> Path:
    import sumo

    return Path(sumo.__file__).parent / "tools" / "game" / f"{name}.sumocfg"


def _formats() -> str:
    """Every export format when the optional extra is installed (dev installs it), else SUMO only."""
    import test_export_openscenario as osc_checks

    return "all" if osc_checks.HAS_EXTRA else "sumo"


def _check_openscenario_too(out: Path) -> None:
    """Every variant's .xosc valid with its knots exact and the .xodr lanes on the SUMO lanes."""
    import test_export_openscenario as osc_checks

    if not osc_checks.HAS_EXTRA:
        return
    rows = osc_checks.check_openscenario(out)
    osc_checks.assert_xodr_on_lanes(rows[0]["xodr"], rows[0]["net"])


@pytest.mark.sumo
@pytest.mark.slow
@pytest.mark.parametrize(("config", "target"), [("square", "horiz.1"), ("grid6", "leftRight.1"),
                                                ("corridor", "N30.1")])
def test_wheel_scenario_with_a_flow_member_target_plays_in_plain_sumo(tmp_path, config, target):
    """SUMO's own game scenarios (eclipse-sumo wheel): the target is a flow member, the routes of
    square live in an additional file, grid6's flows depart at random. Every flow becomes the
    vehicles it made, the target leaves them, and the contact happens at t_col in plain sumo.
    corridor's flows S20_0 and N20_0 begin after its export ends: they leave it."""
    cfg = _sumo_game(config)
    if not cfg.is_file():
        pytest.skip(f"{cfg} not in this SUMO build")
    out = tmp_path / "run"
    assert main(["-q", "run", str(cfg), "--target", target, "--planner", "replay", "--samples", "200",
                 "--variants", "2", "--no-render", "--export", _formats(), "-o", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["variants"]
    _check_openscenario_too(out)
    for v in summary["variants"]:
        i = v["variant"]
        export = out / "variants" / str(i) / "export"
        demand = json.loads((export / "variant.json").read_text())["export"]["demand"]
        assert target.rpartition(".")[0] in demand["expanded_flows"] and demand["expanded_vehicles"] > 0
        expanded = ET.parse(export / demand["expanded_file"]).getroot()
        ids = [el.get("id") for el in expanded.iter("vehicle")]
        assert target not in ids and len(ids) == demand["expanded_vehicles"]
        assert all(el.get("insertionChecks") == "all" for el in expanded.iter("vehicle"))
        assert not [el for f in export.glob("*.xml") for el in ET.parse(f).getroot().iter("flow")]
        check_variant(out, i, tmp_path / f"plain{i}.fcd.xml")


@pytest.mark.sumo
def test_demo_variant_plays_in_plain_sumo_and_in_replay(tmp_path):
    """One variant of the shipped demo (weight-free generator: one variant, a few seconds)."""
    out = tmp_path / "run"
    assert main(["-q", "run", str(DEMO), "--planner", "replay", "--init", "random", "--rollout", "cv",
                 "--no-render", "-o", str(out)]) == 0
    export = out / "variants" / "0" / "export"
    names = {p.name for p in export.iterdir()}
    assert {"intersection.sumocfg", "intersection.net.xml", "intersection.rou.xml", "variant.json", FCD_FILE,
            VTYPES_FILE} <= names
    assert "ego" not in {el.get("id") for el in ET.parse(export / "intersection.rou.xml").getroot()}, \
        "the replayed target must leave the route file (SUMO refuses two vehicles with one id)"
    check_variant(out, 0, tmp_path / "plain.fcd.xml")
    check_variant(out, 0, tmp_path / "replay" / "replay.fcd.xml", replay_cli=True)


@pytest.mark.sumo
@pytest.mark.slow
def test_demo_all_variants_play_in_plain_sumo(tmp_path):
    """The demo exactly as shipped (`make demo` without renders): every variant it keeps (5 asked;
    candidates that touch the target or another car early are dropped, 3 are left with the
    weights of c9d4c22)."""
    out = tmp_path / "run"
    assert main(["-q", "run", str(DEMO), "--planner", "replay", "--no-render", "--export", _formats(),
                 "-o", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["num_variants"] == len(summary["variants"]) >= 3
    _check_openscenario_too(out)
    for v in summary["variants"]:
        check_variant(out, v["variant"], tmp_path / f"plain{v['variant']}.fcd.xml")


@pytest.mark.sumo
@pytest.mark.slow
@pytest.mark.realdata
@pytest.mark.skipif(not WOMD_SAMPLES, reason=NO_WOMD_REASON)
@pytest.mark.parametrize("sample", WOMD_SAMPLES, ids=lambda p: p.stem)
def test_womd_scene_variants_play_in_plain_sumo(tmp_path, sample):
    """A converted real WOMD scene: every logged agent replayed from the pass, nothing of the
    staging lane in the output, and every variant's adversary and contact as planned."""
    conv = tmp_path / "conv"
    assert main(["-q", "convert", "-o", str(conv), str(sample)]) == 0
    (cfg,) = sorted(conv.glob("*/*.sumocfg"))
    out = tmp_path / "run"
    assert main(["-q", "run", str(cfg), "--no-render", "-o", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["planner"] == "replay" and summary["variants"]
    for v in summary["variants"]:
        i = v["variant"]
        fcd = tmp_path / f"plain{i}.fcd.xml"
        check_variant(out, i, fcd)
        export = out / "variants" / str(i) / "export"
        assert not (export / "scene.npz").exists(), "a log beside the export would make replay drive it twice"
        # every vehicle SUMO shows is a replayed one, exactly where the FCD file puts it, and only at the
        # steps the pass recorded it, after one step where it enters: its first entry (staging) inserts it
        # on the lane nearest to its first pose, SUMO's insertion (not on the staging lane: issue 46);
        # a parking entry on the staging lane never shows up
        staging = json.loads((export / "variant.json").read_text())["export"]["staging_lane"]
        assert staging
        shown: States = {}
        for ts in ET.parse(export / FCD_FILE).getroot().iter("timestep"):
            for e in ts.iter("vehicle"):
                assert e.get("lane") != staging or e.get("id", "") in shown, "staged on the staging lane"
                if e.get("lane") != staging:
                    shown.setdefault(e.get("id", ""), {})[round(float(ts.get("time", "nan")), 3)] = (
                        float(e.get("x", "nan")), float(e.get("y", "nan")), 0.0, 0.0)
        played = read_fcd(fcd)
        assert set(played) == set(shown)
        for vid, track in shown.items():
            assert set(played[vid]) == set(track), vid
            for t, (x, y, _, _) in sorted(track.items())[1:]:
                px, py, _, _ = played[vid][t]
                assert np.hypot(px - x, py - y) < 0.02, (vid, t)
